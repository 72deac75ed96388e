"""The intrinsic objectives of the flat skill learners, as pure functions and their models.

Each objective has a model (a posterior, skill dynamics or a representation phi), a loss
that trains it on a replay minibatch, and the reward SAC then maximises:

- DIAYN (Eysenbach et al. 2019): posterior q(z | s0, s'), a diagonal Gaussian; reward
  log q(z | s0, s') - log p(z) with p uniform on [-1, 1]^d.
- HIDIO (Zhang et al. 2021), the variant Levy et al. ran: q(z | s0, a, s'), where a is the
  action that led to s'.
- DADS (Sharma et al. 2020): skill dynamics q(s' | s, z), a Gaussian over the change of
  the state descriptor with unit variance; reward log q(s'|s,z) - log (1/L) sum_i q(s'|s,z_i)
  over L skills z_i from the prior.
- METRA (Park et al. 2024): phi(s) in R^d under ||phi(s') - phi(s)|| <= 1, enforced by
  dual gradient descent on lambda; reward (phi(s') - phi(s))^T z.

A "descriptor" y(s) is what these models see of a state: the network features and the
displacement h(s) - h(s0) from where the skill began (see :func:`descriptor`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from mjx_emp.envs.env import Env
from mjx_emp.learners.sac import LOG_STD_MAX, LOG_STD_MIN
from mjx_emp.nets import MLP

LOG_2PI = math.log(2.0 * math.pi)


def descriptor(env: Env, obs: jax.Array, s0: jax.Array) -> jax.Array:
    """y(s): the state's network features and its displacement h(s) - h(s0) in goal space."""
    return jnp.concatenate([env.features(obs), env.goal_of_obs(obs) - env.goal_of_obs(s0)], axis=-1)


def diagonal_gaussian_log_prob(x: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """log N(x; mean, diag(exp(log_std)^2)), summed over the last axis."""
    z = (x - mean) * jnp.exp(-log_std)
    return (-0.5 * z**2 - log_std - 0.5 * LOG_2PI).sum(axis=-1)


def uniform_log_prob(skill_dim: int) -> float:
    """log p(z) of the uniform prior on [-1, 1]^d."""
    return -skill_dim * math.log(2.0)


class GaussianHead(nn.Module):
    """MLP giving a diagonal Gaussian's mean and log std (clipped like the SAC actor's)."""

    hidden: Sequence[int]
    size: int

    @nn.compact
    def __call__(self, x: jax.Array) -> tuple[jax.Array, jax.Array]:
        mean, log_std = jnp.split(MLP(tuple(self.hidden), 2 * self.size)(x), 2, axis=-1)
        return mean, jnp.clip(log_std, LOG_STD_MIN, LOG_STD_MAX)


# ---- DIAYN and HIDIO: a variational posterior over the skill -------------------------------
def posterior_reward(log_q: jax.Array, skill_dim: int) -> jax.Array:
    """DIAYN's and HIDIO's reward log q(z | ...) - log p(z) (uniform prior on [-1, 1]^d)."""
    return log_q - uniform_log_prob(skill_dim)


# ---- DADS: skill dynamics ------------------------------------------------------------------
def dads_reward(log_q_own: jax.Array, log_q_prior: jax.Array) -> jax.Array:
    """log q(s'|s,z) - log (1/L) sum_i q(s'|s,z_i), from [B] own and [L, B] prior-skill log densities."""
    count = log_q_prior.shape[0]
    return log_q_own - (jax.scipy.special.logsumexp(log_q_prior, axis=0) - math.log(count))


def unit_gaussian_log_prob(x: jax.Array, mean: jax.Array) -> jax.Array:
    """log N(x; mean, I): DADS's skill dynamics with unit variance."""
    return diagonal_gaussian_log_prob(x, mean, jnp.zeros_like(mean))


# ---- METRA: a temporal-distance-constrained representation ---------------------------------
def metra_reward(phi_obs: jax.Array, phi_next: jax.Array, skill: jax.Array) -> jax.Array:
    """(phi(s') - phi(s))^T z."""
    return ((phi_next - phi_obs) * skill).sum(axis=-1)


def metra_constraint(phi_obs: jax.Array, phi_next: jax.Array, slack: float) -> jax.Array:
    """min(slack, 1 - ||phi(s') - phi(s)||^2): negative where the temporal-distance
    constraint ||phi(s') - phi(s)|| <= 1 is violated."""
    return jnp.minimum(slack, 1.0 - ((phi_next - phi_obs) ** 2).sum(axis=-1))


def metra_phi_loss(phi_obs: jax.Array, phi_next: jax.Array, skill: jax.Array, lam: jax.Array,
                   slack: float) -> jax.Array:
    """phi's loss: -(reward + lambda * constraint), lambda held fixed."""
    objective = metra_reward(phi_obs, phi_next, skill) + jax.lax.stop_gradient(lam) * metra_constraint(
        phi_obs, phi_next, slack)
    return -objective.mean()


def metra_dual_loss(log_lam: jax.Array, constraint: jax.Array) -> jax.Array:
    """The dual variable's loss, log(lambda) * mean(constraint): descending it raises lambda
    while the constraint is violated (constraint < 0) and lowers it while it holds."""
    return log_lam * jax.lax.stop_gradient(constraint).mean()
