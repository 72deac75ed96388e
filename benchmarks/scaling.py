"""Environment steps per second of one preset split over 1, 2 and 4 devices, and of 1, 4 and 8
seeds in one program.

Devices: a subprocess per device count D, with D forced CPU devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=D``) on a CPU machine, or the first D
GPUs; the run is split into D shards (same total environments), one per device. Seeds:
:class:`mjx_emp.run.seeds.SeedGroup` over S seeds, whose steps count S times. Each figure
is the env steps of a warm epoch over its median wall time (``--repeats`` epochs after the
compiling one). Forced CPU devices share the machine's cores, so on a CPU they measure the
cost of the split (collectives, per-device programs), not a speed-up. Prints a Markdown
table and appends one row per device count (``devices/devicesD``) and seed count
(``seeds/seedsS``) to ``results/bench-scaling.jsonl`` (``--results``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import tyro

from mjx_emp.run.rows import append_row, benchmark_row

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import row_name  # noqa: E402

SPEC = "bench-scaling"


@dataclasses.dataclass
class Args:
    """Scaling over devices and seeds."""

    preset: str = "point-mass-k1"
    devices: tuple[int, ...] = (1, 2, 4)
    seeds: tuple[int, ...] = (1, 4, 8)
    repeats: int = 3
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""


def total_steps(counter) -> int:
    """A step counter's count summed over any leading (seed or shard) axes."""
    import numpy as np

    from mjx_emp.counters import StepCounter

    return sum(StepCounter(hi=hi, lo=lo).value() for hi, lo in zip(np.ravel(counter.hi), np.ravel(counter.lo)))


def warm_epoch(program, repeats: int) -> tuple[float, float]:
    """(median seconds of a warm epoch, env steps it simulated) of ``program`` (init/train_epoch)."""
    import jax

    state = program.init()
    state, _ = program.train_epoch(state)
    jax.block_until_ready(state)
    seconds, steps = [], []
    for _ in range(repeats):
        before = total_steps(state.env_steps)
        start = time.perf_counter()
        state, _ = program.train_epoch(state)
        jax.block_until_ready(state)
        seconds.append(time.perf_counter() - start)
        steps.append(total_steps(state.env_steps) - before)
    return statistics.median(seconds), statistics.median(steps)


def measure_devices(preset: str, devices: int, repeats: int) -> dict:
    """In this process (started with ``devices`` devices): the preset split into one shard each."""
    import jax

    from mjx_emp.algos.registry import all_presets
    from mjx_emp.run.devices import ShardedAgent

    cfg = dataclasses.replace(all_presets()[preset][1], shards=devices)
    program = ShardedAgent(cfg, devices)
    seconds, steps = warm_epoch(program, repeats)
    # A split state counts the whole run's steps on every shard: count it once.
    steps /= cfg.shards
    return {"devices": devices, "backend": jax.default_backend(), "epoch_s": seconds, "env_steps": steps,
            "env_steps_per_s": steps / seconds}


def measure_seeds(preset: str, seeds: int, repeats: int) -> dict:
    """S seeds of the preset as one vmapped program (S = 1: the agent alone)."""
    from mjx_emp.algos.registry import all_presets, make_agent
    from mjx_emp.run.seeds import SeedGroup

    agent = make_agent(all_presets()[preset][1])
    program = agent if seeds == 1 else SeedGroup(agent, tuple(range(seeds)))
    seconds, steps = warm_epoch(program, repeats)
    return {"seeds": seeds, "epoch_s": seconds, "env_steps": steps, "env_steps_per_s": steps / seconds}


def main(args: Args) -> None:
    import jax

    device_rows = []
    for count in args.devices:
        env = {**os.environ}
        if jax.default_backend() == "cpu":
            env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={count}".strip()
        code = (f"import json, sys; sys.path.insert(0, 'benchmarks'); from scaling import measure_devices; "
                f"print(json.dumps(measure_devices({args.preset!r}, {count}, {args.repeats})))")
        result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        device_rows.append(json.loads(result.stdout.strip().splitlines()[-1]))
        append_row(Path(args.results), benchmark_row(SPEC, row_name(device_rows[-1], "devices"), device_rows[-1],
                                                     preset=args.preset))
        print(json.dumps(device_rows[-1]), flush=True)
    seed_rows = []
    for count in args.seeds:
        seed_rows.append(measure_seeds(args.preset, count, args.repeats))
        append_row(Path(args.results), benchmark_row(SPEC, row_name(seed_rows[-1], "seeds"), seed_rows[-1],
                                                     preset=args.preset))
        print(json.dumps(seed_rows[-1]), flush=True)
    print(f"| {args.preset} | env steps/s | relative to 1 |")
    print("|---|---|---|")
    for rows, key, name in ((device_rows, "devices", "devices"), (seed_rows, "seeds", "seeds")):
        for row in rows:
            print(f"| {row[key]} {name} | {row['env_steps_per_s']:.3g} | "
                  f"{row['env_steps_per_s'] / rows[0]['env_steps_per_s']:.2f}x |")
    print(f"appended {len(device_rows) + len(seed_rows)} rows to {args.results}")


if __name__ == "__main__":
    main(tyro.cli(Args))
