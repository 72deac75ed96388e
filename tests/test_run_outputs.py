"""A trained run's follow-ups: `mjx-emp phase2`, `render` (skill video), `plot` (figures), `eval` (report)."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from PIL import Image
from tiny import SMALL, run_cli

from mjx_emp.run import checkpoint, jobs
from mjx_emp.viz.render import Recording, first_skills, marker_position


def test_a_recording_is_cut_where_its_top_level_skills_end():
    goals = np.array([[[0.0, 0.0], [1.0, 1.0]]] * 3 + [[[0.0, 0.0], [2.0, 2.0]]] * 2 + [[[0.0, 0.0], [3.0, 3.0]]])
    recording = Recording(np.arange(6.0)[:, None], np.zeros((6, 0, 3)), goals)
    # The first top-level skill ends at step 3 (a new top subgoal appears there), the second at 5.
    assert first_skills(recording, 1).qpos[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0]
    assert first_skills(recording, 2).qpos[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert len(first_skills(recording, 3).qpos) == 6  # fewer skills recorded: all of it


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


# A phase-2 config small enough for a test (the point-mass-k1 preset otherwise).
PHASE2_SMALL = ["--epochs", "2", "--num-envs", "8", "--iterations", "2", "--grad-steps", "5", "--batch-size", "16",
                "--hidden", "16", "--eval-rounds", "1", "--replay-capacity", "1000"]


@pytest.fixture(scope="module")
def phase2_run(trained_run):
    result = run_cli("phase2", str(trained_run), *PHASE2_SMALL)
    assert result.returncode == 0, result.stderr
    return trained_run / "phase2"


def test_phase2_trains_on_the_runs_skills_and_resumes_exactly(trained_run, phase2_run):
    config = json.loads((phase2_run / "config.json").read_text())
    assert config["phase1_epoch"] == 1 and config["region"] == [2.4, 2.4]  # the run's own preset, point-mass-k1
    assert json.loads((phase2_run / "skills.json").read_text()) == json.loads((trained_run / "config.json").read_text())
    assert [json.loads(line)["epoch"] for line in (phase2_run / "metrics.jsonl").read_text().splitlines()] == [1, 2]

    again = run_cli("phase2", str(trained_run), *PHASE2_SMALL)
    assert again.returncode == 2 and "already holds a phase-2 run" in again.stderr
    resumed = run_cli("phase2", "--resume", str(phase2_run), "--epochs", "3")
    assert resumed.returncode == 0, resumed.stderr

    # Resumed at epoch 2, the run matches three straight epochs bit for bit.
    trainer, epoch, state = jobs.load_phase2(phase2_run)
    _, _, skills_state = jobs.load_run(trained_run)
    straight = trainer.init(skills_state)
    for _ in range(3):
        straight, _ = trainer.train_epoch(straight)
    assert epoch == 3
    for a, b in zip(jax.tree.leaves(checkpoint.pack(state)), jax.tree.leaves(checkpoint.pack(straight))):
        np.testing.assert_array_equal(a, b)


def test_render_films_the_phase2_policy_with_its_goal(trained_run, phase2_run, tmp_path):
    out = tmp_path / "phase2.gif"
    result = run_cli("render", str(trained_run), "--phase2", "--steps", "4", "--width", "32", "--height", "24",
                     "--out", str(out))
    if result.returncode == 3:  # no offscreen OpenGL on this machine
        pytest.skip(result.stderr.strip())
    assert result.returncode == 0, result.stderr
    with Image.open(out) as gif:
        assert gif.n_frames == 4 and gif.size == (32, 24)


@pytest.mark.parametrize("args, message", [
    (["--region", "3"], "region: the domain's goal space has 2"),
    (["--phase1-epoch", "7"], "phase1_epoch: "),
])
def test_phase2_bad_input_exits_2_naming_the_field(trained_run, tmp_path, args, message):
    result = run_cli("phase2", str(trained_run), "--out", str(tmp_path / "p2"), *args)
    assert result.returncode == 2 and message in result.stderr


def test_plot_draws_growth_the_goal_space_boxes_and_phase2_curves(trained_run, phase2_run):
    result = run_cli("plot", str(trained_run))
    assert result.returncode == 0, result.stderr
    names = ["goal_space_growth.png", "phase2_curves.png", "goal_spaces_epoch0.png", "goal_spaces.png"]
    assert [line.rsplit("/", 1)[-1] for line in result.stdout.split()] == names
    for name in names:
        with Image.open(trained_run / "plots" / name) as image:
            assert image.format == "PNG" and np.asarray(image.convert("L")).std() > 0


def test_eval_reports_every_level_and_phase2_and_aggregates_runs_as_seeds(trained_run, phase2_run, tmp_path):
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
    first = report["runs"][0]
    assert first["coverage_cells"] >= 1 and report["coverage_cells"]["count"] == 2
    assert first["volume_x_success"] == pytest.approx(first["levels"][0]["volume"] * first["levels"][0]["success"])
    assert "coverage (48 greedy top-level skills" in result.stdout
    phase2 = report["runs"][0]["phase2"]
    assert phase2["episodes"] == 16 and phase2["eps"] == 0.6 and phase2["min_distance"] >= 0.0
    assert report["phase2"]["min_distance"]["count"] == 2 and report["phase2"]["min_distance"]["stderr"] == 0.0
    assert "mean min distance to goal" in result.stdout
