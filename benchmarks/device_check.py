"""One prepared check for a GPU machine: everything the paper-scale path needs measured in one
command, its rows appended step by step (a step that fails is recorded and the next one runs;
``--steps`` picks the steps and their order when a lease is short).

Steps, each on every MJX backend that can run here (``jax``; ``warp`` where mujoco-warp and a
CUDA device are present):
1. ``rollout``: raw batched ``mjx.step`` and the one-scan k = 1..3 rollout on the Ant at
   B = 4096, 16384 and 32768 (``benchmarks/rollout.py``'s measurement);
2. ``train``: compile seconds, epoch seconds and env steps/s of ``ant-field-k1-paper-small``;
3. ``seeds``: 1, 4 and 8 seeds of it in one vmapped program (``benchmarks/seeds.py``'s timing);
4. ``memory``: the preflight's estimate (state and one epoch's working set) against the
   device's memory; ``train`` adds the device's peak after its epochs (run ``memory`` first,
   as ``--steps memory train ...`` does, so that the peak is that preset's alone).

``--dry-run`` runs every step at tiny sizes on the point mass (B = 8, 8 environments, 2
seeds, ``point-mass-k1`` for the training steps) so that the script can be tested on a CPU
in about a minute and cannot rot; its figures mean nothing. Steps not started when
``--budget-s`` has passed are recorded as skipped. See docs/gpu.md.

Each measured setting is a row of ``results/gpu-leases.jsonl`` (``--results``; a dry run's go
to ``results/gpu-leases-dry-run.jsonl``), named ``LEASE/check/STEP/...`` (a step on another
backend than jax: ``LEASE/check/IMPL/STEP/...``; one that did not run:
``LEASE/check/not_run/...`` with the reason). ``LEASE`` (``--lease``) defaults to
``gpu_lease_<device model>``, such as ``gpu_lease_h200``.

    python benchmarks/device_check.py --results /tmp/out/check.jsonl
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
import traceback
from pathlib import Path

import jax
import tyro

sys.path.insert(0, str(Path(__file__).parent))  # the sibling benchmarks whose measurements are reused

import rollout as rollout_benchmark  # noqa: E402
import seeds as seeds_benchmark  # noqa: E402
from bench_rows import RowNames, lease_name  # noqa: E402

from mjx_emp.algos.registry import all_presets, make_agent  # noqa: E402
from mjx_emp.envs.env import check_backend, make_env  # noqa: E402
from mjx_emp.errors import ConfigError  # noqa: E402
from mjx_emp.run.preflight import available_bytes, state_bytes, working_set_bytes  # noqa: E402
from mjx_emp.run.rows import RESULTS_DIR, append_row, benchmark_row  # noqa: E402
from mjx_emp.run.seeds import SeedGroup  # noqa: E402

PRESET = "ant-field-k1-paper-small"
SPEC = "gpu-leases"
DRY_RUN_SPEC = "gpu-leases-dry-run"
"""A dry run's rows: kept apart from the measured ones."""


@dataclasses.dataclass
class Args:
    """Every measurement a GPU lease needs, in one command."""

    dry_run: bool = False
    """Tiny sizes on any device: checks that every step runs, measures nothing."""
    batch_sizes: tuple[int, ...] = (4096, 16384, 32768)
    seed_counts: tuple[int, ...] = (1, 4, 8)
    impls: tuple[str, ...] = ("jax", "warp")
    steps: tuple[str, ...] = ("rollout", "train", "seeds", "memory")
    """Which steps run, in this order (a short lease puts the ones it needs most first)."""
    budget_s: float = 420.0
    """Start no new step after this many seconds (one command may run 10 minutes)."""
    results: str = ""
    """The results store the rows are appended to; empty means results/<spec>.jsonl."""
    lease: str = ""
    """The lease's name, the first part of every row name; empty: gpu_lease_<device model>."""


def sizes(args: Args) -> dict:
    """What each step runs at: the real sizes, or tiny ones for ``--dry-run``."""
    if args.dry_run:
        return {"env": "point_mass", "preset": "point-mass-k1", "batch_sizes": (8,), "levels": (1,),
                "rollout_steps": 4, "repeats": 1, "seed_counts": (2,),
                "train": dict(num_envs=8, batch_size=16, gc_iterations=1, gc_grad_steps=2, gs_iterations=1,
                              gs_grad_steps=1, replay_capacity=512, gs_replay_capacity=64, start_capacity=64,
                              start_chain=2, hidden=(16,))}
    return {"env": "ant_field", "preset": PRESET, "batch_sizes": args.batch_sizes, "levels": (1, 2, 3),
            "rollout_steps": 40, "repeats": 3, "seed_counts": args.seed_counts, "train": {}}


def backend_problem(impl: str) -> str | None:
    """Why ``impl`` cannot run in this process, or None."""
    try:
        check_backend(impl)
    except ConfigError as err:
        return str(err)
    return None


