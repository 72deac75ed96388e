"""The goal-space learner: a critic R(s0, noise, a) of the empowerment reward and an actor
mu(s0) trained through it by the reparameterised (SVG) gradient."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct

from mjx_emp.rollout.structures import Params


@struct.dataclass
class GoalSpaceLearner:
    """A level's goal-space actor mu(s0) and critic R(s0, noise, a) with Adam states."""

    actor: Params
    critic: Params
    actor_opt: optax.OptState
    critic_opt: optax.OptState


@struct.dataclass
class GoalSpaceSample:
    """One stored goal-space sample (s0, noise, a, r)."""

    obs: jax.Array
    noise: jax.Array
    action: jax.Array
    reward: jax.Array


def svg_losses(value: Callable, action: Callable, batch: GoalSpaceSample, noise: jax.Array):
    """(critic loss, actor loss) functions of one goal-space minibatch (SVG through R).

    ``value(critic, obs, noise, action)`` is the critic R and ``action(actor, obs)`` the
    goal-space actor mu(s0) for one observation. The critic regresses the stored rewards;
    the actor averages R over fresh uniform ``noise``: the stored noise over-represents
    goals that end their episodes early (they are collected more often per step).
    """

    def critic_loss(critic):
        return jnp.mean(jnp.square(value(critic, batch.obs, batch.noise, batch.action) - batch.reward))

    def actor_loss(actor, critic):
        actions = jax.vmap(lambda o: action(actor, o))(batch.obs)
        return -jnp.mean(value(critic, batch.obs, noise, actions))

    return critic_loss, actor_loss
