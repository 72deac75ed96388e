"""A trained run's follow-ups: `mjx-emp phase2`, `render` (skill video), `plot` (figures), `eval` (report)."""

from __future__ import annotations

import json
import shutil

import jax
import numpy as np
import pytest
from PIL import Image
from tiny import SMALL, cli_in_process, run_cli

from mjx_emp.run import jobs, packing
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
    trained = cli_in_process("train", *SMALL, "--epochs", "1", "--run-dir", str(run_dir))
    assert trained.returncode == 0, trained.stderr
    return run_dir


def marker_frames(frames: list[np.ndarray], colour: tuple[float, ...], hue_window: float = 12.0) -> int:
    """How many frames hold at least 3 pixels of ``colour``'s hue (within ``hue_window`` degrees),
    saturated and lit as a marker is: shading changes a sphere's brightness, not its hue."""
    import colorsys

    import matplotlib.colors

    hue = 360 * colorsys.rgb_to_hsv(*colour[:3])[0]
    count = 0
    for frame in frames:
        hsv = matplotlib.colors.rgb_to_hsv(frame / 255.0)
        apart = np.abs((360 * hsv[..., 0] - hue + 180) % 360 - 180)
        count += int(((apart <= hue_window) & (hsv[..., 1] > 0.5) & (hsv[..., 2] > 0.35)).sum() >= 3)
    return count


def rendered(run_dir, out, *args) -> None:
    result = run_cli("render", str(run_dir), "--steps", "12", "--width", "320", "--height", "240", "--out", str(out),
                     *args)
    if result.returncode == 3:  # the CLI's exit code for "no offscreen OpenGL on this machine"
        pytest.skip(result.stderr.strip())
    assert result.returncode == 0, result.stderr


def test_the_mp4_keeps_the_goal_colour_in_every_frame(trained_run, tmp_path):
    import imageio_ffmpeg

    from mjx_emp.viz.render import LEVEL_COLOURS

    out = tmp_path / "skills.mp4"
    rendered(trained_run, out)
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = next(reader)
    assert tuple(meta["size"]) == (320, 240)
    frames = [np.frombuffer(raw, np.uint8).reshape(240, 320, 3) for raw in reader]
    assert len(frames) == 12
    assert marker_frames(frames, LEVEL_COLOURS[0]) == 12  # the goal, in its own colour, after compression


def test_the_gif_shares_one_palette_that_keeps_the_goal_colour(trained_run, tmp_path):
    from mjx_emp.viz.render import LEVEL_COLOURS

    out = tmp_path / "skills.gif"
    rendered(trained_run, out)
    with Image.open(out) as gif:
        assert gif.size == (320, 240)
        frames = []
        for index in range(gif.n_frames):  # identical neighbours are merged into one longer frame
            gif.seek(index)
            frames.append(np.asarray(gif.convert("RGB")))
    assert all(frame.std() > 0 for frame in frames)  # a scene was drawn, not a blank image
    assert marker_frames(frames, LEVEL_COLOURS[0]) == len(frames)  # the goal's colour in every frame


def test_a_video_that_cannot_be_written_is_refused_before_the_run_loads(trained_run, tmp_path):
    odd = cli_in_process("render", str(trained_run), "--width", "161", "--out", str(tmp_path / "v.mp4"))
    assert odd.returncode == 2 and "width and height: an MP4 needs even sizes; got 161x480" in odd.stderr
    other = cli_in_process("render", str(trained_run), "--out", str(tmp_path / "v.avi"))
    assert other.returncode == 2 and "out: a video file ends in one of ['.mp4', '.gif']; got 'v.avi'" in other.stderr


# A phase-2 config small enough for a test (the point-mass-k1 preset otherwise).
PHASE2_SMALL = ["--epochs", "2", "--num-envs", "8", "--iterations", "2", "--grad-steps", "5", "--batch-size", "16",
                "--hidden", "16", "--eval-rounds", "1", "--replay-capacity", "1000"]


@pytest.fixture(scope="module")
def phase2_run(trained_run):
    result = cli_in_process("phase2", str(trained_run), *PHASE2_SMALL)
    assert result.returncode == 0, result.stderr
    return trained_run / "phase2"


