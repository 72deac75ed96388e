"""A run split into shards (data parallelism) on one device and on several (forced CPU devices)."""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest
from tiny import TINY1, mjx_emp

from mjx_emp.errors import ConfigError
from mjx_emp.run.devices import ShardedAgent, shard_slice

# TINY1 split in two: 4 environments, minibatches of 8 and half of every buffer per shard.
SPLIT = dataclasses.replace(TINY1, shards=2)


def test_shards_keep_equal_networks_explore_apart_and_count_the_whole_run():
    program = ShardedAgent(SPLIT, 1)
    state, stats = program.train_epoch(program.init())
    first, second = shard_slice(state, 0), shard_slice(state, 1)
    for a, b in zip(jax.tree.leaves((first.policies, first.goal_spaces)),
                    jax.tree.leaves((second.policies, second.goal_spaces))):
        np.testing.assert_array_equal(a, b)  # averaged gradients: the same step on every shard
    assert not np.array_equal(jax.random.key_data(first.key), jax.random.key_data(second.key))
    assert not np.array_equal(first.starts[0].data, second.starts[0].data)  # each shard its own start states
    # every shard holds the whole run's step count, which is what the unsplit run counts
    unsplit_state, _ = program.alone.__class__(TINY1).train_epoch(program.alone.__class__(TINY1).init())
    assert int(first.env_steps.value()) == int(second.env_steps.value())
    assert program.alone.cfg.num_envs == TINY1.num_envs // 2 and program.alone.cfg.shards == 1
    assert 0 < int(first.env_steps.value()) <= 2 * int(unsplit_state.env_steps.value())
    assert program.divergence(state, stats) is None


def test_a_split_the_batch_cannot_take_is_refused_naming_the_field():
    try:
        ShardedAgent(dataclasses.replace(TINY1, shards=3), 1)
    except ConfigError as err:
        assert "num_envs: must be a multiple of shards (3); got 8" in str(err)
    else:
        raise AssertionError("shards=3 of 8 environments was accepted")


FORCED_DEVICES = textwrap.dedent("""
    import dataclasses, json, sys
    import jax, numpy as np
    sys.path.insert(0, "tests")
    from tiny import TINY1
    from mjx_emp.run.devices import ShardedAgent
    cfg = dataclasses.replace(TINY1, shards=4)
    results = {}
    for devices in (1, 4):
        program = ShardedAgent(cfg, devices)
        state, _ = program.train_epoch(program.init())
        leaf = jax.tree.leaves(state.policies)[0]
        results[devices] = (len(leaf.sharding.device_set), jax.tree.map(np.asarray, (state.policies, state.goal_spaces)))
    worst = max(float(np.max(np.abs(a - b))) for a, b in zip(jax.tree.leaves(results[1][1]), jax.tree.leaves(results[4][1])))
    print(json.dumps({"devices": [results[1][0], results[4][0]], "max_difference": worst}))
""")


def forced_cpu_devices(count: int) -> dict[str, str]:
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={count}".strip()
    return {**os.environ, "XLA_FLAGS": flags}


def test_one_epoch_on_one_device_and_on_four_gives_the_same_parameters():
    result = subprocess.run([sys.executable, "-c", FORCED_DEVICES], env=forced_cpu_devices(4), capture_output=True,
                            text=True, timeout=900)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["devices"] == [1, 4]  # the 4-device state really lives on 4 devices
    assert report["max_difference"] < 1e-4, report


@pytest.mark.slow  # the split itself: test_one_epoch_on_one_device_and_on_four_gives_the_same_parameters
def test_cli_trains_on_two_devices_and_resumes_on_one(tmp_path):
    run_dir = tmp_path / "split"
    small = ["--num-envs", "8", "--hidden", "16", "--batch-size", "16", "--gc-iterations", "2", "--gc-grad-steps",
             "3", "--replay-capacity", "2048", "--start-chain", "2"]
    env = forced_cpu_devices(2)
    trained = subprocess.run(mjx_emp("train", "point-mass-k1", *small, "--num-devices", "2", "--epochs", "3",
                                     "--run-dir", str(run_dir)), env=env, capture_output=True, text=True, timeout=900)
    assert trained.returncode == 0, trained.stderr
    assert "split into 2 shards on 2 device(s)" in trained.stdout
    assert json.loads((run_dir / "config.json").read_text())["shards"] == 2
    resumed = subprocess.run(mjx_emp("train", "--resume", str(run_dir), "--num-devices", "1", "--epochs", "4"),
                             env=env, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr
    lines = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [m["epoch"] for m in lines] == [1, 2, 3, 4]
    evaluated = subprocess.run(mjx_emp("eval", str(run_dir), "--episodes", "8", "--out", str(tmp_path / "e.json")),
                               env=env, capture_output=True, text=True, timeout=900)
    assert evaluated.returncode == 0, evaluated.stderr


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.slow  # two processes compiling side by side: a minute and a half on two cores
def test_two_processes_train_one_split_run_and_the_lead_writes_it(tmp_path):
    """jax.distributed on localhost: each process holds one shard on its CPU device; process 0
    writes config, metrics and checkpoints (the whole state gathered to it)."""
    run_dir, port = tmp_path / "two-hosts", free_port()
    small = ["--num-envs", "8", "--hidden", "16", "--batch-size", "16", "--gc-iterations", "2", "--gc-grad-steps",
             "3", "--replay-capacity", "2048", "--start-chain", "2", "--epochs", "2", "--run-dir", str(run_dir),
             "--coordinator-address", f"127.0.0.1:{port}", "--num-processes", "2"]
    processes = [subprocess.Popen(mjx_emp("train", "point-mass-k1", *small, "--process-id", str(index)),
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for index in (0, 1)]
    outputs = [process.communicate(timeout=900) for process in processes]
    for process, (_, err) in zip(processes, outputs):
        assert process.returncode == 0, err[-3000:]
    assert "split into 2 shards on 2 device(s)" in outputs[0][0]
    assert json.loads((run_dir / "config.json").read_text())["shards"] == 2
    assert [json.loads(line)["epoch"] for line in (run_dir / "metrics.jsonl").read_text().splitlines()] == [1, 2]
    assert sorted(int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit()) == [0, 1, 2]
