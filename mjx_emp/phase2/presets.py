"""Phase 2's tasks: Table 2's on the paper's presets, and CPU-sized tasks for the recipes.

A task is named ``reach-DOMAIN[-kK][-SIZE][-VARIANT]`` (:mod:`mjx_emp.algos.names`):
``reach-`` and the name of the Table-1 row it belongs to for Table 2's tasks
(``reach-ant-field-k1-paper-small``), ``reach-DOMAIN-cpu`` for the task every depth of a robot's
CPU recipes shares, and ``reach-point-mass`` with ``-wide`` and ``-wider`` for the point mass's
larger regions. Each names the phase-1 preset it builds on; :func:`phase2_preset_for` picks one
for a run. The names that left with the old catalogue are in :data:`PHASE2_RETIRED`.
"""

from __future__ import annotations

import dataclasses

from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.algos.names import size_of_envs
from mjx_emp.algos.registry import GOAL_SPACES, skill_kind
from mjx_emp.algos.retired import Retired
from mjx_emp.checks import LOOP_FIELDS
from mjx_emp.phase2.config import Phase2Config

# ---- phase 2 -------------------------------------------------------------------------
# Table 2 gives n (attempts), eps and the region's length per dimension. The rest is ours:
# the reward's sigma equals eps (phase 1's goal-conditioned reward, as wide as the goal
# threshold); Half Cheetah's regions lie ahead of the start by a tenth of their length
# (the paper shifts them "slightly" forward without a number); the GPU-scale learning
# settings below; 100 epochs.
_PHASE2_PAPER = dict(
    num_envs=1024, batch_size=1024, hidden=(256, 256), replay_capacity=500_000, epochs=100,
)


def _phase2(n: int, eps: float, length: float, dims: int, ahead: float = 0.0) -> Phase2Config:
    return Phase2Config(n=n, eps=eps, sigma=eps, region=(length,) * dims,
                        region_offset=(ahead * length,) + (0.0,) * (dims - 1), **_PHASE2_PAPER)


def _robot_phase2(n: int, eps: float, length: float, dims: int, ahead: float = 0.0) -> Phase2Config:
    """A Table-2 task sized for the CPU: 16 environments, 30 epochs."""
    return dataclasses.replace(_phase2(n, eps, length, dims, ahead), num_envs=16, batch_size=256, epochs=30,
                               replay_capacity=100_000)


_ANT_SMALL_TASK = _robot_phase2(10, 1.8, 40, 2)
_CHEETAH_SMALL_TASK = _robot_phase2(10, 3.0, 95, 1, ahead=0.1)

# The cages on a CPU: goals in a square (Ant) or on a track (Half Cheetah) twice as wide as the
# cage, centred on the start, so most of them lie beyond the walls and need the button first.
_ANT_CAGE_TASK = _robot_phase2(10, 1.8, 16, 2)
_CHEETAH_CAGE_TASK = _robot_phase2(10, 3.0, 32, 1)

_POINT_MASS_PHASE2 = Phase2Config(n=3, eps=0.6, sigma=0.6, region=(2.4, 2.4), region_offset=(0.0, 0.0), epochs=30)

