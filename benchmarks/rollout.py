"""Throughput of the one-scan k-level rollout next to raw batched ``mjx.step``.

For each domain, batch size B and number of levels k, measured in the same process:
- raw: a jitted ``lax.scan`` of ``vmap(mjx.step)`` over the same number of physics steps;
- hier: ``jit_rollout`` of a k-level agent with 256x256 MLP policies at every level;
- useful physics steps/s (physics steps that advanced a live episode), the useful-step
  fraction, compile time (first call minus a warm call), and whether a later call
  recompiled. Per (domain, B) the raw loop and every k are timed round-robin; each
  ratio is the median over rounds of that round's ratio (so drifts of a shared machine
  cancel), and each absolute figure the median of ``--repeats`` calls.

Prints Markdown tables and appends one row per (domain, solver iterations, B, k), and per k of
the hand-over comparison, to ``results/<spec>.jsonl`` (``--spec``, default bench-rollout;
``--results``).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np
import tyro

from mjx_emp.envs.env import make_env
from mjx_emp.envs.mjx_quiet import mjx
from mjx_emp.envs.scripted import bounded_hop, point_mass_pd
from mjx_emp.nets import mlp_agent
from mjx_emp.rollout.hierarchy import (
    ROLLOUT_TRACE,
    default_start,
    jit_init_rollout,
    jit_rollout,
)
from mjx_emp.rollout.structures import Hierarchy
from mjx_emp.run.rows import RESULTS_DIR, append_row, benchmark_row
from mjx_emp.tracing import traces

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import RowNames  # noqa: E402

SPEC = "bench-rollout"

# Paper-style per-level settings (Ant Field XL, k=3): n=[20,10,10], eps=[0.6,1.2,2.4].
N_PER_LEVEL = (20, 10, 10)
EPS_PER_LEVEL = (0.6, 1.2, 2.4)
SUBGOAL_HALF_WIDTH = (2.0, 8.0)  # box of subgoals issued by levels 1 and 2


@dataclasses.dataclass
class Args:
    """Rollout throughput benchmark."""

    envs: tuple[str, ...] = ("point_mass", "ant_field")
    batch_sizes: tuple[int, ...] = (64, 256, 1024)
    levels: tuple[int, ...] = (1, 2, 3)
    hidden: tuple[int, ...] = (256, 256)
    primitive_steps: int = 0
    """Primitive actions per timed call; 0 picks per domain (point mass 400, others 40)."""
    repeats: int = 7
    solver_iterations: tuple[int, ...] = (0,)
    """Constraint-solver iterations of the physics, each measured in turn (0: the model file's;
    ``--solver-iterations 0 4`` gives the cost of the accurate-physics presets)."""
    handover_steps: int = 400
    """Primitive actions per call in the hand-over comparison (0 skips it)."""
    spec: str = SPEC
    """The rows' spec name (bench-rollout-solver: the solver-iterations comparison)."""
    results: str = ""
    """The results store the rows are appended to; empty means results/<spec>.jsonl."""


def _timed(fn, *args):
    start = time.perf_counter()
    out = fn(*args)
    jax.block_until_ready(out)
    return time.perf_counter() - start, out


def make_agent(env, k: int, hidden: tuple[int, ...], key: jax.Array):
    """The benchmark's k-level agent: random-init MLP policies with the paper-style n and eps."""
    policies, params = mlp_agent(env, k, hidden, SUBGOAL_HALF_WIDTH, key)
    return Hierarchy(env, policies, n=N_PER_LEVEL[:k], eps=EPS_PER_LEVEL[:k]), params


def make_raw(env, batch: int, physics_steps: int):
    """Jitted raw batched ``mjx.step`` loop with a fixed random control per environment."""

    @jax.jit
    def raw(data, ctrl):
        data = data.replace(ctrl=ctrl)
        step = jax.vmap(lambda d: mjx.step(env.model, d))
        return jax.lax.fori_loop(0, physics_steps, lambda _, d: step(d), data)

    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), batch))
    ctrl = jax.random.uniform(jax.random.key(1), (batch, env.action_size), minval=-1, maxval=1)
    return raw, (states.data, ctrl)


