"""The GPU lease summary reads what a lease leaves behind and reports it faithfully."""

import json

from tiny import benchmark

from mjx_emp.run.rows import append_row, benchmark_row, read_rows

gpu_summary = benchmark("gpu_summary")


def epoch(n: int, seconds: float, volume: float, success: float) -> dict:
    return {"epoch": n, "env_steps": 1000.0 * n, "seconds": seconds, "env_steps_per_s": 1000.0 / seconds,
            "flip_resets": 3, "levels": [{"level": 0, "volume": volume, "success": success}]}


def test_the_summary_reports_the_check_and_each_training_row_and_stores_them_as_rows(tmp_path, capsys):
    lease = tmp_path / "out"
    lease.mkdir()
    (lease / "versions.txt").write_text("|   0  NVIDIA H200   On |\njax 0.11.2\nmujoco 3.17.0\ntyro missing\n")
    rollout = [{"impl": "jax", "batch": 8, "k": k, "raw_physics_steps_per_s": 100.0,
                "hier_useful_physics_steps_per_s": 90.0 / k, "hier_over_raw": 0.9 / k, "step": "rollout"}
               for k in (1, 2)]
    train = {"impl": "jax", "preset": "p", "epoch_s": 2.0, "step": "train"}
    skipped = {"step": "seeds", "impl": "jax", "why": "time budget of 1 s spent"}
    check = [benchmark_row("gpu-leases", name, figures) for name, figures in (
        ("gpu_lease_h200/check/rollout/batch8/k1", rollout[0]), ("gpu_lease_h200/check/rollout/batch8/k2", rollout[1]),
        ("gpu_lease_h200/check/train/p", train), ("gpu_lease_h200/check/not_run/all", skipped))]
    for row in check:
        append_row(lease / "check.jsonl", row)
    rows = [epoch(1, 10.0, 1.0, 1.0), epoch(2, 2.0, 5.0, 0.5), epoch(3, 4.0, 3.0, 0.7)]
    (lease / "ant.metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    results = tmp_path / "gpu-leases.jsonl"
    summary = gpu_summary.main(gpu_summary.Args(lease=str(lease), results=str(results)))
    assert summary["gpu"] == "NVIDIA H200"
    assert summary["packages"] == {"jax": "0.11.2", "mujoco": "3.17.0", "tyro": "missing"}
    assert summary["check"]["rollout"] == rollout and summary["check"]["train"] == [train]
    assert summary["check"]["not_run"] == [skipped]
    (row,) = summary["training"]
    assert row["preset"] == "ant" and row["epochs"] == 3 and row["env_steps"] == 3000.0
    assert row["first_epoch_s"] == 10.0 and row["median_epoch_s"] == 3.0  # the first epoch (compile) left out
    assert row["flips_per_1000_env_steps"] == 3.0
    assert (row["final_volume"], row["final_success"]) == (3.0, 0.7)
    assert (row["largest_volume"], row["largest_volume_epoch"], row["success_at_largest"]) == (5.0, 2, 0.5)
    assert row["top_box_by_epoch"] == [[1, 1.0, 1.0], [2, 5.0, 0.5], [3, 3.0, 0.7]]
    assert summary["phase2"] == [] and summary["settings"] == {}
    table = capsys.readouterr().out
    assert "| 8 | 2 | 100 | 45 | 0.45 |" in table and "| ant | 3 | 0.0 M | 10.0 | 3.00 |" in table
    assert "phase-2 epochs" not in table
    # The check's rows as the GPU machine wrote them, then the training row, named after the GPU.
    stored = read_rows(results)
    assert stored[:4] == check
    assert [row["row"] for row in stored[4:]] == ["gpu_lease_h200/training/ant"]
    assert stored[4]["spec"] == "gpu-leases" and stored[4]["kind"] == "benchmark"
    assert stored[4]["figures"]["final_volume"] == 3.0 and stored[4]["figures"]["gpu"] == "NVIDIA H200"


def test_the_summary_reports_the_settings_and_each_rows_phase2(tmp_path, capsys):
    (tmp_path / "versions.txt").write_text("ROWS=ant\nTRAIN_FLAGS=--solver-iterations 4 --critic-layer-norm\n"
                                           "LEASE=gpu_lease_h200_reach\n"
                                           "|====|\n|   0  NVIDIA H200   On |\njax 0.11.2\n")
    (tmp_path / "ant.metrics.jsonl").write_text(json.dumps(epoch(1, 10.0, 1.0, 1.0)) + "\n")
    phase2 = [{"epoch": n, "env_steps": 100.0 * n, "seconds": s, "min_distance": d, "success": w}
              for n, s, d, w in ((1, 50.0, 11.0, 0.05), (2, 20.0, 10.5, 0.07), (3, 30.0, 9.25, 0.1))]
    (tmp_path / "ant.phase2.jsonl").write_text("\n".join(json.dumps(r) for r in phase2) + "\n")
    results = tmp_path / "rows.jsonl"
    summary = gpu_summary.main(gpu_summary.Args(lease=str(tmp_path), results=str(results)))
    assert summary["settings"] == {"ROWS": "ant", "TRAIN_FLAGS": "--solver-iterations 4 --critic-layer-norm",
                                   "LEASE": "gpu_lease_h200_reach"}
    (row,) = summary["phase2"]
    assert row["preset"] == "ant" and row["epochs"] == 3 and row["env_steps"] == 300.0
    assert row["median_epoch_s"] == 25.0  # the first epoch (compile) left out
    assert row["min_distance_by_epoch"] == [11.0, 10.5, 9.25] and row["success_by_epoch"] == [0.05, 0.07, 0.1]
    assert (row["final_min_distance"], row["final_success"]) == (9.25, 0.1)
    assert "| ant | 3 | 0.0 M | 25.0 | 11.0, 10.5, 9.2 | 0.10 |" in capsys.readouterr().out
    stored = {row["row"]: row["figures"] for row in read_rows(results)}  # named by the lease's LEASE
    assert list(stored) == ["gpu_lease_h200_reach/training/ant", "gpu_lease_h200_reach/phase2/ant"]
    assert stored["gpu_lease_h200_reach/phase2/ant"]["final_min_distance"] == 9.25
