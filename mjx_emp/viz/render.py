"""Skill videos: a trained agent from a checkpoint, rendered offscreen.

The agent runs the same greedy chain of top-level skills that fills the start-state
buffers: from the initial state, each top-level skill is drawn from the top goal space and
executed by the levels below without exploration noise. Or, after phase 2, the phase-2
policy reaches goals from its region, and the goal is drawn as one more level's marker.
Every primitive step becomes a frame, with each level's current subgoal drawn as a
coloured sphere (level 0 yellow, then green, blue, magenta). A flat skill learner
(no goals to draw) runs its greedy skills from the prior one after another. Rendering uses MuJoCo's offscreen renderer, headless via EGL.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mjx_emp.algos.registry import GOAL_SPACES, skill_kind
from mjx_emp.errors import RenderError

if TYPE_CHECKING:  # importing the rollout imports mujoco, which must wait for configure_headless_gl
    from mjx_emp.rollout.hierarchy import RolloutPlan

LEVEL_COLOURS = ((1.0, 0.8, 0.0, 0.9), (0.1, 0.75, 0.2, 0.9), (0.15, 0.35, 0.95, 0.9), (0.85, 0.1, 0.85, 0.9))
HEADLESS_HELP = (
    "offscreen OpenGL is unavailable. mjx-emp renders with MUJOCO_GL=egl (EGL_PLATFORM="
    "surfaceless), which needs Mesa's EGL and DRI drivers (Debian/Ubuntu: apt install libegl1 "
    "libgl1-mesa-dri); or install libosmesa6 and set MUJOCO_GL=osmesa"
)


def configure_headless_gl() -> None:
    """Default MuJoCo to headless EGL rendering; call before ``mujoco`` is first imported."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    if os.environ["MUJOCO_GL"] == "egl":
        os.environ.setdefault("EGL_PLATFORM", "surfaceless")


@dataclasses.dataclass(frozen=True)
class Recording:
    """What the frames need, per primitive step: joint positions, mocap bodies, subgoals."""

    qpos: np.ndarray  # [T, nq]
    mocap_pos: np.ndarray  # [T, nmocap, 3]
    goals: np.ndarray  # [T, k, goal_size], absolute h-coordinates


def record_rollout(plan: RolloutPlan, key, steps: int) -> Recording:
    """Run one environment of ``plan`` for ``steps`` primitive steps, step by step.

    Records joint positions, mocap bodies and the goals of the plan's shown levels.
    """
    import jax

    from mjx_emp.rollout.hierarchy import jit_init_rollout, jit_rollout

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
        return record_rollout(agent.skill_chain(state), key, steps)
    qpos, mocap = agent.record_skills(state, key, steps)
    return Recording(qpos, mocap, np.zeros((steps, 0, len(agent.env.goal_qpos))))


def first_skills(recording: Recording, skills: int) -> Recording:
    """The recording cut where the top recorded level's ``skills``-th action ends (all of it if sooner)."""
    top = recording.goals[:, -1]
    ends = np.flatnonzero(np.any(top[1:] != top[:-1], axis=-1)) + 1  # a new top subgoal at these steps
    stop = ends[skills - 1] + 1 if len(ends) >= skills else len(top)
    return Recording(recording.qpos[:stop], recording.mocap_pos[:stop], recording.goals[:stop])


def marker_position(goal: np.ndarray, height: float = 0.1) -> np.ndarray:
    """Where a subgoal is drawn: (x, y) goals on the floor plane, x-only goals on the y = 0 line."""
    x, y = (goal[0], goal[1]) if goal.shape[0] >= 2 else (goal[0], 0.0)
    return np.array([x, y, height])


def render_frames(env, recording: Recording, width: int, height: int, distance: float) -> np.ndarray:
    """RGB frames [T, height, width, 3] following the torso from above, subgoals as spheres."""
    import mujoco

    try:
        renderer = mujoco.Renderer(env.mj_model, height, width)
    except Exception as err:  # the GL backends raise various types when no context can be made
        raise RenderError(f"{HEADLESS_HELP} ({type(err).__name__}: {err})") from err
    data = mujoco.MjData(env.mj_model)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.distance, camera.elevation, camera.azimuth = distance, -60.0, 90.0
    frames = []
    try:
        for qpos, mocap_pos, goals in zip(recording.qpos, recording.mocap_pos, recording.goals):
            data.qpos[:] = qpos
            if env.mj_model.nmocap:
                data.mocap_pos[:] = mocap_pos
            mujoco.mj_forward(env.mj_model, data)
            torso = marker_position(qpos[list(env.goal_qpos)], height=0.0)
            camera.lookat[:] = torso
            renderer.update_scene(data, camera)
            scene = renderer.scene
            for level, goal in enumerate(goals):
                if scene.ngeom >= scene.maxgeom:
                    break
                mujoco.mjv_initGeom(
                    scene.geoms[scene.ngeom], type=mujoco.mjtGeom.mjGEOM_SPHERE,
                    size=np.array([0.08 * (level + 1), 0.0, 0.0]), pos=marker_position(goal),
                    mat=np.eye(3).ravel(), rgba=np.array(LEVEL_COLOURS[level % len(LEVEL_COLOURS)]),
                )
                scene.ngeom += 1
            frames.append(renderer.render().copy())
    finally:
        renderer.close()
    return np.stack(frames)


def write_gif(frames: np.ndarray, path: Path, fps: float) -> Path:
    """Save frames as a looping GIF (Pillow, which matplotlib already brings)."""
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path
