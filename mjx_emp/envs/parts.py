"""The parts of an environment that only some domains have: a torso whose tilt and heading are
read from an observation (:class:`Torso`), and a cage of walls a floor button opens (:class:`Cage`).

What they read of an observation broadcasts over leading axes; what they do to ``mjx.Data`` works on one
environment, as ``Env.step`` does, and ``jax.vmap`` batches it.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from mjx_emp.envs.mjx_quiet import mjx

TURN_LIFT = 0.8
"""Metres a turned start (:meth:`Torso.turned`) lifts the torso per unit sin(angle): about the
farthest a foot of the Ant or the Half Cheetah reaches from the torso's centre, so that no
foot starts below the floor (the robot drops a little instead)."""


@dataclasses.dataclass(frozen=True)
class Torso:
    """Where a robot's torso orientation sits in an observation (or qpos: an observation's first
    entries), and what is read from it: how far it tilts, how fast it turns, its heading.

    ``quat`` is where a free torso's quaternion starts (the Ant), ``pitch`` where a planar torso's
    pitch hinge is (the Half Cheetah); neither for a robot without one (the point mass). ``nq``
    is where the velocities start in an observation.
    """

    nq: int
    quat: int | None = None
    pitch: int | None = None
    height: int | None = None
    """Where the torso's height is in qpos (lifted by :meth:`turned`)."""

    @property
    def free(self) -> bool:
        """Whether the torso turns freely, so that upside down it cannot right itself."""
        return self.quat is not None

    def up_axis_z(self, obs: jax.Array) -> jax.Array:
        """World z of the torso's up axis: 1 upright, 0 on its side, -1 upside down; from the free
        torso's quaternion or the cosine of the planar torso's pitch; 1 without a torso."""
        if self.pitch is not None:
            return jnp.cos(obs[..., self.pitch])
        if self.quat is None:
            return jnp.ones(jnp.shape(obs)[:-1])
        w, x, y, z = (obs[..., self.quat + i] for i in range(4))
        return (w * w - x * x - y * y + z * z) / (w * w + x * x + y * y + z * z)

    def tilt(self, obs: jax.Array) -> jax.Array:
        """1 - z of the torso's up axis: 0 upright, 1 on its side, 2 on its back. What a level that
        pays for tilting pays (``tilt_cost``), what the reflex watches, what the flip table reads."""
        return 1.0 - self.up_axis_z(obs)

    def upside_down(self, obs: jax.Array) -> jax.Array:
        """Whether the torso's up axis points below the horizon (tilted past 90 degrees): a flip
        for a planar torso, which is never reset, and what ``upright`` resets a free one on."""
        return self.up_axis_z(obs) < 0.0

    def upright(self, qpos: jax.Array) -> jax.Array:
        """False once a free torso's up axis points below the horizon (tilted past 90 degrees).

        Always True for robots without a free torso (point mass, Half Cheetah): a planar robot
        on its back is never reset.
        """
        if not self.free:
            return jnp.ones((), bool)
        return self.up_axis_z(qpos) > 0.0

    def angular_speed(self, obs: jax.Array) -> jax.Array:
        """How fast the torso turns, in rad/s: the norm of a free torso's angular velocity or the
        planar torso's pitch rate; 0 without a torso."""
        velocity = obs[..., self.nq:]
        if self.pitch is not None:
            return jnp.abs(velocity[..., self.pitch])
        if self.quat is None:
            return jnp.zeros(jnp.shape(obs)[:-1])
        # The free torso joint comes first (position, then quaternion in qpos; linear, then angular
        # velocity in qvel), so its angular velocity is qvel[3:6].
        return jnp.linalg.norm(velocity[..., 3:6], axis=-1)

    def turned(self, obs: jax.Array, angle: jax.Array, heading: jax.Array) -> jax.Array:
        """``obs`` with the torso turned by ``angle`` (radians) about the horizontal axis at
        ``heading`` (radians from world x), its velocities kept, and lifted by
        :data:`TURN_LIFT` x sin(angle) so that no foot starts below the floor. A free torso turns
        about that axis (its tilt becomes 1 - cos(angle) from upright); a planar torso pitches
        by ``angle`` in the sign of cos(heading); a robot without a torso is left as it is."""
        obs = jnp.asarray(obs)
        if self.pitch is not None:
            obs = obs.at[..., self.pitch].add(jnp.where(jnp.cos(heading) >= 0.0, angle, -angle))
        elif self.quat is not None:
            half = 0.5 * angle
            r = (jnp.cos(half), jnp.sin(half) * jnp.cos(heading), jnp.sin(half) * jnp.sin(heading), jnp.zeros_like(half))
            q = tuple(obs[..., self.quat + i] for i in range(4))
            obs = obs.at[..., self.quat : self.quat + 4].set(jnp.stack(hamilton(r, q), axis=-1))
        else:
            return obs
        if self.height is not None:
            obs = obs.at[..., self.height].add(TURN_LIFT * jnp.abs(jnp.sin(angle)))
        return obs

    def yaw(self, obs: jax.Array) -> jax.Array:
        """Heading of a free torso about the world z axis, read from its quaternion."""
        w, x, y, z = (obs[..., self.quat + i] for i in range(4))
        return jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

    def without_yaw(self, obs: jax.Array) -> jax.Array:
        """``obs`` as seen facing +x: quaternion q -> q_yaw^-1 q (sign fixed so w >= 0), world
        x-y velocity turned by -yaw.

        A free joint's first three velocities are world-frame linear velocity (its angular
        velocity is already in the torso's frame, so it stays).
        """
        obs = jnp.asarray(obs)
        half = -0.5 * self.yaw(obs)
        c, s = jnp.cos(half), jnp.sin(half)
        q = self.quat
        w, x, y, z = (obs[..., q + i] for i in range(4))
        quat = jnp.stack(hamilton((c, 0.0, 0.0, s), (w, x, y, z)), axis=-1)
        quat = jnp.where(quat[..., :1] < 0.0, -quat, quat)  # q and -q are one rotation: keep w >= 0
        turned = rotate_xy(obs[..., self.nq : self.nq + 2], 2.0 * half)
        return obs.at[..., q : q + 4].set(quat).at[..., self.nq : self.nq + 2].set(turned)


