"""Evaluation metrics: the paper's minimum distance to goal, and aggregation over seeds.

The paper's phase-2 figure reports, per seed, the mean over episodes of the smallest
distance between h(s_t) and the goal reached at any step of the episode, then the mean and
spread over seeds. Phase 2 computes the per-episode minimum on device as its rollout
runs (:func:`running_min_distance`); the rest turns episode values into those figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np


def running_min_distance(distance: jax.Array, valid: jax.Array, ended: jax.Array,
                         running: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Each environment's smallest distance to its goal so far in the current episode.

    ``distance``, ``valid`` and ``ended`` are [T, B] per primitive step: ||h(s_t+1) - goal||,
    whether that step counts (not a physics reset) and whether the episode ended with it.
    ``running`` [B] is carried in from earlier steps (inf where an episode is just starting).
    Returns (running after the last step, per-step minimum so far [T, B]); where ``ended``,
    the per-step value is that finished episode's minimum distance to goal (inf if no step
    of it counted).
    """

    def step(run, x):
        d, v, e = x
        run = jnp.minimum(run, jnp.where(v, d, jnp.inf))
        return jnp.where(e, jnp.inf, run), run

    return jax.lax.scan(step, running, (distance, valid, ended))


def mean_and_stderr(values: Sequence[float]) -> dict[str, float]:
    """Mean and standard error of the mean (sample std / sqrt(count)); stderr is 0 for one value."""
    x = np.asarray(values, float)
    if x.size == 0:
        raise ValueError("mean_and_stderr needs at least one value")
    stderr = float(x.std(ddof=1) / math.sqrt(x.size)) if x.size > 1 else 0.0
    return {"mean": float(x.mean()), "stderr": stderr, "count": int(x.size)}


def phase1_figures(trainer, state, key, episodes: int) -> dict:
    """Per level: the goal-space box at the initial state and greedy goal-conditioned results.

    Goals come from each level's own (noise-free) goal space, episodes start from its
    start-state buffer; at least ``episodes`` episodes per level (whole rounds of
    ``num_envs``).
    """
    import jax

    rounds = max(1, math.ceil(episodes / trainer.cfg.num_envs))
    levels = []
    for level, box in enumerate(trainer.goal_spaces(state)):
        result = trainer.evaluate(state, level, jax.random.fold_in(key, level), rounds)
        levels.append({"level": level, **box, **result, "episodes": rounds * trainer.cfg.num_envs})
    return {"epoch": int(state.epoch), "env_steps": float(state.env_steps), "levels": levels}


def aggregate_runs(reports: Sequence[dict]) -> list[dict]:
    """Mean and standard error over runs (seeds) of each level's volume, success and final distance."""
    if not reports:
        raise ValueError("aggregate_runs needs at least one report")
    k = len(reports[0]["levels"])
    if any(len(r["levels"]) != k for r in reports):
        raise ValueError("runs to aggregate must have the same number of levels")
    return [
        {"level": level, **{name: mean_and_stderr([r["levels"][level][name] for r in reports])
                            for name in ("volume", "success", "final_distance")}}
        for level in range(k)
    ]


def aggregate_phase2(reports: Sequence[dict]) -> dict:
    """Mean and standard error over runs (seeds) of phase 2's mean minimum distance and success."""
    if not reports:
        raise ValueError("aggregate_phase2 needs at least one report")
    return {name: mean_and_stderr([r[name] for r in reports]) for name in ("min_distance", "success")}
