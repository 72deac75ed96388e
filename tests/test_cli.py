"""``mjx-emp`` command line: bad input exits 2 naming the field; the main job runs.

The commands run in this process through the command line's entry point (``tiny.cli_in_process``); the
first test runs bad input and the main job as processes of their own, as a user's shell does."""

import json
import os
import subprocess
import sys

import pytest
from tiny import cli_in_process, run_cli


def test_a_process_exits_2_with_one_line_naming_the_field_and_0_after_the_main_job():
    refused = run_cli("train", "point-mass-k1", "--eps", "0")
    assert refused.returncode == 2 and refused.stdout == ""
    assert refused.stderr == "mjx-emp: invalid configuration: eps: every entry must be > 0; got (0.0,)\n"
    typo = run_cli("trian")
    assert typo.returncode == 2 and "train" in typo.stderr
    done = run_cli("rollout", "--n", "5", "--eps", "0.3", "--batch-size", "8", "--steps", "10", "--calls", "1",
                   "--hidden", "16")
    assert done.returncode == 0 and json.loads(done.stdout)["primitive_steps"] == 8 * 10, done.stderr


@pytest.mark.parametrize(
    "args, message",
    [
        # tyro's own errors (in a box): the flag and the allowed choices
        (["rollout", "--env", "pointmass"], "invalid choice 'pointmass' for argument '--env'. Expected one of"),
        (["train", "--resume", "/nonexistent/mjx-emp-run", "--seed", "3"], "--seed (applied to mjx-emp resume)"),
        # ours: the field, the rule and the value given
        (["rollout", "--n", "20", "10", "--eps", "0.5"],
         "invalid configuration: n and eps: need one entry per level (k=2); got n=(20, 10), eps=(0.5,)"),
        (["rollout", "--n", "0", "--eps", "0.5"], "invalid configuration: n: every entry must be an integer >= 1; got (0,)"),
        (["rollout", "--n", "20", "--eps", "-1"], "invalid configuration: eps: every entry must be > 0; got (-1.0,)"),
        (["rollout", "--n", "20", "10", "10", "--eps", "1", "1", "1", "--subgoal-half-width", "2"],
         "invalid configuration: subgoal_half_width: needs k-1=2 positive entries; got (2.0,)"),
        (["rollout", "--batch-size", "0"], "invalid configuration: batch_size: must be >= 1; got 0"),
        (["train", "point-mass-k1", "--sigma-gc", "0.4", "0.8"],
         "invalid configuration: sigma_gc: need one entry per level (k=1 from n); got (0.4, 0.8)"),
        (["train", "point-mass-k2", "--n", "10"],
         "invalid configuration: n and eps: need one entry per level (k=1); got n=(10,), eps=(0.3, 0.6)"),
        (["train", "point-mass-k1", "--eps", "0"], "invalid configuration: eps: every entry must be > 0; got (0.0,)"),
        (["train", "point-mass-k1", "--sigma-gs", "-1"],
         "invalid configuration: sigma_gs: every entry must be > 0; got (-1.0,)"),
        (["train", "point-mass-k1", "--env", "maze"],
         "invalid configuration: env: 'maze' is unknown; allowed values: ['ant_cage', 'ant_field', "
         "'half_cheetah_cage', 'half_cheetah_field', 'point_mass']"),
        (["train", "point-mass-k1", "--run-dir", "/proc/mjx-emp-cannot-write"],
         "invalid configuration: run_dir: cannot write to '/proc/mjx-emp-cannot-write'"),
        (["train", "point-mass-k1", "--n"], "invalid configuration: n: give at least one level (k >= 1), e.g. --n 20 10"),
        (["train", "point-mass-k1", "--keep-checkpoints", "0"],
         "invalid configuration: keep_checkpoints: must be >= 1; got 0"),
        (["train", "--resume", "/nonexistent/mjx-emp-run"],
         "invalid configuration: resume: '/nonexistent/mjx-emp-run' has no config.json; is it a run directory?"),
        (["render", "/nonexistent/mjx-emp-run", "--steps", "0"], "invalid configuration: steps: must be in [1, 100000]; got 0"),
        (["render", "/nonexistent/mjx-emp-run"],
         "invalid configuration: run_dir: '/nonexistent/mjx-emp-run' has no config.json; is it a run directory?"),
        (["train", "point-mass-k1", "--num-devices", "-1"],
         "invalid configuration: num_devices: must be >= 0 (0: every local device); got -1"),
        (["resume", "/nonexistent/mjx-emp-run", "--num-devices", "-2"], "num_devices: must be >= 0"),
        (["resume", "/nonexistent/mjx-emp-run", "--epochs", "0"], "epochs: must be >= 1; got 0"),
        (["train", "ant-feld-k1-cpu"], "preset: 'ant-feld-k1-cpu' is unknown (mjx-emp train PRESET); did you mean "
                                       "ant-field-k1-cpu,"),
        (["phase2", "reach-point-mas", "runs/x"], "preset: 'reach-point-mas' is unknown (mjx-emp phase2 PRESET "
                                                  "RUN_DIR); did you mean reach-point-mass"),
        (["eval", "/nonexistent/mjx-emp-run", "--episodes", "0"],
         "invalid configuration: episodes: must be in [1, 10000000]; got 0"),
        (["eval", "/nonexistent/mjx-emp-run"],
         "invalid configuration: run_dirs: '/nonexistent/mjx-emp-run' has no config.json; is it a run directory?"),
    ],
)
def test_bad_config_exits_2_naming_the_field_and_the_rule(args, message):
    result = cli_in_process(*args)
    assert result.returncode == 2, result.stderr
    assert message in result.stderr, result.stderr


