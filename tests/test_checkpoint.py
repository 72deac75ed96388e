"""Checkpoints: exact round trips, exact resume after SIGKILL, and refusing bad checkpoints."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny import (
    SMALL,
    TINY,
    cli_in_process,
    mjx_emp,
    run_cli,
    tiny_after_two_epochs,
    tiny_trainer,
)

from mjx_emp import cli
from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.registry import config_from_json
from mjx_emp.errors import CheckpointError, CheckpointWriteError, TrainingDiverged
from mjx_emp.run import checkpoint, loop
from mjx_emp.run.checkpoint import Checkpoints, config_mismatches
from mjx_emp.run.jobs import load_run
from mjx_emp.run.packing import layout_mismatch, layout_of, pack, unpack
from mjx_emp.run.store import keep_metrics_through, read_metrics, write_config


def host_leaves(tree) -> list[np.ndarray]:
    """Every array of a pytree as numpy (PRNG keys as their raw data), for bitwise comparison."""
    return [np.asarray(jax.random.key_data(x) if jnp.issubdtype(x.dtype, jax.dtypes.prng_key) else x)
            for x in jax.tree.leaves(tree)]


def assert_bitwise_equal(a, b) -> None:
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(host_leaves(a), host_leaves(b)):
        assert x.dtype == y.dtype and x.shape == y.shape
        assert np.array_equal(x, y, equal_nan=True)


def test_packing_round_trips_keys_empty_arrays_and_every_dtype():
    tree = {"key": jax.random.split(jax.random.key(3), 4), "empty": jnp.zeros((8, 0, 3)),
            "x": jnp.arange(5.0), "n": jnp.int32(7), "flag": jnp.array([True, False]),
            "m": jnp.arange(6, dtype=jnp.int32).reshape(2, 3)}
    packed = pack(tree)
    assert sorted(packed) == ["bool", "float32", "int32", "uint32"]
    assert packed["int32"].tolist() == [0, 1, 2, 3, 4, 5, 7]  # dict leaves in sorted key order
    back = unpack(packed, jax.eval_shape(lambda: tree))
    assert back["empty"].shape == (8, 0, 3)
    assert_bitwise_equal(back, tree)


def test_layout_mismatch_names_the_first_differing_array():
    a = layout_of({"w": jnp.zeros((2, 3)), "b": jnp.zeros(3)})
    b = layout_of({"w": jnp.zeros((2, 4)), "b": jnp.zeros(3)})
    assert layout_mismatch(a, a) is None
    assert layout_mismatch(a, b) == "array ['w'] is [2, 3] float32, expected [2, 4] float32"


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory):
    """A run directory with checkpoints of the tiny trainer's epochs 1 and 2."""
    trainer = tiny_trainer()
    state = trainer.init()
    run_dir = tmp_path_factory.mktemp("run")
    checkpoints = Checkpoints(run_dir, keep=3)
    states = {}
    for _ in range(2):
        state, _ = trainer.train_epoch(state)
        epoch = int(state.epoch)
        states[epoch] = jax.tree.map(lambda x: x.copy(), state)  # the next epoch donates `state`
        checkpoints.save(epoch, state, TINY)
    checkpoints.close()
    return run_dir, states


def test_restore_gives_back_the_saved_state_bit_for_bit(saved_run):
    run_dir, states = saved_run
    with Checkpoints(run_dir) as checkpoints:
        epoch, restored = checkpoints.restore_latest(jax.eval_shape(tiny_trainer().init), TINY)
        assert epoch == 2
        assert_bitwise_equal(restored, states[2])
        assert_bitwise_equal(checkpoints.restore(1, states[1], TINY), states[1])


def without_format_number(step_dir: Path) -> None:
    """Rewrite a checkpoint's digests item as checkpoints were written before formats were numbered."""
    path = step_dir / "digests" / "metadata"
    digests = json.loads(path.read_text())
    assert digests.pop("format") == checkpoint.FORMAT
    path.write_text(json.dumps(digests))


