"""Experiment: a video of a trained agent's skills, with each level's subgoal drawn."""

from __future__ import annotations

import dataclasses

import tyro


@dataclasses.dataclass(frozen=True)
class RenderExperiment:
    """Render the greedy chain of top-level skills from RUN_DIR's newest checkpoint as a GIF
    (or, with --phase2, the phase-2 policy reaching goals from its region)."""

    run_dir: tyro.conf.Positional[str]
    """Run directory written by `mjx-emp train`."""
    steps: int = 200
    """Primitive steps (frames) to record."""
    width: int = 320
    """Frame width in pixels."""
    height: int = 240
    """Frame height in pixels."""
    fps: float = 10.0
    """Frames per second of the GIF (one frame is one control step)."""
    distance: float = 6.0
    """Camera distance from the torso."""
    seed: int = 0
    """Seed of the skills drawn from the top goal space (or of the phase-2 goals)."""
    phase2: bool = False
    """Film the phase-2 policy of RUN_DIR/phase2 instead of the skill chain."""
    out: str = ""
    """Output GIF; empty means RUN_DIR/skills.gif (RUN_DIR/phase2.gif with --phase2)."""
