"""benchmarks/time_to_quality.py: the first epoch whose top box and smoothed success meet both targets."""

import pytest
from tiny import benchmark

from mjx_emp.run.rows import append_row, read_rows


def _curve(volumes, successes, steps_per_epoch):
    return [[e + 1, (e + 1) * steps_per_epoch, v, s] for e, (v, s) in enumerate(zip(volumes, successes))]


def test_time_to_quality_finds_the_first_epoch_meeting_both_targets_on_smoothed_success():
    ttq = benchmark("time_to_quality")
    args = ttq.Args(target_volume=16.0, target_success=0.8, window=3)
    # Epoch 3 has the volume but its 3-epoch success is (0.5 + 0.5 + 1) / 3 < 0.8; epoch 4 meets both.
    curve = _curve([10, 12, 16, 17, 18], [0.5, 0.5, 1.0, 1.0, 1.0], 100.0)
    found = ttq.first_crossing(curve, args)
    assert found["reached"] and found["epoch"] == 4 and found["env_steps"] == 400.0
    assert found["success"] == pytest.approx((0.5 + 1.0 + 1.0) / 3)
    missed = ttq.first_crossing(_curve([20, 20, 20], [0.7, 0.7, 0.7], 100.0), args)
    assert not missed["reached"] and missed["best"]["volume"] == 20


def test_time_to_quality_appends_a_row_per_stored_run_and_seed(tmp_path):
    ttq = benchmark("time_to_quality")
    stored = tmp_path / "ablation.jsonl"
    for seed, setting, volumes, successes in ((0, "curriculum", [16, 17, 18], [0.9, 0.9, 0.9]),
                                              (1, "curriculum", [10, 12, 14], [0.9, 0.9, 0.9]),
                                              (1, "fixed-box", [20, 20, 20], [1.0, 1.0, 1.0])):
        append_row(stored, {"schema": 1, "spec": "ablation", "row": f"ln/{setting}", "seed": seed, "preset": "p",
                            "figures": {"variant": "ln", "setting": setting, "curve": _curve(volumes, successes, 100.0)},
                            "train": {}})
    # a row with per-epoch curves instead of a recorded curve, under the name it was recorded as
    append_row(stored, {"schema": 1, "spec": "levels", "row": "k1", "seed": 2, "preset": "q", "figures": {},
                        "curves": {"env_steps": [100.0, 200.0, 300.0], "top_volume": [16, 17, 18],
                                   "top_success": [0.9, 0.9, 0.9]}, "train": {"recorded_as": "ln"}})
    results = tmp_path / "rows.jsonl"
    ttq.main(ttq.Args(presets=("ln",), curves=(str(stored),), window=3, results=str(results)))
    rows = read_rows(results)
    assert [(row["spec"], row["row"], row["seed"]) for row in rows] == [
        ("bench-time-to-quality", "curriculum/ln", 0), ("bench-time-to-quality", "curriculum/ln", 1),
        ("bench-time-to-quality", "curriculum/ln", 2)]
    assert rows[0]["figures"]["reached"] and rows[0]["figures"]["env_steps"] == 300.0
    assert not rows[1]["figures"]["reached"] and rows[1]["figures"]["best"]["volume"] == 14
    assert rows[0]["figures"]["target"] == {"volume": 16.0, "success": 0.8, "window": 3}
    assert rows[2]["figures"]["reached"] and rows[2]["figures"]["epoch"] == 3
