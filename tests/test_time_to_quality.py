"""The k=2 against k=1 comparison at an equal step budget (experiments/equal_steps.py)."""

import importlib.util
import sys
from pathlib import Path

import pytest
from equal_steps import equal_steps, read_curve_at


def _curve(volumes, successes, steps_per_epoch):
    return [[e + 1, (e + 1) * steps_per_epoch, v, s] for e, (v, s) in enumerate(zip(volumes, successes))]


def test_read_curve_at_takes_the_nearest_epoch_and_averages_success_around_it():
    curve = _curve([1, 2, 3, 4, 5], [0.0, 0.5, 1.0, 0.5, 0.0], 100.0)
    point = read_curve_at(curve, 290.0, window=3)
    assert point["epoch"] == 3 and point["top_volume"] == 3
    assert point["success"] == pytest.approx(2 / 3)
    assert read_curve_at(curve, 10.0, window=3)["window_epochs"] == 2  # clipped at the start


def test_target_needs_both_a_larger_box_and_success_of_80_percent():
    k1 = {"preset": "ant-field-cpu-k1", "seed": 0, "env_steps": 300.0,
          "curve": _curve([5, 5, 5], [0.9, 0.9, 0.9], 100.0)}
    big_but_unreliable = {"preset": "ant-field-cpu-k2", "seed": 0, "env_steps": 1000.0,
                          "curve": _curve([1, 9, 9, 9, 40], [0.5, 0.6, 0.6, 0.6, 0.1], 75.0)}
    report = equal_steps([k1, big_but_unreliable], window=3, extra={})["ant-field"]
    assert report["budget_env_steps"] == 300.0
    assert report["k2"][0]["epoch"] == 4 and report["k2"][0]["top_volume"] == 9
    assert report["k2_larger_box"] and not report["target_met"]
    reliable = dict(big_but_unreliable, curve=_curve([1, 9, 9, 9, 40], [0.9] * 5, 75.0))
    assert equal_steps([k1, reliable], window=3, extra={})["ant-field"]["target_met"]



def _benchmark(name: str):
    """A script under benchmarks/ as a module (benchmarks are not a package)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the script runs
    spec.loader.exec_module(module)
    return module


def test_time_to_quality_finds_the_first_epoch_meeting_both_targets_on_smoothed_success():
    ttq = _benchmark("time_to_quality")
    args = ttq.Args(target_volume=16.0, target_success=0.8, window=3)
    # Epoch 3 has the volume but its 3-epoch success is (0.5 + 0.5 + 1) / 3 < 0.8; epoch 4 meets both.
    curve = _curve([10, 12, 16, 17, 18], [0.5, 0.5, 1.0, 1.0, 1.0], 100.0)
    found = ttq.first_crossing(curve, args)
    assert found["reached"] and found["epoch"] == 4 and found["env_steps"] == 400.0
    assert found["success"] == pytest.approx((0.5 + 1.0 + 1.0) / 3)
    missed = ttq.first_crossing(_curve([20, 20, 20], [0.7, 0.7, 0.7], 100.0), args)
    assert not missed["reached"] and missed["best"]["volume"] == 20
