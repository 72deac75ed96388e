"""Cost of a full phase-1 training epoch next to pure rollout, and its compile time.

For each domain and k, in one process:
- compile: wall time of the first epoch minus a warm epoch (the epoch is one jitted call);
- recompiled: whether a later epoch compiled again (it must not);
- epoch env steps/s: physics-level primitive steps of a warm epoch over its wall time
  (collection at every level plus all gradient steps, start-state chain and evaluation);
- rollout steps/s: the same agent's compiled rollout alone (no learning), rooted at the top
  level, over the same batch, timed in the same process;
- overhead = rollout steps/s / epoch env steps/s (goal <= 2);
- checkpoint: what the per-epoch save adds to an epoch as `mjx-emp train` runs it (the
  write runs in the background during the next epoch): median over rounds of
  (save + next epoch + rest of the write) / (an epoch with no write in flight) - 1; and, for a
  single save, the seconds it blocks, the seconds until it is committed to disk and its size;
  the single-save figures are also taken with every buffer filled with noise
  (incompressible: the worst case, a run whose buffers are full).

Epoch and rollout are timed alternately (``--repeats`` rounds); the overhead is the median
of per-round ratios. Prints Markdown tables and appends one row per preset
(``PRESET/ENV/kK/num_envsB``) to ``results/bench-train.jsonl`` (``--results``).
"""

from __future__ import annotations

import dataclasses
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import tyro

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.he.config import HEConfig
from mjx_emp.algos.he.state import MODE_GC, TRAIN_EPOCH_TRACE
from mjx_emp.algos.registry import preset_or_retired_config
from mjx_emp.rollout.hierarchy import jit_init_rollout, jit_rollout
from mjx_emp.run.checkpoint import Checkpoints
from mjx_emp.run.rows import append_row, benchmark_row
from mjx_emp.tracing import traces

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import row_name  # noqa: E402

SPEC = "bench-train"


@dataclasses.dataclass
class Args:
    """Training-epoch throughput and compile-time benchmark."""

    presets: tuple[str, ...] = ("point-mass-k1", "point-mass-k2", "ant-field-k1-paper-small",
                                "ant-field-k2-paper-big", "ant-field-k3-paper-xl")
    num_envs: int = 0
    """Environments per collection; 0 keeps each preset's value on GPU and uses 64 on CPU."""
    hidden: tuple[int, ...] = ()
    """Network widths; empty keeps the preset's."""
    gc_iterations: int = 0
    """Goal-conditioned iterations per level and epoch; 0 keeps the preset's 10. Fewer keep
    a CPU epoch of deep agents short; the compiled program (and compile time) is the same."""
    repeats: int = 3
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""


def _seconds(fn):
    start = time.perf_counter()
    out = fn()
    jax.block_until_ready(out)
    return time.perf_counter() - start, out


def _noisy_buffers(state, key: jax.Array):
    """``state`` with every floating-point buffer entry replaced by uniform noise."""
    def fill(path, leaf):
        if not jnp.issubdtype(leaf.dtype, jnp.floating):
            return leaf
        return jax.random.uniform(jax.random.fold_in(key, hash(jax.tree_util.keystr(path)) % 2**31), leaf.shape, leaf.dtype)

    buffers = jax.tree_util.tree_map_with_path(fill, (state.replay, state.goal_space_replay, state.starts))
    return state.replace(replay=buffers[0], goal_space_replay=buffers[1], starts=buffers[2])


def checkpoint_cost(cfg: HEConfig, state, repeats: int) -> dict:
    """Median blocking and commit seconds of a checkpoint save, and its size in MB."""
    with tempfile.TemporaryDirectory() as tmp, Checkpoints(Path(tmp), keep=2) as checkpoints:
        blocking, committed = [], []
        for epoch in range(repeats):
            start = time.perf_counter()
            blocking.append(checkpoints.save(epoch, state, cfg))
            checkpoints.wait()
            committed.append(time.perf_counter() - start)
        size = sum(f.stat().st_size for f in checkpoints.step_dir(repeats - 1).rglob("*") if f.is_file())
    return {"block_s": statistics.median(blocking), "commit_s": statistics.median(committed), "mb": size / 2**20}


