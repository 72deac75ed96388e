"""The agent of the flat skill learners: DIAYN, HIDIO, DADS and METRA share all but their objective.

An epoch is ``iterations`` rounds of: every environment takes ``collect_steps`` steps
with the stochastic SAC policy (skills held for ``n`` actions, episodes from the initial
state), the valid transitions go to one replay ring, then ``grad_steps`` times: a
minibatch trains the method's model (:mod:`mjx_emp.algos.skills.objectives`), the updated
model rewards the minibatch, and SAC takes a step on that reward. The discount is never
cut: an episode ends on a time limit, not a terminal state (METRA's ``turn_off_dones``).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mjx_emp.algos.skills.config import (
    SkillConfig,
)
from mjx_emp.algos.skills.evaluation import SkillEvaluation
from mjx_emp.algos.skills.methods import METHODS, ModelContext, ModelInfo, SkillMethod
from mjx_emp.algos.skills.policies import SkillPolicies
from mjx_emp.algos.skills.state import (
    SKILL_EPOCH_TRACE,
    IterationStats,
    SkillModel,
    SkillState,
    SkillTransition,
)
from mjx_emp.checks import compile_identity
from mjx_emp.counters import StepCounter
from mjx_emp.envs.env import Env, make_env
from mjx_emp.learners.sac import SACBatch, SACInfo, SACLearner
from mjx_emp.replay import (
    ReplayBuffer,
    flatten_rows,
    replay_init,
    replay_insert,
    replay_sample,
)
from mjx_emp.rollout.flat import flat_init, flat_rollout
from mjx_emp.shards import ShardAxes, mean_gradients, shard_all, shard_mean, shard_sum
from mjx_emp.tracing import count_trace


@dataclasses.dataclass(frozen=True)
class SkillAgent(SkillPolicies, SkillEvaluation):
    """Static side of one flat skill learner's config; hashes by the config without its epoch
    count (a jit argument, :func:`~mjx_emp.checks.compile_identity`)."""

    cfg: SkillConfig = dataclasses.field(compare=False)
    shard_axes: ShardAxes = ()
    """The mapped axes this agent's shards run along when a split run trains (see
    :mod:`mjx_emp.shards`); empty for an agent on its own."""
    identity: SkillConfig = dataclasses.field(init=False, repr=False)
    """What it compares and hashes by: ``cfg`` without its epoch count."""
    env: Env = dataclasses.field(init=False, compare=False, repr=False)

    def __post_init__(self):
        if type(self.cfg) not in METHODS:
            raise TypeError(f"cfg: a {type(self.cfg).__name__}; expected one of {[c.__name__ for c in METHODS]}")
        object.__setattr__(self, "identity", compile_identity(self.cfg))
        object.__setattr__(self, "env", make_env(self.cfg.env, solver_iterations=self.cfg.solver_iterations,
                                                   integrator=self.cfg.integrator, impl=self.cfg.impl))

    @property
    def skill_method(self) -> SkillMethod:
        """What this learner's objective does (DIAYN, HIDIO, DADS or METRA)."""
        return METHODS[type(self.cfg)]

    @property
    def method(self) -> str:
        """The learner's name, for reports."""
        return self.skill_method.name

    # ---- state ----------------------------------------------------------------------
    @functools.cached_property
    def initial_obs(self) -> np.ndarray:
        """Observation of the task's initial state (a constant under jit), computed once."""
        return self.env.initial_obs()

    def example_transition(self) -> SkillTransition:
        obs = jnp.asarray(self.initial_obs)
        return SkillTransition(s0=obs, obs=obs, skill=jnp.zeros(self.cfg.skill_dim),
                               action=jnp.zeros(self.env.action_size), next_obs=obs)

    def init(self, key: jax.Array | None = None) -> SkillState:
        """Fresh networks, an empty replay, every environment at the start of an episode."""
        return _jit_init(self, jax.random.key(self.cfg.seed) if key is None else key)

    def _init(self, key: jax.Array) -> SkillState:
        cfg = self.cfg
        sac_key, model_key, rollout_key, key = jax.random.split(key, 4)
        example = self.example_transition()
        sac = self.sac.init(sac_key, self.policy_input(example.obs, example.s0, example.skill))
        params = self.model_net.init(model_key, self.model_input(example))
        log_lam = jnp.log(jnp.asarray(self.skill_method.initial_dual(cfg), jnp.float32))
        model = SkillModel(params=params, opt=self.model_tx.init(params), log_lam=log_lam,
                           lam_opt=self.model_tx.init(log_lam))
        return SkillState(
            sac=sac, model=model, replay=replay_init(example, cfg.replay_capacity),
            rollout=flat_init(self.env, self.start, None, rollout_key, cfg.num_envs),
            key=key, epoch=jnp.zeros((), jnp.int32), env_steps=StepCounter.zero(),
        )

    @property
    def model_tx(self) -> optax.GradientTransformation:
        return mean_gradients(optax.adam(self.cfg.model_lr), self.shard_axes)

    # ---- the objectives -------------------------------------------------------------
    def model_step(self, model: SkillModel, batch: SkillTransition, key: jax.Array):
        """Train the method's model on ``batch``, then reward ``batch`` with the new model:
        (model, reward [B], :class:`~mjx_emp.algos.skills.methods.ModelInfo`)."""
        context = ModelContext(self.env, self.cfg, self.model_net, self.model_tx, self.sample_skill)
        return self.skill_method.model_step(context, model, batch, key)

    def learn_step(self, carry: tuple[SACLearner, SkillModel], replay: ReplayBuffer, key: jax.Array):
        """One gradient step: the model, then SAC on the model's reward."""
        sac, model = carry
        sample_key, model_key, sac_key = jax.random.split(key, 3)
        batch = replay_sample(replay, sample_key, self.cfg.batch_size)
        model, reward, model_info = self.model_step(model, batch, model_key)
        sac_batch = SACBatch(
            x=self.policy_input(batch.obs, batch.s0, batch.skill), action=batch.action,
            reward=jax.lax.stop_gradient(reward),
            next_x=self.policy_input(batch.next_obs, batch.s0, batch.skill),
            discount=jnp.full(reward.shape, self.cfg.gamma),
        )
        sac, sac_info = self.sac.step(sac, sac_batch, sac_key)
        return (sac, model), (sac_info, model_info, reward.mean())

    # ---- the epoch ------------------------------------------------------------------
    def _iteration(self, state: SkillState, _) -> tuple[SkillState, IterationStats]:
        cfg, env = self.cfg, self.env
        key, learn_key = jax.random.split(state.key)
        flips_before = state.rollout.env.flip_resets.sum()
        rollout, steps = flat_rollout(env, self.explore, state.sac.actor, self.start, None,
                                      state.rollout, cfg.collect_steps, cfg.n)
        rows = flatten_rows(SkillTransition(s0=steps.s0, obs=steps.obs, skill=steps.skill, action=steps.action,
                                            next_obs=steps.next_obs))
        replay = replay_insert(state.replay, rows, steps.valid.reshape(-1))
        ended = steps.last & steps.valid
        moved = jnp.linalg.norm(env.goal_of_obs(steps.next_obs) - env.goal_of_obs(steps.s0), axis=-1)

        def learn(carry):
            carry, (sac_info, model_info, reward) = jax.lax.scan(
                lambda c, k: self.learn_step(c, replay, k), carry, jax.random.split(learn_key, cfg.grad_steps))
            return carry, *jax.tree.map(lambda x: x.mean(0), (sac_info, model_info)), reward.mean()

        def wait(carry):
            return carry, SACInfo.nan(), ModelInfo.nan(), jnp.float32(jnp.nan)

        axes = self.shard_axes
        learned = shard_all(replay.size >= cfg.min_replay, axes)  # every shard learns from the same iteration on
        (sac, model), sac_info, model_info, reward = jax.lax.cond(learned, learn, wait, (state.sac, state.model))
        sac_info, model_info, reward = shard_mean((sac_info, model_info, reward), axes)
        env_steps, episodes, moved_sum, flips = shard_sum(
            (jnp.int32(cfg.collect_steps * cfg.num_envs), ended.sum(), jnp.where(ended, moved, 0.0).sum(),
             rollout.env.flip_resets.sum() - flips_before), axes)
        stats = IterationStats(
            env_steps=env_steps, learned=learned, sac=sac_info, model_loss=model_info.loss, reward=reward,
            posterior_std=model_info.posterior_std, dual_lambda=model_info.dual_lambda,
            constraint=model_info.constraint,
            episodes=episodes, displacement=moved_sum / jnp.maximum(episodes, 1), flip_resets=flips,
        )
        state = state.replace(sac=sac, model=model, replay=replay, rollout=rollout, key=key,
                              env_steps=state.env_steps.add(env_steps))
        return state, stats

    def _train_epoch(self, state: SkillState) -> tuple[SkillState, IterationStats]:
        count_trace(SKILL_EPOCH_TRACE)
        state, stats = jax.lax.scan(self._iteration, state, None, length=self.cfg.iterations)
        return state.replace(epoch=state.epoch + 1), stats

    def train_epoch(self, state: SkillState) -> tuple[SkillState, IterationStats]:
        """One epoch as one jitted call; returns per-iteration stats."""
        return _jit_train_epoch(self, state)


_jit_init = jax.jit(SkillAgent._init, static_argnums=0)
_jit_train_epoch = jax.jit(SkillAgent._train_epoch, static_argnums=0, donate_argnums=1)
