"""`--seeds`: several seeds of one config trained as one vmapped program, one run directory each."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from test_skills import tiny
from tiny import TINY1, cli_in_process

from mjx_emp.commands import ResumeExperiment, TrainExperiment
from mjx_emp.run import jobs, store

# Per-epoch figures that depend on wall time, not on what was computed.
TIMING = {"seconds", "env_steps_per_s", "checkpoint_blocked_s"}


def metric_lines(run_dir) -> list[dict]:
    return [json.loads(line) for line in (run_dir / store.METRICS_FILE).read_text().splitlines() if line]


def leaves(value, path: str = "") -> dict[str, object]:
    """A metric line's values by path (nested levels flattened)."""
    if isinstance(value, dict):
        return {k: v for name, item in value.items() if name not in TIMING for k, v in leaves(item, f"{path}.{name}").items()}
    if isinstance(value, list):
        return {k: v for i, item in enumerate(value) for k, v in leaves(item, f"{path}[{i}]").items()}
    return {path: value}


def assert_same_metrics(mine: list[dict], theirs: list[dict]) -> None:
    """Equal epoch by epoch in every computed figure, floats within float tolerance."""
    assert len(mine) == len(theirs)
    flat_mine, flat_theirs = leaves(mine), leaves(theirs)
    assert flat_mine.keys() == flat_theirs.keys()
    for path, value in flat_mine.items():
        if isinstance(value, float) and isinstance(flat_theirs[path], float):
            np.testing.assert_allclose(value, flat_theirs[path], rtol=1e-4, atol=1e-5, err_msg=path)
        else:
            assert value == flat_theirs[path], path


@pytest.mark.parametrize("config", [pytest.param(dataclasses.replace(TINY1, epochs=2), id="he"),
                                    pytest.param(tiny("metra"), id="metra", marks=pytest.mark.slow)])
def test_seeds_in_one_program_match_separate_runs_and_each_resumes_alone(config, tmp_path):
    jobs.train(TrainExperiment(config=config, run_dir=str(tmp_path / "group"), seeds=(4, 9)))
    for seed in (4, 9):
        assert store.read_run_config(tmp_path / f"group-s{seed}").seed == seed
    # the second member against its run alone: a seed's place in the group changes nothing it computes
    jobs.train(TrainExperiment(config=dataclasses.replace(config, seed=9), run_dir=str(tmp_path / "alone-9")))
    assert_same_metrics(metric_lines(tmp_path / "group-s9"), metric_lines(tmp_path / "alone-9"))
    assert leaves(metric_lines(tmp_path / "group-s4")) != leaves(metric_lines(tmp_path / "group-s9"))  # seeds differ
    # a seed's directory is an ordinary run: it resumes on its own and goes on like the lone run
    jobs.resume(ResumeExperiment(resume=str(tmp_path / "group-s9"), epochs=config.epochs + 1))
    jobs.resume(ResumeExperiment(resume=str(tmp_path / "alone-9"), epochs=config.epochs + 1))
    assert_same_metrics(metric_lines(tmp_path / "group-s9"), metric_lines(tmp_path / "alone-9"))


def test_repeated_seeds_are_refused_naming_the_field(tmp_path):
    result = cli_in_process("train", "point-mass-k1", "--seeds", "1", "1", "--run-dir", str(tmp_path / "r"))
    assert result.returncode == 2
    assert "seeds: must be distinct integers >= 0; got [1, 1]" in result.stderr
    assert not (tmp_path / "r-s1").exists()
