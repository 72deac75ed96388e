"""TensorBoard and W&B tracking receive what metrics.jsonl receives."""

from __future__ import annotations

import dataclasses
import struct

import pytest
from tiny import TINY1

from mjx_emp.commands import TrainExperiment, Tracking
from mjx_emp.errors import ConfigError
from mjx_emp.run import jobs, store
from mjx_emp.run.tracking import flatten


def test_a_metrics_line_flattens_to_named_numbers():
    line = {"epoch": 3, "env_steps": 96.0, "algorithm": "he", "learned": True,
            "levels": [{"volume": 2.5, "success": None}, {"volume": 8.0, "success": 0.5}]}
    assert flatten(line) == {"epoch": 3.0, "env_steps": 96.0, "levels/0/volume": 2.5, "levels/1/volume": 8.0,
                             "levels/1/success": 0.5}


def tensorboard_scalars(folder) -> dict[str, list[tuple[int, float]]]:
    """Every scalar in the event files of ``folder``, by tag, as (step, value); the files are read
    record by record (length, its CRC, the Event, its CRC)."""
    from tensorboardX.proto.event_pb2 import Event

    scalars: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(folder.glob("events.out.tfevents.*")):
        data = path.read_bytes()
        offset = 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset:offset + 8])
            event = Event.FromString(data[offset + 12:offset + 12 + length])
            offset += 12 + length + 4
            for value in event.summary.value:
                if value.HasField("simple_value"):
                    scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars


def test_tensorboard_and_an_offline_wandb_run_get_every_epoch(tmp_path, monkeypatch):
    monkeypatch.delenv("WANDB_API_KEY", raising=False)
    monkeypatch.setenv("WANDB_SILENT", "true")
    run_dir = tmp_path / "run"
    tracking = Tracking(tensorboard=True, wandb=True, wandb_project="mjx-emp-test", wandb_group="tiny")
    jobs.train(TrainExperiment(config=dataclasses.replace(TINY1, epochs=2), run_dir=str(run_dir), tracking=tracking))
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
