"""Experiment tracking beside metrics.jsonl: TensorBoard event files and Weights & Biases runs.

metrics.jsonl stays the record. A tracker receives every epoch's metrics line as it is written
(numbers flattened to names such as ``levels/0/volume``), with the environment steps as its
step, and the run's config once. TensorBoard writes to RUN_DIR/tensorboard; W&B runs offline
(into RUN_DIR/wandb, for ``wandb sync`` later) unless an API key is set. Both are optional
extras: ``pip install "mjx-emp[tracking]"``.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mjx_emp.commands import Tracking
from mjx_emp.errors import ConfigError

TENSORBOARD_SUBDIR = "tensorboard"


def flatten(metrics: Any, prefix: str = "") -> dict[str, float]:
    """The numbers of a metrics line by path (``levels/0/success``); strings, booleans and
    missing values (None, as an epoch that learnt nothing reports) are left out."""
    if isinstance(metrics, dict):
        items = metrics.items()
    elif isinstance(metrics, (list, tuple)):
        items = enumerate(metrics)
    else:
        return {prefix: float(metrics)} if isinstance(metrics, (int, float)) and not isinstance(metrics, bool) else {}
    found: dict[str, float] = {}
    for name, value in items:
        found.update(flatten(value, f"{prefix}/{name}" if prefix else str(name)))
    return found


def _extra(module: str):
    try:
        return __import__(module)
    except ImportError as err:
        raise ConfigError(f"tracking: {module} is not installed; pip install \"mjx-emp[tracking]\"") from err


class TensorBoardTracker:
    """Scalars of every metrics line at its env steps, and the config as text, in RUN_DIR/tensorboard."""

    def __init__(self, run_dir: Path, config: dict):
        tensorboardx = _extra("tensorboardX")
        self.writer = tensorboardx.SummaryWriter(logdir=str(Path(run_dir) / TENSORBOARD_SUBDIR))
        self.writer.add_text("config", "    " + json.dumps(config, indent=1).replace("\n", "\n    "), 0)

    def log(self, metrics: dict) -> None:
        step = int(metrics.get("env_steps", metrics["epoch"]))
        for name, value in flatten(metrics).items():
            self.writer.add_scalar(name, value, step)
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


class WandbTracker:
    """A W&B run holding the config and every metrics line (offline without an API key)."""

    def __init__(self, run_dir: Path, config: dict, tracking: Tracking):
        wandb = _extra("wandb")
        mode = tracking.wandb_mode
        if mode == "auto":
            mode = "online" if os.environ.get("WANDB_API_KEY") else "offline"
        self.run = wandb.init(project=tracking.wandb_project, group=tracking.wandb_group or None,
                              name=tracking.wandb_name or Path(run_dir).name, dir=str(run_dir), config=config,
                              mode=mode)

    def log(self, metrics: dict) -> None:
        self.run.log(flatten(metrics), step=int(metrics["epoch"]))

    def close(self) -> None:
        self.run.finish()


@contextlib.contextmanager
def open_trackers(tracking: Tracking, run_dir: Path, config: dict) -> Iterator[Callable[[dict], None] | None]:
    """The trackers ``tracking`` asks for, as one callable taking each epoch's metrics line
    (None when none is asked for); closed when the block ends, however it ends."""
    trackers: list = []
    try:
        if tracking.tensorboard:
            trackers.append(TensorBoardTracker(run_dir, config))
        if tracking.wandb:
            trackers.append(WandbTracker(run_dir, config, tracking))
        yield (lambda metrics: [tracker.log(metrics) for tracker in trackers]) if trackers else None
    finally:
        for tracker in trackers:
            tracker.close()
