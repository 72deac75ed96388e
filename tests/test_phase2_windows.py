"""experiments/phase2_windows.py: phase-2 learning curves averaged over windows of epochs."""

import pytest
from phase2_windows import window_means


def _line(epoch: int, distance: float) -> dict:
    return {"epoch": epoch, "train_min_distance": distance, "train_success": 0.5, "min_distance": distance + 1,
            "success": 0.25}


def test_windows_average_whole_windows_and_drop_a_short_last_one():
    lines = [_line(e, float(e)) for e in range(1, 8)]  # epochs 1-7 in windows of 3: 1-3, 4-6 (7 dropped)
    windows = window_means(lines, 3)
    assert [(w["first_epoch"], w["last_epoch"]) for w in windows] == [(1, 3), (4, 6)]
    assert [w["train_min_distance"] for w in windows] == [2.0, 5.0]
    assert [w["min_distance"] for w in windows] == [3.0, 6.0]
    with pytest.raises(SystemExit, match="window: must be >= 1; got 0"):
        window_means(lines, 0)
