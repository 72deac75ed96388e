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
