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
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from mjx_emp.algos.skills import objectives as obj
from mjx_emp.algos.skills.config import (
    SkillConfig,
)
from mjx_emp.algos.skills.methods import METHODS, ModelContext, ModelInfo, SkillMethod
from mjx_emp.checks import compile_identity
from mjx_emp.counters import StepCounter
from mjx_emp.envs.env import Env, EnvState, make_env
from mjx_emp.learners.common import all_finite
from mjx_emp.learners.sac import SAC, SACBatch, SACInfo, SACLearner
from mjx_emp.metrics import epoch_header
from mjx_emp.replay import (
    ReplayBuffer,
    flatten_rows,
    replay_init,
    replay_insert,
    replay_sample,
)
from mjx_emp.rollout.flat import FlatState, flat_init, flat_rollout
from mjx_emp.shards import ShardAxes, mean_gradients, shard_all, shard_mean, shard_sum
from mjx_emp.tracing import count_trace

SKILL_EPOCH_TRACE = "skills.train_epoch"
"""Name under which :mod:`mjx_emp.tracing` counts traces (compiles) of a flat learner's epoch."""
Params = Any


@struct.dataclass
class SkillTransition:
    """One stored step: where its episode began, the step itself, and the skill it served."""

    s0: jax.Array
    obs: jax.Array
    skill: jax.Array
    action: jax.Array
    next_obs: jax.Array


@struct.dataclass
class SkillModel:
    """The method's own model and its Adam state; ``log_lam`` and ``lam_opt`` are METRA's
    dual variable (kept, unused, by the others so that every method has one state shape)."""

    params: Params
    opt: optax.OptState
    log_lam: jax.Array
    lam_opt: optax.OptState


@struct.dataclass
class SkillState:
    """Everything a flat skill learner carries between epochs."""

    sac: SACLearner
    model: SkillModel
    replay: ReplayBuffer
    rollout: FlatState
    key: jax.Array
    epoch: jax.Array
    env_steps: StepCounter


@struct.dataclass
class IterationStats:
    """Per iteration of an epoch (stacked [iterations]); NaN where nothing was learnt or ended."""

    env_steps: jax.Array
    learned: jax.Array
    sac: SACInfo
    model_loss: jax.Array
    reward: jax.Array
    posterior_std: jax.Array
    dual_lambda: jax.Array
    constraint: jax.Array
    episodes: jax.Array
    displacement: jax.Array
    flip_resets: jax.Array




