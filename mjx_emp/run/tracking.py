"""Experiment tracking beside metrics.jsonl: TensorBoard event files and Weights & Biases runs.

metrics.jsonl stays the record. A tracker receives every epoch's metrics line as it is written
(numbers flattened to names such as ``levels/0/volume``), with the environment steps as its
step, the run's config once, and when training ends a video of the trained run (TensorBoard
plays it as an animated GIF in its images tab, W&B as the MP4). TensorBoard writes to
RUN_DIR/tensorboard; W&B runs offline (into RUN_DIR/wandb, for ``wandb sync`` later) unless an
API key is set. Both are optional extras: ``pip install "mjx-emp[tracking]"``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mjx_emp.commands import Tracking
from mjx_emp.errors import ConfigError

TENSORBOARD_SUBDIR = "tensorboard"
VIDEO_TAG = "video"


@dataclasses.dataclass(frozen=True)
class Video:
    """A trained run filmed for the trackers: the MP4 written into the run directory, and the
    same frames as an animated GIF (what TensorBoard's image panel plays)."""

    path: Path
    gif: bytes
    width: int
    height: int


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
        self.logdir = str(Path(run_dir) / TENSORBOARD_SUBDIR)
        self.writer = tensorboardx.SummaryWriter(logdir=self.logdir)
        self.writer.add_text("config", "    " + json.dumps(config, indent=1).replace("\n", "\n    "), 0)

    def log(self, metrics: dict) -> None:
        for name, value in flatten(metrics).items():
            self.writer.add_scalar(name, value, _env_steps(metrics))
        self.writer.flush()

    def log_video(self, video: Video, metrics: dict) -> None:
        """The video as an animated GIF image summary at the last metrics line's env steps (written
        as tensorboardX's own ``add_video`` writes it, from our GIF, whose one palette keeps every
        marker colour)."""
        from tensorboardX import FileWriter
        from tensorboardX.proto.summary_pb2 import Summary

        image = Summary.Image(height=video.height, width=video.width, colorspace=3, encoded_image_string=video.gif)
        writer = FileWriter(self.logdir, filename_suffix=".video")
        writer.add_summary(Summary(value=[Summary.Value(tag=VIDEO_TAG, image=image)]), _env_steps(metrics))
        writer.close()

    def close(self) -> None:
        self.writer.close()


def _env_steps(metrics: dict) -> int:
    return int(metrics.get("env_steps", metrics["epoch"]))


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

    def log_video(self, video: Video, metrics: dict) -> None:
        """The MP4 at the last metrics line's epoch (W&B copies the file into the run)."""
        import wandb

        self.run.log({VIDEO_TAG: wandb.Video(str(video.path), format="mp4")}, step=int(metrics["epoch"]))

    def close(self) -> None:
        self.run.finish()


class Trackers:
    """The trackers of one run, fed together: each epoch's metrics line, then the video."""

    def __init__(self, trackers: list):
        self.trackers = trackers
        self.last: dict | None = None

    def log(self, metrics: dict) -> None:
        self.last = metrics
        for tracker in self.trackers:
            tracker.log(metrics)

    def log_video(self, video: Video) -> None:
        """The video at the step of the last metrics line (nothing when no epoch was logged)."""
        if self.last is not None:
            for tracker in self.trackers:
                tracker.log_video(video, self.last)


@contextlib.contextmanager
def open_trackers(tracking: Tracking, run_dir: Path, config: dict) -> Iterator[Trackers | None]:
    """The trackers ``tracking`` asks for (None when none is asked for); closed when the block
    ends, however it ends."""
    trackers: list = []
    try:
        if tracking.tensorboard:
            trackers.append(TensorBoardTracker(run_dir, config))
        if tracking.wandb:
            trackers.append(WandbTracker(run_dir, config, tracking))
        yield Trackers(trackers) if trackers else None
    finally:
        for tracker in trackers:
            tracker.close()


Film = Callable[[Any, Any, Path, int], Video]
"""What films a trained run for the trackers: ``film(trainer, state, run_dir, steps)``. The
command layer provides it (rendering lives above the run layer)."""
