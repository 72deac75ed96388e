"""Goal-conditioned DDPG: the learner of every goal-conditioned level (phase 1) and of phase 2.

The reward is the paper's log N(goal; h(s'), sigma); the discount drops to 0 once the
goal is reached; bootstrapped values are capped at :func:`reward_cap`.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import optax
from flax import struct

from mjx_emp import gce
from mjx_emp.envs.env import Env
from mjx_emp.learners.common import actor_critic_step
from mjx_emp.rollout.hierarchy import Params, Transition


@struct.dataclass
class DDPGLearner:
    """A level's goal-conditioned actor-critic with target networks and Adam states."""

    actor: Params
    critic: Params
    target_actor: Params
    target_critic: Params
    actor_opt: optax.OptState
    critic_opt: optax.OptState


@struct.dataclass
class GoalTransition:
    """One stored goal-conditioned transition; reward and discount are derived on sampling."""

    obs: jax.Array
    goal: jax.Array
    action: jax.Array
    next_obs: jax.Array
    reached: jax.Array


def reward_cap(goal_size: int, sigma: float, gamma: float) -> float:
    """Largest value any return can have: every step at the reward's peak, never ending.

    The reward log N(goal; h(s'), sigma) peaks at h(s') = goal. Bootstrapped targets are
    capped here, which stops the critic's overestimation from feeding on itself.
    """
    peak = -goal_size * (math.log(sigma) + 0.5 * gce.LOG_2PI)
    return max(peak, peak / (1.0 - gamma))


def ddpg_losses(policy, q_value, learner: DDPGLearner, batch: GoalTransition, env: Env, sigma: float, gamma: float):
    """(critic loss, actor loss) functions of one goal-conditioned DDPG minibatch.

    ``policy(actor, obs, goal)`` is the deterministic policy over a batch and
    ``q_value(critic, obs, goal, action)`` the critic: [B] values, or [critics, B] for a
    clipped double-Q ensemble, whose targets bootstrap from the smallest. The reward is
    the paper's log N(goal; h(s'), sigma); the discount drops to 0 once the goal is
    reached, and bootstrapped values are capped at :func:`reward_cap`. Every
    goal-conditioned level of phase 1, and phase 2's added level, learn with these losses.
    """
    reward = gce.goal_conditioned_reward(batch.goal, env.goal_of_obs(batch.next_obs), sigma)
    discount = gce.goal_conditioned_discount(batch.reached, gamma)
    next_action = policy(learner.target_actor, batch.next_obs, batch.goal)
    next_q = q_value(learner.target_critic, batch.next_obs, batch.goal, next_action)
    if next_q.ndim > reward.ndim:
        next_q = next_q.min(axis=0)
    cap = reward_cap(env.goal_size, sigma, gamma)
    target = jax.lax.stop_gradient(reward + discount * jnp.minimum(next_q, cap))

    def critic_loss(critic):
        q = q_value(critic, batch.obs, batch.goal, batch.action)
        return jnp.mean(jnp.square(q - target))

    def actor_loss(actor, critic):
        action = policy(actor, batch.obs, batch.goal)
        return -jnp.mean(q_value(critic, batch.obs, batch.goal, action))

    return critic_loss, actor_loss


def ddpg_step(learner: DDPGLearner, losses, actor_tx, critic_tx, tau: float) -> tuple[DDPGLearner, jax.Array]:
    """One DDPG step of a goal-conditioned learner (critic, actor, Polyak targets); returns its losses."""
    actor, critic, actor_opt, critic_opt, values = actor_critic_step(
        *losses, learner.actor, learner.critic, learner.actor_opt, learner.critic_opt, actor_tx, critic_tx,
    )
    learner = DDPGLearner(
        actor=actor, critic=critic,
        target_actor=optax.incremental_update(actor, learner.target_actor, tau),
        target_critic=optax.incremental_update(critic, learner.target_critic, tau),
        actor_opt=actor_opt, critic_opt=critic_opt,
    )
    return learner, values


def relabel_goals(batch: GoalTransition, key: jax.Array, fraction: float, env: Env, eps: float) -> GoalTransition:
    """``batch`` with a ``fraction`` of its rows given another row's goal offset.

    Row i keeps its (s, a, s') and gets the goal h(s_i) + (goal_j - h(s_j)) for a random j,
    so the critic sees every transition's outcome scored against many goal directions
    and distances of the kind the level is asked for; ``reached`` is recomputed against
    the new goal (within ``eps`` of h(s')).
    """
    pick_key, which_key = jax.random.split(key)
    rows = batch.goal.shape[0]
    offsets = batch.goal - env.goal_of_obs(batch.obs)
    donor = jax.random.randint(pick_key, (rows,), 0, rows)
    swap = jax.random.uniform(which_key, (rows,)) < fraction
    goal = jnp.where(swap[:, None], env.goal_of_obs(batch.obs) + offsets[donor], batch.goal)
    reached = jnp.linalg.norm(env.goal_of_obs(batch.next_obs) - goal, axis=-1) < eps
    return batch.replace(goal=goal, reached=jnp.where(swap, reached, batch.reached))


def goal_transitions(t: Transition) -> GoalTransition:
    """The stored form of a level's transitions (reward and discount are derived on sampling)."""
    return GoalTransition(obs=t.obs, goal=t.goal, action=t.action, next_obs=t.next_obs, reached=t.reached)
