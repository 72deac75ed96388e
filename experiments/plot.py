"""Experiment: draw the pictures of a finished (or running) phase-1 run."""

from __future__ import annotations

import dataclasses

import tyro


@dataclasses.dataclass(frozen=True)
class PlotExperiment:
    """Draw RUN_DIR/plots/goal_space_growth.png from RUN_DIR/metrics.jsonl."""

    run_dir: tyro.conf.Positional[str]
    """Run directory written by `mjx-emp train`."""