def test_a_checkpoint_records_its_format_and_one_written_before_formats_with_todays_layout_restores(saved_run,
                                                                                                    tmp_path):
    _, states = saved_run
    state = states[2]
    with Checkpoints(tmp_path, keep=1) as checkpoints:
        checkpoints.save(2, state, TINY)
        checkpoints.wait()
        assert json.loads((checkpoints.step_dir(2) / "digests" / "metadata").read_text())["format"] == checkpoint.FORMAT
        without_format_number(checkpoints.step_dir(2))
        assert_bitwise_equal(checkpoints.restore(2, jax.eval_shape(lambda: state), TINY), state)


def test_an_earlier_layout_is_refused_naming_its_format_and_the_first_array_that_differs(saved_run, tmp_path):
    _, states = saved_run
    state = states[2]
    float_count = state.replace(env_steps=jnp.float32(state.env_steps.value()))  # how early checkpoints held it
    with Checkpoints(tmp_path, keep=1) as checkpoints:
        checkpoints.save(2, float_count, TINY)
        checkpoints.wait()
        without_format_number(checkpoints.step_dir(2))
        with pytest.raises(CheckpointError, match=r"\(checkpoint format 0\) does not fit this config's train state in "
                                                  r"format 1: array \.env_steps\.hi is \(missing\)"):
            checkpoints.restore(2, jax.eval_shape(lambda: state), TINY)


def test_a_checkpoint_of_a_newer_format_is_refused_naming_both_formats(saved_run, tmp_path, monkeypatch):
    _, states = saved_run
    with Checkpoints(tmp_path, keep=1) as checkpoints:
        monkeypatch.setattr(checkpoint, "FORMAT", checkpoint.FORMAT + 1)
        checkpoints.save(2, states[2], TINY)
        checkpoints.wait()
        monkeypatch.undo()
        with pytest.raises(CheckpointError, match=r"checkpoint format 2 was written by a newer mjx-emp; this one reads "
                                                  r"format 1"):
            checkpoints.restore(2, states[2], TINY)


def test_a_layout_of_another_train_state_is_refused_naming_the_array(saved_run, tmp_path):
    _, states = saved_run
    state = states[2]
    with Checkpoints(tmp_path, keep=1) as checkpoints:
        checkpoints.save(2, state.replace(epoch=jnp.zeros(2, jnp.int32)), TINY)
        checkpoints.wait()
        with pytest.raises(CheckpointError, match=r"\(checkpoint format 1\) does not fit this config's train state "
                                                  r"in format 1: array \.epoch is"):
            checkpoints.restore(2, state, TINY)


def test_config_mismatch_names_the_checkpoint_file_and_the_field(saved_run):
    run_dir, states = saved_run
    with Checkpoints(run_dir) as checkpoints, pytest.raises(
        CheckpointError, match=r"checkpoints/2/config.*sigma_gs: checkpoint has \[0.4, 0.8\]"
    ):
        checkpoints.restore_latest(states[2], dataclasses.replace(TINY, sigma_gs=(0.5, 0.8)))


# orbax leaves an "Exception ignored" note from its event loop after a failed read; harmless.
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_truncated_checkpoint_names_the_file_and_fallback_uses_the_previous_one(saved_run, tmp_path):
    run_dir, states = saved_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, symlinks=True)
    data_files = sorted((copy / "checkpoints" / "2" / "state" / "d").iterdir(), key=lambda p: p.stat().st_size)
    victim = data_files[-1]  # the largest array file of the newest checkpoint
    os.truncate(victim, victim.stat().st_size // 2)
    with Checkpoints(copy) as checkpoints:
        with pytest.raises(CheckpointError, match=victim.name) as err:
            checkpoints.restore_latest(states[2], TINY)
        assert "--fallback" in str(err.value)
        epoch, restored = checkpoints.restore_latest(states[2], TINY, fallback=True)
        assert epoch == 1
        assert_bitwise_equal(restored, states[1])


def test_nan_stops_the_run_and_keeps_the_last_good_checkpoint(tmp_path):
    trainer, _, state, _, _ = tiny_after_two_epochs()
    good = jax.tree.map(lambda x: x.copy(), state)  # the cached state stays intact for other tests
    poisoned = jax.tree.map(lambda x: x.copy(), good)  # train_epoch donates (deletes) its input
    actor = jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), poisoned.policies[0].actor)
    poisoned = poisoned.replace(policies=(poisoned.policies[0].replace(actor=actor), *poisoned.policies[1:]))
    with Checkpoints(tmp_path) as checkpoints:
        checkpoints.save(2, good, TINY)
    with pytest.raises(TrainingDiverged, match="epoch 3: level 0 goal-conditioned .*nan.*last good checkpoint is epoch 2"):
        loop.train(trainer, poisoned, [loop.Member(trainer, tmp_path)])
    with Checkpoints(tmp_path) as checkpoints:
        assert checkpoints.epochs() == [2]
        assert_bitwise_equal(checkpoints.restore(2, good, TINY), good)


