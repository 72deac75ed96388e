"""What `--seeds` saves: S seeds as one vmapped program against S runs one after another.

For each preset and seed count S, in one process, side by side:
- one seed: compile time (first epoch minus a warm one) and the median warm epoch;
- S seeds under one vmap (:class:`mjx_emp.run.seeds.SeedGroup`): the same two figures;
- speed-up = S x (one seed's warm epoch) / (the group's warm epoch): the steady-state gain
  over running the S seeds one after another; and for a whole run of ``--epochs`` epochs,
  S x (compile + epochs x epoch) over (group compile + epochs x group epoch).
Prints a Markdown table and appends one row per (preset, S) to ``results/bench-seeds.jsonl``
(``--results``).
"""

from __future__ import annotations

import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path

import jax
import tyro

from mjx_emp.algos.registry import all_presets, make_agent
from mjx_emp.run.rows import append_row, benchmark_row
from mjx_emp.run.seeds import SeedGroup

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import row_name  # noqa: E402

SPEC = "bench-seeds"


@dataclasses.dataclass
class Args:
    """Seeds-in-one-program benchmark."""

    presets: tuple[str, ...] = ("point-mass-k1", "metra-point-mass")
    seed_counts: tuple[int, ...] = (4, 8)
    repeats: int = 3
    """Warm epochs timed per program (the median is reported)."""
    epochs: int = 150
    """Run length for the whole-run speed-up (point-mass-k1's own)."""
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""


def _seconds(fn) -> tuple[float, object]:
    start = time.perf_counter()
    out = fn()
    jax.block_until_ready(out)
    return time.perf_counter() - start, out


def time_program(init, train_epoch, repeats: int) -> dict:
    """Compile seconds (first epoch minus the median warm one) and the median warm epoch."""
    state = init()
    first, (state, _) = _seconds(lambda: train_epoch(state))
    warm = []
    for _ in range(repeats):
        seconds, (state, _) = _seconds(lambda: train_epoch(state))
        warm.append(seconds)
    epoch = statistics.median(warm)
    return {"compile_s": first - epoch, "epoch_s": epoch}


def main(args: Args) -> None:
    rows = []
    for preset in args.presets:
        agent = make_agent(all_presets()[preset][1])
        one = time_program(agent.init, agent.train_epoch, args.repeats)
        for count in args.seed_counts:
            group = SeedGroup(agent, tuple(range(count)))
            together = time_program(group.init, group.train_epoch, args.repeats)
            sequential_run = count * (one["compile_s"] + args.epochs * one["epoch_s"])
            group_run = together["compile_s"] + args.epochs * together["epoch_s"]
            rows.append({
                "preset": preset, "seeds": count, "one_seed": one, "group": together,
                "epoch_speedup": count * one["epoch_s"] / together["epoch_s"],
                "run_speedup": sequential_run / group_run, "epochs": args.epochs,
            })
            append_row(Path(args.results), benchmark_row(SPEC, row_name(rows[-1]), rows[-1], preset=preset))
            print(json.dumps(rows[-1]), flush=True)
    print("| preset | seeds | one seed: epoch s (compile s) | vmapped: epoch s (compile s) | epoch speed-up | "
          "run speed-up |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['preset']} | {r['seeds']} | {r['one_seed']['epoch_s']:.3f} ({r['one_seed']['compile_s']:.1f}) | "
              f"{r['group']['epoch_s']:.3f} ({r['group']['compile_s']:.1f}) | {r['epoch_speedup']:.2f}x | "
              f"{r['run_speedup']:.2f}x |")
    print(f"appended {len(rows)} rows to {args.results}")


if __name__ == "__main__":
    main(tyro.cli(Args))
