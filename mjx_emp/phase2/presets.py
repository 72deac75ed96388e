"""Phase 2's presets: Table 2's tasks on the paper's presets, and CPU-sized tasks for the CPU presets.

Each names the phase-1 preset it builds on; :func:`phase2_preset_for` picks one for a run.
"""

from __future__ import annotations

import dataclasses

from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.algos.registry import LATENT_SKILLS, skill_kind
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
    # name: (description, the phase-1 preset it builds on, config). A run without a named
    # preset gets the first one whose phase-1 preset has its domain and n.
    "point-mass-k1": ("CPU default: goals in a 2.4 x 2.4 square, inside the k=1 agent's learned "
                      "goal space; 3 attempts", "point-mass-k1", _POINT_MASS_PHASE2),
    "point-mass-wide-k2": ("CPU: goals in an 8 x 8 square, beyond the k=1 goal space; 3 attempts",
                           "point-mass-k2", dataclasses.replace(_POINT_MASS_PHASE2, region=(8.0, 8.0))),
    "point-mass-wide-k1": ("CPU: point-mass-wide-k2's task for the k=1 agent", "point-mass-k1",
                           dataclasses.replace(_POINT_MASS_PHASE2, region=(8.0, 8.0))),
    "point-mass-wider-k2": ("CPU: goals in a 16 x 16 square, beyond 3 of the k=1 agent's skills; 3 attempts",
                            "point-mass-k2", dataclasses.replace(_POINT_MASS_PHASE2, region=(16.0, 16.0))),
    "point-mass-wider-k1": ("CPU: point-mass-wider-k2's task for the k=1 agent", "point-mass-k1",
                            dataclasses.replace(_POINT_MASS_PHASE2, region=(16.0, 16.0))),
    "ant-field-cpu-k1": ("CPU: Table 2's Ant Field Small task (40 x 40, 10 attempts, eps 1.8)",
                         "ant-field-cpu-k1", _ANT_SMALL_TASK),
    "ant-field-cpu-k2": ("CPU: Table 2's Ant Field Small task for the two-level agent", "ant-field-cpu-k2",
                         _ANT_SMALL_TASK),
    "ant-field-cpu-k2-wide": ("CPU: Table 2's Ant Field Small task for ant-field-cpu-k2-wide",
                              "ant-field-cpu-k2-wide", _ANT_SMALL_TASK),
    "half-cheetah-cpu-k1": ("CPU: Table 2's Half Cheetah Small task (95 m, 10 attempts, eps 3.0)",
                            "half-cheetah-cpu-k1", _CHEETAH_SMALL_TASK),
    "half-cheetah-cpu-k2": ("CPU: Table 2's Half Cheetah Small task for the two-level agent",
                            "half-cheetah-cpu-k2", _CHEETAH_SMALL_TASK),
    "ant-cage-cpu-k1": ("CPU: goals in a 16 x 16 m square around the 8 x 8 m cage, 10 attempts, eps 1.8",
                        "ant-cage-cpu-k1", _ANT_CAGE_TASK),
    "half-cheetah-cage-cpu-k1": ("CPU: goals on 32 m of track around the 16 m cage, 10 attempts, eps 3.0",
                                 "half-cheetah-cage-cpu-k1", _CHEETAH_CAGE_TASK),
    "ant-cage-cpu-k2": ("CPU: ant-cage-cpu-k1's task for the two-level agent", "ant-cage-cpu-k2", _ANT_CAGE_TASK),
    "half-cheetah-cage-cpu-k2": ("CPU: half-cheetah-cage-cpu-k1's task for the two-level agent",
                                 "half-cheetah-cage-cpu-k2", _CHEETAH_CAGE_TASK),
    "ant-field-small-k1": ("Table 2: Ant Field Small, k=1", "ant-field-small-k1", _phase2(10, 1.8, 40, 2)),
    "ant-field-big-k1": ("Table 2: Ant Field Big, k=1", "ant-field-big-k1", _phase2(25, 2.4, 200, 2)),
    "ant-field-big-k2": ("Table 2: Ant Field Big, k=2", "ant-field-big-k2", _phase2(10, 2.4, 200, 2)),
    "ant-field-xl-k2": ("Table 2: Ant Field XL, k=2", "ant-field-xl-k2", _phase2(10, 9.6, 800, 2)),
    "ant-field-xl-k3": ("Table 2: Ant Field XL, k=3", "ant-field-xl-k3", _phase2(10, 9.6, 800, 2)),
    "half-cheetah-small-k1": ("Table 2: Half Cheetah Small, k=1", "half-cheetah-small-k1",
                              _phase2(10, 3.0, 95, 1, ahead=0.1)),
    "half-cheetah-big-k1": ("Table 2: Half Cheetah Big, k=1", "half-cheetah-big-k1",
                            _phase2(10, 10.0, 450, 1, ahead=0.1)),
    "half-cheetah-big-k2": ("Table 2: Half Cheetah Big, k=2", "half-cheetah-big-k2",
                            _phase2(10, 10.0, 450, 1, ahead=0.1)),
    "ant-cage-k1": ("Table 2: Ant Cage, k=1", "ant-cage-k1", _phase2(25, 2.4, 100, 2)),
    "ant-cage-k2": ("Table 2: Ant Cage, k=2", "ant-cage-k2", _phase2(10, 2.4, 100, 2)),
    "half-cheetah-cage-k1": ("Table 2: Half Cheetah Cage, k=1", "half-cheetah-cage-k1",
                             _phase2(10, 10.0, 150, 1, ahead=0.1)),
    "half-cheetah-cage-k2": ("Table 2: Half Cheetah Cage, k=2", "half-cheetah-cage-k2",
                             _phase2(10, 10.0, 150, 1, ahead=0.1)),
}


def phase2_preset_for(skills) -> str | None:
    """The phase-2 preset for a run trained with ``skills``: the one built on the phase-1
    preset it was trained with (seed and when it stops aside), else the first one built on a
    preset with its domain, n and number of environments (GPU or CPU scale), else the first
    with its domain and n, else None. A flat skill learner's run gets its domain's one-level
    task at its scale (the skills there are as long as HE's k=1 skills)."""
    def same_preset(base) -> bool:
        stops = {name: getattr(skills, name) for name in LOOP_FIELDS}
        return dataclasses.replace(base, seed=skills.seed, **stops) == skills

    candidates = [(name, PRESETS[phase1][1]) for name, (_, phase1, _) in PHASE2_PRESETS.items()]
    if skill_kind(skills) == LATENT_SKILLS:  # a flat skill learner: the one-level task of its domain and scale
        gpu = skills.num_envs >= PRESETS["ant-field-small-k1"][1].num_envs
        one_level = {"point_mass": ("point-mass-k1",) * 2, "ant_field": ("ant-field-cpu-k1", "ant-field-small-k1"),
                     "half_cheetah_field": ("half-cheetah-cpu-k1", "half-cheetah-small-k1")}
        return one_level[skills.env][gpu] if skills.env in one_level else None
    for name, base in candidates:
        if same_preset(base):
            return name
    for same_scale in (True, False):
        for name, base in candidates:
            if (base.env, tuple(base.n)) == (skills.env, tuple(skills.n)) and (
                    not same_scale or base.num_envs == skills.num_envs):
                return name
    return None
