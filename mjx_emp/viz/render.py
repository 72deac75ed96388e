"""Skill videos: a trained agent from a checkpoint, rendered offscreen.

The agent runs the same greedy chain of top-level skills that fills the start-state
buffers: from the initial state, each top-level skill is drawn from the top goal space and
executed by the levels below without exploration noise. Or, after phase 2, the phase-2
policy reaches goals from its region, and the goal is drawn as one more level's marker.
Every primitive step becomes a frame, with each level's current subgoal drawn as a
coloured sphere (level 0 yellow, then green, blue, magenta). A flat skill learner
(no goals to draw) runs its greedy skills from the prior one after another. Rendering uses
MuJoCo's offscreen renderer, headless via EGL: importing this module imports MuJoCo, so the
OpenGL backend is chosen first (:mod:`mjx_emp.viz.gl`, which the command line calls).
"""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import imageio_ffmpeg
import jax
import mujoco
import numpy as np
from PIL import Image

from mjx_emp.algos.registry import GOAL_SPACES, skill_kind
from mjx_emp.commands import RenderExperiment
from mjx_emp.errors import ConfigError, RenderError
from mjx_emp.rollout.hierarchy import jit_init_rollout, jit_rollout
from mjx_emp.rollout.structures import RolloutPlan
from mjx_emp.run.store import SKILLS_FILE, replace_file
from mjx_emp.run.tracking import Video

LEVEL_COLOURS = ((1.0, 0.8, 0.0, 0.9), (0.1, 0.75, 0.2, 0.9), (0.15, 0.35, 0.95, 0.9), (0.85, 0.1, 0.85, 0.9))
HEADLESS_HELP = (
    "offscreen OpenGL is unavailable. mjx-emp renders with MUJOCO_GL=egl (EGL_PLATFORM="
    "surfaceless), which needs Mesa's EGL and DRI drivers (Debian/Ubuntu: apt install libegl1 "
    "libgl1-mesa-dri); or install libosmesa6 and set MUJOCO_GL=osmesa"
)


@dataclasses.dataclass(frozen=True)
class Recording:
    """What the frames need, per primitive step: joint positions, mocap bodies, subgoals."""

    qpos: np.ndarray  # [T, nq]
    mocap_pos: np.ndarray  # [T, nmocap, 3]
    goals: np.ndarray  # [T, k, goal_size], absolute h-coordinates
    box: np.ndarray | None = None
    """The top goal-space box at s0 as [low, high] in h-coordinates ([2, goal_size]), drawn on the
    floor; None where the skills have no box (flat skill learners, phase 2)."""


def record_rollout(plan: RolloutPlan, key, steps: int) -> Recording:
    """Run one environment of ``plan`` for ``steps`` primitive steps, step by step.

    Records joint positions, mocap bodies and the goals of the plan's shown levels.
    """
    hierarchy, params, start, start_params = plan.hierarchy, plan.params, plan.start, plan.start_params
    rollout_state = jit_init_rollout(hierarchy, params, start, start_params, key, 1, plan.root)
    qpos, mocap, goals = [], [], []
    for _ in range(steps):
        rollout_state = jit_rollout(hierarchy, params, start, start_params, rollout_state, 1)[0]
        data = jax.device_get(rollout_state.env.data)
        qpos.append(np.asarray(data.qpos[0]))
        mocap.append(np.asarray(data.mocap_pos[0]))
        goals.append(np.stack([np.asarray(g[0]) for g in rollout_state.goals[: plan.levels_with_goals]]))
    return Recording(np.stack(qpos), np.stack(mocap), np.stack(goals))


def skill_recording(agent, state, key, steps: int) -> Recording:
    """``steps`` primitive steps of an agent's greedy skills from the initial state, as its
    registry entry's kind of skills calls for: the chain of top-level skills, every level's goal
    recorded, for goal spaces; skills z from the prior one after another (no goals) otherwise."""
    if skill_kind(agent.cfg) == GOAL_SPACES:
        recording = record_rollout(agent.skill_chain(state), key, steps)
        top = agent.goal_spaces(state)[-1]
        start = np.asarray(agent.env.goal_of_obs(agent.initial_obs))
        centre, half_width = start + np.asarray(top["shift"]), np.asarray(top["half_width"])
        return dataclasses.replace(recording, box=np.stack([centre - half_width, centre + half_width]))
    qpos, mocap = agent.record_skills(state, key, steps)
    return Recording(qpos, mocap, np.zeros((steps, 0, len(agent.env.goal_qpos))))


def first_skills(recording: Recording, skills: int) -> Recording:
    """The recording cut where the top recorded level's ``skills``-th action ends (all of it if sooner)."""
    top = recording.goals[:, -1]
    ends = np.flatnonzero(np.any(top[1:] != top[:-1], axis=-1)) + 1  # a new top subgoal at these steps
    stop = ends[skills - 1] + 1 if len(ends) >= skills else len(top)
    return Recording(recording.qpos[:stop], recording.mocap_pos[:stop], recording.goals[:stop], recording.box)


