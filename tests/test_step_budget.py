"""`--max-env-steps`: a run stops at the end of the first epoch that reaches its step budget,
resumes under a new budget (or none), and its budget never changes what an epoch computes."""

from __future__ import annotations

import dataclasses
import json

import pytest
from tiny import TINY1, cli_in_process

from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.checks import compile_identity
from mjx_emp.commands import ResumeExperiment, TrainExperiment, check_resume
from mjx_emp.errors import ConfigError
from mjx_emp.phase2.presets import phase2_preset_for
from mjx_emp.run import jobs, store


def steps_per_line(run_dir) -> list[float]:
    lines = (run_dir / store.METRICS_FILE).read_text().splitlines()
    return [json.loads(line)["env_steps"] for line in lines if line]


def test_a_budget_stops_training_at_the_first_epoch_that_reaches_it_and_a_resume_can_move_it(tmp_path):
    run_dir = tmp_path / "run"
    jobs.train(TrainExperiment(config=dataclasses.replace(TINY1, epochs=4, max_env_steps=1), run_dir=str(run_dir)))
    [first] = steps_per_line(run_dir)  # any epoch spends a budget of one step
    assert store.read_run_config(run_dir).max_env_steps == 1

    jobs.resume(ResumeExperiment(resume=str(run_dir)))  # the budget is spent: nothing more to train
    assert steps_per_line(run_dir) == [first]

    jobs.resume(ResumeExperiment(resume=str(run_dir), max_env_steps=int(first) + 1))
    steps = steps_per_line(run_dir)
    assert len(steps) == 2 and steps[0] < first + 1 <= steps[1]  # stops once the budget is reached, not before

    jobs.resume(ResumeExperiment(resume=str(run_dir), max_env_steps=0))  # 0 lifts the budget: on to `epochs`
    assert len(steps_per_line(run_dir)) == 4
    assert store.read_run_config(run_dir).max_env_steps is None


def test_seeds_in_one_program_stop_once_every_seed_has_spent_the_budget(tmp_path):
    config = dataclasses.replace(TINY1, epochs=3, max_env_steps=1)
    jobs.train(TrainExperiment(config=config, run_dir=str(tmp_path / "group"), seeds=(4, 9)))
    for seed in (4, 9):
        assert len(steps_per_line(tmp_path / f"group-s{seed}")) == 1


def test_a_budget_is_not_part_of_what_compiles_or_of_which_preset_a_run_belongs_to():
    assert compile_identity(dataclasses.replace(TINY1, max_env_steps=10)) == compile_identity(TINY1)
    budgeted = dataclasses.replace(PRESETS["ant-field-k1-cpu"][1], seed=3, epochs=400, max_env_steps=960_000)
    assert phase2_preset_for(budgeted) == "reach-ant-field-cpu"


def test_a_budget_below_one_step_is_refused_naming_the_field(tmp_path):
    result = cli_in_process("train", "point-mass-k1", "--max-env-steps", "0", "--run-dir", str(tmp_path / "r"))
    assert result.returncode == 2
    assert "max_env_steps: must be >= 1; got 0" in result.stderr
    assert not (tmp_path / "r").exists()
    with pytest.raises(ConfigError, match="max_env_steps: must be >= 1, or 0 to lift the run's budget; got -5"):
        check_resume(ResumeExperiment(resume=str(tmp_path / "r"), max_env_steps=-5))
