"""Outputs of a trained run: `mjx-emp render` (skill video), `plot` (figures), `eval` (report)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from tiny import SMALL, run_cli

from mjx_emp.render import marker_position


def test_markers_sit_on_the_floor_plane_for_2d_goals_and_on_the_x_axis_for_1d_goals():
    assert marker_position(np.array([1.5, -2.0])).tolist() == [1.5, -2.0, 0.1]
    assert marker_position(np.array([7.0]), height=0.3).tolist() == [7.0, 0.0, 0.3]


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("render") / "run"
    trained = run_cli("train", *SMALL, "--epochs", "1", "--run-dir", str(run_dir))
    assert trained.returncode == 0, trained.stderr
    return run_dir


def test_render_writes_frames_of_the_requested_size(trained_run, tmp_path):
    run_dir = trained_run
    out = tmp_path / "skills.gif"
    result = run_cli("render", str(run_dir), "--steps", "6", "--width", "64", "--height", "48", "--out", str(out))
    if result.returncode == 3:  # the CLI's exit code for "no offscreen OpenGL on this machine"
        pytest.skip(result.stderr.strip())
    assert result.returncode == 0, result.stderr
    with Image.open(out) as gif:
        assert gif.n_frames == 6 and gif.size == (64, 48)
        frames = []
        for index in range(gif.n_frames):
            gif.seek(index)
            frames.append(np.asarray(gif.convert("RGB")))
    assert all(frame.std() > 0 for frame in frames)  # a scene was drawn, not a blank image


def test_plot_draws_growth_and_the_goal_space_boxes_before_and_after_training(trained_run):
    result = run_cli("plot", str(trained_run))
    assert result.returncode == 0, result.stderr
    names = ["goal_space_growth.png", "goal_spaces_epoch0.png", "goal_spaces.png"]
    assert [line.rsplit("/", 1)[-1] for line in result.stdout.split()] == names
    for name in names:
        with Image.open(trained_run / "plots" / name) as image:
            assert image.format == "PNG" and np.asarray(image.convert("L")).std() > 0


def test_eval_reports_every_level_and_aggregates_runs_as_seeds(trained_run, tmp_path):
    out = tmp_path / "eval.json"
    result = run_cli("eval", str(trained_run), str(trained_run), "--episodes", "16", "--out", str(out))
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    assert len(report["runs"]) == 2 and report["runs"][0]["epoch"] == 1
    (level,) = report["levels"]  # SMALL is a one-level agent
    assert level["volume"]["count"] == 2 and level["volume"]["stderr"] == 0.0  # same run twice
    assert 0.0 <= level["success"]["mean"] <= 1.0 and level["final_distance"]["mean"] >= 0.0
    assert report["runs"][0]["levels"][0]["episodes"] == 16
    assert "| 0 |" in result.stdout
