"""Scripted point-mass policies: known-good controllers for tests, benchmarks and sanity checks.

They follow the :data:`mjx_emp.rollout.hierarchy.LevelPolicy` signature, ignore params and keys,
and assume the point-mass observation (x, y, vx, vy).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def point_mass_pd(params, obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
    """Level 0: a PD controller that drives the mass to its goal in a handful of actions."""
    del params, key
    return jnp.clip(2.0 * (goal - obs[:2]) - 0.5 * obs[2:4], -1.0, 1.0)


def bounded_hop(max_step: float):
    """Upper level: the next subgoal is a step toward the level's own goal, at most ``max_step`` per axis."""

    def hop(params, obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
        del params, key
        return jnp.clip(goal - obs[:2], -max_step, max_step)

    return hop
