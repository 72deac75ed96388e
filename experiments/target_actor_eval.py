"""Does the Polyak-averaged (target) actor reach more goals than the online one?

A diagnostic for the Ant k=1 runs, whose greedy success wavers from epoch to epoch:
evaluates each run's newest checkpoint twice, as `mjx-emp eval` does (400+ greedy goals
from the top box at s0, coverage from 48 skills), once with the online goal-conditioned
actors and once with their target copies, on the same goals.
``python experiments/target_actor_eval.py --runs runs/robots_cpu/ant-field-cpu-k1-s0``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import tyro

from mjx_emp.run import jobs
from mjx_emp.run.evaluate import phase1_figures


@dataclasses.dataclass
class Args:
    runs: tuple[str, ...] = ("runs/robots_cpu/ant-field-cpu-k1-s0", "runs/robots_cpu/ant-field-cpu-k1-s1")
    episodes: int = 400
    out: str = "benchmarks/results/ant_target_actor_eval_cpu.json"


def top_figures(trainer, state, key, episodes: int) -> dict:
    """Top level's greedy success and final distance, and the coverage cells."""
    figures = phase1_figures(trainer, state, key, episodes)
    top = figures["levels"][-1]
    return {"success": top["success"], "final_distance": top["final_distance"], "coverage_cells": figures["coverage_cells"]}


def main(args: Args) -> None:
    rows = []
    for seed, run_dir in enumerate(args.runs):
        trainer, epoch, state = jobs.load_run(Path(run_dir))
        target = state.replace(policies=tuple(p.replace(actor=p.target_actor) for p in state.policies))
        key = jax.random.key(1000 + seed)
        rows.append({"run_dir": run_dir, "epoch": epoch, "online": top_figures(trainer, state, key, args.episodes),
                     "target": top_figures(trainer, target, key, args.episodes)})
        print(json.dumps(rows[-1]), flush=True)
    Path(args.out).write_text(json.dumps({"backend": jax.default_backend(), "rows": rows}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