@pytest.mark.parametrize(
    "args, message",
    [
        (["train", "point-mass-k1", "--sigma-gs", "inf"], "sigma_gs: must be a finite number; got (inf,)"),
        (["train", "point-mass-k1", "--tau", "nan"], "tau: must be in (0, 1]; got nan"),
        (["train", "point-mass-k1", "--replay-capacity", "1", "--batch-size", "128"],
         "replay_capacity: must hold at least a minibatch (batch_size) (128 rows); got 1"),
        (["train", "point-mass-k1", "--start-capacity", "8"],
         "start_capacity: must hold at least one start state per environment (num_envs) (64 rows); got 8"),
        (["train", "metra-point-mass", "--batch-size", "16", "--replay-capacity", "100"],
         "replay_capacity: must hold at least one collection (num_envs x collect_steps) (160 rows); got 100"),
        (["train", "point-mass-k1", "--shards", "3"], "num_envs: must be a multiple of shards (3); got 64"),
        (["train", "point-mass-k1", "--seeds", "0", "1", "--shards", "2"],
         "seeds: a seed group trains on one device, unsplit; got shards=2"),
    ],
)
def test_bad_values_exit_2_with_the_whole_reason(args, message):
    result = cli_in_process(*args)
    assert result.returncode == 2, result.stderr
    assert message in result.stderr, result.stderr


COMMAND_NAMES = ("train", "resume", "phase2", "export", "presets", "eval", "plot", "render", "rollout")


@pytest.mark.parametrize("args", [["--help"], ["trian"]])
def test_help_and_a_typo_list_every_command(args):
    result = cli_in_process(*args)
    assert result.returncode == (0 if args == ["--help"] else 2)
    listed = (result.stdout + result.stderr).replace("\n", " ")
    for name in COMMAND_NAMES:
        assert name in listed, name


@pytest.mark.parametrize("args", [["eval", "--help"], ["plot", "--help"], ["render", "--help"], ["resume", "--help"],
                                  ["phase2", "reach-point-mass", "--help"]])
def test_run_directories_are_named_run_dir_in_help(args):
    result = cli_in_process(*args)
    assert result.returncode == 0, result.stderr
    usage = result.stdout.split("\n\n")[0]
    positional = [token for token in usage.split()[2:] if not token.startswith(("[", "-")) and not token.endswith("]")]
    assert positional and all(token == "RUN_DIR" for token in positional[-1:]), usage


