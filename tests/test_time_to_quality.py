"""benchmarks/time_to_quality.py: the first epoch whose top box and smoothed success meet both targets."""

import pytest
from tiny import benchmark


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
