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
from mjx_emp.replay import episode_walk
from mjx_emp.rollout.structures import Params, Transition


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
    successor: jax.Array | None = None
    """Slot of the next stored row of the same episode (the buffer's capacity: none), in a
    replay that links episodes (see :func:`mjx_emp.replay.link_episode_rows`); else None."""
    cut: jax.Array | None = None
    """Whether a reset (a flipped Ant) ended the task during this action, ``next_obs`` being
    the last state before it, in a replay that keeps such rows (see :func:`cut_backup`); else None."""


@struct.dataclass
class Backup:
    """What a critic's target is built from: the discounted reward of the steps taken, the
    discount left after them (0 once the goal was reached) and the state to bootstrap from."""

    reward: jax.Array
    discount: jax.Array
    next_obs: jax.Array


def step_reward(goal: jax.Array, next_obs: jax.Array, env: Env, sigma: float, tilt_cost: float = 0.0) -> jax.Array:
    """A goal-conditioned step's reward: the paper's log N(goal; h(s'), sigma), less
    ``tilt_cost`` times the torso's tilt at s' (1 - z of its up axis: 0 upright, 1 on its side)
    where a level pays for tilting (an option beyond the paper, off at 0)."""
    reward = gce.goal_conditioned_reward(goal, env.goal_of_obs(next_obs), sigma)
    if tilt_cost == 0.0:
        return reward
    return reward - tilt_cost * env.torso.tilt(next_obs)


def one_step_backup(batch: GoalTransition, env: Env, sigma: float, gamma: float, tilt_cost: float = 0.0,
                    flip_cost: float = 0.0) -> Backup:
    """The paper's one-step target: r = log N(goal; h(s'), sigma) (less a tilt cost, see
    :func:`step_reward`), discount gamma until reached; rows a flip ended (:func:`flipped`)
    are scored by :func:`cut_backup` (with ``flip_cost``)."""
    reward = step_reward(batch.goal, batch.next_obs, env, sigma, tilt_cost)
    backup = Backup(reward=reward, discount=gce.goal_conditioned_discount(batch.reached, gamma),
                    next_obs=batch.next_obs)
    ended = flipped(batch.cut, batch.next_obs, env, flip_cost)
    return backup if ended is None else cut_backup(backup, ended, gamma, flip_cost)


def flipped(cut: jax.Array | None, next_obs: jax.Array, env: Env, flip_cost: float) -> jax.Array | None:
    """The rows a flip ended, for :func:`cut_backup`: those a reset cut short (a flipped Ant, in
    a replay that keeps them), and with a ``flip_cost`` also those that left the torso upside
    down (a Half Cheetah on its back, which is never reset). None: no row can be one."""
    if flip_cost == 0.0:
        return cut
    down = env.torso.upside_down(next_obs)
    return down if cut is None else cut | down


def cut_backup(backup: Backup, cut: jax.Array, gamma: float, flip_cost: float = 0.0) -> Backup:
    """``backup`` where a reset ended the task: an absorbing state with nothing left to
    bootstrap, where the robot stays where it fell and pays ``flip_cost`` every step, so the
    action is scored as (r - flip_cost) / (1 - gamma). At 0 a flip costs only the reach it
    lost."""
    return backup.replace(reward=jnp.where(cut, (backup.reward - flip_cost) / (1.0 - gamma), backup.reward),
                          discount=jnp.where(cut, 0.0, backup.discount))


def n_step_backup(rows: GoalTransition, slots: jax.Array, batch: GoalTransition, env: Env, sigma: float,
                  gamma: float, eps: float, steps: int, tilt_cost: float = 0.0, flip_cost: float = 0.0) -> Backup:
    """An n-step target for ``batch`` (the rows at ``slots`` of the stored ``rows``, goals possibly relabelled).

    Follows each row's episode for up to ``steps`` stored transitions: sum_j gamma^j r_j,
    every r_j scored against the batch row's goal (by :func:`step_reward`), stopping after the step that reaches
    it (then nothing is bootstrapped) or at the episode's last stored row, whose next
    state is bootstrapped from with discount gamma^m. The later steps' actions came from
    older policies; as in most n-step off-policy learners nothing corrects for that.
    """
    walk, exists = episode_walk(rows.successor, slots, steps)
    next_obs = rows.next_obs[walk]  # [steps, B, obs]
    achieved = env.goal_of_obs(next_obs)
    reached = jnp.linalg.norm(achieved - batch.goal, axis=-1) < eps
    reached = reached.at[0].set(batch.reached)
    step = Backup(reward=step_reward(batch.goal, next_obs, env, sigma, tilt_cost),
                  discount=gce.goal_conditioned_discount(reached, gamma), next_obs=next_obs)
    ended = flipped(None if rows.cut is None else rows.cut[walk], next_obs, env, flip_cost)
    if ended is not None:  # a flip ends the walk at its row (for a reset, the episode's last)
        step = cut_backup(step, ended, gamma, flip_cost)
    total, discount, boot = jnp.zeros_like(step.reward[0]), jnp.ones_like(step.reward[0]), batch.next_obs
    going = jnp.ones_like(exists[0])
    for j in range(steps):
        take = going & exists[j]
        total = total + jnp.where(take, discount * step.reward[j], 0.0)
        boot = jnp.where(take[:, None], next_obs[j], boot)
        discount = jnp.where(take, discount * step.discount[j], discount)
        going = take & ~reached[j]
        if ended is not None:  # nothing after a flip counts, nor is bootstrapped from
            going = going & ~ended[j]
    return Backup(reward=total, discount=discount, next_obs=boot)


