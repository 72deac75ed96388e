"""Functional MuJoCo MJX environments for skill learning.

Every function here is pure and works on one environment; ``jax.vmap`` batches it.
An environment is a frozen description (model, action repeat, goal coordinates,
its torso's place in an observation, an optional cage) and an :class:`EnvState` pytree. The goal space of every domain is
the torso position, read straight from ``qpos``: h(s) = (x, y) for point mass and
Ant, h(s) = x for Half Cheetah.

Resets only rewrite the integration state (qpos, qvel, warm start, controls, mocap
poses). Derived quantities such as ``xpos`` or contacts still describe the home pose
until the next :meth:`Env.step`, which recomputes them; nothing here reads them, and
this keeps a reset free of a full ``mjx.forward``.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from mjx_emp.envs.mjx_quiet import mjx
from mjx_emp.envs.parts import Cage, Torso, rotate_xy
from mjx_emp.envs.registry import DOMAINS, DomainSpec, check_physics
from mjx_emp.errors import ConfigError

MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
"""The MJCF of every domain, shipped inside the package so that a wheel install can build them."""


@struct.dataclass
class EnvState:
    """State of one environment.

    ``key`` drives the reset that follows a non-finite physics state or a flipped torso;
    ``nan_resets`` and ``flip_resets`` count those resets over the environment's life.
    """

    data: mjx.Data
    key: jax.Array
    nan_resets: jax.Array
    flip_resets: jax.Array

    @property
    def resets(self) -> jax.Array:
        """Resets of either kind: a step that raised this ended the episode it was in."""
        return self.nan_resets + self.flip_resets


@dataclasses.dataclass(frozen=True, eq=False)
class Env:
    """A functional MJX environment; hashable by identity so it can be a static jit argument."""

    name: str
    mj_model: mujoco.MjModel
    model: mjx.Model
    template: mjx.Data
    home_qpos: np.ndarray
    action_repeat: int
    goal_qpos: tuple[int, ...]
    torso: Torso
    cage: Cage | None = None
    heading_frame: bool = False
    """Express what networks see in the torso's heading frame (robots with a free torso):
    the yaw is taken out of the torso quaternion and the world-frame torso velocity and
    goal offset are turned by minus the yaw, so a skill learnt facing one way applies
    facing any other (see :meth:`features` and :meth:`goal_offset`)."""
    feature_mean: np.ndarray | None = None
    feature_std: np.ndarray | None = None

    @property
    def action_size(self) -> int:
        return self.mj_model.nu

    @property
    def goal_size(self) -> int:
        return len(self.goal_qpos)

    @property
    def obs_size(self) -> int:
        return self.mj_model.nq + self.mj_model.nv + (1 if self.cage else 0)

    @property
    def control_dt(self) -> float:
        """Seconds of simulated time per primitive action."""
        return float(self.mj_model.opt.timestep) * self.action_repeat

    def home_goal(self) -> jax.Array:
        """Torso position of the home pose (the default start)."""
        return jnp.asarray(self.home_qpos[list(self.goal_qpos)])

    def reset(self, key: jax.Array) -> EnvState:
        """Start state of an episode: the home pose at its home position, at rest."""
        return self.reset_to(key, self.home_goal())

    def reset_to(self, key: jax.Array, torso_pos: jax.Array) -> EnvState:
        """Home joint pose and zero velocity with the torso moved to ``torso_pos``.

        Phase-1 training starts skills from arbitrary torso positions, so this is the
        reset the algorithm needs, not just a convenience.
        """
        torso_pos = jnp.asarray(torso_pos, dtype=self.template.qpos.dtype)
        qpos = jnp.asarray(self.home_qpos).at[jnp.asarray(self.goal_qpos)].set(torso_pos)
        data = self.template.replace(qpos=qpos)
        return EnvState(data=data, key=key, **_no_resets())

    def restore(self, key: jax.Array, obs: jax.Array) -> EnvState:
        """The state an observation describes: qpos, qvel and, in cages, open or closed walls.

        Start-state buffers keep observations; this turns one back into a state to start a
        skill from.
        """
        nq, nv = self.mj_model.nq, self.mj_model.nv
        dtype = self.template.qpos.dtype
        data = self.template.replace(qpos=obs[:nq].astype(dtype), qvel=obs[nq : nq + nv].astype(dtype))
        if self.cage is not None:
            data = data.replace(mocap_pos=self.cage.wall_positions(self.cage.open_of_obs(obs)))
        return EnvState(data=data, key=key, **_no_resets())

    def step(self, state: EnvState, action: jax.Array) -> EnvState:
        """Apply one primitive action (clipped to [-1, 1]) for ``action_repeat`` physics steps.

        A non-finite state after the physics resets the environment to its home pose
        and increments ``nan_resets``, so one bad batch member never poisons the rest;
        an Ant left upside down is reset the same way and counted in ``flip_resets``.
        """
        data = state.data.replace(ctrl=jnp.clip(action, -1.0, 1.0).astype(state.data.ctrl.dtype))
        data = jax.lax.fori_loop(
            0, self.action_repeat, lambda _, d: mjx.step(self.model, d), data
        )
        if self.cage is not None:
            data = self.cage.press(data)
        finite = jnp.isfinite(data.qpos).all() & jnp.isfinite(data.qvel).all()
        flipped = finite & ~self.torso.upright(data.qpos)
        key, reset_key = jax.random.split(state.key)
        data = tree_where(finite & ~flipped, data, self.reset(reset_key).data)
        return EnvState(
            data=data, key=key,
            nan_resets=state.nan_resets + (~finite).astype(jnp.int32),
            flip_resets=state.flip_resets + flipped.astype(jnp.int32),
        )

    def goal_of(self, state: EnvState) -> jax.Array:
        """h(s): the torso coordinates that make up the goal space."""
        return state.data.qpos[jnp.asarray(self.goal_qpos)]

    def observe(self, state: EnvState) -> jax.Array:
        """Policy input: qpos, qvel and, in cages, whether the cage is open."""
        parts = [state.data.qpos, state.data.qvel]
        if self.cage is not None:
            parts.append(self.cage.is_open(state.data)[None].astype(state.data.qpos.dtype))
        return jnp.concatenate(parts)

    def initial_obs(self) -> np.ndarray:
        """Observation of the task's initial state, computed eagerly (a constant under jit)."""
        with jax.ensure_compile_time_eval():
            return np.asarray(self.observe(self.reset(jax.random.key(0))))

    def features(self, obs: jax.Array) -> jax.Array:
        """What networks see of an observation.

        On an open field nothing depends on where the torso is, so h(s) is dropped and
        every network is translation invariant: skills learnt near the start transfer to
        start states far away. In a cage the position matters (walls, button) and stays.
        On the robots each feature is then standardised (fixed statistics, clipped to
        +-10): under random actions their joint speeds have standard deviations of 2-8
        rad/s, beside quaternion entries below 1.
        """
        if self.heading_frame:
            obs = self.torso.without_yaw(obs)
        raw = obs if self.cage is not None else obs[..., self.feature_index(obs.shape[-1])]
        if self.feature_mean is None:
            return raw
        return jnp.clip((raw - self.feature_mean) / self.feature_std, -10.0, 10.0)

    def goal_offset(self, obs: jax.Array, goal: jax.Array) -> jax.Array:
        """What networks see of a goal: goal - h(s), turned into the heading frame if set."""
        offset = goal - self.goal_of_obs(obs)
        if not self.heading_frame:
            return offset
        return rotate_xy(offset, -self.torso.yaw(obs))

    def feature_index(self, obs_size: int) -> np.ndarray:
        """Indices of an observation that an open-field network sees (all but h(s))."""
        return np.setdiff1d(np.arange(obs_size), np.asarray(self.goal_qpos))

    @property
    def feature_size(self) -> int:
        return self.obs_size - (0 if self.cage is not None else self.goal_size)

    def goal_of_obs(self, obs: jax.Array) -> jax.Array:
        """h(s) read back from an observation (the first entries of obs are qpos).

        A NumPy observation gives a NumPy result (constants stay constants under jit).
        """
        return obs[..., np.asarray(self.goal_qpos)]


