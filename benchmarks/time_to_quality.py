"""Time to quality on a small machine: env steps and wall-clock minutes until a preset's top
box first holds a target volume at a target greedy success.

For each (preset, seed), trains in this process epoch by epoch (``HEAgent.train_epoch``,
compile included; no checkpoints are written, which `mjx-emp train` would add) and after
every epoch reads the run's curve as ``experiments/equal_steps.py`` does: the top box's
volume at that epoch and its greedy success averaged over the last ``--window`` epochs'
evaluations (one epoch's goals are too few to read alone). At the first epoch where both
meet the target it confirms with the 400-goal evaluation of `mjx-emp eval` on that state;
a confirmation that fails is recorded and training goes on. The row gives the env steps
and wall seconds (training only, compile included; the confirmations' time is excluded
and reported apart) of the first confirmed epoch, or ``reached: false`` with the run's
best smoothed point if the budget (``--max-env-steps``, ``--max-minutes``) ends first. Each row is
appended to ``results/bench-time-to-quality.jsonl`` (``--results``) as it is made, named by its
preset (``SETTING/PRESET`` for a stored curve's) with its seed. Run it alone: timings shared with
another job are not the figure. ``python benchmarks/time_to_quality.py --presets ant-field-k1-cpu
--seeds 0``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import tyro

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.registry import all_presets, preset_or_retired_config
from mjx_emp.algos.retired import RETIRED
from mjx_emp.run.evaluate import phase1_figures
from mjx_emp.run.rows import append_row, benchmark_row, read_rows

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import row_name  # noqa: E402

SPEC = "bench-time-to-quality"


@dataclasses.dataclass
class Args:
    """Env steps and minutes until a target box at a target success."""

    presets: tuple[str, ...] = ("ant-field-k1-cpu",)
    seeds: tuple[int, ...] = (0,)
    target_volume: float = 16.0
    """Top box volume to reach (m^2 on the Ant, m on the Half Cheetah)."""
    target_success: float = 0.8
    window: int = 11
    """Epochs whose per-epoch greedy success is averaged (the trailing window)."""
    max_env_steps: float = 2.0e6
    max_minutes: float = 0.0
    """Also stop once training has taken this many minutes (0: no limit); a target asked
    for within N minutes needs no longer run."""
    episodes: int = 400
    """Greedy goals of the confirming evaluation."""
    curves: tuple[str, ...] = ()
    """Train nothing: read the per-epoch curves of the rows in these stores (e.g.
    ``results/robots-levels.jsonl``, ``results/learner-ablation.jsonl``) for ``--presets`` (a
    row's ``variant``, or the preset name it was recorded under) and report the first epoch that
    meets the target by the same smoothing; no 400-goal confirmation and no wall time (those
    runs shared the machine)."""
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""


def smoothed(curve: list[tuple[float, float]], window: int) -> float:
    """Mean success of the last ``window`` points of a (volume, success) curve."""
    recent = curve[-window:]
    return sum(success for _, success in recent) / len(recent)


def time_to_quality(preset: str, seed: int, args: Args) -> dict:
    """One row: when (env steps, wall seconds) PRESET's seed SEED first met the target, confirmed."""
    cfg = dataclasses.replace(preset_or_retired_config(preset), seed=seed)  # retired names rerun their rows
    trainer = HEAgent(cfg)
    start = time.perf_counter()
    state = trainer.init()
    curve: list[tuple[float, float]] = []
    checks, confirm_seconds, best = [], 0.0, None
    while True:
        state, stats = trainer.train_epoch(state)
        top = trainer.metrics(state, stats, 0.0)["levels"][-1]
        curve.append((top["volume"], top["success"]))
        steps = float(state.env_steps.value())
        wall = time.perf_counter() - start - confirm_seconds
        success = smoothed(curve, args.window)
        if len(curve) >= args.window and (best is None or top["volume"] * success > best["volume_x_success"]):
            best = {"epoch": int(state.epoch), "env_steps": steps, "volume": top["volume"], "success": success,
                    "volume_x_success": top["volume"] * success}
        if len(curve) >= args.window and top["volume"] >= args.target_volume and success >= args.target_success:
            began = time.perf_counter()
            figures = phase1_figures(trainer, state, jax.random.key(1000 + seed), args.episodes)
            confirm_seconds += time.perf_counter() - began
            level = figures["levels"][-1]
            confirmed = level["volume"] >= args.target_volume and level["success"] >= args.target_success
            checks.append({"epoch": int(state.epoch), "env_steps": steps, "wall_s": wall, "smoothed_success": success,
                           "volume": level["volume"], "success": level["success"], "confirmed": confirmed})
            print(json.dumps(checks[-1]), flush=True)
            if confirmed:
                return {"preset": preset, "seed": seed, "reached": True, "env_steps": steps, "wall_s": wall,
                        "wall_min": wall / 60, "epoch": int(state.epoch), "checks": checks,
                        "confirm_seconds": confirm_seconds, "config": dataclasses.asdict(cfg)}
        out_of_time = args.max_minutes > 0 and wall >= 60 * args.max_minutes
        if steps >= args.max_env_steps or int(state.epoch) >= cfg.epochs or out_of_time:
            return {"preset": preset, "seed": seed, "reached": False, "env_steps": steps, "wall_s": wall,
                    "wall_min": wall / 60, "epoch": int(state.epoch), "best": best, "checks": checks,
                    "confirm_seconds": confirm_seconds, "config": dataclasses.asdict(cfg)}


def first_crossing(curve: list[list[float]], args: Args) -> dict:
    """The first epoch of a stored curve ([epoch, env steps, top volume, success]) whose volume
    and trailing mean success meet the target, or the curve's best smoothed point."""
    best = None
    for i, (epoch, steps, volume, _) in enumerate(curve):
        if i + 1 < args.window:
            continue
        success = smoothed([(point[2], point[3]) for point in curve[:i + 1]], args.window)
        if volume >= args.target_volume and success >= args.target_success:
            return {"reached": True, "epoch": int(epoch), "env_steps": steps, "volume": volume, "success": success}
        if best is None or volume * success > best["volume"] * best["success"]:
            best = {"epoch": int(epoch), "env_steps": steps, "volume": volume, "success": success}
    return {"reached": False, "epoch": int(curve[-1][0]), "env_steps": curve[-1][1], "best": best}


def stored_curve(row: dict) -> list[list[float]] | None:
    """A stored row's per-epoch [epoch, env steps, top volume, success]: its recorded ``curve``,
    or the same rebuilt from its ``curves`` (epochs counted from 1); None where it has neither."""
    if row["figures"].get("curve"):
        return row["figures"]["curve"]
    curves = row.get("curves") or {}
    if not curves.get("top_volume"):
        return None
    return [[epoch, steps, volume, success] for epoch, (steps, volume, success)
            in enumerate(zip(curves["env_steps"], curves["top_volume"], curves["top_success"]), start=1)]


def from_curves(args: Args) -> list[dict]:
    """Rows of :func:`first_crossing` for every stored run of ``--presets`` in ``--curves``."""
    rows = []
    for path in args.curves:
        for stored in read_rows(Path(path)):
            name = stored["figures"].get("variant") or stored["train"].get("recorded_as") or stored["preset"]
            curve = stored_curve(stored)
            if name in args.presets and curve is not None:
                rows.append({"preset": name, "seed": stored["seed"], "source": path,
                             "setting": stored["figures"].get("setting", "curriculum"),
                             **first_crossing(curve, args), "wall_s": None})
    return rows


def store(row: dict, args: Args) -> None:
    """Append ``row`` (with the target it was held against) to the results store and print it."""
    row["target"] = {"volume": args.target_volume, "success": args.target_success, "window": args.window}
    append_row(Path(args.results), benchmark_row(SPEC, row_name(row), row, seed=row["seed"], preset=row["preset"],
                                                 env_steps=row["env_steps"], wall_s=row["wall_s"]))
    print(json.dumps({k: v for k, v in row.items() if k != "config"}), flush=True)


def main(args: Args) -> None:
    if args.curves:
        # One row per (preset, seed, source): a run evaluated at two budgets stores its curve twice.
        for row in {(r["preset"], r["seed"], r["source"]): r
                    for r in from_curves(args) if r["setting"] == "curriculum"}.values():
            store(row, args)
        return
    presets = all_presets()
    for preset in args.presets:
        if preset not in presets and preset not in RETIRED:
            raise SystemExit(f"presets: {preset!r} is unknown; allowed values: {sorted(presets)}")
        for seed in args.seeds:
            store(time_to_quality(preset, seed, args), args)


if __name__ == "__main__":
    main(tyro.cli(Args))
