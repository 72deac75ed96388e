"""How phase 1 learns: per level, the goal-conditioned DDPG update (losses, backups, hindsight
goals) and the goal-space SVG update, as branches of the epoch's switch."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from mjx_emp import gce
from mjx_emp.learners.common import actor_critic_step
from mjx_emp.learners.ddpg import (
    Backup,
    DDPGLearner,
    GoalTransition,
    ddpg_losses,
    ddpg_step,
    hindsight_goals,
    n_step_backup,
    one_step_backup,
    relabel_goals,
)
from mjx_emp.learners.goal_space import GoalSpaceLearner, GoalSpaceSample, svg_losses
from mjx_emp.nets import (
    greedy_batch,
)
from mjx_emp.replay import (
    replay_sample,
    sample_slots,
)
from mjx_emp.rollout.structures import Params


class HELearning:
    """The update methods of :class:`~mjx_emp.algos.he.agent.HEAgent` (``self`` is the agent)."""

    def gc_losses(self, level: int, learner: DDPGLearner, box: Params, batch: GoalTransition,
                  backup: Backup | None = None):
        """(critic loss, actor loss) functions of one goal-conditioned minibatch (DDPG);
        ``backup`` replaces the one-step target."""
        cfg = self.cfg
        policy = self.hierarchy.policies[level]
        return ddpg_losses(
            lambda actor, obs, goal: greedy_batch(policy, actor, box)(obs, goal),
            self.nets.q_value, learner, batch, self.env, cfg.sigma_gc[level], cfg.gamma, backup,
        )

    def gc_backup(self, level: int, rows: GoalTransition, slots: jax.Array, batch: GoalTransition) -> Backup:
        """The critic target of a minibatch ``batch`` (the stored ``rows`` at ``slots``, goals possibly
        relabelled) at ``level``: one-step or ``n_step``, with ``tilt_cost`` at level 0, the level
        whose actions move the joints."""
        cfg = self.cfg
        tilt_cost = cfg.tilt_cost if level == 0 else 0.0
        if cfg.n_step > 1:
            return n_step_backup(rows, slots, batch, self.env, cfg.sigma_gc[level], cfg.gamma, cfg.eps[level],
                                 cfg.n_step, tilt_cost, cfg.flip_cost)
        return one_step_backup(batch, self.env, cfg.sigma_gc[level], cfg.gamma, tilt_cost, cfg.flip_cost)

    def gc_update(self, level: int):
        cfg, opt = self.cfg, self.optimizers

        def update(learners, replay, goal_space_replay, key):
            del goal_space_replay
            policies, goal_spaces = learners
            box = None if level == 0 else goal_spaces[level - 1].actor

            def step(learner: DDPGLearner, step_key):
                if cfg.her > 0:
                    sample_key, her_key, relabel_key = jax.random.split(step_key, 3)
                else:  # the keys of runs from before hindsight goals existed, so they replay bit for bit
                    sample_key, relabel_key = jax.random.split(step_key)
                rows = replay[level].data
                slots = sample_slots(replay[level], sample_key, cfg.batch_size)
                batch = jax.tree.map(lambda x: x[slots], rows)
                if cfg.her > 0:
                    batch = hindsight_goals(rows, slots, batch, her_key, cfg.her, self.env, cfg.eps[level], cfg.n[level])
                if cfg.relabel > 0:
                    batch = relabel_goals(batch, relabel_key, cfg.relabel, self.env, cfg.eps[level])
                losses = self.gc_losses(level, learner, box, batch, self.gc_backup(level, rows, slots, batch))
                return ddpg_step(learner, losses, opt["actor"], opt["critic"], cfg.tau)

            learner, losses = jax.lax.scan(step, policies[level], jax.random.split(key, cfg.gc_grad_steps))
            policies = policies[:level] + (learner,) + policies[level + 1 :]
            return (policies, goal_spaces), losses.mean(axis=0)

        return update

    def gs_losses(self, level: int, batch: GoalSpaceSample, noise: jax.Array):
        """(critic loss, actor loss) functions of one goal-space minibatch at ``level`` (SVG)."""
        return svg_losses(self.nets.gs_value, functools.partial(self.nets.goal_space_action, level), batch, noise)

    def gs_update(self, level: int):
        cfg, opt = self.cfg, self.optimizers

        def update(learners, replay, goal_space_replay, key):
            del replay
            policies, goal_spaces = learners

            def step(learner: GoalSpaceLearner, step_key):
                sample_key, noise_key = jax.random.split(step_key)
                batch = replay_sample(goal_space_replay[level], sample_key, cfg.batch_size)
                noise = gce.goal_noise(noise_key, batch.noise.shape)
                losses_fns = self.gs_losses(level, batch, noise)
                actor, critic, actor_opt, critic_opt, losses = actor_critic_step(
                    *losses_fns, learner.actor, learner.critic, learner.actor_opt, learner.critic_opt,
                    opt["gs_actor"], opt["gs_critic"],
                )
                return GoalSpaceLearner(actor, critic, actor_opt, critic_opt), losses

            learner, losses = jax.lax.scan(step, goal_spaces[level], jax.random.split(key, cfg.gs_grad_steps))
            goal_spaces = goal_spaces[:level] + (learner,) + goal_spaces[level + 1 :]
            return (policies, goal_spaces), losses.mean(axis=0)

        return update

    def _no_update(self, learners, replay, goal_space_replay, key):
        del replay, goal_space_replay, key
        return learners, jnp.full(2, jnp.nan)