def test_metrics_after_the_resumed_epoch_are_dropped(tmp_path):
    path = tmp_path / "metrics.jsonl"
    path.write_text("".join(json.dumps({"epoch": e}) + "\n" for e in (1, 2, 3)) + '{"epoch": 4, "lev')
    keep_metrics_through(path, 2)
    assert [json.loads(line)["epoch"] for line in path.read_text().splitlines()] == [1, 2]


def test_damaged_metrics_lines_are_named_and_no_valid_line_is_lost(tmp_path, capsys):
    path = tmp_path / "metrics.jsonl"
    lines = [json.dumps({"epoch": 1}), "garbled{", json.dumps({"epoch": 2}), json.dumps([3]),
             json.dumps({"epoch": 3})]
    path.write_bytes(("\n".join(lines) + "\n").encode() + b'{"epoch": 4, "l\xff\xfe')
    assert [m["epoch"] for m in read_metrics(tmp_path)] == [1, 2, 3]
    err = capsys.readouterr().err
    assert "line 2: not JSON" in err and "line 4: not an epoch's metrics" in err and "line 6: not JSON" in err
    keep_metrics_through(path, 5)
    assert [json.loads(line)["epoch"] for line in path.read_text().splitlines()] == [1, 2, 3]
    assert "no metrics line for epochs [4, 5]" in capsys.readouterr().err


def test_plot_reads_a_metrics_file_with_a_torn_last_line(tmp_path):
    from mjx_emp.viz.plots import (
        axes_content,
        goal_space_growth_figure,
        plot_goal_space_growth,
    )

    path = tmp_path / "metrics.jsonl"
    lines = [{"epoch": e, "env_steps": 10.0 * e, "levels": [{"level": 0, "volume": float(e), "success": 0.25 * e,
                                                             "shift": [0.0, 0.0], "half_width": [0.5, 0.5]}]}
             for e in (1, 2)]
    path.write_text("".join(json.dumps(line) + "\n" for line in lines) + json.dumps(lines[0])[:20])
    metrics = read_metrics(tmp_path)
    volume, success = axes_content(goal_space_growth_figure(metrics))
    # One point per whole line: the torn line adds none, neither a gap nor a zero.
    assert volume.series == {"level 0": ([10.0, 20.0], [1.0, 2.0])}
    assert success.series == {"level 0": ([10.0, 20.0], [0.25, 0.5])}
    assert volume.legend == ["level 0"] and volume.yscale == "log"
    assert (volume.title, volume.ylabel) == ("goal-space growth", "goal-space volume at s0")  # no unit given
    assert (success.xlabel, success.ylabel) == ("environment steps", "greedy success in own goal space")
    assert plot_goal_space_growth(metrics, tmp_path / "growth.png").stat().st_size > 0


# ---- the command line, in separate processes that are killed for real ---------------------

def kill_when(process: subprocess.Popen, ready, timeout: float = 300, signum: int = signal.SIGKILL) -> None:
    """Send ``signum`` (SIGKILL) to ``process`` as soon as ``ready()`` holds (polled every few
    milliseconds) and wait for it to end."""
    deadline = time.monotonic() + timeout
    while not ready():
        assert process.poll() is None, f"process ended before it could be killed: {process.communicate()}"
        assert time.monotonic() < deadline, "condition never held"
        time.sleep(0.002)
    process.send_signal(signum)
    process.wait()
    if signum == signal.SIGKILL:
        assert process.returncode == -signal.SIGKILL


