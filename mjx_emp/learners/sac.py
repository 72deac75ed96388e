"""Soft Actor-Critic (Haarnoja et al. 2018) for skill-conditioned policies.

A tanh-squashed Gaussian actor, two critics with Polyak-averaged targets and clipped
double-Q targets, and a learned temperature alpha driven towards a target entropy. The
flat skill learners (DIAYN, HIDIO, DADS, METRA) train their policies with it, each on
its own intrinsic reward; what a network sees (``x``: state features and skill) is the
caller's business.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from mjx_emp.nets import MLP
from mjx_emp.shards import mean_gradients

Params = Any
LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0
"""Range of the actor's log standard deviation (METRA's policy caps its std at e^2)."""


class GaussianActor(nn.Module):
    """MLP giving the mean and log std (clipped to [LOG_STD_MIN, LOG_STD_MAX]) of a Gaussian
    that is squashed by tanh into the [-1, 1] action box."""

    hidden: Sequence[int]
    action_size: int

    @nn.compact
    def __call__(self, x: jax.Array) -> tuple[jax.Array, jax.Array]:
        out = MLP(tuple(self.hidden), 2 * self.action_size)(x)
        mean, log_std = jnp.split(out, 2, axis=-1)
        return mean, jnp.clip(log_std, LOG_STD_MIN, LOG_STD_MAX)


def squashed_sample(mean: jax.Array, log_std: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """a = tanh(mean + std * noise) and its log density (tanh change of variables, summed
    over the last axis)."""
    noise = jax.random.normal(key, mean.shape)
    pre = mean + jnp.exp(log_std) * noise
    gaussian = -0.5 * noise**2 - log_std - 0.5 * jnp.log(2.0 * jnp.pi)
    # log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)), stable for large |u|
    jacobian = 2.0 * (jnp.log(2.0) - pre - jax.nn.softplus(-2.0 * pre))
    return jnp.tanh(pre), (gaussian - jacobian).sum(axis=-1)


@struct.dataclass
class SACInfo:
    """What one SAC step reports: its three losses, the temperature and the policy's entropy."""

    critic_loss: jax.Array
    actor_loss: jax.Array
    alpha_loss: jax.Array
    alpha: jax.Array
    entropy: jax.Array

    @classmethod
    def nan(cls) -> SACInfo:
        """The report of an iteration that took no step (every field NaN)."""
        return cls(*(jnp.float32(jnp.nan) for _ in range(5)))


@struct.dataclass
class SACLearner:
    """Actor, the two critics ([2, ...] stacked) and their targets, log alpha, Adam states."""

    actor: Params
    critics: Params
    target_critics: Params
    log_alpha: jax.Array
    actor_opt: optax.OptState
    critic_opt: optax.OptState
    alpha_opt: optax.OptState


@struct.dataclass
class SACBatch:
    """A minibatch as the networks see it: inputs x and x' (features with the skill), the
    action taken, its reward, and the discount (gamma, or 0 after a terminal step)."""

    x: jax.Array
    action: jax.Array
    reward: jax.Array
    next_x: jax.Array
    discount: jax.Array