def marker_position(goal: np.ndarray, height: float = 0.1) -> np.ndarray:
    """Where a subgoal is drawn: (x, y) goals on the floor plane, x-only goals on the y = 0 line."""
    x, y = (goal[0], goal[1]) if goal.shape[0] >= 2 else (goal[0], 0.0)
    return np.array([x, y, height])


TRAIL_COLOUR = (0.2, 0.85, 0.95)
"""The fading trail of h(s): cyan, apart from every level's marker colour."""
BOX_COLOUR = (0.95, 0.3, 0.3, 0.9)
"""The top goal-space box's outline on the floor."""
TRAIL_STEPS = 80
"""How many past steps of h(s) the trail shows, fading out."""


def view_of(env, recording: Recording, fovy: float) -> tuple[np.ndarray, float]:
    """A fixed camera's look-at point and distance that keep the whole recording in view: every
    position of h(s), every goal and the top box, with a margin."""
    points = [recording.qpos[:, list(env.goal_qpos)].reshape(-1, len(env.goal_qpos)),
              recording.goals.reshape(-1, recording.goals.shape[-1])]
    if recording.box is not None:
        points.append(recording.box)
    points = np.concatenate([marker_position_all(p) for p in points if len(p)])
    low, high = points.min(0), points.max(0)
    centre = (low + high) / 2
    radius = 1.15 * max(float(np.max(high - low)) / 2, 0.5) + 0.3  # a margin for the robot's body around h(s)
    return centre, radius / np.tan(np.radians(fovy) / 2)


def marker_position_all(goals: np.ndarray, height: float = 0.0) -> np.ndarray:
    """:func:`marker_position` of every row of ``goals`` ([N, goal_size]) -> [N, 3]."""
    return np.stack([marker_position(g, height) for g in goals]) if len(goals) else np.zeros((0, 3))


def _add_geom(scene, geom_type, size, pos, rgba) -> None:
    if scene.ngeom >= scene.maxgeom:
        return
    mujoco.mjv_initGeom(scene.geoms[scene.ngeom], type=geom_type, size=np.asarray(size, float),
                        pos=np.asarray(pos, float), mat=np.eye(3).ravel(), rgba=np.asarray(rgba, float))
    scene.ngeom += 1


def _draw_box_outline(scene, box: np.ndarray) -> None:
    """The top goal-space box as four thin bars on the floor (an interval on the x axis in 1-D)."""
    low, high = marker_position(box[0], 0.01), marker_position(box[1], 0.01)
    if box.shape[1] < 2:
        low[1], high[1] = -0.5, 0.5
    thick = 0.03
    centre = (low + high) / 2
    half = (high - low) / 2
    for axis in (0, 1):
        for side in (low, high):
            pos = centre.copy()
            pos[1 - axis] = side[1 - axis]
            size = [thick, thick, thick]
            size[axis] = half[axis] + thick
            _add_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, size, pos, BOX_COLOUR)


def render_frames(env, recording: Recording, width: int, height: int, camera_mode: str = "fixed",
                  distance: float = 6.0) -> np.ndarray:
    """RGB frames [T, height, width, 3]: every level's current subgoal as a sphere in its fixed
    colour, a fading trail of h(s) and the top goal-space box on the floor. The ``fixed`` camera
    keeps the whole recording in view; ``follow`` tracks the torso at ``distance``."""
    try:
        renderer = mujoco.Renderer(env.mj_model, height, width)
    except Exception as err:  # the GL backends raise various types when no context can be made
        raise RenderError(f"{HEADLESS_HELP} ({type(err).__name__}: {err})") from err
    data = mujoco.MjData(env.mj_model)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.elevation, camera.azimuth = -60.0, 90.0
    if camera_mode == "fixed":
        camera.lookat[:], camera.distance = view_of(env, recording, float(env.mj_model.vis.global_.fovy))
    else:
        camera.distance = distance
    torsos = marker_position_all(recording.qpos[:, list(env.goal_qpos)], height=0.05)
    frames = []
    try:
        for step, (qpos, mocap_pos, goals) in enumerate(zip(recording.qpos, recording.mocap_pos, recording.goals)):
            data.qpos[:] = qpos
            if env.mj_model.nmocap:
                data.mocap_pos[:] = mocap_pos
            mujoco.mj_forward(env.mj_model, data)
            if camera_mode != "fixed":
                camera.lookat[:] = marker_position(qpos[list(env.goal_qpos)], height=0.0)
            renderer.update_scene(data, camera)
            scene = renderer.scene
            if recording.box is not None:
                _draw_box_outline(scene, recording.box)
            first = max(0, step - TRAIL_STEPS)
            for past in range(first, step):
                fade = (past - first + 1) / (step - first + 1)
                _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, [0.05, 0, 0], torsos[past], (*TRAIL_COLOUR, 0.8 * fade))
            for level, goal in enumerate(goals):
                _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, [0.08 * (level + 1), 0, 0], marker_position(goal),
                          LEVEL_COLOURS[level % len(LEVEL_COLOURS)])
            frames.append(renderer.render().copy())
    finally:
        renderer.close()
    return np.stack(frames)