def rollout_step(impl: str, plan: dict) -> list[dict]:
    env = make_env(plan["env"], impl=impl)
    options = rollout_benchmark.Args(levels=plan["levels"], repeats=plan["repeats"])
    return [{"impl": impl, **row} for batch in plan["batch_sizes"]
            for row in rollout_benchmark.bench_group(env, batch, plan["rollout_steps"], options)]


def train_config(impl: str, plan: dict):
    return dataclasses.replace(all_presets()[plan["preset"]][1], impl=impl, **plan["train"])


def device_memory_stats() -> dict:
    """The default device's allocator figures (empty where the device reports none, as a CPU)."""
    device = jax.local_devices()[0]
    return dict((device.memory_stats() if hasattr(device, "memory_stats") else None) or {})


def train_step(impl: str, plan: dict) -> dict:
    cfg = train_config(impl, plan)
    agent = make_agent(cfg)
    timing = seeds_benchmark.time_program(agent.init, agent.train_epoch, plan["repeats"])
    steps = float(agent.metrics(*agent.train_epoch(agent.init()), 1.0)["env_steps"])  # one epoch's
    # The process's peak so far: with ``memory`` run first, that is this preset's init and epochs.
    peak = device_memory_stats().get("peak_bytes_in_use")
    return {"impl": impl, "preset": plan["preset"], "num_envs": cfg.num_envs, **timing,
            "env_steps_per_epoch": steps, "env_steps_per_s": steps / timing["epoch_s"], "peak_bytes_in_use": peak}


def seeds_step(impl: str, plan: dict) -> list[dict]:
    agent = make_agent(train_config(impl, plan))
    rows = []
    for count in plan["seed_counts"]:
        group = SeedGroup(agent, tuple(range(count)))
        rows.append({"impl": impl, "seeds": count,
                     **seeds_benchmark.time_program(group.init, group.train_epoch, plan["repeats"])})
    return rows


def memory_step(impl: str, plan: dict) -> dict:
    cfg = train_config(impl, plan)
    agent = make_agent(cfg)
    free, where = available_bytes()
    return {"impl": impl, "state_bytes": state_bytes(agent), "working_set_bytes": working_set_bytes(cfg, agent.env),
            "free_bytes": free, "where": where, "device_memory_stats": device_memory_stats()}


STEPS = {"rollout": rollout_step, "train": train_step, "seeds": seeds_step, "memory": memory_step}


def step_rows(spec: str, lease: str, entry: dict, names: RowNames) -> list[dict]:
    """One step's rows: one per setting it measured, or one saying why it did not run."""
    step, impl = entry["step"], entry["impl"]
    if "result" not in entry:
        record = {"step": step, "impl": impl, "why": entry.get("skipped") or entry.get("error"),
                  **{key: entry[key] for key in ("traceback",) if key in entry}}
        return [benchmark_row(spec, names(record, f"{lease}/check/not_run"), record)]
    group = f"{lease}/check/{step}" if impl == "jax" else f"{lease}/check/{impl}/{step}"
    result = entry["result"]
    return [benchmark_row(spec, names(record, group), {**record, "step": step, "step_s": entry["seconds"]})
            for record in (result if isinstance(result, list) else [result])]


def main(args: Args) -> list[dict]:
    unknown = [name for name in args.steps if name not in STEPS]
    if unknown:
        print(f"--steps: unknown {unknown}; allowed values are {sorted(STEPS)}", file=sys.stderr)
        raise SystemExit(2)
    spec = DRY_RUN_SPEC if args.dry_run else SPEC
    results = Path(args.results or Path(RESULTS_DIR) / f"{spec}.jsonl")
    lease = args.lease or lease_name(jax.devices()[0].device_kind)
    plan = sizes(args)
    names = RowNames()
    rows = []
    start = time.perf_counter()
    for impl in args.impls:
        problem = backend_problem(impl)
        for name in args.steps:
            step = STEPS[name]
            entry = {"step": name, "impl": impl}
            if problem:
                entry["skipped"] = problem
            elif time.perf_counter() - start > args.budget_s:
                entry["skipped"] = f"time budget of {args.budget_s:.0f} s spent"
            else:
                began = time.perf_counter()
                try:
                    entry["result"] = step(impl, plan)
                except Exception as err:  # recorded, and the next step still runs
                    entry["error"] = f"{type(err).__name__}: {err}"
                    entry["traceback"] = traceback.format_exc(limit=8)
                entry["seconds"] = time.perf_counter() - began
            for row in step_rows(spec, lease, entry, names):
                append_row(results, row)
                rows.append(row)
            print(json.dumps({k: v for k, v in entry.items() if k != "traceback"})[:400], flush=True)
    print(f"appended {len(rows)} rows to {results} ({time.perf_counter() - start:.0f} s)")
    return rows


if __name__ == "__main__":
    main(tyro.cli(Args))
