"""Evaluation metrics: the paper's minimum distance to goal, and aggregation over seeds.

The paper's phase-2 figure reports, per seed, the mean over episodes of the smallest
distance between h(s_t) and the goal reached at any step of the episode, then the mean and
spread over seeds. These functions compute exactly that from recorded trajectories.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def min_distance_to_goal(positions: np.ndarray, goals: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Per episode, the smallest Euclidean distance between h(s_t) and the goal.

    ``positions`` is [T, B, d] (h(s) at each step of B episodes), ``goals`` [B, d] and
    ``valid`` [T, B] marks the steps that belong to each episode (all by default). An
    episode with no valid step has distance inf.
    """
    positions, goals = np.asarray(positions, float), np.asarray(goals, float)
    if positions.ndim != 3 or goals.shape != positions.shape[1:]:
        raise ValueError(f"positions must be [T, B, d] and goals [B, d]; got {positions.shape} and {goals.shape}")
    distance = np.linalg.norm(positions - goals[None], axis=-1)
    if valid is not None:
        distance = np.where(np.asarray(valid, bool), distance, np.inf)
    return distance.min(axis=0)


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
