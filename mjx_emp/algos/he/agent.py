"""Phase 1 of Hierarchical Empowerment: curriculum epochs, entirely on device.

One epoch (the paper's appendix) is, for every level from the bottom up: 10
goal-conditioned iterations (collect experience at that level, then S=50 DDPG-style
gradient steps) and one goal-space iteration (execute skills sampled from the noisy
goal space, then S=10 SVG gradient steps). Before the levels train, the start-state
buffers are refreshed by greedily chaining top-level skills from the initial state.

The epoch is a single jitted call: a ``lax.scan`` over a schedule of (level, mode)
items. Each item collects data with the same compiled k-level rollout (its root level
is data) inside a ``lax.while_loop`` that runs until every environment has finished
at least one episode at that level, and then runs the level's update through a
``lax.switch``. So the physics appears once in the compiled program whatever k is.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mjx_emp import gce
from mjx_emp.algos.he.collection import HECollection
from mjx_emp.algos.he.config import (
    HEConfig,
    keeps_cut_rows,
)
from mjx_emp.algos.he.evaluation import HEEvaluation
from mjx_emp.algos.he.learning import HELearning
from mjx_emp.algos.he.networks import HENetworks
from mjx_emp.algos.he.state import (
    MODE_GC,
    MODE_GS,
    MODE_STARTS,
    TRAIN_EPOCH_TRACE,
    HEState,
    ItemStats,
    epoch_schedule,
)
from mjx_emp.checks import compile_identity
from mjx_emp.counters import StepCounter
from mjx_emp.envs.env import Env, make_env
from mjx_emp.learners.ddpg import (
    DDPGLearner,
    GoalTransition,
)
from mjx_emp.learners.goal_space import GoalSpaceLearner, GoalSpaceSample
from mjx_emp.nets import (
    goal_features,
    level_policy,
    primitive_box,
)
from mjx_emp.replay import (
    replay_init,
    replay_insert,
)
from mjx_emp.rollout.hierarchy import init_rollout
from mjx_emp.rollout.structures import Driver, Hierarchy, Params
from mjx_emp.shards import ShardAxes, mean_gradients, shard_mean
from mjx_emp.tracing import count_trace


@dataclasses.dataclass(frozen=True)
class HEAgent(HECollection, HELearning, HEEvaluation):
    """Static side of phase 1 for one config: env, networks, optimisers, the rollout agent.

    It is a static jit argument that hashes and compares by its config (all but the epoch
    count, :func:`~mjx_emp.checks.compile_identity`), so trainers of equal configs share
    compiled programs. Drive it with :meth:`init` and :meth:`train_epoch`.
    """

    cfg: HEConfig = dataclasses.field(compare=False)
    shard_axes: ShardAxes = ()
    """The mapped axes this agent's shards run along when a split run trains (see
    :mod:`mjx_emp.shards`); empty for an agent on its own."""
    identity: HEConfig = dataclasses.field(init=False, repr=False)
    """What it compares and hashes by: ``cfg`` without its epoch count."""
    env: Env = dataclasses.field(init=False, compare=False, repr=False)
    nets: HENetworks = dataclasses.field(init=False, compare=False, repr=False)
    hierarchy: Hierarchy = dataclasses.field(init=False, compare=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "identity", compile_identity(self.cfg))
        env = make_env(self.cfg.env, self.cfg.heading_frame, self.cfg.solver_iterations, self.cfg.integrator,
                       self.cfg.impl)
        object.__setattr__(self, "env", env)
        object.__setattr__(self, "nets", HENetworks(self.cfg, env))
        policies = tuple(
            level_policy(env, self.nets.actor_net(level), primitive_box if level == 0 else self.nets.learned_box(level - 1))
            for level in range(self.cfg.k)
        )
        hierarchy = Hierarchy(
            env, policies, n=tuple(self.cfg.n), eps=tuple(self.cfg.eps),
            driver=Driver(self._chooser, self.cfg.start_chain),
        )
        object.__setattr__(self, "hierarchy", hierarchy)

    def _chooser(self, params: Params, obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
        """The start-state chain's driver: a skill drawn uniformly from the top goal space."""
        del goal
        action = self.nets.goal_space_action(self.cfg.k - 1, params, obs)
        return gce.sample_goal(gce.goal_noise(key, (self.env.goal_size,)), action)

    @functools.cached_property
    def optimizers(self) -> dict[str, optax.GradientTransformation]:
        c = self.cfg
        rates = {"actor": c.actor_lr, "critic": c.critic_lr, "gs_actor": c.gs_actor_lr, "gs_critic": c.gs_critic_lr}
        return {name: mean_gradients(optax.adam(rate), self.shard_axes) for name, rate in rates.items()}

    # ---- state ----------------------------------------------------------------------
    @functools.cached_property
    def initial_obs(self) -> np.ndarray:
        """Observation of the task's initial state (a constant under jit), computed once."""
        return self.env.initial_obs()

    def init(self, key: jax.Array | None = None) -> HEState:
        """Fresh networks, empty replay buffers, start buffers holding the initial state."""
        return _jit_init(self, jax.random.key(self.cfg.seed) if key is None else key)

    def _init(self, key: jax.Array) -> HEState:
        env, cfg, opt = self.env, self.cfg, self.optimizers
        obs, goal = jnp.asarray(self.initial_obs), jnp.zeros(env.goal_size)
        policies, goal_spaces, replay, goal_space_replay, starts = [], [], [], [], []
        for level in range(cfg.k):
            keys = jax.random.split(jax.random.fold_in(key, level), 4)
            action = jnp.zeros(self.nets.action_size(level))
            actor = self.nets.actor_net(level).init(keys[0], goal_features(env, obs, goal))
            critic_input = jnp.concatenate([goal_features(env, obs, goal), action])
            if cfg.critics == 1:
                critic = self.nets.gc_critic_net.init(keys[1], critic_input)
            else:
                critic_keys = jax.random.split(keys[1], cfg.critics)
                critic = jax.vmap(lambda k: self.nets.gc_critic_net.init(k, critic_input))(critic_keys)
            policies.append(DDPGLearner(actor, critic, actor, critic, opt["actor"].init(actor), opt["critic"].init(critic)))
            gs_action = jnp.zeros(2 * env.goal_size)
            gs_actor = self.nets.gs_actor_net(level).init(keys[2], env.features(obs))
            gs_critic = self.nets.critic_net.init(keys[3], jnp.concatenate([env.features(obs), goal, gs_action]))
            goal_spaces.append(GoalSpaceLearner(gs_actor, gs_critic, opt["gs_actor"].init(gs_actor), opt["gs_critic"].init(gs_critic)))
            row = GoalTransition(obs, goal, action, obs, jnp.zeros((), bool), successor=jnp.zeros((), jnp.int32),
                                 cut=jnp.zeros((), bool) if keeps_cut_rows(cfg) else None)
            replay.append(replay_init(row, cfg.replay_capacity))
            goal_space_replay.append(replay_init(GoalSpaceSample(obs, goal, gs_action, jnp.zeros(())), cfg.gs_replay_capacity))
            start_buffer = replay_init(obs, cfg.start_capacity)
            starts.append(replay_insert(start_buffer, obs[None], jnp.ones(1, bool)))
        key, chain_key = jax.random.split(jax.random.fold_in(key, cfg.k))
        state = HEState(
            policies=tuple(policies), goal_spaces=tuple(goal_spaces), replay=tuple(replay), goal_space_replay=tuple(goal_space_replay),
            starts=tuple(starts), chain=None, key=key,
            epoch=jnp.zeros((), jnp.int32), env_steps=StepCounter.zero(),
        )
        params, start_params = self.rollout_inputs(state, jnp.int32(cfg.k), jnp.int32(MODE_STARTS))
        chain = init_rollout(self.hierarchy, params, self.start, start_params, chain_key, cfg.num_envs, cfg.k)
        return state.replace(chain=chain)

    # ---- the epoch ------------------------------------------------------------------
    def _train_epoch(self, state: HEState) -> tuple[HEState, ItemStats]:
        count_trace(TRAIN_EPOCH_TRACE)
        cfg = self.cfg
        branches = [self._no_update]
        for level in range(cfg.k):
            branches += [self.gc_update(level), self.gs_update(level)]

        def item(state: HEState, schedule_item):
            root, mode = schedule_item[0], schedule_item[1]
            key, collect_key, update_key = jax.random.split(state.key, 3)
            state, totals = self._collect(state.replace(key=key), root, mode, collect_key)
            branch = jnp.select([mode == MODE_GC, mode == MODE_GS], [1 + 2 * root, 2 + 2 * root], 0)
            (policies, goal_spaces), losses = jax.lax.switch(
                branch, branches, (state.policies, state.goal_spaces), state.replay, state.goal_space_replay, update_key
            )
            losses = shard_mean(losses, self.shard_axes)
            stats = ItemStats(
                root=root, mode=mode, env_steps=totals.env_steps, transitions=totals.transitions,
                episodes=totals.episodes, reached=totals.success(), final_distance=totals.mean_distance(),
                critic_loss=losses[0], actor_loss=losses[1], flip_resets=totals.flip_resets,
            )
            return state.replace(policies=policies, goal_spaces=goal_spaces), stats

        state, stats = jax.lax.scan(item, state, jnp.asarray(epoch_schedule(cfg)))
        return state.replace(epoch=state.epoch + 1), stats

    def train_epoch(self, state: HEState) -> tuple[HEState, ItemStats]:
        """One curriculum epoch as one jitted call; returns per-schedule-item stats."""
        return _jit_train_epoch(self, state)


_jit_init = jax.jit(HEAgent._init, static_argnums=0)
_jit_train_epoch = jax.jit(HEAgent._train_epoch, static_argnums=0, donate_argnums=1)
