"""k=2 against k=1 on the robots at an equal number of environment steps, from the runs' curves.

Issue 13's hierarchy target asks whether a two-level agent, given the environment steps a
one-level agent trained for, has a larger top box with greedy success >= 80 %. The k=2
presets run longer than k=1, so their final rows do not answer it. Every row of
``--rows`` (``experiments/robots_cpu.py``'s JSON) carries its per-epoch curve of
``[epoch, env_steps, top volume, greedy success on that epoch's 16 goals]``; this script
reads each curve at a step budget and writes one row per run plus a summary per robot:

- the budget of a robot is the mean final ``env_steps`` of its k=1 rows;
- a run's figure at the budget is the top volume at the epoch whose env steps are nearest
  to it, with success averaged over the ``--window`` epochs centred there (one epoch's 16
  goals are too few to read alone);
- a k=1 run is read the same way at its own last epoch, so both sides use one estimator.

Extra run directories (tuning runs not in the JSON) can be read with ``--extra
LABEL=RUN_DIR``; their curve comes from the run's ``metrics.jsonl`` and is written beside the figures.
``python experiments/equal_steps.py``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import tyro
from robots_cpu import top_curve

from mjx_emp.metrics import mean_and_stderr
from mjx_emp.run.store import read_metrics

ROBOTS = {"ant-field": ("ant-field-cpu-k1", "ant-field-cpu-k2"),
          "half-cheetah": ("half-cheetah-cpu-k1", "half-cheetah-cpu-k2")}
TARGET_SUCCESS = 0.8


@dataclasses.dataclass
class Args:
    """Read the robots' curves at k=1's step budget."""

    rows: str = "benchmarks/results/robots_cpu.json"
    window: int = 11
    """Epochs whose 16-goal success is averaged around the read epoch (odd)."""
    extra: tuple[str, ...] = ()
    """``LABEL=RUN_DIR`` runs to read as well (robot taken from LABEL's prefix)."""
    out: str = "benchmarks/results/robots_equal_steps_cpu.json"


def read_curve_at(curve: list[list[float]], steps: float, window: int) -> dict:
    """Top volume at the epoch nearest ``steps`` env steps, success averaged over ``window`` epochs there."""
    if not curve:
        raise ValueError("read_curve_at needs a non-empty curve")
    index = min(range(len(curve)), key=lambda i: abs(curve[i][1] - steps))
    half = window // 2
    around = curve[max(0, index - half):index + half + 1]
    epoch, env_steps, volume, _ = curve[index]
    return {"epoch": int(epoch), "env_steps": env_steps, "top_volume": volume,
            "success": sum(point[3] for point in around) / len(around), "window_epochs": len(around)}


def summarise(points: list[dict]) -> dict:
    """Mean and spread of volume and success over runs, and how many meet the success target."""
    return {"runs": len(points),
            "top_volume": mean_and_stderr([p["top_volume"] for p in points]),
            "success": mean_and_stderr([p["success"] for p in points]),
            "runs_at_target_success": sum(p["success"] >= TARGET_SUCCESS for p in points)}


def equal_steps(rows: list[dict], window: int, extra: dict[str, list[list[float]]]) -> dict:
    """Per robot: k=1 at its end, k=2 (and extra runs) at k=1's mean step budget, and the verdict."""
    report = {}
    for robot, (one, two) in ROBOTS.items():
        ones = [r for r in rows if r["preset"] == one]
        twos = [r for r in rows if r["preset"] == two]
        if not ones or not twos:
            continue
        budget = sum(r["env_steps"] for r in ones) / len(ones)
        k1 = [{"seed": r["seed"], **read_curve_at(r["curve"], r["env_steps"], window)} for r in ones]
        k2 = [{"seed": r["seed"], **read_curve_at(r["curve"], budget, window)} for r in twos]
        others = {label: {**read_curve_at(curve, budget, window), "curve": curve}
                  for label, curve in extra.items() if label.startswith(robot)}
        k1_sum, k2_sum = summarise(k1), summarise(k2)
        larger = k2_sum["top_volume"]["mean"] > k1_sum["top_volume"]["mean"]
        report[robot] = {
            "budget_env_steps": budget, "k1": k1, "k2": k2, "extra": others,
            "k1_summary": k1_sum, "k2_summary": k2_sum,
            "k2_larger_box": larger,
            "target_met": larger and k2_sum["success"]["mean"] >= TARGET_SUCCESS,
        }
    return report


def main(args: Args) -> None:
    """Print each robot's comparison and write it to ``--out``."""
    rows = json.loads(Path(args.rows).read_text())["rows"]
    extra = {}
    for item in args.extra:
        label, _, path = item.partition("=")
        if not path:
            raise SystemExit(f"--extra: expected LABEL=RUN_DIR, got {item!r}")
        extra[label] = top_curve(read_metrics(Path(path)))
    report = equal_steps(rows, args.window, extra)
    for robot, entry in report.items():
        k1, k2 = entry["k1_summary"], entry["k2_summary"]
        print(f"{robot}: budget {entry['budget_env_steps']:.3g} steps; "
              f"k=1 {k1['top_volume']['mean']:.2f} at {k1['success']['mean']:.2f} ({k1['runs']} runs), "
              f"k=2 {k2['top_volume']['mean']:.2f} at {k2['success']['mean']:.2f} ({k2['runs']} runs); "
              f"target met: {entry['target_met']}")
        for label, point in entry["extra"].items():
            print(f"  {label}: epoch {point['epoch']} {point['top_volume']:.2f} at {point['success']:.2f}")
    Path(args.out).write_text(json.dumps({"window": args.window, "target_success": TARGET_SUCCESS,
                                          "robots": report}, indent=1))


if __name__ == "__main__":
    main(tyro.cli(Args))
