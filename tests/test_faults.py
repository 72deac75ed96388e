"""Faults met as trusted tools meet them: nothing but a regular file is ever written over, a path
that cannot be written is refused before the work, a request a run cannot honour is refused
before the run is touched, and a wrong place or a damaged file is one line, never a traceback."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest
from tiny import TINY1, cli_in_process, run_cli

from mjx_emp.commands import ResumeExperiment, TrainExperiment
from mjx_emp.errors import ConfigError
from mjx_emp.run import jobs, store


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A one-epoch run trained in-process (the tests only read it or are refused before writing)."""
    path = tmp_path_factory.mktemp("faults") / "run"
    jobs.train(TrainExperiment(config=dataclasses.replace(TINY1, epochs=1), run_dir=str(path)))
    return path


def special_files(folder: Path) -> dict[str, Path]:
    """A FIFO, a symlink to it and, where this process may make one, a character device that is
    the machine's /dev/null (major 1, minor 3): what a write must never replace."""
    made = {"fifo": folder / "fifo", "symlink to a fifo": folder / "link"}
    os.mkfifo(made["fifo"])
    os.symlink(made["fifo"], made["symlink to a fifo"])
    try:
        os.mknod(folder / "fakenull", stat.S_IFCHR | 0o666, os.makedev(1, 3))
        made["character device"] = folder / "fakenull"
    except PermissionError:
        pass
    return made


def one_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in stderr, stderr[-2000:]
    return lines[0]


def each_command(commands) -> list:
    """(command, result) of each command line: the first run as a process of its own (what a
    user's shell starts), the others in this process through the same entry point (``tiny.cli_in_process``),
    but for render, which chooses OpenGL before MuJoCo loads and so needs a process of its own."""
    return [(command, (run_cli if i == 0 or command[0] == "render" else cli_in_process)(*command))
            for i, command in enumerate(commands)]


def test_no_write_replaces_what_is_not_a_regular_file(tmp_path):
    for kind, path in special_files(tmp_path).items():
        before = os.lstat(path)
        with pytest.raises(ConfigError, match="not a regular file"):
            store.replace_file(path, "text", chosen=True)
        after = os.lstat(path)
        assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino), kind
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left behind


def test_a_symlink_to_a_file_is_written_through_and_stays_a_link(tmp_path):
    target = tmp_path / "target.json"
    target.write_text("old")
    os.symlink(target, tmp_path / "link.json")
    store.replace_file(tmp_path / "link.json", "new", chosen=True)
    assert (tmp_path / "link.json").is_symlink() and target.read_text() == "new"


@pytest.mark.parametrize("where, reason", [("missing/x.json", "does not exist"), ("afile/x.json", "Not a directory"),
                                           ("loop", "Too many levels of symbolic links")])
def test_a_path_that_cannot_be_written_is_refused_naming_it(tmp_path, where, reason):
    (tmp_path / "afile").write_text("")
    os.symlink(tmp_path / "loop", tmp_path / "loop")
    with pytest.raises(ConfigError, match=reason):
        store.output_target(tmp_path / where, "out")


def test_every_output_path_of_the_cli_refuses_a_special_file_in_one_line(run_dir, tmp_path):
    """eval --out, render --out, report --into and --figure, sweep --results: one line, exit 2,
    the special file untouched, and nothing evaluated or rendered first."""
    spec = tmp_path / "s.toml"
    spec.write_text('[[row]]\nname = "a"\npreset = "point-mass-k1"\nseeds = [0]\n')
    for kind, path in special_files(tmp_path).items():
        video = tmp_path / f"{path.name}.mp4"  # a video needs its suffix: a link to the special file
        os.symlink(path, video)
        commands = [("eval", str(run_dir), "--out", str(path)),
                    ("render", str(run_dir), "--out", str(video)),
                    ("report", str(spec), "--into", str(path), "--results", str(run_dir / "none.jsonl")),
                    ("report", str(spec), "--figure", str(path), "--results", str(run_dir / "none.jsonl")),
                    ("sweep", str(spec), "--results", str(path), "--runs", str(tmp_path / "runs"))]
        for command, result in each_command(commands):
            assert result.returncode == 2, (kind, command, result.stderr[-1500:])
            assert "not a regular file" in one_line(result.stderr), (kind, command)
            assert not (tmp_path / "runs").exists()


def test_eval_into_a_missing_folder_is_refused_before_it_evaluates(run_dir, tmp_path):
    result = run_cli("eval", str(run_dir), "--out", str(tmp_path / "nope" / "eval.json"))
    assert result.returncode == 2 and "does not exist" in one_line(result.stderr)
    assert "evaluating" not in result.stdout