def bench_group(env, batch: int, steps: int, args: Args) -> list[dict]:
    """Raw mjx.step and every k for one (env, B), timed round-robin so ratios are side by side."""
    physics = steps * env.action_repeat
    raw, raw_args = make_raw(env, batch, physics)
    start = default_start(env, goal_half_width=2.0)
    first = {"raw": _timed(raw, *raw_args)[0]}
    agents = {}
    for k in args.levels:
        h, params = make_agent(env, k, args.hidden, jax.random.key(k))
        state = jit_init_rollout(h, params, start, None, jax.random.key(2), batch)
        first[k], (state, _, _, _) = _timed(jit_rollout, h, params, start, None, state, steps)
        agents[k] = [h, params, state]
    compiled_programs = traces(ROLLOUT_TRACE)

    times = {name: [] for name in first}
    useful = {k: 0 for k in agents}
    for _ in range(args.repeats):
        times["raw"].append(_timed(raw, *raw_args)[0])
        for k, agent in agents.items():
            h, params, state = agent
            dt, (agent[2], _, _, stats) = _timed(jit_rollout, h, params, start, None, state, steps)
            times[k].append(dt)
            useful[k] += int(stats.useful_steps)
    recompiled = traces(ROLLOUT_TRACE) > compiled_programs

    t_raw = statistics.median(times["raw"])
    raw_sps = batch * physics / t_raw
    base_k = min(agents)
    rows = []
    for k, (h, _, _) in agents.items():
        useful_fraction = useful[k] / (args.repeats * steps * batch)
        hier_sps = useful_fraction * batch * physics / statistics.median(times[k])
        # Ratios pair the calls of one round, so slow drifts of a shared machine cancel.
        over_raw = [useful_fraction * r / t for r, t in zip(times["raw"], times[k])]
        over_base = [tb / t for tb, t in zip(times[base_k], times[k])]
        rows.append({
            "env": env.name,
            "solver_iterations": int(env.model.opt.iterations),
            "batch": batch,
            "k": k,
            "n": list(h.n),
            "primitive_steps_per_call": steps,
            "physics_steps_per_call": batch * physics,
            "raw_physics_steps_per_s": raw_sps,
            "hier_useful_physics_steps_per_s": hier_sps,
            "hier_over_raw": statistics.median(over_raw),
            f"hier_over_k{base_k}": statistics.median(over_base),
            "useful_fraction": useful_fraction,
            "compile_s_raw": first["raw"] - t_raw,
            "compile_s_hier": first[k] - statistics.median(times[k]),
            "recompiled_on_later_calls": recompiled,
        })
    return rows


def padded_nested_fraction(root_final: np.ndarray, n: tuple[int, ...]) -> float | None:
    """Useful-step fraction a nested scan would get on the same episodes.

    A nested scan pads every level to its n actions with masked no-op physics, so each
    root episode occupies prod(n) primitive slots however early it ends. Uses the
    complete root episodes in ``root_final`` ([T, B]); None when there are none.
    """
    lengths = []
    for column in np.asarray(root_final).T:
        lengths.extend(np.diff(np.flatnonzero(column)).tolist())
    if not lengths:
        return None
    return sum(lengths) / (len(lengths) * math.prod(n))


