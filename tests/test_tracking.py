"""TensorBoard and W&B tracking receive what metrics.jsonl receives."""

from __future__ import annotations

import dataclasses
import io
import os
import struct

import numpy as np
import pytest
from tiny import SMALL, TINY1, run_cli

from mjx_emp.commands import Tracking, TrainExperiment
from mjx_emp.errors import ConfigError, RenderError
from mjx_emp.run import jobs, store
from mjx_emp.run.tracking import VIDEO_TAG, flatten


def test_a_metrics_line_flattens_to_named_numbers():
    line = {"epoch": 3, "env_steps": 96.0, "algorithm": "he", "learned": True,
            "levels": [{"volume": 2.5, "success": None}, {"volume": 8.0, "success": 0.5}]}
    assert flatten(line) == {"epoch": 3.0, "env_steps": 96.0, "levels/0/volume": 2.5, "levels/1/volume": 8.0,
                             "levels/1/success": 0.5}


def tensorboard_values(folder) -> list[tuple[int, object]]:
    """Every summary value in the event files of ``folder`` as (step, value); the files are read
    record by record (length, its CRC, the Event, its CRC)."""
    from tensorboardX.proto.event_pb2 import Event

    values = []
    for path in sorted(folder.glob("events.out.tfevents.*")):
        data = path.read_bytes()
        offset = 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset:offset + 8])
            event = Event.FromString(data[offset + 12:offset + 12 + length])
            offset += 12 + length + 4
            values += [(event.step, value) for value in event.summary.value]
    return values


def tensorboard_scalars(folder) -> dict[str, list[tuple[int, float]]]:
    """Every scalar in the event files of ``folder``, by tag, as (step, value)."""
    scalars: dict[str, list[tuple[int, float]]] = {}
    for step, value in tensorboard_values(folder):
        if value.HasField("simple_value"):
            scalars.setdefault(value.tag, []).append((step, value.simple_value))
    return scalars


def test_tensorboard_and_an_offline_wandb_run_get_every_epoch(tmp_path, monkeypatch, capsys):
    """... and a run whose video cannot be rendered still ends as trained, saying so."""
    monkeypatch.delenv("WANDB_API_KEY", raising=False)
    monkeypatch.setenv("WANDB_SILENT", "true")
    run_dir = tmp_path / "run"
    tracking = Tracking(tensorboard=True, wandb=True, wandb_project="mjx-emp-test", wandb_group="tiny")

    def no_gl(trainer, state, run_dir, steps):
        raise RenderError("offscreen OpenGL is unavailable")

    jobs.train(TrainExperiment(config=dataclasses.replace(TINY1, epochs=2), run_dir=str(run_dir), tracking=tracking),
               film=no_gl)
    assert "no video for the trackers: offscreen OpenGL is unavailable" in capsys.readouterr().err
    metrics = store.read_metrics(run_dir)
    scalars = tensorboard_scalars(run_dir / "tensorboard")
    assert [step for step, _ in scalars["levels/0/volume"]] == [int(m["env_steps"]) for m in metrics]
    assert [value for _, value in scalars["levels/0/volume"]] == pytest.approx(
        [m["levels"][0]["volume"] for m in metrics], rel=1e-6)
    offline = list((run_dir / "wandb").glob("offline-run-*"))
    assert len(offline) == 1
    (record,) = offline[0].glob("run-*.wandb")  # the run's record, what `wandb sync` uploads
    data = record.read_bytes()
    assert b"sigma_gc" in data and b"levels/0/volume" in data  # the config and the metrics


def test_tracking_a_seed_group_is_refused_naming_the_field(tmp_path):
    with pytest.raises(ConfigError, match="seeds: tracking follows one run"):
        jobs.train(TrainExperiment(config=TINY1, run_dir=str(tmp_path / "r"), seeds=(0, 1),
                                   tracking=Tracking(tensorboard=True)))


def test_a_tracked_cli_run_ends_with_its_video_in_tensorboard_and_wandb(tmp_path):
    from PIL import Image

    run_dir = tmp_path / "run"
    env = {**os.environ, "WANDB_SILENT": "true", "WANDB_MODE": "offline"}
    env.pop("WANDB_API_KEY", None)
    result = run_cli("train", *SMALL[:-1], "2", "--run-dir", str(run_dir), "--tensorboard", "--wandb",
                     "--video-steps", "12", env=env)
    assert result.returncode == 0, result.stderr
    assert f"{run_dir / 'skills.mp4'}: logged to the trackers" in result.stdout
    last_steps = int(store.read_metrics(run_dir)[-1]["env_steps"])
    ((step, value),) = [(step, value) for step, value in tensorboard_values(run_dir / "tensorboard")
                        if value.tag == VIDEO_TAG]
    assert step == last_steps and (value.image.width, value.image.height) == (640, 480)
    with Image.open(io.BytesIO(value.image.encoded_image_string)) as gif:  # an animated GIF, one frame a step
        assert gif.format == "GIF" and gif.n_frames == 12
        assert np.asarray(gif.convert("RGB")).std() > 0
    (offline,) = (run_dir / "wandb").glob("offline-run-*")
    (video,) = offline.glob("files/media/videos/video_*.mp4")  # the MP4, copied into the W&B run
    assert video.read_bytes() == (run_dir / "skills.mp4").read_bytes()