@dataclasses.dataclass(frozen=True)
class SAC:
    """The static side of a SAC learner: network sizes, rates, discount, Polyak rate and
    target entropy (a hashable jit argument)."""

    hidden: tuple[int, ...]
    action_size: int
    actor_lr: float = 1e-4
    critic_lr: float = 1e-4
    alpha_lr: float = 1e-4
    init_alpha: float = 0.01
    tau: float = 5e-3
    target_entropy: float = -1.0
    shard_axes: tuple[str, ...] = ()
    """Axes over which a split run's shards average their gradients (see :mod:`mjx_emp.shards`)."""

    @property
    def actor_net(self) -> GaussianActor:
        return GaussianActor(self.hidden, self.action_size)

    @property
    def critic_net(self) -> MLP:
        return MLP(self.hidden, 1)

    @property
    def optimizers(self) -> tuple[optax.GradientTransformation, ...]:
        return tuple(mean_gradients(optax.adam(rate), self.shard_axes)
                     for rate in (self.actor_lr, self.critic_lr, self.alpha_lr))

    def init(self, key: jax.Array, x: jax.Array) -> SACLearner:
        """Fresh networks for inputs shaped like ``x`` (one row), alpha at ``init_alpha``."""
        actor_key, critic_key = jax.random.split(key)
        actor = self.actor_net.init(actor_key, x)
        critic_input = jnp.concatenate([x, jnp.zeros(self.action_size, x.dtype)])
        critics = jax.vmap(lambda k: self.critic_net.init(k, critic_input))(jax.random.split(critic_key, 2))
        log_alpha = jnp.log(jnp.asarray(self.init_alpha, jnp.float32))
        actor_tx, critic_tx, alpha_tx = self.optimizers
        return SACLearner(actor=actor, critics=critics, target_critics=critics, log_alpha=log_alpha,
                          actor_opt=actor_tx.init(actor), critic_opt=critic_tx.init(critics),
                          alpha_opt=alpha_tx.init(log_alpha))

    def sample(self, actor: Params, x: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """A stochastic action for input ``x`` and its log density."""
        mean, log_std = self.actor_net.apply(actor, x)
        return squashed_sample(mean, log_std, key)

    def greedy(self, actor: Params, x: jax.Array) -> jax.Array:
        """The deterministic action tanh(mean), for evaluation."""
        return jnp.tanh(self.actor_net.apply(actor, x)[0])

    def q_values(self, critics: Params, x: jax.Array, action: jax.Array) -> jax.Array:
        """[2, B] values of both critics."""
        inputs = jnp.concatenate([x, action], axis=-1)
        return jax.vmap(lambda p: self.critic_net.apply(p, inputs)[..., 0])(critics)

    def step(self, learner: SACLearner, batch: SACBatch, key: jax.Array) -> tuple[SACLearner, SACInfo]:
        """One critic, actor and temperature step, then the target update; returns the learner
        and what the step reports."""
        actor_tx, critic_tx, alpha_tx = self.optimizers
        next_key, actor_key = jax.random.split(key)
        alpha = jnp.exp(learner.log_alpha)

        next_action, next_log_prob = self.sample(learner.actor, batch.next_x, next_key)
        next_q = self.q_values(learner.target_critics, batch.next_x, next_action).min(axis=0)
        target = jax.lax.stop_gradient(batch.reward + batch.discount * (next_q - alpha * next_log_prob))

        def critic_loss(critics):
            return ((self.q_values(critics, batch.x, batch.action) - target[None]) ** 2).mean()

        c_loss, c_grad = jax.value_and_grad(critic_loss)(learner.critics)
        c_updates, critic_opt = critic_tx.update(c_grad, learner.critic_opt, learner.critics)
        critics = optax.apply_updates(learner.critics, c_updates)

        def actor_loss(actor):
            action, log_prob = self.sample(actor, batch.x, actor_key)
            q = self.q_values(critics, batch.x, action).min(axis=0)
            return (alpha * log_prob - q).mean(), log_prob

        (a_loss, log_prob), a_grad = jax.value_and_grad(actor_loss, has_aux=True)(learner.actor)
        a_updates, actor_opt = actor_tx.update(a_grad, learner.actor_opt, learner.actor)
        actor = optax.apply_updates(learner.actor, a_updates)

        entropy = -jax.lax.stop_gradient(log_prob).mean()

        def alpha_loss(log_alpha):
            return log_alpha * (entropy - self.target_entropy)

        t_loss, t_grad = jax.value_and_grad(alpha_loss)(learner.log_alpha)
        t_updates, alpha_opt = alpha_tx.update(t_grad, learner.alpha_opt, learner.log_alpha)
        log_alpha = optax.apply_updates(learner.log_alpha, t_updates)

        target_critics = optax.incremental_update(critics, learner.target_critics, self.tau)
        learner = SACLearner(actor=actor, critics=critics, target_critics=target_critics, log_alpha=log_alpha,
                             actor_opt=actor_opt, critic_opt=critic_opt, alpha_opt=alpha_opt)
        return learner, SACInfo(critic_loss=c_loss, actor_loss=a_loss, alpha_loss=t_loss, alpha=jnp.exp(log_alpha),
                                entropy=entropy)
