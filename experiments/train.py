"""Experiments: phase-1 training of a preset (any field overridable), and resuming a run
(of phase 1, or of phase 2 with `mjx-emp phase2 --resume`)."""

from __future__ import annotations

import dataclasses
from typing import Annotated

import tyro

from mjx_emp.config import TrainConfig


@dataclasses.dataclass(frozen=True)
class TrainExperiment:
    """Phase-1 Hierarchical Empowerment training.

    RUN_DIR receives config.json, metrics.jsonl (one line per epoch) and checkpoints/ (an
    orbax checkpoint after every epoch; continue with `mjx-emp train --resume RUN_DIR`).
    """

    config: Annotated[TrainConfig, tyro.conf.OmitArgPrefixes]
    run_dir: str = ""
    """Run directory; empty picks runs/<env>-k<k>-<date>-<time>. Must not hold a run already."""
    keep_checkpoints: int = 3
    """How many of the newest epoch checkpoints to keep."""


@dataclasses.dataclass(frozen=True)
class ResumeExperiment:
    """Continue a run from its latest good checkpoint, bit for bit as if never stopped."""

    resume: str
    """Run directory written by `mjx-emp train` (for `mjx-emp phase2 --resume`: the phase-2 directory)."""
    epochs: int | None = None
    """New total number of epochs (default: the run's own). The only setting a resume may change."""
    fallback: bool = False
    """If the newest checkpoint is unusable, resume from the newest one that restores."""
    keep_checkpoints: int = 3
    """How many of the newest epoch checkpoints to keep."""
