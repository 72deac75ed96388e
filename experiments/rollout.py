"""Experiment: run a k-level agent's hierarchical rollout and report what it did.

Until the phase-1 trainer lands this is the main job: it builds random-init MLP
policies for every level, rolls them out in one jitted scan, and prints per-level
statistics and throughput as one JSON object.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

EnvName = Literal["point_mass", "ant_field", "ant_cage", "half_cheetah_field", "half_cheetah_cage"]


@dataclasses.dataclass(frozen=True)
class RolloutExperiment:
    """Hierarchical rollout of a k-level agent with random-init MLP policies."""

    env: EnvName = "point_mass"
    """Domain to simulate."""
    n: tuple[int, ...] = (20, 10)
    """Max actions per level, bottom first; its length is k."""
    eps: tuple[float, ...] = (0.6, 1.2)
    """Goal threshold per level (distance in goal space), bottom first."""
    subgoal_half_width: tuple[float, ...] = (2.0,)
    """Half-width of the subgoal box each level above 0 outputs (one per upper level)."""
    root_goal_half_width: float = 4.0
    """Root goals are drawn uniformly within this distance of the start position."""
    batch_size: int = 256
    """Environments simulated in parallel."""
    steps: int = 400
    """Primitive actions per environment per call."""
    calls: int = 3
    """Timed calls after the compiling one."""
    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer widths of every policy MLP."""
    seed: int = 0