def tree_where(condition: jax.Array, on_true, on_false):
    """Select between two pytrees of equal structure, broadcasting ``condition`` over leading axes."""

    def pick(a, b):
        c = jnp.reshape(condition, condition.shape + (1,) * (a.ndim - condition.ndim))
        return jnp.where(c, a, b)

    return jax.tree.map(pick, on_true, on_false)


def _no_resets() -> dict[str, jax.Array]:
    """Zeroed reset counters of a fresh environment state."""
    zero = jnp.zeros((), jnp.int32)
    return {"nan_resets": zero, "flip_resets": zero}


def random_action_feature_stats(env: Env, envs: int = 16, actions: int = 100, seed: int = 0):
    """Mean and std of ``env``'s raw features over uniform random actions from the home pose.

    Run in MuJoCo C (a fraction of a second), so building an environment needs no JAX
    compilation. Constant features keep a std of 1.
    """
    m = env.mj_model
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(envs):
        d = mujoco.MjData(m)
        d.qpos[:] = env.home_qpos
        for _ in range(actions):
            d.ctrl[:] = rng.uniform(-1.0, 1.0, m.nu)
            for _ in range(env.action_repeat):
                mujoco.mj_step(m, d)
            rows.append(np.concatenate([d.qpos, d.qvel, [0.0] if env.cage else []]))
    raw = np.asarray(env.features(np.asarray(rows, np.float32)))
    std = raw.std(axis=0)
    return raw.mean(axis=0).astype(np.float32), np.where(std < 1e-6, 1.0, std).astype(np.float32)