def measure(name: str, cfg: HEConfig, repeats: int) -> dict:
    """Compile time, warm epoch throughput and rollout-only throughput of one config."""
    trainer = HEAgent(cfg)
    state = trainer.init()
    cached = traces(TRAIN_EPOCH_TRACE)
    first, (state, stats) = _seconds(lambda: trainer.train_epoch(state))
    compiled = traces(TRAIN_EPOCH_TRACE)

    # The epoch donates its input state, so rollout inputs are re-read after every epoch.
    root, mode = jnp.int32(cfg.k - 1), jnp.int32(MODE_GC)
    h, start, steps = trainer.hierarchy, trainer.start, cfg.chunk_steps
    params, start_params = trainer.rollout_inputs(state, root, mode)
    rollout_state = jit_init_rollout(h, params, start, start_params, jax.random.key(1), cfg.num_envs, cfg.k - 1)
    rollout_state = jax.block_until_ready(jit_rollout(h, params, start, start_params, rollout_state, steps))[0]

    epoch_rates, rollout_rates, ratios, epoch_seconds = [], [], [], []
    for _ in range(repeats):
        dt, (state, stats) = _seconds(lambda: trainer.train_epoch(state))
        epoch_rate = float(jnp.sum(stats.env_steps)) / dt
        params, start_params = trainer.rollout_inputs(state, root, mode)
        dt_roll, out = _seconds(lambda: jit_rollout(h, params, start, start_params, rollout_state, steps))
        rollout_state = out[0]
        rollout_rate = steps * cfg.num_envs / dt_roll
        epoch_rates.append(epoch_rate)
        rollout_rates.append(rollout_rate)
        ratios.append(rollout_rate / epoch_rate)
        epoch_seconds.append(dt)
    warm = statistics.median(epoch_seconds)
    # Epoch lengths drift as the agent learns, so the save's cost is measured in pairs: an
    # epoch with no write in flight, then (save, epoch overlapping that write, rest of the write).
    plain, loaded = [], []
    with tempfile.TemporaryDirectory() as tmp, Checkpoints(Path(tmp), keep=2) as checkpoints:
        for epoch in range(max(repeats, 5)):
            dt, (state, stats) = _seconds(lambda: trainer.train_epoch(state))
            plain.append(dt)
            start_time = time.perf_counter()
            checkpoints.save(epoch, state, cfg)
            state, stats = trainer.train_epoch(state)
            jax.block_until_ready(state)
            checkpoints.wait()
            loaded.append(time.perf_counter() - start_time)
    added = statistics.median(b / a for a, b in zip(plain, loaded)) - 1
    checkpoint = checkpoint_cost(cfg, state, repeats)
    checkpoint_full = checkpoint_cost(cfg, _noisy_buffers(state, jax.random.key(5)), repeats)
    return {
        "preset": name, "env": cfg.env, "k": cfg.k, "n": list(cfg.n), "num_envs": cfg.num_envs,
        "hidden": list(cfg.hidden), "gc_iterations": cfg.gc_iterations, "compile_s": first - warm, "epoch_s": warm,
        "epoch_env_steps_per_s": statistics.median(epoch_rates),
        "rollout_steps_per_s": statistics.median(rollout_rates),
        "overhead": statistics.median(ratios),
        "recompiled": traces(TRAIN_EPOCH_TRACE) > compiled,
        "new_programs_first_epoch": compiled - cached,
        "epoch_with_checkpoint_s": statistics.median(loaded),
        "checkpoint_added_fraction": added,
        "checkpoint": checkpoint, "checkpoint_full_buffers": checkpoint_full,
    }


def main(args: Args) -> None:
    backend = jax.default_backend()
    rows = []
    for name in args.presets:
        cfg = preset_or_retired_config(name)  # a retired name reruns the rows recorded under it
        num_envs = args.num_envs or (cfg.num_envs if backend == "gpu" else min(cfg.num_envs, 64))
        cfg = dataclasses.replace(cfg, num_envs=num_envs, batch_size=min(cfg.batch_size, 256),
                                  hidden=tuple(args.hidden) or cfg.hidden,
                                  gc_iterations=args.gc_iterations or cfg.gc_iterations)
        row = measure(name, cfg, args.repeats)
        rows.append(row)
        append_row(Path(args.results), benchmark_row(SPEC, row_name(row), row))
        print(json.dumps(row), flush=True)
    print("\n| preset | k | B | GC iters | compile s | epoch s | epoch env steps/s | rollout steps/s | overhead | recompiled |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['preset']} | {r['k']} | {r['num_envs']} | {r['gc_iterations']} | {r['compile_s']:.1f} | {r['epoch_s']:.2f} | "
              f"{r['epoch_env_steps_per_s']:,.0f} | {r['rollout_steps_per_s']:,.0f} | {r['overhead']:.2f} | "
              f"{r['recompiled']} |")
    print("\n| preset | epoch s | per-epoch save adds | one save: blocks s | committed s | MB | "
          "full buffers: committed s | MB |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        c, f = r["checkpoint"], r["checkpoint_full_buffers"]
        print(f"| {r['preset']} | {r['epoch_s']:.2f} | {r['checkpoint_added_fraction']:+.0%} | "
              f"{c['block_s']:.3f} | {c['commit_s']:.3f} | {c['mb']:.1f} | {f['commit_s']:.3f} | {f['mb']:.1f} |")
    print(f"appended {len(rows)} rows to {args.results}")


if __name__ == "__main__":
    main(tyro.cli(Args))
