"""Experiment: draw the pictures of a finished (or running) phase-1 run."""

from __future__ import annotations

import dataclasses

import tyro


@dataclasses.dataclass(frozen=True)
class PlotExperiment:
    """Draw RUN_DIR/plots/: goal_space_growth.png from metrics.jsonl and, from the checkpoints,
    goal_spaces_epoch0.png and goal_spaces.png (boxes per level with greedy skill chains)."""

    run_dir: tyro.conf.Positional[str]
    """Run directory written by `mjx-emp train`."""