def test_a_resume_to_a_budget_already_spent_is_refused_before_anything_is_rewritten(run_dir, tmp_path):
    config = (run_dir / store.CONFIG_FILE).read_text()
    steps = store.read_metrics(run_dir)[-1]["env_steps"]
    with pytest.raises(ConfigError, match=f"max_env_steps: .* is at {int(steps)} env steps"):
        jobs.resume(ResumeExperiment(resume=str(run_dir), max_env_steps=int(steps) // 2, epochs=5))
    assert (run_dir / store.CONFIG_FILE).read_text() == config


def test_phase2_resume_of_a_run_without_phase2_never_trains_phase1(run_dir):
    epochs = [line["epoch"] for line in store.read_metrics(run_dir)]
    result = run_cli("phase2", "--resume", str(run_dir), "--epochs", "3")
    assert result.returncode == 2 and "holds no phase 2 to continue" in one_line(result.stderr)
    assert [line["epoch"] for line in store.read_metrics(run_dir)] == epochs


@pytest.mark.parametrize("damage", ["a file", "a JSON string", "a JSON list", "a symlink loop"])
def test_a_wrong_place_or_a_damaged_config_is_one_line_for_every_reader(tmp_path, damage):
    target = tmp_path / "run"
    if damage == "a file":
        target.write_text("not a run")
    else:
        target.mkdir()
        config = target / store.CONFIG_FILE
        if damage == "a symlink loop":
            os.symlink(config, config)
        else:
            config.write_text(json.dumps("point_mass" if damage == "a JSON string" else [1, 2]))
    for command, result in each_command((("eval", str(target)), ("export", str(target), "--out", str(tmp_path / "x")),
                                         ("render", str(target)), ("phase2", "reach-point-mass", str(target)),
                                         ("resume", str(target)), ("plot", str(target)))):
        assert result.returncode == 2, (damage, command, result.stderr[-1500:])
        one_line(result.stderr)


def test_a_seed_of_a_group_resumed_alone_is_told_and_the_group_resumes_as_one(tmp_path, capsys):
    cfg = dataclasses.replace(TINY1, epochs=1)
    jobs.train(TrainExperiment(config=cfg, run_dir=str(tmp_path / "g"), seeds=(0, 1)))
    jobs.resume(ResumeExperiment(resume=str(tmp_path / "g-s0"), epochs=2))
    assert "trained in one program with 1 other seed(s)" in capsys.readouterr().err
    jobs.resume(ResumeExperiment(resume=str(tmp_path / "g-s1"), epochs=2, group=True))
    assert "as one program" in capsys.readouterr().out
    assert [line["epoch"] for line in store.read_metrics(tmp_path / "g-s1")] == [1, 2]


@pytest.fixture
def tmpfs(tmp_path):
    """Mount a small tmpfs of the size asked for (skipped where this machine cannot mount one);
    unmounted afterwards."""
    mounts = []

    def mount(size: str) -> Path:
        point = tmp_path / f"tmpfs-{len(mounts)}"
        point.mkdir()
        if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(point)],
                          capture_output=True).returncode:
            pytest.skip("cannot mount a tmpfs here (needs root or a user namespace)")
        mounts.append(point)
        return point

    yield mount
    for point in mounts:
        subprocess.run(["umount", "-l", str(point)], capture_output=True)


FULL_DISK_RUN = ["point-mass-k1", "--num-envs", "8", "--hidden", "32", "32", "--batch-size", "32",
                 "--gc-iterations", "2", "--gc-grad-steps", "20", "--replay-capacity", "30000", "--start-chain", "2"]


def test_every_command_on_a_full_disk_says_so_in_one_line_and_loses_nothing(tmpfs, run_dir):
    """A run trained until its disk fills, then every command that writes, on that full disk:
    each exits non-zero with one line (no orbax thread tracebacks, no asyncio noise), and the
    newest checkpoint the message names still restores."""
    disk = tmpfs("400k")
    full = disk / "run"
    trained = run_cli("train", *FULL_DISK_RUN, "--epochs", "50", "--run-dir", str(full))
    line = one_line(trained.stderr)
    assert trained.returncode == 1 and "No space left on device" in line and "newest complete checkpoint" in line
    newest = jobs.load_run(full)[1]  # the newest checkpoint left restores
    for command, result in each_command((("resume", str(full), "--epochs", "60"), ("phase2", str(full)),
                                         ("export", str(full), "--out", str(disk / "export")),
                                         ("eval", str(run_dir), "--out", str(disk / "eval.json")),
                                         ("render", str(run_dir), "--steps", "5", "--out", str(disk / "v.gif")))):
        assert result.returncode in (1, 2, 3), (command, result.stderr[-2000:])
        one_line(result.stderr)
    assert jobs.load_run(full)[1] == newest  # nothing the commands did cost the run its checkpoint


def test_every_command_on_a_read_only_disk_says_so_in_one_line(tmpfs, run_dir):
    disk = tmpfs("8m")
    copy = disk / "run"
    shutil.copytree(run_dir, copy, ignore=shutil.ignore_patterns(".lock"))
    subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
    for command, result in each_command((("resume", str(copy), "--epochs", "3"), ("phase2", str(copy)),
                                         ("eval", str(copy)), ("export", str(copy), "--out", str(disk / "export")),
                                         ("render", str(copy), "--steps", "5"), ("plot", str(copy)))):
        assert result.returncode in (1, 2, 3), (command, result.stderr[-2000:])
        one_line(result.stderr)


def test_a_gl_backend_whose_library_is_missing_is_one_line(run_dir, tmp_path):
    import ctypes.util

    if ctypes.util.find_library("OSMesa"):
        pytest.skip("OSMesa is installed here")
    result = run_cli("render", str(run_dir), "--steps", "2", "--out", str(tmp_path / "v.gif"),
                     env={**os.environ, "MUJOCO_GL": "osmesa"})
    assert result.returncode == 3 and "OSMesa library is not installed" in one_line(result.stderr)


def test_export_of_an_epoch_it_lacks_names_the_flag(run_dir, tmp_path):
    result = run_cli("export", str(run_dir), "--epoch", "7", "--out", str(tmp_path / "e"))
    assert result.returncode == 2 and one_line(result.stderr).startswith("mjx-emp: invalid configuration: epoch: ")