@dataclasses.dataclass(frozen=True)
class SkillAgent:
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

    # ---- networks -------------------------------------------------------------------
    @functools.cached_property
    def sac(self) -> SAC:
        c = self.cfg
        return SAC(hidden=tuple(c.hidden), action_size=self.env.action_size, actor_lr=c.actor_lr,
                   critic_lr=c.critic_lr, alpha_lr=c.alpha_lr, init_alpha=c.init_alpha, tau=c.tau,
                   target_entropy=-c.target_entropy_scale * self.env.action_size, shard_axes=self.shard_axes)

    @property
    def descriptor_size(self) -> int:
        return self.env.feature_size + self.env.goal_size

    @functools.cached_property
    def model_net(self):
        """DIAYN/HIDIO: posterior q(z|...); DADS: mean of the descriptor's change; METRA: phi."""
        return self.skill_method.model_net(tuple(self.cfg.hidden), self.cfg.skill_dim, self.descriptor_size)

    def model_input(self, batch: SkillTransition) -> jax.Array:
        """What the model sees of a minibatch (at the state it judges)."""
        return self.skill_method.model_input(self.env, batch)

    def policy_input(self, obs: jax.Array, s0: jax.Array, skill: jax.Array) -> jax.Array:
        """pi's and Q's input: the state's descriptor and the skill."""
        return jnp.concatenate([obj.descriptor(self.env, obs, s0), skill], axis=-1)

    def sample_skill(self, key: jax.Array, shape: tuple[int, ...] = ()) -> jax.Array:
        """z from the prior: uniform on [-1, 1]^d, or for METRA a direction on the unit sphere."""
        return self.skill_method.sample_skill(key, shape, self.cfg.skill_dim)

    def start(self, _: Any, key: jax.Array) -> tuple[EnvState, jax.Array]:
        """A new episode: the initial state and a skill from the prior."""
        env_key, skill_key = jax.random.split(key)
        return self.env.reset(env_key), self.sample_skill(skill_key)

    def explore(self, actor: Params, obs, s0, skill, key) -> jax.Array:
        """The stochastic SAC policy (training collection)."""
        return self.sac.sample(actor, self.policy_input(obs, s0, skill), key)[0]

    def greedy(self, actor: Params, obs, s0, skill, key) -> jax.Array:
        """The deterministic policy tanh(mean) (evaluation)."""
        del key
        return self.sac.greedy(actor, self.policy_input(obs, s0, skill))

    def greedy_policy(self, state: SkillState) -> Callable[[jax.Array, jax.Array, jax.Array], jax.Array]:
        """The greedy skill-conditioned policy, (obs [B, obs], s0 [B, obs], skill [B, d]) -> action:
        ``s0`` is the observation where the skill began (its descriptor counts from there)."""
        actor = state.sac.actor
        return jax.vmap(lambda obs, s0, skill: self.greedy(actor, obs, s0, skill, None))

    # ---- state ----------------------------------------------------------------------
    @functools.cached_property
    def initial_obs(self) -> np.ndarray:
        """Observation of the initial state (a constant under jit)."""
        with jax.ensure_compile_time_eval():
            return np.asarray(self.env.observe(self.env.reset(jax.random.key(0))))

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
        log_lam = jnp.log(jnp.asarray(getattr(cfg, "dual_lam", 1.0), jnp.float32))
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

    # ---- evaluation and reports -----------------------------------------------------
    def skill_paths(self, state: SkillState, key: jax.Array, skills: int = 48) -> tuple[np.ndarray, np.ndarray]:
        """h(s) along ``skills`` greedy skills from the prior, each from the initial state.

        Returns positions [n + 1, skills, d] (the start, then every action) and a mask that
        is False after a reset cut a skill short (METRA's coverage count reads these).
        """
        positions, mask = _jit_skill_paths(self, state, key, skills)
        return np.asarray(positions), np.asarray(mask)

    def _skill_paths(self, state: SkillState, key: jax.Array, skills: int):
        rollout = flat_init(self.env, self.start, None, key, skills)
        _, steps = flat_rollout(self.env, self.greedy, state.sac.actor, self.start, None, rollout,
                                self.cfg.n, self.cfg.n)
        alive = jnp.cumsum(steps.cut, axis=0) == 0
        start = self.env.goal_of_obs(jnp.asarray(self.initial_obs))
        positions = jnp.concatenate([jnp.broadcast_to(start, (1, skills, start.shape[-1])),
                                     self.env.goal_of_obs(steps.next_obs)])
        return positions, jnp.concatenate([jnp.ones((1, skills), bool), alive])

    def record_skills(self, state: SkillState, key: jax.Array, steps: int) -> tuple[np.ndarray, np.ndarray]:
        """One environment running greedy skills from the prior, one after another, each from
        a fresh start state: its joint positions [steps, nq] and mocap bodies [steps, nmocap, 3]
        after every primitive step (what ``mjx-emp render`` draws), in one jitted scan."""
        qpos, mocap = _jit_record_skills(self, state, key, steps)
        return np.asarray(qpos), np.asarray(mocap)

    def _record_skills(self, state: SkillState, key: jax.Array, steps: int):
        def one_step(rollout, _):
            rollout, _ = flat_rollout(self.env, self.greedy, state.sac.actor, self.start, None, rollout, 1, self.cfg.n)
            return rollout, (rollout.env.data.qpos[0], rollout.env.data.mocap_pos[0])

        _, (qpos, mocap) = jax.lax.scan(one_step, flat_init(self.env, self.start, None, key, 1), None, length=steps)
        return qpos, mocap

    def posterior_std(self, state: SkillState, key: jax.Array, rows: int = 4096) -> float | None:
        """DIAYN and HIDIO: the mean standard deviation of q(z | ...) over ``rows`` replayed
        transitions (Levy et al.'s diagnostic: it stays large when skills overlap); None for
        the other methods or an empty replay."""
        if not self.skill_method.has_posterior or int(state.replay.size) == 0:
            return None
        batch = replay_sample(state.replay, key, rows)
        _, log_std = self.model_net.apply(state.model.params, self.model_input(batch))
        return float(jnp.exp(log_std).mean())

    def metrics(self, state: SkillState, stats: IterationStats, seconds: float) -> dict[str, Any]:
        """One JSON-ready line of per-epoch metrics."""
        s = jax.tree.map(np.asarray, stats)

        def mean(values) -> float | None:
            values = np.asarray(values)[np.isfinite(values)]
            return float(values.mean()) if values.size else None

        header = epoch_header(state, float(s.env_steps.sum()), seconds)
        return {
            **header, "algorithm": self.method, "learned_iterations": int(s.learned.sum()),
            "critic_loss": mean(s.sac.critic_loss), "actor_loss": mean(s.sac.actor_loss), "alpha": mean(s.sac.alpha),
            "entropy": mean(s.sac.entropy), "model_loss": mean(s.model_loss), "reward": mean(s.reward),
            "posterior_std": mean(s.posterior_std), "dual_lambda": mean(s.dual_lambda),
            "constraint": mean(s.constraint), "episodes": int(s.episodes.sum()),
            "displacement": mean(np.where(s.episodes > 0, s.displacement, np.nan)),
            "flip_resets": int(s.flip_resets.sum()),
        }

    def divergence(self, state: SkillState, stats: IterationStats) -> str | None:
        """Why this epoch must not be kept (a non-finite loss or parameter), or None."""
        s = jax.tree.map(np.asarray, stats)
        learned = s.learned.astype(bool)
        for name, values in (("critic loss", s.sac.critic_loss), ("actor loss", s.sac.actor_loss),
                             ("model loss", s.model_loss)):
            if not np.isfinite(values[learned]).all():
                return f"the {self.method} {name} is not finite"
        if not bool(all_finite((state.sac, state.model))):
            return "a network parameter or optimizer state is not finite"
        return None

    def describe(self, metrics: dict) -> str:
        """A short human-readable summary of an epoch's metrics."""
        def show(name):
            value = metrics[name]
            return "-" if value is None else f"{value:.3g}"

        extra = self.skill_method.reports
        tail = f"  {extra.replace('_', ' ')} {show(extra)}" if extra else ""
        return (f"{metrics['env_steps']:.3g} env steps  {metrics['env_steps_per_s']:.3g} steps/s  "
                f"reward {show('reward')}  displacement {show('displacement')}  alpha {show('alpha')}{tail}")


_jit_init = jax.jit(SkillAgent._init, static_argnums=0)
_jit_train_epoch = jax.jit(SkillAgent._train_epoch, static_argnums=0, donate_argnums=1)
_jit_skill_paths = jax.jit(SkillAgent._skill_paths, static_argnums=(0, 3))
_jit_record_skills = jax.jit(SkillAgent._record_skills, static_argnums=(0, 3))
