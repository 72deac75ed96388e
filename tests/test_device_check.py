"""The GPU machine's prepared lease runs every step at tiny sizes here, so it cannot rot."""

import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
from tiny import benchmark

from mjx_emp.run.rows import read_rows

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # four minutes of CPU in six processes; run it before a GPU lease (docs/gpu.md)
def test_the_device_lease_dry_run_runs_every_step_and_writes_its_rows(tmp_path):
    out = tmp_path / "out"
    env = {**os.environ, "DRY": "1", "WHEELS": "none", "PYTHON": sys.executable, "OUT": str(out),
           "RUNS": str(tmp_path / "runs"), "TOTAL_S": "720", "CHECK_S": "400", "PHASE2_S": "200",
           "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "cache")}
    result = subprocess.run(["bash", str(ROOT / "benchmarks" / "device_lease.sh")], capture_output=True, text=True,
                            timeout=900, cwd=ROOT, env=env)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "smoke epoch" in (out / "versions.txt").read_text()
    rows = read_rows(out / "check.jsonl")
    assert {row["spec"] for row in rows} == {"gpu-leases-dry-run"}  # never mixed with measured rows
    jax_rows = [row for row in rows if row["figures"]["impl"] == "jax"]
    assert [row["row"].split("/", 1)[1] for row in jax_rows] == [  # the lease's order, each after the lease
        "check/memory/all", "check/train/point-mass-k1/num_envs8", "check/rollout/point_mass/batch8/k1",
        "check/seeds/seeds2"]
    figures = {row["figures"]["step"]: row["figures"] for row in jax_rows}
    assert figures["train"]["env_steps_per_s"] > 0 and figures["memory"]["state_bytes"] > 0
    assert figures["rollout"]["hier_useful_physics_steps_per_s"] > 0 and figures["seeds"]["epoch_s"] > 0
    if rows[0]["train"]["machine"]["backend"] != "gpu":  # warp cannot run here: every step says why instead
        assert all("warp" in row["figures"]["why"] for row in rows if row["figures"]["impl"] == "warp")
    lines = (out / "point-mass-k1.metrics.jsonl").read_text().splitlines()  # the training row ran its two epochs
    assert [json.loads(line)["epoch"] for line in lines] == [1, 2]
    assert "PHASE2_S=200" in (out / "versions.txt").read_text()  # the settings head the file
    with tarfile.open(out / "point-mass-k1.skills.tar") as tar:  # the row's skills export, to go on from elsewhere
        names = tar.getnames()
        assert json.loads(tar.extractfile("point-mass-k1.skills/config.json").read())["env"] == "point_mass"
    assert "point-mass-k1.skills/checkpoints/2/state" in names
    lines = (out / "point-mass-k1.phase2.jsonl").read_text().splitlines()  # phase 2 on the row's skills
    assert [json.loads(line)["epoch"] for line in lines] == [1]
    (row,) = json.loads((out / "point-mass-k1.eval.json").read_text())["runs"]
    run = row["figures"]
    assert run["epoch"] == 2 and run["phase2"]["epoch"] == 1 and run["phase2"]["episodes"] == 8
    summary = benchmark("gpu_summary")  # back home: the lease's rows into the store, a dry run's apart
    summary.main(summary.Args(lease=str(out), results=str(tmp_path / "rows.jsonl")))
    stored = read_rows(tmp_path / "rows.jsonl")
    assert stored[:len(rows)] == rows and {row["spec"] for row in stored} == {"gpu-leases-dry-run"}
    lease = rows[0]["row"].split("/")[0]
    assert [row["row"] for row in stored[len(rows):]] == [f"{lease}/training/point-mass-k1",
                                                          f"{lease}/phase2/point-mass-k1"]


@pytest.mark.slow  # two and a half minutes of CPU; run it before a GPU lease that trains seeds together
def test_the_device_lease_trains_a_rows_seeds_in_one_program_and_returns_each_seeds_skills(tmp_path):
    out = tmp_path / "out"
    env = {**os.environ, "DRY": "1", "WHEELS": "none", "PYTHON": sys.executable, "OUT": str(out), "SEEDS": "0 1",
           "RUNS": str(tmp_path / "runs"), "TOTAL_S": "700", "CHECK_S": "0", "PHASE2_S": "300",
           "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "cache")}
    result = subprocess.run(["bash", str(ROOT / "benchmarks" / "device_lease.sh")], capture_output=True, text=True,
                            timeout=900, cwd=ROOT, env=env)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    log = (out / "point-mass-k1.log").read_text()
    assert f"run directories: {tmp_path}/runs/point-mass-k1-s0, {tmp_path}/runs/point-mass-k1-s1" in log  # one program
    assert not (out / "point-mass-k1.metrics.jsonl").exists()  # each seed's metrics travel in its export
    for seed in (0, 1):
        run = f"point-mass-k1-s{seed}"
        with tarfile.open(out / f"{run}.skills.tar") as tar:
            assert json.loads(tar.extractfile(f"{run}.skills/config.json").read())["seed"] == seed
            lines = tar.extractfile(f"{run}.skills/metrics.jsonl").read().decode().splitlines()
        assert [json.loads(line)["epoch"] for line in lines] == [1, 2]
        (row,) = json.loads((out / f"{run}.eval.json").read_text())["runs"]  # phase 2 and eval per seed
        assert row["figures"]["phase2"]["episodes"] == 8
        assert len((out / f"{run}.phase2.jsonl").read_text().splitlines()) == 1


def test_the_device_check_refuses_an_unknown_step_with_exit_2(tmp_path):
    result = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "device_check.py"), "--dry-run",
                             "--steps", "memory", "warmup", "--results", str(tmp_path / "x.jsonl")],
                            capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 2
    assert "--steps" in result.stderr and "warmup" in result.stderr and "rollout" in result.stderr
    assert not (tmp_path / "x.jsonl").exists()
