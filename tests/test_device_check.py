"""The GPU machine's prepared check runs every step at tiny sizes here, so it cannot rot."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_device_check_dry_run_runs_every_step_and_writes_json(tmp_path):
    out = tmp_path / "check.json"
    result = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "device_check.py"), "--dry-run",
                             "--out", str(out)], capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(out.read_text())
    assert report["dry_run"]
    jax_steps = {s["step"]: s for s in report["steps"] if s["impl"] == "jax"}
    assert sorted(jax_steps) == ["memory", "rollout", "seeds", "train"]
    assert not [s for s in jax_steps.values() if "error" in s or "skipped" in s], jax_steps
    assert {row["k"] for row in jax_steps["rollout"]["result"]} == {1}
    assert [row["seeds"] for row in jax_steps["seeds"]["result"]] == [2]
    assert jax_steps["train"]["result"]["env_steps_per_s"] > 0
    assert jax_steps["memory"]["result"]["state_bytes"] > 0
    if report["backend"] != "gpu":  # warp cannot run here: every step says why instead of failing
        assert all("warp" in s["skipped"] for s in report["steps"] if s["impl"] == "warp")
