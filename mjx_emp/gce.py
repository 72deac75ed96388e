"""Goal-Conditioned Empowerment math: rewards, the uniform goal-space box, discounts.

Notation follows the paper. A goal-space action ``a`` = (shift, log_half_width) describes
a uniform box of goals z relative to h(s0); z = g(noise, a) = shift + noise * exp(log_hw)
with noise ~ U[-1, 1]^d (the reparameterisation trick). Rewards use a fixed-variance
Gaussian variational distribution centred on the achieved goal h(s).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

LOG_2PI = math.log(2.0 * math.pi)


def log_normal(x: jax.Array, mean: jax.Array, sigma: float) -> jax.Array:
    """log N(x; mean, sigma^2 I), summed over the last axis."""
    d = x.shape[-1]
    sq = jnp.sum(jnp.square(x - mean), axis=-1)
    return -0.5 * sq / sigma**2 - d * (math.log(sigma) + 0.5 * LOG_2PI)


def goal_conditioned_reward(goal: jax.Array, achieved: jax.Array, sigma_gc: float) -> jax.Array:
    """Per-step reward log N(h(s0) + z; h(s_{t+1}), sigma_gc): ``goal`` is the absolute h(s0) + z."""
    return log_normal(goal, achieved, sigma_gc)


def goal_conditioned_discount(reached: jax.Array, gamma: float) -> jax.Array:
    """gamma, or 0 once h(s_{t+1}) is within eps of the goal (the episode of that goal ends)."""
    return jnp.where(reached, 0.0, gamma)


def split_goal_space_action(action: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(shift, log_half_width) halves of a goal-space action [..., 2d]."""
    d = action.shape[-1] // 2
    return action[..., :d], action[..., d:]


def sample_goal(noise: jax.Array, action: jax.Array) -> jax.Array:
    """z = g(noise, a) = shift + noise * half_width, noise in [-1, 1]^d; differentiable in ``a``."""
    shift, log_half_width = split_goal_space_action(action)
    return shift + noise * jnp.exp(log_half_width)


def goal_noise(key: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """Exogenous noise of the reparameterisation: uniform on [-1, 1]."""
    return jax.random.uniform(key, shape, minval=-1.0, maxval=1.0)


def log_prob_box(action: jax.Array) -> jax.Array:
    """log p(z | a) of the uniform box: -sum_i log(2 * half_width_i), the same for every z inside."""
    _, log_half_width = split_goal_space_action(action)
    return -jnp.sum(math.log(2.0) + log_half_width, axis=-1)


def goal_space_reward(
    start_goal: jax.Array, z: jax.Array, final_goal: jax.Array, action: jax.Array, sigma_gs: float
) -> jax.Array:
    """Goal-space critic target: log N(h(s0) + z; h(s_n), sigma_gs) - log p(z | a).

    The entropy term is linear in the log half-widths, so the incentive to grow does not
    fade as the box gets large (the reason the paper's mu outputs log half-widths).
    """
    return log_normal(start_goal + z, final_goal, sigma_gs) - log_prob_box(action)


def box_volume(action: jax.Array) -> jax.Array:
    """Volume (length in 1-D) of the goal-space box: prod_i 2 * half_width_i."""
    return jnp.exp(-log_prob_box(action))