def bench_handover(args: Args, batch: int = 256) -> list[dict]:
    """Agents that reach their goals (scripted point mass): one-scan vs padded nested useful fraction."""
    env = make_env("point_mass")
    steps = args.handover_steps
    start = default_start(env, goal_half_width=10.0)
    rows = []
    for k in args.levels:
        policies = (point_mass_pd, bounded_hop(SUBGOAL_HALF_WIDTH[0]), bounded_hop(SUBGOAL_HALF_WIDTH[1]))[:k]
        h = Hierarchy(env, policies, n=N_PER_LEVEL[:k], eps=EPS_PER_LEVEL[:k])
        params = (None,) * k
        state = jit_init_rollout(h, params, start, None, jax.random.key(3), batch)
        state, _, _, _ = jit_rollout(h, params, start, None, state, steps)  # compile, reach steady state
        times, finals, useful = [], [], 0
        for _ in range(args.repeats):
            dt, (state, transitions, _, stats) = _timed(jit_rollout, h, params, start, None, state, steps)
            times.append(dt)
            finals.append(np.asarray(transitions[-1].final))
            useful += int(stats.useful_steps)
        nested = padded_nested_fraction(np.concatenate(finals), h.n)
        rows.append({
            "env": env.name,
            "batch": batch,
            "k": k,
            "n": list(h.n),
            "useful_fraction": useful / (args.repeats * steps * batch),
            "padded_nested_fraction": nested,
            "useful_physics_steps_per_s": useful * env.action_repeat / sum(times),
        })
    return rows


def markdown(rows: list[dict]) -> str:
    """The results as a Markdown table (ratios are medians of per-round ratios)."""
    lines = [
        "| env | solver iterations | B | k | raw mjx.step /s | hier useful /s | hier/raw | hier/k=1 | useful frac | "
        "compile s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        vs_k1 = f"{r['hier_over_k1']:.2f}" if "hier_over_k1" in r else "-"
        lines.append(
            f"| {r['env']} | {r['solver_iterations']} | {r['batch']} | {r['k']} | "
            f"{r['raw_physics_steps_per_s']:,.0f} | "
            f"{r['hier_useful_physics_steps_per_s']:,.0f} | {r['hier_over_raw']:.2f} | {vs_k1} | "
            f"{r['useful_fraction']:.3f} | {r['compile_s_hier']:.1f} |"
        )
    return "\n".join(lines)


def handover_markdown(rows: list[dict]) -> str:
    """The hand-over comparison as a Markdown table."""
    lines = [
        "| env | B | k | n | one-scan useful frac | padded nested useful frac | one-scan useful /s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        nested = "-" if r["padded_nested_fraction"] is None else f"{r['padded_nested_fraction']:.3f}"
        lines.append(
            f"| {r['env']} | {r['batch']} | {r['k']} | {r['n']} | {r['useful_fraction']:.3f} | "
            f"{nested} | {r['useful_physics_steps_per_s']:,.0f} |"
        )
    return "\n".join(lines)


def main(args: Args) -> None:
    results = Path(args.results or Path(RESULTS_DIR) / f"{args.spec}.jsonl")
    names = RowNames()
    rows = []
    for name, iterations in itertools.product(args.envs, args.solver_iterations):
        env = make_env(name, solver_iterations=iterations)
        steps = args.primitive_steps or (400 if name == "point_mass" else 40)
        for batch in args.batch_sizes:
            for row in bench_group(env, batch, steps, args):
                rows.append(row)
                append_row(results, benchmark_row(args.spec, names(row), row))
                print(
                    f"{name} iterations={row['solver_iterations']} B={batch} k={row['k']}: "
                    f"raw {row['raw_physics_steps_per_s']:,.0f}/s, "
                    f"hier {row['hier_useful_physics_steps_per_s']:,.0f}/s "
                    f"({row['hier_over_raw']:.2f}x), useful {row['useful_fraction']:.3f}, "
                    f"compile {row['compile_s_hier']:.1f}s",
                    flush=True,
                )
    print(markdown(rows))
    handover = bench_handover(args) if args.handover_steps else []
    for row in handover:
        append_row(results, benchmark_row(args.spec, names(row, "handover"), row))
    print(handover_markdown(handover))
    print(f"appended {len(rows) + len(handover)} rows to {results}")


if __name__ == "__main__":
    main(tyro.cli(Args))
