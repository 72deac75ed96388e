"""Evaluation metrics: the paper's minimum distance to goal, and aggregation over seeds.

The paper's phase-2 figure reports, per seed, the mean over episodes of the smallest
distance between h(s_t) and the goal reached at any step of the episode, then the mean and
spread over seeds. Phase 2 computes the per-episode minimum on device as its rollout
runs (:func:`running_min_distance`); the rest turns episode values into those figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

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


def coverage_cells(positions: np.ndarray, mask: np.ndarray, cell: float = 1.0) -> int:
    """METRA's state coverage: distinct ``cell``-sized cells of goal space that any path visits.

    ``positions`` [..., d] are goal-space points (x, y for Ant and point mass, x for Half
    Cheetah) and ``mask`` [...] marks the points that count. Park et al. (METRA, 2024) count
    1 x 1 m (x, y) cells visited by 48 skills on Ant; the same count in 1-D is 1 m bins of x.
    """
    points = np.asarray(positions)[np.asarray(mask, bool)]
    if points.size == 0:
        return 0
    return int(np.unique(np.floor(points / cell).astype(np.int64), axis=0).shape[0])


def mean_and_stderr(values: Sequence[float]) -> dict[str, float]:
    """Mean, sample standard deviation (the paper's error bars) and standard error of the mean.

    std and stderr (std / sqrt(count)) are 0 for one value.
    """
    x = np.asarray(values, float)
    if x.size == 0:
        raise ValueError("mean_and_stderr needs at least one value")
    std = float(x.std(ddof=1)) if x.size > 1 else 0.0
    return {"mean": float(x.mean()), "std": std, "stderr": std / math.sqrt(x.size), "count": int(x.size)}


LEVEL_FIGURES = ("volume", "success", "final_distance", "success_from_initial", "success_chained", "cut_short")
"""What :func:`aggregate_runs` averages per level (see :func:`level_figures`)."""


def level_figures(level: dict) -> dict[str, float]:
    """One level's evaluation (see ``run.evaluate.phase1_figures``) as flat figures: volume,
    success and final distance from its start buffer, success from the initial state only and
    from chained start states only, and the fraction of episodes a reset (a flip) cut short."""
    return {"volume": level["volume"], "success": level["success"], "final_distance": level["final_distance"],
            "success_from_initial": level["from_initial"]["success"], "success_chained": level["chained"]["success"],
            "cut_short": level["cut_short"]}


def aggregate_runs(reports: Sequence[dict]) -> list[dict]:
    """Mean and standard error over runs (seeds) of each level's :data:`LEVEL_FIGURES`."""
    if not reports:
        raise ValueError("aggregate_runs needs at least one report")
    k = len(reports[0]["levels"])
    if any(len(r["levels"]) != k for r in reports):
        raise ValueError("runs to aggregate must have the same number of levels")
    figures = [[level_figures(level) for level in r["levels"]] for r in reports]
    return [
        {"level": level, **{name: mean_and_stderr([f[level][name] for f in figures]) for name in LEVEL_FIGURES}}
        for level in range(k)
    ]


def aggregate_agent(reports: Sequence[dict]) -> dict:
    """Mean and standard error over runs (seeds) of the agent-wide figures: coverage cells and
    the top box's volume times greedy success."""
    if not reports:
        raise ValueError("aggregate_agent needs at least one report")
    return {name: mean_and_stderr([r[name] for r in reports]) for name in ("coverage_cells", "volume_x_success")}


PHASE2_DIAGNOSTICS = ("aimed", "aimed_half", "random")
"""Phase-2 policies evaluated beside the learned one on the same goals (``Phase2Trainer.top``):
subgoals aimed straight at the goal within the top box, the same within its central half
(each half-width halved), and uniform in the box."""


PHASE2_REQUIRED_FIGURES = ("min_distance", "success")
"""The phase-2 figures every evaluation holds: the mean minimum distance to the goal and the success."""

PHASE2_FIGURES = PHASE2_REQUIRED_FIGURES + ("cut_short", "uncut_min_distance")
"""Phase 2's figures of one evaluation: the required two, the fraction of episodes a reset (a
flip) cut short and the mean minimum distance over the others. Results written before the last
two existed lack them, so readers take those where present."""


def shared_phase2_figures(reports: Sequence[dict]) -> tuple[str, ...]:
    """The :data:`PHASE2_FIGURES` every one of ``reports`` holds, in that order."""
    return tuple(name for name in PHASE2_FIGURES if all(name in r for r in reports))


def aggregate_phase2(reports: Sequence[dict]) -> dict:
    """Mean and standard error over runs (seeds) of each of :data:`PHASE2_FIGURES` that every
    report holds (the minimum distance and the success always)."""
    if not reports:
        raise ValueError("aggregate_phase2 needs at least one report")
    missing = [name for name in PHASE2_REQUIRED_FIGURES if not all(name in r for r in reports)]
    if missing:
        raise ValueError(f"aggregate_phase2: every report needs {missing}")
    figures = {name: mean_and_stderr([r[name] for r in reports]) for name in shared_phase2_figures(reports)}
    for policy in PHASE2_DIAGNOSTICS:  # the chaining diagnostic's policies, where every run has them
        if all(policy in r for r in reports):
            figures[policy] = aggregate_phase2([r[policy] for r in reports])
    return figures


HEADER_FIELDS = ("epoch", "env_steps", "epoch_env_steps", "seconds", "env_steps_per_s")
"""The fields every epoch's metrics line starts with (:func:`epoch_header`)."""

AGENT_FIELDS = (*HEADER_FIELDS, "flip_resets", "checkpoint_blocked_s")
"""The fields of an epoch's metrics line that belong to the whole agent, whatever the algorithm:
the header, the resets of flipped environments and the time the loop waited on a checkpoint."""


def epoch_header(state: Any, epoch_env_steps: float, seconds: float) -> dict[str, Any]:
    """The fields every epoch's metrics line starts with (:data:`HEADER_FIELDS`): counters and
    throughput.

    ``state`` is any train state with an ``epoch`` array and an ``env_steps`` StepCounter.
    """
    values = (int(state.epoch), float(state.env_steps.value()), epoch_env_steps, seconds,
              epoch_env_steps / seconds if seconds > 0 else None)
    return dict(zip(HEADER_FIELDS, values, strict=True))