def final_state(run_dir: Path, epoch: int):
    cfg = config_from_json(json.loads((run_dir / "config.json").read_text()))
    with Checkpoints(run_dir) as checkpoints:
        assert epoch in checkpoints.epochs()
        return checkpoints.restore(epoch, jax.eval_shape(HEAgent(cfg).init), cfg)


@pytest.fixture(scope="module")
def straight_run(tmp_path_factory):
    """SMALL trained to the end without a stop."""
    straight = tmp_path_factory.mktemp("straight") / "run"
    result = cli_in_process("train", *SMALL, "--run-dir", str(straight))
    assert result.returncode == 0, result.stderr
    return straight


@pytest.mark.parametrize("signum", [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow)])  # one handler
def test_sigterm_or_sigint_stops_after_the_write_names_the_checkpoint_and_resumes_bitwise(straight_run, tmp_path,
                                                                                            signum):
    stopped = tmp_path / "stopped"
    process = subprocess.Popen(mjx_emp("train", *SMALL, "--run-dir", str(stopped)), stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True)
    kill_when(process, lambda: (stopped / "checkpoints" / "2").exists(), signum=signum)
    err = process.stderr.read()
    assert process.returncode == 128 + signum, err
    kept = sorted(int(p.name) for p in (stopped / "checkpoints").iterdir() if p.name.isdigit())
    assert not [p for p in (stopped / "checkpoints").iterdir() if "tmp" in p.name]  # no write left half done
    assert f"stopped by {signal.Signals(signum).name}; the newest checkpoint is epoch {kept[-1]} in" in err
    assert kept[-1] < 4, "the run finished before the signal"
    lines = [json.loads(line) for line in (stopped / "metrics.jsonl").read_text().splitlines()]
    assert [m["epoch"] for m in lines] == list(range(1, kept[-1] + 1))  # a metrics line for every checkpoint

    result = cli_in_process("train", "--resume", str(stopped))
    assert result.returncode == 0, result.stderr
    assert_bitwise_equal(final_state(stopped, 4), final_state(straight_run, 4))