def hindsight_goals(rows: GoalTransition, slots: jax.Array, batch: GoalTransition, key: jax.Array,
                    fraction: float, env: Env, eps: float, horizon: int) -> GoalTransition:
    """``batch`` with a ``fraction`` of its rows given a goal their own episode achieved later.

    HER's "future" strategy (Andrychowicz et al. 2017): row t's new goal is h(s_{t'+1})
    for t' drawn uniformly from t and the episode's later stored rows (at most ``horizon``,
    the level's actions per episode), so misses become reached goals at every distance
    the episode covered; ``reached`` is recomputed against the new goal.
    """
    walk, exists = episode_walk(rows.successor, slots, horizon)
    pick_key, which_key = jax.random.split(key)
    count = exists.sum(axis=0)  # the walk's rows exist as a prefix
    step = jnp.minimum(jnp.floor(jax.random.uniform(pick_key, count.shape) * count).astype(jnp.int32), count - 1)
    chosen = walk[step, jnp.arange(slots.shape[0])]
    future = env.goal_of_obs(rows.next_obs[chosen])
    swap = jax.random.uniform(which_key, count.shape) < fraction
    reached = jnp.linalg.norm(env.goal_of_obs(batch.next_obs) - future, axis=-1) < eps
    return batch.replace(goal=jnp.where(swap[:, None], future, batch.goal),
                         reached=jnp.where(swap, reached, batch.reached))


def reward_cap(goal_size: int, sigma: float, gamma: float) -> float:
    """Largest value any return can have: every step at the reward's peak, never ending.

    The reward log N(goal; h(s'), sigma) peaks at h(s') = goal. Bootstrapped targets are
    capped here, which stops the critic's overestimation from feeding on itself.
    """
    peak = -goal_size * (math.log(sigma) + 0.5 * gce.LOG_2PI)
    return max(peak, peak / (1.0 - gamma))


def ddpg_losses(policy, q_value, learner: DDPGLearner, batch: GoalTransition, env: Env, sigma: float, gamma: float,
                backup: Backup | None = None, flip_cost: float = 0.0):
    """(critic loss, actor loss) functions of one goal-conditioned DDPG minibatch.

    ``policy(actor, obs, goal)`` is the deterministic policy over a batch and
    ``q_value(critic, obs, goal, action)`` the critic: [B] values, or [critics, B] for a
    clipped double-Q ensemble, whose targets bootstrap from the smallest. The reward is
    the paper's log N(goal; h(s'), sigma); the discount drops to 0 once the goal is
    reached, and bootstrapped values are capped at :func:`reward_cap`. ``backup`` replaces
    the one-step target (an n-step one, say); rows a reset cut short, where the replay keeps
    them, are scored by :func:`cut_backup` with ``flip_cost``. Every goal-conditioned level of
    phase 1, and phase 2's added level, learn with these losses.
    """
    backup = one_step_backup(batch, env, sigma, gamma, flip_cost=flip_cost) if backup is None else backup
    next_action = policy(learner.target_actor, backup.next_obs, batch.goal)
    next_q = q_value(learner.target_critic, backup.next_obs, batch.goal, next_action)
    if next_q.ndim > backup.reward.ndim:
        next_q = next_q.min(axis=0)
    cap = reward_cap(env.goal_size, sigma, gamma)
    target = jax.lax.stop_gradient(backup.reward + backup.discount * jnp.minimum(next_q, cap))

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


def goal_transitions(t: Transition, successor: jax.Array | None = None, keep_cut: bool = False) -> GoalTransition:
    """The stored form of a level's transitions (reward and discount are derived on sampling);
    ``successor`` gives rows episode links and ``keep_cut`` their reset flags, for a replay
    that keeps the rows a reset ended (see :class:`GoalTransition`)."""
    return GoalTransition(obs=t.obs, goal=t.goal, action=t.action, next_obs=t.next_obs, reached=t.reached,
                          successor=successor, cut=t.cut if keep_cut else None)


def stored_rows(t: Transition, keep_cut: bool) -> jax.Array:
    """Which of a level's transitions a replay stores: the valid ones, and with ``keep_cut``
    also those a reset ended."""
    return t.valid | t.cut if keep_cut else t.valid
