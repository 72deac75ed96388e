"""Persistent replay rings against the paper's fresh buffer D per call, same presets and seeds.

The paper's Algorithms 2 and 3 start every goal-conditioned and goal-space iteration with
an empty buffer and learn from that iteration's collection only; the library's default
keeps ring buffers across iterations (``HEConfig.fresh_replay``). For each preset and
seed this trains both variants for the same number of epochs and evaluates them the
same way as `mjx-emp eval` (top box at the initial state, greedy success on goals from
it, coverage). ``python experiments/replay_compare.py --presets point-mass-k1
--seeds 0 1``; results go to ``--out``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import tyro

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.metrics import mean_and_stderr
from mjx_emp.run.evaluate import phase1_figures
from mjx_emp.tables import markdown_table, mean_stderr_text


@dataclasses.dataclass
class Args:
    """Fresh per-call buffers (the paper) against persistent rings (the default)."""

    presets: tuple[str, ...] = ("point-mass-k1",)
    seeds: tuple[int, ...] = (0, 1)
    epochs: int | None = None
    """Override the presets' epoch counts; None keeps them."""
    episodes: int = 400
    out: str = "benchmarks/results/replay_compare_cpu.json"


def train_and_evaluate(config, episodes: int) -> dict:
    """Train ``config`` in process and report its top level as `mjx-emp eval` would."""
    trainer = HEAgent(config)
    state = trainer.init()
    start = time.perf_counter()
    for _ in range(config.epochs):
        state, _ = trainer.train_epoch(state)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - start
    figures = phase1_figures(trainer, state, jax.random.key(1000 + config.seed), episodes)
    top = figures["levels"][-1]
    return {"fresh_replay": config.fresh_replay, "seed": config.seed, "epochs": config.epochs,
            "env_steps": figures["env_steps"], "seconds": seconds, "top_volume": top["volume"],
            "success": top["success"], "final_distance": top["final_distance"],
            "coverage_cells": figures["coverage_cells"]}


def main(args: Args) -> None:
    result = {}
    for preset in args.presets:
        base = PRESETS[preset][1]
        if args.epochs is not None:
            base = dataclasses.replace(base, epochs=args.epochs)
        rows = []
        for seed in args.seeds:
            for fresh in (False, True):
                row = train_and_evaluate(dataclasses.replace(base, seed=seed, fresh_replay=fresh), args.episodes)
                rows.append(row)
                print(json.dumps({"preset": preset, **row}), flush=True)
        summary = {
            ("fresh" if fresh else "persistent"): {
                name: mean_and_stderr([r[name] for r in rows if r["fresh_replay"] == fresh])
                for name in ("top_volume", "success", "coverage_cells")
            }
            for fresh in (False, True)
        }
        result[preset] = {"rows": rows, "summary": summary}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    rows = [(preset, kind, *(mean_stderr_text(s[name]) for name in ("top_volume", "success", "coverage_cells")))
            for preset, entry in result.items() for kind, s in entry["summary"].items()]
    print(markdown_table(("preset", "buffers", "top volume", "greedy success", "coverage cells"), rows))
    print(f"wrote {out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