def test_resume_forms_are_one_command(tmp_path):
    from mjx_emp.cli import canonical_args

    assert canonical_args(["train", "--resume", "r", "--epochs", "3"]) == ["resume", "r", "--epochs", "3"]
    assert canonical_args(["phase2", "--epochs", "3", "--resume=r/phase2"]) == ["resume", "r/phase2", "--epochs", "3",
                                                                                 "--phase2"]
    assert canonical_args(["train", "point-mass-k1", "--epochs", "3"]) == ["train", "point-mass-k1", "--epochs", "3"]


def test_phase2_of_a_run_directory_is_its_own_task_with_only_the_named_fields_replaced(tmp_path):
    """`phase2 RUN_DIR` reads no file to parse: it is the `own` task, resolved where the run is read."""
    import dataclasses

    from mjx_emp.algos.registry import all_presets
    from mjx_emp.cli import canonical_args, given_fields, parse
    from mjx_emp.phase2.config import Phase2Config
    from mjx_emp.phase2.presets import PHASE2_PRESETS, phase2_preset_for
    from mjx_emp.run.jobs import own_task

    missing = str(tmp_path / "no-run-here")
    assert canonical_args(["phase2", missing, "--epochs", "3"]) == ["phase2", "own", missing, "--epochs", "3"]
    assert given_fields(["--epochs", "3", "--flip-cost=2.5", "--no-learn-from-resets", "--out", "x"], Phase2Config) \
        == ["epochs", "flip_cost", "learn_from_resets"]
    _, exp = parse(canonical_args(["phase2", missing, "--epochs", "3"]))
    assert exp.own_task == ("epochs",)
    skills = all_presets()["point-mass-k1"][1]
    task = phase2_preset_for(skills)
    asked = {"preset": "own", "overrides": {"epochs": 3}, "command": f"mjx-emp phase2 own {missing} --epochs 3"}
    resolved, record = own_task(exp, skills, asked)
    assert resolved.config == dataclasses.replace(PHASE2_PRESETS[task][2], epochs=3) and resolved.own_task is None
    assert record == {"preset": task, "overrides": {"epochs": 3}, "command": f"mjx-emp phase2 {task} {missing} --epochs 3"}


def test_help_explains_fields():
    result = cli_in_process("rollout", "--help")
    assert result.returncode == 0
    assert "Max actions per level" in result.stdout
    result = cli_in_process("train", "point-mass-k2", "--help")
    assert result.returncode == 0
    for text in ("Maximum number of actions per level", "--keep-checkpoints", "--run-dir", "Polyak"):
        assert text in result.stdout


def test_train_refuses_a_run_dir_that_holds_a_run(tmp_path):
    (tmp_path / "metrics.jsonl").write_text('{"epoch": 1}\n')
    result = cli_in_process("train", "point-mass-k1", "--run-dir", str(tmp_path))
    assert result.returncode == 2
    assert f"run_dir: '{tmp_path}' already holds a run; continue it with `mjx-emp train --resume {tmp_path}`" in result.stderr


def test_rollout_main_job_reports_statistics():
    result = cli_in_process("rollout", "--n", "5", "3", "--eps", "0.3", "0.6", "--batch-size", "16",
                 "--steps", "30", "--calls", "1", "--hidden", "32", "32")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["k"] == 2 and report["primitive_steps"] == 16 * 30
    assert report["useful_step_fraction"] >= 0.95
    assert len(report["goals_ended_per_level"]) == 2
    assert report["goals_ended_per_level"][0] >= 16 * 30 // 5  # level 0 ends a goal at least every n actions


def test_unknown_preset_exits_2_listing_presets():
    result = cli_in_process("train", "point-mass-k9")
    assert result.returncode == 2
    assert "point-mass-k1" in result.stderr


def test_presets_lists_every_table_1_row():
    result = cli_in_process("presets")
    assert result.returncode == 0
    for name in ("point-mass-k1", "ant-field-k1-paper-small", "ant-field-k3-paper-xl",
                 "half-cheetah-field-k2-paper-big", "ant-cage-k2-paper", "half-cheetah-cage-k1-paper"):
        assert name in result.stdout


