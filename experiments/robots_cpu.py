"""Hierarchical Empowerment on the paper's robots at CPU scale: presets x seeds, one JSON row each.

For every (preset, seed), trains the preset (or resumes BASE/<preset>-s<seed> if a run is
there: a finished run is only evaluated) through the CLI's own functions, then evaluates
its newest checkpoint as `mjx-emp eval` does: the top goal-space box at the initial
state, greedy success on ``--episodes`` goals from it, and METRA's coverage (1 m cells
of goal space visited by 48 greedy top-level skills). Rows carry ``preset``, ``seed``,
``env_steps``, ``wall_s`` (training time summed from the run's metrics, compile
included), ``top_area`` (m^2 for Ant, m for Half Cheetah), ``success``,
``coverage_cells`` and, where RUN_DIR/phase2 holds a phase-2 run (`mjx-emp phase2
RUN_DIR`), ``phase2``: its mean minimum distance to goal and success.
``python experiments/robots_cpu.py --presets ant-field-k1-cpu --seeds 0 1 2 3``;
rows are merged into ``--out`` (one per preset and seed).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import tyro
from baselines import merge_row, phase2_evaluation, train_or_resume

from mjx_emp.run import jobs
from mjx_emp.run.evaluate import phase1_figures
from mjx_emp.run.store import read_metrics


@dataclasses.dataclass
class Args:
    """Robot presets over seeds, evaluated the same way."""

    presets: tuple[str, ...] = ("ant-field-k1-cpu",)
    seeds: tuple[int, ...] = (0, 1, 2, 3)
    epochs: int | None = None
    """Override the presets' epoch counts (a shorter budget); None keeps them for a new run and a run's own count
    for one already there (it is resumed, never trained past it)."""
    base: str = "runs/robots_cpu"
    """Where the runs go (existing runs are resumed or reused)."""
    train: bool = True
    """False evaluates existing runs at their newest checkpoint without training further
    (a row then records the epoch it reached)."""
    at_epoch: int | None = None
    """Evaluate this epoch's checkpoint (it must still be kept) instead of the newest; wall
    time and resets are then summed up to it."""
    episodes: int = 400
    """Greedy evaluation episodes per run."""
    out: str = "benchmarks/results/robots_cpu.json"


def top_curve(metrics: list[dict]) -> list[list[float]]:
    """Per epoch of a run's metrics: epoch, env steps, top box volume and greedy success on that
    epoch's num_envs goals (the ``curve`` of a row, read by ``equal_steps.py``)."""
    return [[m["epoch"], m["env_steps"], m["levels"][-1]["volume"], m["levels"][-1]["success"]] for m in metrics]


def critic_loss_curve(metrics: list[dict]) -> list[list[float | None]]:
    """Per epoch: epoch, then each level's goal-conditioned critic loss, bottom level first (the
    ``gc_critic_loss`` of a row: whether a learner's critic diverges is read off it)."""
    return [[m["epoch"], *(level.get("gc_critic_loss") for level in m["levels"])] for m in metrics]


def evaluate_run(run_dir: Path, preset: str, seed: int, episodes: int, epoch: int | None = None) -> dict:
    """One JSON row: what the run used and what its top level learned (at ``epoch``, or the newest)."""
    return loaded_run_row(run_dir, preset, seed, episodes, jobs.load_run(run_dir, epoch=epoch))


def loaded_run_row(run_dir: Path, preset: str, seed: int, episodes: int, loaded: tuple,
                   phase2_loaded: tuple | None = None) -> dict:
    """``evaluate_run``'s row from a run already loaded by ``jobs.load_run`` (trainer, epoch,
    state), for callers that need the loaded agent too and should not restore it twice; likewise
    its phase 2 when ``phase2_loaded`` (``jobs.load_phase2``'s tuple) is given."""
    trainer, epoch, state = loaded
    figures = phase1_figures(trainer, state, jax.random.key(1000 + seed), episodes)
    metrics = [m for m in read_metrics(run_dir) if m["epoch"] <= epoch]
    top = figures["levels"][-1]
    return {
        "preset": preset, "seed": seed, "run_dir": str(run_dir), "epoch": figures["epoch"],
        "preset_epochs": trainer.cfg.epochs,
        "env_steps": figures["env_steps"], "wall_s": sum(m["seconds"] for m in metrics),
        "top_area": top["volume"], "top_half_width": top["half_width"], "top_shift": top["shift"],
        "success": top["success"], "final_distance": top["final_distance"],
        "coverage_cells": figures["coverage_cells"], "volume_x_success": figures["volume_x_success"],
        "flip_resets": sum(m.get("flip_resets", 0) for m in metrics),
        "levels": figures["levels"],
        "curve": top_curve(metrics),
        "gc_critic_loss": critic_loss_curve(metrics),
        "phase2": phase2_evaluation(run_dir, seed, episodes, phase2_loaded),
        "config": dataclasses.asdict(trainer.cfg),
    }


def main(args: Args) -> None:
    out = Path(args.out)
    rows = json.loads(out.read_text())["rows"] if out.exists() else []
    for preset in args.presets:
        for seed in args.seeds:
            if args.train:
                run_dir = train_or_resume(Path(args.base), preset, seed, args.epochs)
            else:
                run_dir = Path(args.base) / f"{preset}-s{seed}"
            row = evaluate_run(run_dir, preset, seed, args.episodes, args.at_epoch)
            summary = {k: v for k, v in row.items() if k not in ("levels", "curve", "gc_critic_loss")}
            print(json.dumps(summary), flush=True)
            rows = merge_row(out, row)  # re-reads OUT: a run beside this one may have written rows meanwhile
    print("| preset | seed | env steps | wall s | top area | success | coverage cells |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['preset']} | {r['seed']} | {r['env_steps']:.3g} | {r['wall_s']:.0f} | {r['top_area']:.3g} | "
              f"{r['success']:.2f} | {r['coverage_cells']} |")
    print(f"wrote {out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
