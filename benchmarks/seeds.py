"""What `--seeds` saves: S seeds as one vmapped program against S runs one after another.

For each preset and seed count S, in one process, side by side:
- one seed: compile time (first epoch minus a warm one) and the median warm epoch;
- S seeds under one vmap (:class:`mjx_emp.run.seeds.SeedGroup`): the same two figures;
- speed-up = S x (one seed's warm epoch) / (the group's warm epoch): the steady-state gain
  over running the S seeds one after another; and for a whole run of ``--epochs`` epochs,
  S x (compile + epochs x epoch) over (group compile + epochs x group epoch).
Prints a Markdown table and writes JSON (default ``benchmarks/results/seeds_<backend>.json``).
"""

from __future__ import annotations

import dataclasses
import json
import platform
import statistics
import time
from pathlib import Path

import jax
import tyro

from mjx_emp.algos.registry import all_presets, make_agent
from mjx_emp.run.seeds import SeedGroup


@dataclasses.dataclass
class Args:
    """Seeds-in-one-program benchmark."""

    presets: tuple[str, ...] = ("point-mass-k1", "metra-point-mass")
    seed_counts: tuple[int, ...] = (4, 8)
    repeats: int = 3
    """Warm epochs timed per program (the median is reported)."""
    epochs: int = 150
    """Run length for the whole-run speed-up (point-mass-k1's own)."""
    out: str = ""
    """JSON output path; empty means benchmarks/results/seeds_<backend>.json."""


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
            print(json.dumps(rows[-1]), flush=True)
    print("| preset | seeds | one seed: epoch s (compile s) | vmapped: epoch s (compile s) | epoch speed-up | "
          "run speed-up |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['preset']} | {r['seeds']} | {r['one_seed']['epoch_s']:.3f} ({r['one_seed']['compile_s']:.1f}) | "
              f"{r['group']['epoch_s']:.3f} ({r['group']['compile_s']:.1f}) | {r['epoch_speedup']:.2f}x | "
              f"{r['run_speedup']:.2f}x |")
    out = Path(args.out or f"benchmarks/results/seeds_{jax.default_backend()}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"backend": jax.default_backend(), "devices": [str(d) for d in jax.devices()],
                               "machine": platform.processor() or platform.machine(), "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