def test_train_writes_config_and_one_metrics_line_per_epoch(tmp_path):
    run_dir = tmp_path / "run"
    result = cli_in_process("train", "point-mass-k2", "--epochs", "2", "--n", "3", "2", "--num-envs", "8",
                 "--hidden", "16", "--gc-iterations", "1", "--gc-grad-steps", "2", "--batch-size", "16",
                 "--replay-capacity", "256", "--start-chain", "2", "--run-dir", str(run_dir))
    assert result.returncode == 0, result.stderr
    config = json.loads((run_dir / "config.json").read_text())
    assert config["n"] == [3, 2] and config["epochs"] == 2
    lines = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [m["epoch"] for m in lines] == [1, 2]
    for m in lines:
        assert len(m["levels"]) == 2 and m["env_steps_per_s"] > 0
        assert all(level["volume"] > 0 for level in m["levels"])
    assert "epoch    2" in result.stdout


@pytest.mark.parametrize("flags, cached", [((), True), (("--no-compile-cache",), False)])
def test_compiled_programs_are_cached_under_the_users_cache_dir_unless_turned_off(tmp_path, flags, cached):
    # Store every program, however fast it compiles: what is checked is where the cache goes, and on a fast
    # machine this small rollout compiles in under the default one-second threshold.
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)  # the test session's own cache
    result = subprocess.run([sys.executable, "-m", "mjx_emp.cli", "rollout", "--n", "10", "--eps", "0.3", "--steps",
                             "20", "--batch-size", "8", "--calls", "1", *flags],
                            env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    stored = list((tmp_path / "mjx-emp" / "xla").glob("*")) if (tmp_path / "mjx-emp" / "xla").exists() else []
    assert bool(stored) == cached, stored


@pytest.mark.parametrize("args", [
    ["--replay-capacity", "2000000000"],
    ["--batch-size", "20000000", "--replay-capacity", "20000000", "--gs-replay-capacity", "20000000"],
])
def test_a_run_that_cannot_fit_in_memory_is_refused_before_anything_is_allocated(tmp_path, args):
    result = cli_in_process("train", "point-mass-k1", *args, "--run-dir", str(tmp_path / "run"))
    assert result.returncode == 2, result.stderr
    assert "invalid configuration: memory: this run needs about" in result.stderr
    assert "lower one of replay_capacity, num_envs, batch_size" in result.stderr
    assert not (tmp_path / "run").exists()  # refused before the run directory was made


def test_a_diverging_run_exits_1_through_the_cli_keeping_the_last_good_checkpoint(tmp_path):
    run_dir = tmp_path / "run"
    result = cli_in_process("train", "point-mass-k1", "--num-envs", "8", "--hidden", "16", "--batch-size", "16",
                 "--gc-iterations", "2", "--gc-grad-steps", "3", "--replay-capacity", "2048",
                 "--sigma-gc", "1e-30", "--epochs", "3", "--run-dir", str(run_dir))  # rewards overflow to -inf
    assert result.returncode == 1, result.stderr
    assert ("training diverged: epoch 1: level 0 goal-conditioned critic loss is nan. Stopped without saving this "
            f"epoch; the last good checkpoint is epoch 0 in {run_dir / 'checkpoints'}") in result.stderr
    assert sorted(p.name for p in (run_dir / "checkpoints").iterdir()) == ["0"]
    assert (run_dir / "metrics.jsonl").read_text() == ""


def test_ctrl_c_outside_training_exits_130_with_one_line(capsys):
    """Ctrl-C where no checkpoint is kept (an eval, a report) ends in one line and 130, not a
    traceback; training's own stop, which names its checkpoint, is test_checkpoint's."""
    from mjx_emp.cli import exit_codes

    with pytest.raises(SystemExit) as stop, exit_codes():
        raise KeyboardInterrupt
    assert stop.value.code == 130
    assert capsys.readouterr().err == "mjx-emp: stopped by SIGINT before it finished; run it again for its outputs\n"
