"""Experiment: phase 2, a goal-conditioned policy over a phase-1 run's frozen skills."""

from __future__ import annotations

import dataclasses
from typing import Annotated

import tyro

from mjx_emp.config import Phase2Config


@dataclasses.dataclass(frozen=True)
class Phase2Experiment:
    """Phase 2 of Hierarchical Empowerment: learn to reach goals drawn uniformly from a fixed
    region, with the phase-1 run's top-level skills as actions.

    Writes to OUT (default RUN_DIR/phase2): config.json, skills.json (the phase-1 config),
    metrics.jsonl and checkpoints/ (one per epoch; continue with
    `mjx-emp phase2 --resume OUT`).
    """

    run_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """Phase-1 run directory written by `mjx-emp train`."""
    config: Annotated[Phase2Config, tyro.conf.OmitArgPrefixes]
    out: str = ""
    """Phase-2 directory; empty means RUN_DIR/phase2. Must not hold a phase-2 run already."""
    keep_checkpoints: int = 3
    """How many of the newest epoch checkpoints to keep."""