VIDEO_SUFFIXES = (".mp4", ".gif")


def check_video(path: Path, width: int, height: int) -> None:
    """Refuse a video this module cannot write, naming the field: a suffix other than .mp4 or
    .gif, or an MP4 of odd size (H.264's yuv420p halves both)."""
    suffix = Path(path).suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ConfigError(f"out: a video file ends in one of {list(VIDEO_SUFFIXES)}; got {Path(path).name!r}")
    if suffix == ".mp4" and (width % 2 or height % 2):
        raise ConfigError(f"width and height: an MP4 needs even sizes; got {width}x{height}")


def write_video(frames: np.ndarray, path: Path, fps: float) -> Path:
    """Save frames as an H.264 MP4 (the ffmpeg that imageio-ffmpeg ships) or a GIF, by the
    path's suffix; the GIF shares one palette that holds every marker colour, so no frame
    loses them."""
    path = Path(path)
    check_video(path, frames.shape[2], frames.shape[1])
    suffix = path.suffix.lower()
    write = _write_mp4 if suffix == ".mp4" else _write_gif
    return replace_file(path, lambda temporary: write(frames, temporary, fps), chosen=True)


def _write_mp4(frames: np.ndarray, path: Path, fps: float) -> None:
    height, width = frames.shape[1:3]
    writer = imageio_ffmpeg.write_frames(str(path), (width, height), fps=fps, quality=8, macro_block_size=2,
                                         ffmpeg_log_level="error")
    writer.send(None)  # start ffmpeg
    try:
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()


def _write_gif(frames: np.ndarray, path: Path, fps: float) -> None:
    path.write_bytes(gif_bytes(frames, fps))


def gif_bytes(frames: np.ndarray, fps: float) -> bytes:
    """Frames as an animated GIF whose one palette holds every marker colour (a palette per frame
    would drop the small markers' colours in most frames)."""
    swatches = np.repeat(np.repeat(np.array(
        [[[round(255 * c) for c in colour[:3]] for colour in (*LEVEL_COLOURS, TRAIL_COLOUR, BOX_COLOUR)]],
        np.uint8), 16, axis=0), 16, axis=1)  # every marker colour, large enough to earn a palette entry
    sample = frames[:: max(1, len(frames) // 16)].reshape(-1, frames.shape[2], 3)
    canvas = np.zeros((sample.shape[0] + swatches.shape[0], max(sample.shape[1], swatches.shape[1]), 3), np.uint8)
    canvas[: sample.shape[0], : sample.shape[1]] = sample
    canvas[sample.shape[0]:, : swatches.shape[1]] = swatches
    palette = Image.fromarray(canvas).quantize(colors=255, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(frame).quantize(palette=palette, dither=Image.Dither.NONE) for frame in frames]
    encoded = io.BytesIO()
    images[0].save(encoded, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return encoded.getvalue()


def record_trained(trainer, state, phase2: bool, key, steps: int) -> Recording:
    """``steps`` primitive steps of a trained run: the phase-2 policy reaching goals of its region
    (``phase2``), else the greedy skills (:func:`skill_recording`)."""
    if phase2:
        return record_rollout(trainer.greedy_episodes(state), key, steps)
    return skill_recording(trainer, state, key, steps)


def video_name(phase2: bool) -> str:
    """A run's default video file: ``skills.mp4``, or ``phase2.mp4`` for its phase-2 policy."""
    return "phase2.mp4" if phase2 else "skills.mp4"


def film_for_trackers(trainer, state, run_dir: Path, steps: int):
    """The trackers' video of a run that just finished training (a :data:`mjx_emp.run.tracking.Film`):
    ``steps`` greedy steps filmed as `mjx-emp render` films them by default (its size, fps,
    camera and seed), written into RUN_DIR (:func:`video_name`; a phase-2 directory films its
    phase-2 policy) and kept as a GIF for TensorBoard."""
    phase2 = (Path(run_dir) / SKILLS_FILE).exists()
    look = RenderExperiment(run_dir=str(run_dir), steps=steps)
    recording = record_trained(trainer, state, phase2, jax.random.key(look.seed), steps)
    frames = render_frames(trainer.env, recording, look.width, look.height, look.camera, look.distance)
    path = write_video(frames, Path(run_dir) / video_name(phase2), look.fps)
    return Video(path, gif_bytes(frames, look.fps), look.width, look.height)
