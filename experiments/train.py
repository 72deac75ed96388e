"""Experiment: phase-1 training of a preset, with any field overridden on the command line."""

from __future__ import annotations

import dataclasses
from typing import Annotated

import tyro

from mjx_emp.config import TrainConfig


@dataclasses.dataclass(frozen=True)
class TrainExperiment:
    """Phase-1 Hierarchical Empowerment training; metrics go to RUN_DIR/metrics.jsonl."""

    config: Annotated[TrainConfig, tyro.conf.OmitArgPrefixes]
    run_dir: str = "runs/latest"
    """Directory for the resolved config (config.json) and one metrics line per epoch."""
