"""`mjx-emp rollout`: a random-init k-level agent rolled out on one domain, with per-level
statistics and throughput. A quick look at the rollout without training; the benchmark with
side-by-side ratios and rows is ``benchmarks/rollout.py``."""

from __future__ import annotations

import time

import jax

from mjx_emp.commands import RolloutExperiment
from mjx_emp.envs.env import make_env
from mjx_emp.nets import mlp_agent
from mjx_emp.rollout.hierarchy import default_start, jit_init_rollout, jit_rollout
from mjx_emp.rollout.structures import Hierarchy


def random_rollout(cfg: RolloutExperiment) -> dict:
    """Roll out a random-init k-level agent (a request :func:`~mjx_emp.commands.check_rollout`
    accepted) ``cfg.calls`` times after a compiling call; per-level statistics and throughput."""
    env = make_env(cfg.env)
    key = jax.random.key(cfg.seed)
    policies, params = mlp_agent(env, len(cfg.n), cfg.hidden, cfg.subgoal_half_width, key)
    hierarchy = Hierarchy(env, policies, n=cfg.n, eps=cfg.eps)
    start = default_start(env, cfg.root_goal_half_width)

    t0 = time.perf_counter()
    state = jit_init_rollout(hierarchy, params, start, None, jax.random.fold_in(key, 99), cfg.batch_size)
    state, _, _, stats = jit_rollout(hierarchy, params, start, None, state, cfg.steps)
    jax.block_until_ready(stats)
    compile_s = time.perf_counter() - t0

    totals = {"useful": 0, "steps": 0, "episodes": 0, "nan": 0, "flip": 0}
    reached = [0] * hierarchy.k
    finals = [0] * hierarchy.k
    elapsed = 0.0
    for _ in range(cfg.calls):
        t0 = time.perf_counter()
        state, transitions, _, stats = jit_rollout(hierarchy, params, start, None, state, cfg.steps)
        jax.block_until_ready(stats)
        elapsed += time.perf_counter() - t0
        totals["useful"] += int(stats.useful_steps)
        totals["steps"] += int(stats.primitive_steps)
        totals["episodes"] += int(stats.episodes_finished)
        totals["nan"] += int(stats.nan_resets)
        totals["flip"] += int(stats.flip_resets)
        for level, tr in enumerate(transitions):
            reached[level] += int((tr.reached & tr.valid).sum())
            finals[level] += int((tr.final & tr.valid).sum())
    return {
        "env": cfg.env,
        "k": hierarchy.k,
        "n": list(hierarchy.n),
        "batch_size": cfg.batch_size,
        "primitive_steps": totals["steps"],
        "useful_step_fraction": totals["useful"] / totals["steps"],
        "useful_physics_steps_per_s": totals["useful"] * env.action_repeat / elapsed,
        "primitive_steps_per_s": totals["steps"] / elapsed,
        "compile_and_first_call_s": compile_s,
        "root_episodes_finished": totals["episodes"],
        "goals_ended_per_level": finals,
        "goals_reached_per_level": reached,
        "nan_resets": totals["nan"],
        "flip_resets": totals["flip"],
        "backend": jax.default_backend(),
    }