def hamilton(a: tuple[jax.Array, ...], b: tuple[jax.Array, ...]) -> tuple[jax.Array, ...]:
    """The Hamilton product a b of two quaternions given as (w, x, y, z): rotation b, then a."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


@dataclasses.dataclass(frozen=True, eq=False)
class Cage:
    """Walls on mocap bodies plus a floor button that opens them.

    The button is an axis-aligned box in goal space; when h(s) is inside it the walls
    move ``open_scale`` times further from the origin, which for plane walls means
    out of reach for good. An observation in a cage ends with a flag: 1 once the walls are gone.
    """

    wall_mocap_ids: tuple[int, ...]
    button_center: tuple[float, ...]
    button_half_size: tuple[float, ...]
    home_mocap_pos: np.ndarray
    """Mocap positions of the closed cage (the model's home)."""
    goal_qpos: tuple[int, ...]
    """Where h(s) is in qpos: the button is pressed by it."""
    open_scale: float = 1000.0

    def wall_positions(self, is_open: jax.Array) -> jax.Array:
        """Mocap positions of a closed cage, or of an open one (walls moved far out)."""
        home = jnp.asarray(self.home_mocap_pos)
        ids = jnp.asarray(self.wall_mocap_ids)
        opened = home.at[ids].set(home[ids] * self.open_scale)
        return jnp.where(is_open, opened, home)

    def press(self, data: mjx.Data) -> mjx.Data:
        """``data`` with the walls gone if h(s) is on the button (they stay gone once pressed)."""
        offset = jnp.abs(data.qpos[jnp.asarray(self.goal_qpos)] - jnp.asarray(self.button_center))
        pressed = jnp.all(offset <= jnp.asarray(self.button_half_size))
        return data.replace(mocap_pos=jnp.where(pressed, self.wall_positions(True), data.mocap_pos))

    def is_open(self, data: mjx.Data) -> jax.Array:
        """True once the button has been pressed in this episode."""
        return jnp.any(data.mocap_pos != jnp.asarray(self.home_mocap_pos))

    @staticmethod
    def open_of_obs(obs: jax.Array | np.ndarray) -> jax.Array | np.ndarray:
        """Whether the walls are gone in observations ``obs`` [..., obs_size] (NumPy in, NumPy out)."""
        return obs[..., -1] > 0.5

    @staticmethod
    def obs_opened(obs: np.ndarray, is_open: bool) -> np.ndarray:
        """A copy of the host observation ``obs`` with the cage's walls gone (or standing)."""
        changed = np.array(obs, copy=True)
        changed[..., -1] = float(is_open)
        return changed


def rotate_xy(vector: jax.Array, angle: jax.Array) -> jax.Array:
    """Turn the x-y vectors in the last axis of ``vector`` by ``angle`` radians (counter-clockwise)."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    x, y = vector[..., 0], vector[..., 1]
    return jnp.stack([c * x - s * y, s * x + c * y], axis=-1)