def test_train_and_phase2_keep_the_preset_and_overrides_they_were_given(trained_run, phase2_run):
    record = json.loads((trained_run / "provenance.json").read_text())
    assert record["preset"] == "point-mass-k1" and record["overrides"]["num_envs"] == 8
    assert record["overrides"]["epochs"] == 1 and "seed" not in record["overrides"]  # only what differs
    assert record["command"].startswith("mjx-emp train point-mass-k1 ") and len(record["versions"]) == 8
    task = json.loads((phase2_run / "provenance.json").read_text())
    assert task["preset"] == "reach-point-mass" and task["command"].startswith("mjx-emp phase2 reach-point-mass ")


def test_phase2_trains_on_the_runs_skills_and_resumes_exactly(trained_run, phase2_run):
    config = json.loads((phase2_run / "config.json").read_text())
    assert config["phase1_epoch"] == 1 and config["region"] == [2.4, 2.4]  # the run's own preset, point-mass-k1
    assert json.loads((phase2_run / "skills.json").read_text()) == json.loads((trained_run / "config.json").read_text())
    assert [json.loads(line)["epoch"] for line in (phase2_run / "metrics.jsonl").read_text().splitlines()] == [1, 2]

    again = cli_in_process("phase2", str(trained_run), *PHASE2_SMALL)
    assert again.returncode == 2 and "already holds a phase-2 run" in again.stderr
    resumed = cli_in_process("phase2", "--resume", str(phase2_run), "--epochs", "3")
    assert resumed.returncode == 0, resumed.stderr

    # Resumed at epoch 2, the run matches three straight epochs bit for bit.
    trainer, epoch, state = jobs.load_phase2(phase2_run)
    _, _, skills_state = jobs.load_run(trained_run)
    straight = trainer.init(skills_state)
    for _ in range(3):
        straight, _ = trainer.train_epoch(straight)
    assert epoch == 3
    for a, b in zip(jax.tree.leaves(packing.pack(state)), jax.tree.leaves(packing.pack(straight))):
        np.testing.assert_array_equal(a, b)


def test_render_films_the_phase2_policy_with_its_goal(trained_run, phase2_run, tmp_path):
    import imageio_ffmpeg

    result = run_cli("render", str(trained_run), "--phase2", "--steps", "4", "--width", "64", "--height", "48")
    if result.returncode == 3:  # no offscreen OpenGL on this machine
        pytest.skip(result.stderr.strip())
    assert result.returncode == 0, result.stderr
    reader = imageio_ffmpeg.read_frames(str(trained_run / "phase2.mp4"))  # the default name beside the run
    assert tuple(next(reader)["size"]) == (64, 48) and len(list(reader)) == 4


@pytest.mark.parametrize("args, message", [
    (["--region", "3"], "region: the domain's goal space has 2"),
    (["--phase1-epoch", "7"], "phase1_epoch: "),
])
def test_phase2_bad_input_exits_2_naming_the_field(trained_run, tmp_path, args, message):
    result = cli_in_process("phase2", str(trained_run), "--out", str(tmp_path / "p2"), *args)
    assert result.returncode == 2 and message in result.stderr


def test_plot_draws_growth_the_goal_space_boxes_and_phase2_curves(trained_run, phase2_run):
    result = cli_in_process("plot", str(trained_run))
    assert result.returncode == 0, result.stderr
    names = ["goal_space_growth.png", "phase2_curves.png", "goal_spaces.png"]
    assert [line.rsplit("/", 1)[-1] for line in result.stdout.splitlines()[1:]] == names
    for name in names:
        with Image.open(trained_run / "plots" / name) as image:
            assert image.format == "PNG" and np.asarray(image.convert("L")).std() > 0