def _home_qpos(m: mujoco.MjModel) -> np.ndarray:
    key_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
    return np.array(m.key_qpos[key_id] if key_id >= 0 else m.qpos0, dtype=np.float32)


def _make_cage(m: mujoco.MjModel, d: mujoco.MjData, spec: DomainSpec) -> Cage:
    wall_bodies = [b for b in range(m.nbody) if (m.body(b).name or "").startswith("wall_")]
    button = m.site("button")
    dims = spec.goal_qpos
    return Cage(
        wall_mocap_ids=tuple(int(m.body_mocapid[b]) for b in wall_bodies),
        button_center=tuple(float(button.pos[i]) for i in range(len(dims))),
        button_half_size=tuple(float(button.size[i]) for i in range(len(dims))),
        home_mocap_pos=np.array(d.mocap_pos, dtype=np.float32),
        goal_qpos=spec.goal_qpos,
    )


_INTEGRATOR_ENUMS = {"model": None, "euler": mujoco.mjtIntegrator.mjINT_EULER,
                     "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST, "rk4": mujoco.mjtIntegrator.mjINT_RK4}


def check_backend(impl: str) -> None:
    """MJX's Warp backend needs the mujoco-warp package and a CUDA device: refuse it, naming the
    field, where either is missing (the jax backend runs anywhere)."""
    if impl != "warp":
        return
    if importlib.util.find_spec("mujoco_warp") is None:
        raise ConfigError("impl: warp needs the mujoco-warp package (pip install \"mujoco-mjx[warp]\"); "
                          "allowed here: jax")
    if jax.default_backend() != "gpu":
        raise ConfigError(f"impl: warp runs on CUDA GPUs only; this process's devices are "
                          f"{jax.default_backend()}; allowed here: jax")


@functools.cache
def make_env(name: str, heading_frame: bool = False, solver_iterations: int = 0, integrator: str = "model",
             impl: str = "jax") -> Env:
    """Build a domain by name (see :data:`DOMAINS`); cached so every caller shares one Env.

    ``heading_frame`` (robots with a free torso only) shows networks the state and goal
    in the torso's heading frame (:attr:`Env.heading_frame`). ``solver_iterations`` (0:
    the model's) and ``integrator`` (one of ``registry.INTEGRATORS``) replace the MJCF's
    solver settings: the robots' files keep the paper's cheap ones (1 iteration, Euler).
    ``impl`` picks MJX's backend (:func:`check_backend`).
    """
    check_physics(solver_iterations, integrator, impl)
    check_backend(impl)
    if name not in DOMAINS:
        raise ConfigError(f"env name {name!r} is unknown; allowed values: {sorted(DOMAINS)}")
    spec = DOMAINS[name]
    if heading_frame and spec.torso_quat is None:
        raise ConfigError(f"heading_frame: {name!r} has no free torso to take a heading from; "
                          f"allowed only for {sorted(n for n, d in DOMAINS.items() if d.torso_quat is not None)}")
    m = mujoco.MjModel.from_xml_path(str(MODELS_DIR / spec.xml))
    if solver_iterations:
        m.opt.iterations = solver_iterations
    if _INTEGRATOR_ENUMS[integrator] is not None:
        m.opt.integrator = _INTEGRATOR_ENUMS[integrator]
    d = mujoco.MjData(m)
    d.qpos[:] = _home_qpos(m)
    mujoco.mj_forward(m, d)
    device = jax.local_devices()[0]  # this process's (MJX's default is the first device of all processes)
    model = mjx.put_model(m, device=device, impl=impl)
    template = mjx.put_data(m, d, device=device, impl=impl)
    env = Env(
        name=name,
        mj_model=m,
        model=model,
        template=template,
        home_qpos=_home_qpos(m),
        action_repeat=spec.action_repeat,
        goal_qpos=spec.goal_qpos,
        torso=Torso(nq=m.nq, quat=spec.torso_quat, pitch=spec.torso_pitch, height=spec.torso_height),
        cage=_make_cage(m, d, spec) if spec.caged else None,
        heading_frame=heading_frame,
    )
    if spec.standardize:
        mean, std = random_action_feature_stats(env)
        env = dataclasses.replace(env, feature_mean=mean, feature_std=std)
    return env