PHASE2_PRESETS: dict[str, tuple[str, str, Phase2Config]] = {
    # name: (description, the phase-1 preset it builds on, config).
    "reach-point-mass": ("CPU default: goals in a 2.4 x 2.4 square, inside the k=1 agent's learned goal space; "
                         "3 attempts", "point-mass-k1", _POINT_MASS_PHASE2),
    "reach-point-mass-wide": ("CPU: goals in an 8 x 8 square, beyond the k=1 goal space; 3 attempts",
                              "point-mass-k2", dataclasses.replace(_POINT_MASS_PHASE2, region=(8.0, 8.0))),
    "reach-point-mass-wider": ("CPU: goals in a 16 x 16 square, beyond 3 of the k=1 agent's skills; 3 attempts",
                               "point-mass-k2", dataclasses.replace(_POINT_MASS_PHASE2, region=(16.0, 16.0))),
    "reach-ant-field-cpu": ("CPU: Table 2's Ant Field Small task (40 x 40, 10 attempts, eps 1.8) for every depth",
                            "ant-field-k1-cpu", _ANT_SMALL_TASK),
    "reach-half-cheetah-field-cpu": ("CPU: Table 2's Half Cheetah Small task (95 m, 10 attempts, eps 3.0) for every "
                                     "depth", "half-cheetah-field-k1-cpu", _CHEETAH_SMALL_TASK),
    "reach-ant-cage-cpu": ("CPU: goals in a 16 x 16 m square around the 8 x 8 m cage, 10 attempts, eps 1.8",
                           "ant-cage-k1-cpu", _ANT_CAGE_TASK),
    "reach-half-cheetah-cage-cpu": ("CPU: goals on 32 m of track around the 16 m cage, 10 attempts, eps 3.0",
                                    "half-cheetah-cage-k1-cpu", _CHEETAH_CAGE_TASK),
    "reach-ant-field-k1-paper-small": ("Table 2: Ant Field Small, k=1", "ant-field-k1-paper-small",
                                       _phase2(10, 1.8, 40, 2)),
    "reach-ant-field-k1-paper-big": ("Table 2: Ant Field Big, k=1", "ant-field-k1-paper-big",
                                     _phase2(25, 2.4, 200, 2)),
    "reach-ant-field-k2-paper-big": ("Table 2: Ant Field Big, k=2", "ant-field-k2-paper-big",
                                     _phase2(10, 2.4, 200, 2)),
    "reach-ant-field-k2-paper-xl": ("Table 2: Ant Field XL, k=2", "ant-field-k2-paper-xl", _phase2(10, 9.6, 800, 2)),
    "reach-ant-field-k3-paper-xl": ("Table 2: Ant Field XL, k=3", "ant-field-k3-paper-xl", _phase2(10, 9.6, 800, 2)),
    "reach-half-cheetah-field-k1-paper-small": ("Table 2: Half Cheetah Small, k=1", "half-cheetah-field-k1-paper-small",
                                                _phase2(10, 3.0, 95, 1, ahead=0.1)),
    "reach-half-cheetah-field-k1-paper-big": ("Table 2: Half Cheetah Big, k=1", "half-cheetah-field-k1-paper-big",
                                              _phase2(10, 10.0, 450, 1, ahead=0.1)),
    "reach-half-cheetah-field-k2-paper-big": ("Table 2: Half Cheetah Big, k=2", "half-cheetah-field-k2-paper-big",
                                              _phase2(10, 10.0, 450, 1, ahead=0.1)),
    "reach-ant-cage-k1-paper": ("Table 2: Ant Cage, k=1", "ant-cage-k1-paper", _phase2(25, 2.4, 100, 2)),
    "reach-ant-cage-k2-paper": ("Table 2: Ant Cage, k=2", "ant-cage-k2-paper", _phase2(10, 2.4, 100, 2)),
    "reach-half-cheetah-cage-k1-paper": ("Table 2: Half Cheetah Cage, k=1", "half-cheetah-cage-k1-paper",
                                         _phase2(10, 10.0, 150, 1, ahead=0.1)),
    "reach-half-cheetah-cage-k2-paper": ("Table 2: Half Cheetah Cage, k=2", "half-cheetah-cage-k2-paper",
                                         _phase2(10, 10.0, 150, 1, ahead=0.1)),
}
"""Task name -> (description, the phase-1 preset it builds on, config). Within a domain, scale
and depth the first task is the one :func:`phase2_preset_for` gives a run not of its own preset."""