def test_eval_reports_every_level_and_phase2_and_aggregates_runs_as_seeds(trained_run, phase2_run, tmp_path):
    out = tmp_path / "eval.json"
    copy = tmp_path / "copy"  # a second seed that is the same run: the spread over the two is 0
    shutil.copytree(trained_run, copy, ignore=shutil.ignore_patterns(".lock"))
    result = cli_in_process("eval", str(trained_run), str(copy), "--episodes", "16", "--out", str(out))
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    assert len(report["runs"]) == 2 and report["runs"][0]["figures"]["epoch"] == 1
    (level,) = report["levels"]  # SMALL is a one-level agent
    assert level["volume"]["count"] == 2 and level["volume"]["stderr"] == 0.0  # the same run copied
    assert 0.0 <= level["success"]["mean"] <= 1.0 and level["final_distance"]["mean"] >= 0.0
    assert report["runs"][0]["figures"]["levels"][0]["episodes"] == 16
    assert "| 0 |" in result.stdout
    first = report["runs"][0]["figures"]
    assert first["coverage_cells"] >= 1 and report["coverage_cells"]["count"] == 2
    assert first["volume_x_success"] == pytest.approx(first["levels"][0]["volume"] * first["levels"][0]["success"])
    assert "coverage (48 greedy top-level skills" in result.stdout
    (table,) = first["flip_table"]  # one level; a point mass never flips
    assert table["episodes"] == 32 and table["flips"] == 0 and sum(table["by_goal_place"]["episodes"]) == 32
    assert "| 0 | 64 | 0.0% | 0.0% | 0.0% |" in result.stdout  # the two runs' tables pooled
    assert first["phase2"]["flip_table"]["episodes"] == 64 and "phase 2: 0.0% of 128 greedy episodes" in result.stdout
    assert report["flip_table"]["levels"][0]["episodes"] == 64 and f"wrote {tmp_path / 'flips.png'}" in result.stdout
    with Image.open(tmp_path / "flips.png") as image:
        assert image.format == "PNG"
    phase2 = report["runs"][0]["figures"]["phase2"]
    assert phase2["episodes"] == 16 and phase2["eps"] == 0.6 and phase2["min_distance"] >= 0.0
    assert phase2["cut_short"] == 0.0 and report["phase2"]["cut_short"]["count"] == 2  # a point mass never resets
    assert report["phase2"]["min_distance"]["count"] == 2 and report["phase2"]["min_distance"]["stderr"] == 0.0
    assert "mean min distance to goal" in result.stdout
    assert report["phase2"]["uncut_min_distance"]["mean"] == pytest.approx(report["phase2"]["min_distance"]["mean"])
    assert "mean min distance where no reset ended the episode" in result.stdout
    for policy in ("aimed", "aimed_half", "random"):  # the chaining diagnostic on the same goals
        assert 0.0 <= phase2[policy]["min_distance"] and phase2[policy]["episodes"] == 16
        assert report["phase2"][policy]["min_distance"]["count"] == 2
    assert "the same goals with subgoals aimed straight at each goal" in result.stdout
    assert "the same goals with subgoals aimed within the top box's central half" in result.stdout

    assert "2 run(s); mean ± sample std (se: standard error) over runs" in result.stdout


def test_an_export_keeps_the_skills_without_the_replay_and_phase_2_reads_it(trained_run, phase2_run, tmp_path):
    out = tmp_path / "skills"
    result = cli_in_process("export", str(trained_run), "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "(epoch 1)" in result.stdout
    agent, epoch, whole = jobs.load_run(trained_run)
    exported_agent, exported_epoch, lean = jobs.load_run(out)
    assert (exported_epoch, exported_agent.cfg) == (epoch, agent.cfg)
    assert (out / "metrics.jsonl").read_text() == (trained_run / "metrics.jsonl").read_text()
    # Everything but the rebuilt fields comes back bit for bit; those come back empty.
    for field in ("policies", "goal_spaces", "starts", "key", "epoch", "env_steps"):
        for a, b in zip(jax.tree.leaves(getattr(lean, field)), jax.tree.leaves(getattr(whole, field))):
            np.testing.assert_array_equal(np.asarray(jax.random.key_data(a) if field == "key" else a),
                                          np.asarray(jax.random.key_data(b) if field == "key" else b))
    assert int(whole.replay[0].size) > 0 and int(lean.replay[0].size) == 0
    assert not any(np.asarray(leaf).any() for leaf in jax.tree.leaves(lean.replay))
    # Phase 2 starts from the export exactly as from the run.
    trainer, _, _ = jobs.load_phase2(phase2_run)
    for a, b in zip(packing.pack(trainer.init(lean)).values(), packing.pack(trainer.init(whole)).values()):
        np.testing.assert_array_equal(a, b)

    refused = cli_in_process("resume", str(out))
    assert refused.returncode == 2 and "is a skills export" in refused.stderr and "replay" in refused.stderr
    again = cli_in_process("export", str(trained_run), "--out", str(out))
    assert again.returncode == 2 and f"out: {str(out)!r} holds a skills export of {trained_run}" in again.stderr
    assert "choose another --out" in again.stderr
    assert "resume" not in again.stderr  # an export is written once; nothing can continue it
    from mjx_emp import api

    from_python = api.load(api.export(trained_run, tmp_path / "from_python", epoch=1))
    assert from_python.epoch == 1 and int(from_python.state.replay[0].size) == 0