def test_sigkill_then_resume_is_bitwise_identical_to_an_uninterrupted_run(straight_run, tmp_path):
    straight, killed = straight_run, tmp_path / "killed"
    process = subprocess.Popen(mjx_emp("train", *SMALL, "--run-dir", str(killed)),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    kill_when(process, lambda: (killed / "checkpoints" / "2").exists())
    assert not (killed / "checkpoints" / "4").exists(), "the run finished before the kill"

    result = cli_in_process("train", "--resume", str(killed))
    assert result.returncode == 0, result.stderr
    assert "resuming" in result.stdout
    assert_bitwise_equal(final_state(killed, 4), final_state(straight, 4))
    lines = [json.loads(line) for line in (killed / "metrics.jsonl").read_text().splitlines()]
    assert [m["epoch"] for m in lines] == [1, 2, 3, 4]


def test_sigkill_during_a_checkpoint_write_resumes_from_the_previous_epoch(tmp_path):
    run_dir = tmp_path / "run"
    checkpoints_dir = run_dir / "checkpoints"
    process = subprocess.Popen(mjx_emp("train", *SMALL, "--run-dir", str(run_dir)),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def writing_epoch_1_or_later() -> bool:
        if not (checkpoints_dir / "0").exists():
            return False
        return any("tmp" in p.name and not p.name.startswith("0.") for p in checkpoints_dir.iterdir())

    kill_when(process, writing_epoch_1_or_later)
    unfinished = [p.name for p in checkpoints_dir.iterdir() if "tmp" in p.name]
    complete = [int(p.name) for p in checkpoints_dir.iterdir() if p.name.isdigit()]
    assert unfinished and complete, (unfinished, complete)
    unfinished_epoch = int(unfinished[0].split(".")[0])
    assert unfinished_epoch not in complete and max(complete) == unfinished_epoch - 1

    result = cli_in_process("train", "--resume", str(run_dir), "--epochs", str(unfinished_epoch))
    assert result.returncode == 0, result.stderr
    assert f"resuming {run_dir} from epoch {unfinished_epoch - 1}" in result.stdout
    assert (checkpoints_dir / str(unfinished_epoch)).exists()
    assert not [p for p in checkpoints_dir.iterdir() if "tmp" in p.name]


def test_resume_of_a_corrupt_checkpoint_exits_2_naming_the_file_then_falls_back(saved_run, tmp_path, capsys):
    run_dir, _ = saved_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, symlinks=True)
    (copy / "config.json").write_text(json.dumps(dataclasses.asdict(dataclasses.replace(TINY, epochs=2))))
    metadata = copy / "checkpoints" / "2" / "state" / "_METADATA"
    metadata.write_text(metadata.read_text()[:100])
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["train", "--resume", str(copy)])
    assert exit_info.value.code == 2
    assert str(copy / "checkpoints" / "2" / "state") in capsys.readouterr().err
    cli.main(["train", "--resume", str(copy), "--fallback"])
    assert "resuming" in capsys.readouterr().out
    with Checkpoints(copy) as checkpoints:
        assert checkpoints.epochs() == [1, 2]  # epoch 2 written afresh
    assert [p.name.split("-")[0] for p in (copy / "rejected-checkpoints").iterdir()] == ["2"]


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_flipped_bytes_in_a_data_file_are_caught_naming_the_file_or_change_nothing_restored(saved_run, tmp_path):
    """Three bytes flipped in each data file of the newest checkpoint: a restore refuses it,
    naming the file (the array bytes fail their checksum, an index fails orbax's own), and
    --fallback restores the previous epoch bitwise; or, where the flipped bytes are ones a
    restore never reads, it gives back exactly the saved state. Never anything else."""
    run_dir, states = saved_run
    victims = [p.relative_to(run_dir) for p in sorted((run_dir / "checkpoints" / "2" / "state").rglob("*"))
               if p.is_file() and p.parent.name == "d"]
    caught = []
    for index, victim in enumerate(victims):
        copy = tmp_path / f"run{index}"
        shutil.copytree(run_dir, copy, symlinks=True)
        data = bytearray((copy / victim).read_bytes())
        for offset in (len(data) // 3, len(data) // 2, 2 * len(data) // 3):
            data[offset] ^= 0xFF
        (copy / victim).write_bytes(bytes(data))
        with Checkpoints(copy) as checkpoints:
            try:
                restored = checkpoints.restore(2, states[2], TINY)
            except CheckpointError as err:
                assert str(copy / victim) in str(err) or str(copy / victim.parent.parent) in str(err), str(err)
                caught.append(victim)
                with pytest.raises(CheckpointError, match="--fallback"):
                    checkpoints.restore_latest(states[2], TINY)
                epoch, restored = checkpoints.restore_latest(states[2], TINY, fallback=True)
                assert epoch == 1
                assert_bitwise_equal(restored, states[1])
            else:
                assert_bitwise_equal(restored, states[2])
    largest = max(victims, key=lambda v: (run_dir / v).stat().st_size)  # the arrays' own bytes
    assert largest in caught


def test_a_corrupt_array_is_named_with_its_checkpoint(saved_run, tmp_path):
    run_dir, states = saved_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, symlinks=True)
    largest = max((p for p in (copy / "checkpoints" / "2" / "state").rglob("*") if p.is_file()),
                  key=lambda p: p.stat().st_size)
    data = bytearray(largest.read_bytes())
    data[len(data) // 2] ^= 0x01  # one bit
    largest.write_bytes(bytes(data))
    with Checkpoints(copy) as checkpoints, pytest.raises(CheckpointError) as err:
        checkpoints.restore(2, states[2], TINY)
    message = str(err.value)
    assert f"{copy / 'checkpoints' / '2'}: array ." in message and "does not match the checksum written with it" in message
    assert str(largest) in message


def test_a_second_writer_is_refused_naming_the_holder_and_a_killed_holders_lock_is_taken_over(tmp_path):
    run_dir = tmp_path / "run"
    process = subprocess.Popen(mjx_emp("train", *SMALL, "--epochs", "40", "--run-dir", str(run_dir)),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while not (run_dir / "checkpoints" / "1").exists():
            assert process.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        second = cli_in_process("train", "--resume", str(run_dir))
        assert second.returncode == 2, second.stderr
        assert f"resume: '{run_dir}' is in use by process {process.pid} on " in second.stderr
    finally:
        process.kill()
        process.wait()
    assert (run_dir / ".lock").read_text().startswith(f"{process.pid} on ")  # left behind by the killed writer
    newest = max(int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit())
    resumed = cli_in_process("train", "--resume", str(run_dir), "--epochs", str(newest + 1))
    assert resumed.returncode == 0, resumed.stderr
    assert f"taking over the lock of {run_dir} left by process {process.pid}" in resumed.stdout
    assert (run_dir / ".lock").read_text() == ""  # released when the resume ended


def test_a_failed_checkpoint_write_stops_the_run_naming_the_intact_checkpoint(tmp_path, monkeypatch):
    trainer = tiny_trainer()
    with Checkpoints(tmp_path, keep=3) as checkpoints:
        checkpoints.save(0, trainer.init(), TINY)

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(checkpoint.ocp.CheckpointManager, "save", full_disk)  # as orbax reports a full disk
    with pytest.raises(CheckpointWriteError, match="No space left on device.*newest complete checkpoint is "
                                                   "epoch 0, left intact"):
        loop.train(trainer, trainer.init(), [loop.Member(trainer, tmp_path)])
    monkeypatch.undo()
    with Checkpoints(tmp_path) as checkpoints:
        assert checkpoints.epochs() == [0]
    assert not (tmp_path / "metrics.jsonl").read_text()  # no metrics line for the epoch that was not kept


def test_a_new_run_s_epoch_0_is_written_by_the_loop_and_a_resumed_epoch_is_not_written_again(tmp_path):
    one_epoch = dataclasses.replace(TINY, epochs=1)
    trainer = HEAgent(one_epoch)
    loop.train(trainer, trainer.init(), [loop.Member(trainer, tmp_path)])
    with Checkpoints(tmp_path) as checkpoints:
        assert checkpoints.epochs() == [0, 1]
        first = checkpoints.restore(1, jax.eval_shape(trainer.init), one_epoch)
    longer = HEAgent(dataclasses.replace(one_epoch, epochs=2))
    written = (tmp_path / "checkpoints" / "1" / "_CHECKPOINT_METADATA").stat().st_mtime_ns
    loop.train(longer, first, [loop.Member(longer, tmp_path)])
    with Checkpoints(tmp_path) as checkpoints:
        assert checkpoints.epochs() == [0, 1, 2]
    assert (tmp_path / "checkpoints" / "1" / "_CHECKPOINT_METADATA").stat().st_mtime_ns == written
    assert [line["epoch"] for line in read_metrics(tmp_path)] == [1, 2]


def test_a_run_on_a_full_filesystem_exits_1_and_resumes_once_there_is_room(tmp_path):
    """A real full disk: a 320 KB tmpfs (needs permission to mount one; skipped otherwise)."""
    mount = tmp_path / "small"
    mount.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=320k", "tmpfs", str(mount)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        run_dir = mount / "run"
        args = ["point-mass-k1", "--num-envs", "8", "--hidden", "16", "--batch-size", "16", "--gc-iterations", "2",
                "--gc-grad-steps", "3", "--replay-capacity", "20000", "--epochs", "6", "--run-dir", str(run_dir)]
        full = run_cli("train", *args)
        assert full.returncode == 1, full.stderr
        kept = sorted(int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit())
        assert kept and kept[-1] < 6
        assert (f"checkpoint write failed: writing a checkpoint to {run_dir / 'checkpoints'} failed" in full.stderr
                and f"the newest complete checkpoint is epoch {kept[-1]}, left intact" in full.stderr), full.stderr
        subprocess.run(["mount", "-o", "remount,size=4m", str(mount)], check=True)  # space freed
        resumed = run_cli("train", "--resume", str(run_dir))
        assert resumed.returncode == 0, resumed.stderr
        assert f"resuming {run_dir} from epoch {kept[-1]}" in resumed.stdout
        assert 6 in [int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit()]
    finally:
        subprocess.run(["umount", str(mount)], capture_output=True)


def test_a_planted_half_written_checkpoint_is_ignored_and_cleaned_up(saved_run, tmp_path):
    """What a kill in the middle of orbax's write leaves (a temporary directory with part of the
    files), planted deterministically: the previous checkpoint is the newest, and reopening
    the directory removes the leftover."""
    run_dir, states = saved_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, symlinks=True)
    partial = copy / "checkpoints" / "3.orbax-checkpoint-tmp-1234567890"
    shutil.copytree(copy / "checkpoints" / "2", partial, symlinks=True)
    for name in ("commit_success.txt", "_CHECKPOINT_METADATA"):
        (partial / name).unlink(missing_ok=True)
    data = max((p for p in (partial / "state").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
    os.truncate(data, data.stat().st_size // 3)
    with Checkpoints(copy) as checkpoints:
        assert checkpoints.epochs() == [1, 2]
        epoch, restored = checkpoints.restore_latest(states[2], TINY)
        assert epoch == 2
        assert_bitwise_equal(restored, states[2])
    assert not partial.exists()


def test_a_reader_leaves_a_checkpoint_being_written_alone(saved_run, tmp_path):
    """eval, plot and phase 2 open a run read-only: a temporary checkpoint folder (what a
    training process is writing) survives them, and the newest complete epoch is what they load."""
    run_dir, states = saved_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, symlinks=True)
    write_config(copy, TINY)
    writing = copy / "checkpoints" / "3.orbax-checkpoint-tmp"
    writing.mkdir()
    agent, epoch, restored = load_run(copy)
    assert epoch == 2
    assert_bitwise_equal(restored, states[2])
    assert writing.exists()
    with Checkpoints(copy, read_only=True) as checkpoints:
        assert checkpoints.epochs() == [1, 2]
    assert writing.exists()


def test_a_checkpoint_removed_while_a_reader_lists_them_is_passed_over(saved_run, tmp_path, monkeypatch):
    """A writer's retention can remove a step folder after orbax has listed it and before it reads
    the folder's time; that step is simply gone, and the reader lists again and loads the newest
    one there is (planted: the folder is removed as orbax looks for the step's metadata file, so
    orbax falls back to the folder's own time)."""
    run_dir, states = saved_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, symlinks=True)
    vanishing = copy / "checkpoints" / "1"
    metadata = vanishing / "_CHECKPOINT_METADATA"
    assert metadata.exists()
    real_stat, removed = os.stat, []

    def stat_after_retention(path, *args, **kwargs):
        if str(path) == str(metadata) and not removed:
            removed.append(path)
            shutil.rmtree(vanishing)
        return real_stat(path, *args, **kwargs)

    monkeypatch.setattr(os, "stat", stat_after_retention)
    with Checkpoints(copy, read_only=True) as checkpoints:
        epoch, restored = checkpoints.restore_latest(states[2], TINY)
        assert removed and not vanishing.exists()
        assert checkpoints.epochs() == [2] and epoch == 2
        assert_bitwise_equal(restored, states[2])


def test_a_resume_to_fewer_epochs_than_done_is_refused_before_anything_is_rewritten(saved_run, tmp_path, capsys):
    run_dir, _ = saved_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, symlinks=True)
    write_config(copy, TINY)
    config = (copy / "config.json").read_text()
    with pytest.raises(SystemExit) as stop:
        cli.main(["resume", str(copy), "--epochs", "1"])
    assert stop.value.code == 2
    assert f"epochs: {copy} is at epoch 2; give at least that many; got 1" in capsys.readouterr().err
    assert (copy / "config.json").read_text() == config


def test_a_renamed_checkpoint_folder_is_refused_naming_both_epochs(saved_run, tmp_path):
    run_dir, states = saved_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, symlinks=True)
    (copy / "checkpoints" / "1").rename(copy / "checkpoints" / "10")
    with Checkpoints(copy, read_only=True) as checkpoints, pytest.raises(CheckpointError) as err:
        checkpoints.restore_latest(states[2], TINY)
    assert "holds the state of epoch 1, not 10" in str(err.value) and "renamed" in str(err.value)
    assert (copy / "checkpoints" / "10").exists() and (copy / "checkpoints" / "2").exists()


def test_config_fields_a_checkpoint_predates_count_as_their_defaults():
    saved = json.loads(json.dumps(dataclasses.asdict(TINY)))
    del saved["her"], saved["n_step"]
    assert config_mismatches(saved, TINY) == []
    assert config_mismatches(saved, dataclasses.replace(TINY, her=0.5)) == ["her: checkpoint has 0.0, run has 0.5"]
