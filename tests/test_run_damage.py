"""What a kill, a full or read-only disk, or a reader can do to a run: never lose it, never stall it,
and say so in one line."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import time
from pathlib import Path

import pytest
from tiny import SMALL, TINY1, cli_in_process, mjx_emp

from mjx_emp.commands import ResumeExperiment, TrainExperiment
from mjx_emp.errors import ConfigError, WriteError
from mjx_emp.run import jobs, store


def killed_before_its_first_checkpoint(run_dir: Path, cfg) -> Path:
    """What a SIGKILL during the epoch-0 write leaves: config.json and a half-written checkpoint folder."""
    run_dir.mkdir(parents=True)
    store.write_config(run_dir, cfg)
    (run_dir / store.CHECKPOINT_SUBDIR / "0.orbax-checkpoint-tmp-1700000000").mkdir(parents=True)
    return run_dir


def checkpoint_epochs(run_dir: Path) -> list[int]:
    return sorted(int(p.name) for p in (run_dir / store.CHECKPOINT_SUBDIR).iterdir() if p.name.isdigit())


def test_a_run_killed_before_its_first_checkpoint_resumes_from_its_config(tmp_path, capsys):
    run_dir = killed_before_its_first_checkpoint(tmp_path / "run", dataclasses.replace(TINY1, epochs=1))
    jobs.resume(ResumeExperiment(resume=str(run_dir)))
    assert "stopped before its first checkpoint; starting it over" in capsys.readouterr().out
    assert checkpoint_epochs(run_dir) == [0, 1]
    assert [line["epoch"] for line in store.read_metrics(run_dir)] == [1]
    assert not [p for p in (run_dir / store.CHECKPOINT_SUBDIR).iterdir() if "tmp" in p.name]  # the leftover went


def test_a_run_killed_before_its_first_checkpoint_is_reused_by_train(tmp_path, capsys):
    cfg = dataclasses.replace(TINY1, epochs=1)
    run_dir = killed_before_its_first_checkpoint(tmp_path / "run", cfg)
    jobs.train(TrainExperiment(config=cfg, run_dir=str(run_dir)))
    assert "stopped before its first checkpoint; it is started anew" in capsys.readouterr().out
    assert checkpoint_epochs(run_dir) == [0, 1]
    with pytest.raises(ConfigError, match="already holds a run"):  # now it holds one
        jobs.train(TrainExperiment(config=cfg, run_dir=str(run_dir)))
    # phase 2 aimed at it says what it holds and the command that continues that
    with pytest.raises(ConfigError, match=f"out: '{run_dir}' already holds a run; continue it with "
                                          f"`mjx-emp resume {run_dir}`"):
        store.fresh_run_dir(str(run_dir), "out", "a phase-2 run", "mjx-emp phase2")


def test_a_phase2_directory_without_a_checkpoint_names_the_way_out_and_does_not_block_eval(tmp_path):
    run_dir = tmp_path / "run"
    jobs.train(TrainExperiment(config=dataclasses.replace(TINY1, epochs=1), run_dir=str(run_dir)))
    phase2_dir = run_dir / store.PHASE2_SUBDIR
    phase2_dir.mkdir()
    (phase2_dir / store.CONFIG_FILE).write_text(json.dumps({"epochs": 2}))
    (phase2_dir / store.SKILLS_FILE).write_text((run_dir / store.CONFIG_FILE).read_text())
    with pytest.raises(ConfigError, match=f"start it again with `mjx-emp phase2 PHASE1_RUN_DIR --out {phase2_dir}`"):
        jobs.resume(ResumeExperiment(resume=str(phase2_dir)))
    result = cli_in_process("eval", str(run_dir), "--episodes", "8", "--out", str(tmp_path / "eval.json"))
    assert result.returncode == 0, result.stderr
    assert f"{phase2_dir} is unusable, its phase 2 is left out" in result.stderr
    assert "phase 2: no run has a phase-2 directory" in result.stdout
    assert "1 run(s)\n" in result.stdout and " ± " not in result.stdout  # one run: values, no spread


def test_the_same_run_twice_is_not_two_seeds(tmp_path):
    result = cli_in_process("eval", str(tmp_path), f"{tmp_path}/", "--episodes", "8")
    assert result.returncode == 2
    assert "run_dirs: each run counts once" in result.stderr


@pytest.fixture
def small_filesystem(tmp_path):
    """A 64 KB tmpfs (skipped where one cannot be mounted); unmounted afterwards."""
    mount = tmp_path / "small"
    mount.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    yield mount
    subprocess.run(["umount", str(mount)], capture_output=True)


def test_a_write_on_a_full_disk_names_the_file_and_the_newest_intact_checkpoint(small_filesystem):
    run_dir = small_filesystem / "run"
    (run_dir / store.CHECKPOINT_SUBDIR / "3").mkdir(parents=True)
    (run_dir / store.CHECKPOINT_SUBDIR / "4.orbax-checkpoint-tmp-1").mkdir()
    store.write_atomically(run_dir / store.CONFIG_FILE, "{}")
    (small_filesystem / "filler").write_bytes(b"\0" * 60_000)  # what is left is less than the next write
    with pytest.raises(WriteError) as err:
        store.write_atomically(run_dir / store.CONFIG_FILE, "x" * 100_000, run_dir)
    assert str(err.value) == (f"cannot write {run_dir / store.CONFIG_FILE}: No space left on device; the newest "
                              f"intact checkpoint is epoch 3 in {run_dir / store.CHECKPOINT_SUBDIR}")
    assert err.value.exit_code == 1
    assert (run_dir / store.CONFIG_FILE).read_text() == "{}"  # the old file stands, no temporary left beside it
    assert sorted(p.name for p in run_dir.iterdir()) == [store.CHECKPOINT_SUBDIR, store.CONFIG_FILE]


def test_eval_onto_a_read_only_disk_exits_2_in_one_line(tmp_path, small_filesystem):
    run_dir = tmp_path / "run"
    jobs.train(TrainExperiment(config=dataclasses.replace(TINY1, epochs=1), run_dir=str(run_dir)))
    subprocess.run(["mount", "-o", "remount,ro", str(small_filesystem)], check=True)
    out = small_filesystem / "eval.json"
    result = cli_in_process("eval", str(run_dir), "--episodes", "8", "--out", str(out))
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [f"mjx-emp: write failed: cannot write {out}: Read-only file system"]


def test_readers_never_disturb_a_run_being_trained(tmp_path):
    """A trainer that keeps one checkpoint writes one every epoch, removing the one before, while
    this process loads the run read-only (as eval, plot, render and phase 2 do) as often as it
    can: the trainer ends cleanly with every metrics line, and every load saw a complete
    checkpoint (a checkpoint removed under a load is not reported damaged: the load moves on)."""
    run_dir = tmp_path / "run"
    trainer = subprocess.Popen(mjx_emp("train", *SMALL, "--epochs", "6", "--keep-checkpoints", "1", "--run-dir",
                                       str(run_dir)),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    loads = []
    try:
        while trainer.poll() is None:
            if store.newest_checkpoint_on_disk(run_dir) is not None:
                _, epoch, _ = jobs.load_run(run_dir)
                loads.append(epoch)
            else:
                time.sleep(0.2)
        _, err = trainer.communicate(timeout=600)
    finally:
        trainer.kill()
    assert trainer.returncode == 0, err[-3000:]
    assert len(loads) >= 2 and loads == sorted(loads), loads  # it read while the trainer wrote, epochs in order
    assert checkpoint_epochs(run_dir)[-1] == 6
    assert [line["epoch"] for line in store.read_metrics(run_dir)] == [1, 2, 3, 4, 5, 6]


def test_a_hand_edited_config_of_the_wrong_type_is_refused_naming_the_field(tmp_path):
    store.write_config(tmp_path, TINY1)
    values = json.loads((tmp_path / store.CONFIG_FILE).read_text())
    for field, value, message in (("epochs", 2.5, "epochs: must be int; got 2.5"),
                                  ("n", ["three", 2], "n: must be tuple[int, ...]; got ['three', 2]"),
                                  ("env", None, "env: must be str; got None")):
        (tmp_path / store.CONFIG_FILE).write_text(json.dumps({**values, field: value}))
        with pytest.raises(ConfigError) as err:
            store.read_run_config(tmp_path)
        assert f"is not a valid run config ({message})" in str(err.value)


def test_render_with_an_unknown_gl_backend_or_a_non_finite_fps_says_so_in_one_line(tmp_path):
    import os

    bad_gl = subprocess.run(mjx_emp("render", str(tmp_path)), capture_output=True, text=True, timeout=300,
                            env={**os.environ, "MUJOCO_GL": "nonsense"})
    assert bad_gl.returncode == 3
    assert bad_gl.stderr.strip().splitlines() == [
        "mjx-emp: cannot render: MUJOCO_GL='nonsense' is not a backend MuJoCo can render with; allowed values: "
        "['egl', 'osmesa', 'glx', 'glfw']"]
    bad_fps = cli_in_process("render", str(tmp_path), "--fps", "inf")
    assert bad_fps.returncode == 2
    assert bad_fps.stderr.strip().splitlines() == ["mjx-emp: invalid configuration: fps: must be a finite number > 0; "
                                                   "got inf"]


def test_plot_of_a_run_with_no_finished_epoch_says_so(tmp_path):
    store.write_config(tmp_path, TINY1)
    (tmp_path / store.METRICS_FILE).write_text("")
    result = cli_in_process("plot", str(tmp_path))
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [f"mjx-emp: invalid configuration: run_dir: '{tmp_path}' has no "
                                                  f"finished epoch to plot; plot it once an epoch has ended"]


def test_the_progress_bar_fits_80_columns_and_wraps_its_summary_uncut():
    import io

    from rich.console import Console

    from mjx_emp.run.loop import progress_reporter

    screen = io.StringIO()
    console = Console(file=screen, width=80, force_terminal=True, color_system=None)
    summary = "2.02e+06 env steps  1.97e+03 steps/s  L0 volume 44.4 success 0.77  L1 volume 912 success 0.85"
    with progress_reporter(300, 0, lambda metrics: summary, console=console) as report:
        report({"epoch": 12})
    lines = [line for line in screen.getvalue().replace("\r", "\n").splitlines() if line.strip()]
    text = "".join(line.split("\x1b")[0] for line in lines)  # the drawn lines, without cursor controls
    assert max(len(line.split("\x1b")[0]) for line in lines) <= 80
    assert "…" not in text and "success 0.85" in text.replace("\n", "")


def test_the_warp_backend_is_refused_naming_the_field_where_it_cannot_run(tmp_path):
    import jax

    if jax.default_backend() == "gpu":
        pytest.skip("a GPU: warp may run here")
    result = cli_in_process("train", "point-mass-k1", "--impl", "warp", "--run-dir", str(tmp_path / "r"))
    assert result.returncode == 2
    assert "invalid configuration: impl: warp" in result.stderr and "allowed here: jax" in result.stderr
    assert not (tmp_path / "r").exists()  # refused before the run directory is made
    unknown = cli_in_process("train", "point-mass-k1", "--impl", "cuda", "--run-dir", str(tmp_path / "r"))
    assert unknown.returncode == 2 and "impl: 'cuda' is unknown; allowed values: ['jax', 'warp']" in unknown.stderr
