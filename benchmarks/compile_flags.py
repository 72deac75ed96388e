"""Compile time of one training epoch under XLA CPU flag sets, each in a fresh process.

The test suite is mostly XLA compiling small programs, so the flags it compiles under set its
length. For each flag set (rounds interleaved, so a slow spell of the machine hits every set
alike) a new process with the persistent cache off builds a small two-level point-mass agent
and runs its first epoch; JAX's own event durations split the time into tracing, lowering and
the back end's compile. Prints a Markdown table and appends one row per flag set to
``results/bench-compile-flags.jsonl`` (``--results``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

import tyro

from mjx_emp.run.rows import append_row, benchmark_row
from mjx_emp.tables import markdown_table

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import numbered_names  # noqa: E402

SPEC = "bench-compile-flags"

FLAG_SETS = {
    "default": "",
    "llvm-O0": "--xla_backend_optimization_level=0",
    "llvm-O0, older fusion code generator": "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false",
    "llvm-O0, older fusion code generator, legacy runtime": (
        "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false --xla_cpu_use_thunk_runtime=false"
    ),
}

ROW_NAMES = numbered_names(FLAG_SETS)
"""Each flag set's row name: its place in ``FLAG_SETS`` (``all``, ``all#2``, ...)."""

CHILD = r"""
import dataclasses, json, time
from collections import defaultdict
import jax
spent = defaultdict(float)
jax.monitoring.register_event_duration_secs_listener(lambda event, secs, **_: spent.__setitem__(event, spent[event] + secs))
from mjx_emp.algos.registry import all_presets, make_agent
cfg = dataclasses.replace(
    all_presets()["point-mass-k2"][1], n=(3, 2), num_envs=8, chunk_steps=3, gc_iterations=2, gc_grad_steps=3,
    gs_grad_steps=2, batch_size=16, replay_capacity=512, gs_replay_capacity=64, start_capacity=64, start_chain=2,
    hidden=(16,),
)
began = time.perf_counter()
agent = make_agent(cfg)
state, _ = agent.train_epoch(agent.init())
jax.block_until_ready(state)
total = time.perf_counter() - began
short = {event.rsplit("/", 1)[-1]: secs for event, secs in spent.items()}
print(json.dumps({"total_s": total, "trace_s": short.get("jaxpr_trace_duration", 0.0),
                  "lower_s": short.get("jaxpr_to_mlir_module_duration", 0.0),
                  "backend_compile_s": short.get("backend_compile_duration", 0.0), "backend": jax.default_backend()}))
"""


@dataclasses.dataclass
class Args:
    """Compile-flag benchmark."""

    sets: tuple[str, ...] = tuple(FLAG_SETS)
    """Which flag sets to time (names of ``FLAG_SETS``)."""
    rounds: int = 2
    """Fresh processes per flag set, interleaved."""
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""
    beside: str = "nothing"
    """What else ran on the machine (recorded with the result)."""


def time_once(flags: str) -> dict:
    """One fresh process's first epoch under ``flags`` (cache off), as the child prints it."""
    env = {**os.environ, "XLA_FLAGS": flags, "JAX_ENABLE_COMPILATION_CACHE": "false"}
    done = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, env=env, timeout=1800)
    if done.returncode != 0:
        raise SystemExit(f"flags {flags!r}: the child failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(args: Args) -> None:
    """Time every flag set ``args.rounds`` times and write the table."""
    unknown = [name for name in args.sets if name not in FLAG_SETS]
    if unknown:
        print(f"--sets: unknown {unknown}; choose from {list(FLAG_SETS)}", file=sys.stderr)
        raise SystemExit(2)
    runs: dict[str, list[dict]] = {name: [] for name in args.sets}
    for _ in range(args.rounds):
        for name in args.sets:
            runs[name].append(time_once(FLAG_SETS[name]))
            print(name, runs[name][-1], flush=True)
    backend = next(iter(runs.values()))[0]["backend"]
    rows = []
    for name, timings in runs.items():
        row = {"flags": name, "xla_flags": FLAG_SETS[name], "rounds": len(timings), "backend": backend,
               "beside": args.beside}
        for key in ("total_s", "trace_s", "lower_s", "backend_compile_s"):
            values = [t[key] for t in timings]
            row[key] = statistics.fmean(values)
            row[key + "_each"] = values
        rows.append(row)
        append_row(Path(args.results), benchmark_row(SPEC, ROW_NAMES[name], row))
    baseline = rows[0]["backend_compile_s"]
    print(markdown_table(
        ["flags", "first epoch (s)", "back-end compile (s)", "ratio to the first row"],
        [[row["flags"], f"{row['total_s']:.1f}", f"{row['backend_compile_s']:.1f}",
          f"{row['backend_compile_s'] / baseline:.2f}"] for row in rows],
    ))
    print(f"appended {len(rows)} rows ({backend}) to {args.results}")


if __name__ == "__main__":
    main(tyro.cli(Args))