PHASE2_RETIRED: dict[str, Retired] = {
    "point-mass-k1": Retired("reach-point-mass"),
    "point-mass-wide-k1": Retired("reach-point-mass-wide"),
    "point-mass-wide-k2": Retired("reach-point-mass-wide"),
    "point-mass-wider-k1": Retired("reach-point-mass-wider"),
    "point-mass-wider-k2": Retired("reach-point-mass-wider"),
    "ant-field-cpu-k1": Retired("reach-ant-field-cpu"),
    "ant-field-cpu-k2": Retired("reach-ant-field-cpu"),
    "ant-field-cpu-k2-wide": Retired("reach-ant-field-cpu"),
    "half-cheetah-cpu-k1": Retired("reach-half-cheetah-field-cpu"),
    "half-cheetah-cpu-k2": Retired("reach-half-cheetah-field-cpu"),
    "ant-cage-cpu-k1": Retired("reach-ant-cage-cpu"),
    "ant-cage-cpu-k2": Retired("reach-ant-cage-cpu"),
    "half-cheetah-cage-cpu-k1": Retired("reach-half-cheetah-cage-cpu"),
    "half-cheetah-cage-cpu-k2": Retired("reach-half-cheetah-cage-cpu"),
    "ant-field-small-k1": Retired("reach-ant-field-k1-paper-small"),
    "ant-field-big-k1": Retired("reach-ant-field-k1-paper-big"),
    "ant-field-big-k2": Retired("reach-ant-field-k2-paper-big"),
    "ant-field-xl-k2": Retired("reach-ant-field-k2-paper-xl"),
    "ant-field-xl-k3": Retired("reach-ant-field-k3-paper-xl"),
    "half-cheetah-small-k1": Retired("reach-half-cheetah-field-k1-paper-small"),
    "half-cheetah-big-k1": Retired("reach-half-cheetah-field-k1-paper-big"),
    "half-cheetah-big-k2": Retired("reach-half-cheetah-field-k2-paper-big"),
    "ant-cage-k1": Retired("reach-ant-cage-k1-paper"),
    "ant-cage-k2": Retired("reach-ant-cage-k2-paper"),
    "half-cheetah-cage-k1": Retired("reach-half-cheetah-cage-k1-paper"),
    "half-cheetah-cage-k2": Retired("reach-half-cheetah-cage-k2-paper"),
}
"""Retired phase-2 name -> its task (every retired task kept its config; only the name changed)."""


def levels_of(skills) -> int:
    """How many levels a run's skills have: its goal spaces' for HE and GCRL, 1 for a flat
    skill learner (its skills are as long as a one-level agent's)."""
    return len(skills.n) if skill_kind(skills) == GOAL_SPACES else 1


OWN_TASK = "own"
"""`mjx-emp phase2 own RUN_DIR` (or `mjx-emp phase2 RUN_DIR`): the run's own task, :func:`phase2_preset_for`."""


def phase2_preset_for(skills) -> str | None:
    """The phase-2 task for a run trained with ``skills``: the one built on the phase-1 preset
    it was trained with (seed and when it stops aside), else the first built on a preset of its
    domain, scale (``cpu`` or ``gpu``, :func:`mjx_emp.algos.names.size_of_envs`) and number of
    levels, else the first of its domain and scale, else the first of its domain; None for a
    domain without a task. So every depth of a robot's CPU recipes gets the domain's CPU task,
    and a GPU-size run the Table-2 task of its domain and depth (the smallest such row)."""
    def same_preset(base) -> bool:
        if type(base) is not type(skills):
            return False
        stops = {name: getattr(skills, name) for name in LOOP_FIELDS}
        return dataclasses.replace(base, seed=skills.seed, **stops) == skills

    bases = [(name, PRESETS[phase1][1]) for name, (_, phase1, _) in PHASE2_PRESETS.items()]
    for name, base in bases:
        if same_preset(base):
            return name
    scale, levels = size_of_envs(skills.num_envs), levels_of(skills)
    criteria = (
        lambda base: (size_of_envs(base.num_envs), len(base.n)) == (scale, levels),
        lambda base: size_of_envs(base.num_envs) == scale,
        lambda base: True,
    )
    for fits in criteria:
        for name, base in bases:
            if base.env == skills.env and fits(base):
                return name
    return None
