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
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from mjx_emp import gce
from mjx_emp.algos.he.config import (
    HEConfig,
    keeps_cut_rows,
)
from mjx_emp.algos.he.networks import HENetworks
from mjx_emp.checks import compile_identity
from mjx_emp.counters import StepCounter
from mjx_emp.envs.env import Env, make_env
from mjx_emp.errors import ConfigError
from mjx_emp.learners.common import actor_critic_step, all_finite
from mjx_emp.learners.ddpg import (
    Backup,
    DDPGLearner,
    GoalTransition,
    ddpg_losses,
    ddpg_step,
    goal_transitions,
    hindsight_goals,
    n_step_backup,
    one_step_backup,
    relabel_goals,
    stored_rows,
)
from mjx_emp.learners.goal_space import GoalSpaceLearner, GoalSpaceSample, svg_losses
from mjx_emp.metrics import epoch_header
from mjx_emp.nets import (
    LevelParams,
    goal_features,
    greedy_batch,
    level_policy,
    primitive_box,
)
from mjx_emp.replay import (
    ReplayBuffer,
    flatten_rows,
    insertion_slots,
    link_episode_rows,
    replay_clear_where,
    replay_init,
    replay_insert,
    replay_sample,
    replay_write,
    sample_slots,
)
from mjx_emp.rollout.collect import CollectTotals, collect
from mjx_emp.rollout.hierarchy import (
    Driver,
    EpisodeEnd,
    Hierarchy,
    Params,
    RolloutPlan,
    RolloutState,
    Transition,
    init_rollout,
    rollout,
)
from mjx_emp.shards import ShardAxes, mean_gradients, shard_mean, shard_sum
from mjx_emp.tracing import count_trace

EVAL_STARTS = ("buffer", "initial", "chained")
"""Where :meth:`HEAgent.evaluate` starts its episodes: the level's start-state buffer (states
the greedy skill chain began a skill in, the initial state among them), only the initial
state, or only the buffer's other states (those chaining reached)."""
TRAIN_EPOCH_TRACE = "he.train_epoch"
"""Name under which :mod:`mjx_emp.tracing` counts traces (compiles) of the phase-1 epoch."""
# What a schedule item does.
MODE_STARTS, MODE_GC, MODE_GS, MODE_EVAL = 0, 1, 2, 3
MODE_NAMES = {MODE_STARTS: "starts", MODE_GC: "gc", MODE_GS: "gs", MODE_EVAL: "eval"}


@struct.dataclass
class EpisodeInfo:
    """How a root episode began: start observation, box noise and (noisy) goal-space action."""

    obs: jax.Array
    noise: jax.Array
    action: jax.Array


@struct.dataclass
class StartParams:
    """Run-time inputs of the start function: which level, its buffers and goal spaces."""

    root: jax.Array
    goal_noise: jax.Array
    starts: tuple[ReplayBuffer, ...]
    gs_actors: tuple[Params, ...]


@struct.dataclass
class HEState:
    """Everything phase 1 learns or remembers; a pytree of arrays, so it checkpoints whole."""

    policies: tuple[DDPGLearner, ...]
    goal_spaces: tuple[GoalSpaceLearner, ...]
    replay: tuple[ReplayBuffer, ...]
    goal_space_replay: tuple[ReplayBuffer, ...]
    starts: tuple[ReplayBuffer, ...]
    chain: RolloutState
    key: jax.Array
    epoch: jax.Array
    env_steps: StepCounter


@struct.dataclass
class ItemStats:
    """What one schedule item did: its level and mode, the data it saw, its losses."""

    root: jax.Array
    mode: jax.Array
    env_steps: jax.Array
    transitions: jax.Array
    episodes: jax.Array
    reached: jax.Array
    final_distance: jax.Array
    critic_loss: jax.Array
    actor_loss: jax.Array
    flip_resets: jax.Array


def epoch_schedule(cfg: HEConfig) -> np.ndarray:
    """[(level, mode)] of one epoch: start-state refresh, then per level its GC, GS and eval
    items, the whole block ``level_repeats`` times over (once where that is empty)."""
    items = [(cfg.k, MODE_STARTS)]
    for level in range(cfg.k):
        block = [(level, MODE_GC)] * cfg.gc_iterations + [(level, MODE_GS)] * cfg.gs_iterations
        block += [(level, MODE_EVAL)] * cfg.eval_iterations
        items += block * (cfg.level_repeats[level] if cfg.level_repeats else 1)
    return np.asarray(items, np.int32)


def start_subset(buffer: ReplayBuffer, initial: jax.Array, starts: jax.Array | int) -> ReplayBuffer:
    """The start states of ``buffer`` that ``starts`` (an index into :data:`EVAL_STARTS`, may be
    traced) names, as a buffer.

    0 ("buffer") keeps it whole; 1 ("initial") keeps only the initial state; 2 ("chained")
    only the other rows. A selection with no row (no chain has run yet) falls back to the
    initial state.
    """
    filled = jnp.arange(buffer.capacity) < buffer.size
    at_initial = jnp.all(buffer.data == initial, axis=-1)
    keep = filled & jnp.where(starts == 1, at_initial, ~at_initial)
    chosen = replay_insert(replay_init(initial, buffer.capacity), buffer.data, keep)
    fallback = replay_insert(replay_init(initial, buffer.capacity), initial[None], jnp.ones(1, bool))
    subset = jax.tree.map(lambda a, b: jnp.where(chosen.size > 0, a, b), chosen, fallback)
    return jax.tree.map(lambda a, b: jnp.where(starts == 0, a, b), buffer, subset)


@dataclasses.dataclass(frozen=True)
class HEAgent:
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
        """Observation of the task's initial state (computed eagerly, a constant under jit)."""
        with jax.ensure_compile_time_eval():
            return np.asarray(self.env.observe(self.env.reset(jax.random.key(0))))

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

    # ---- data collection ------------------------------------------------------------
    def rollout_inputs(self, state: HEState, root: jax.Array, mode: jax.Array):
        """Per-level policy params (noise only on the trained level) and start params."""
        cfg = self.cfg
        params = tuple(
            LevelParams(
                actor=state.policies[level].actor,
                box=None if level == 0 else state.goal_spaces[level - 1].actor,
                noise=jnp.where((root == level) & (mode == MODE_GC), cfg.action_noise, 0.0),
            )
            for level in range(cfg.k)
        ) + (state.goal_spaces[cfg.k - 1].actor,)
        goal_noise = jnp.select([mode == MODE_GC, mode == MODE_GS], [cfg.goal_noise, cfg.gs_noise], 0.0)
        start_params = StartParams(
            root=root, goal_noise=goal_noise, starts=state.starts,
            gs_actors=tuple(g.actor for g in state.goal_spaces),
        )
        return params, start_params

    def skill_chain(self, state: HEState) -> RolloutPlan:
        """The greedy chain of top-level skills from the initial state, as the start-state
        refresh runs it (each skill's goal drawn from the top goal space), showing the
        goals of levels 0..k-1."""
        k = self.cfg.k
        params, start_params = self.rollout_inputs(state, jnp.int32(k), jnp.int32(MODE_STARTS))
        return RolloutPlan(self.hierarchy, params, self.start, start_params, root=k)

    def greedy_episodes(self, state: HEState, level: int, starts: str = "buffer") -> RolloutPlan:
        """Greedy episodes rooted at ``level`` as :meth:`evaluate` runs them (goals from the
        level's own noise-free box, starts from the states ``starts`` names), for a caller that
        follows them step by step (the flip table)."""
        if starts not in EVAL_STARTS:
            raise ValueError(f"starts: {starts!r} is unknown; allowed values: {list(EVAL_STARTS)}")
        initial = jnp.asarray(self.initial_obs)
        which = EVAL_STARTS.index(starts)
        state = state.replace(starts=tuple(start_subset(buffer, initial, which) for buffer in state.starts))
        params, start_params = self.rollout_inputs(state, jnp.int32(level), jnp.int32(MODE_EVAL))
        return RolloutPlan(self.hierarchy, params, self.start, start_params, root=level)

    def greedy_policy(self, state: HEState, level: int = 0) -> Callable[[jax.Array, jax.Array], jax.Array]:
        """``level``'s greedy goal-conditioned policy, (obs [B, obs], goal [B, goal]) -> action: a
        primitive action at level 0, a subgoal offset from h(obs) above (goals are absolute)."""
        if not 0 <= level < self.cfg.k:
            raise ConfigError(f"level: must be in 0..{self.cfg.k - 1} (k={self.cfg.k}); got {level}")
        box = None if level == 0 else state.goal_spaces[level - 1].actor
        return greedy_batch(self.hierarchy.policies[level], state.policies[level].actor, box)

    def start(self, start_params: StartParams, key: jax.Array):
        """A new episode at level ``start_params.root``: s0 from its start buffer, z from its noisy box.

        Root k is the start-state chain (the hierarchy's driver): it begins at the initial
        state, and the goal returned for it is ignored.
        """
        env, d = self.env, self.env.goal_size
        pick_key, box_key, noise_key, env_key = jax.random.split(key, 4)
        candidates = [replay_sample(buf, pick_key, 1)[0] for buf in start_params.starts]
        s0 = jnp.stack(candidates + [jnp.asarray(self.initial_obs)])[start_params.root]
        state = env.restore(env_key, s0)
        actions = [self.nets.goal_space_action(level, p, s0) for level, p in enumerate(start_params.gs_actors)]
        action = jnp.stack(actions + [jnp.zeros(2 * d)])[start_params.root]
        shift, log_half_width = gce.split_goal_space_action(action)
        jitter = start_params.goal_noise * jax.random.normal(box_key, (2 * d,))
        action = jnp.concatenate([shift + jitter[:d] * jnp.exp(log_half_width), log_half_width + jitter[d:]])
        noise = gce.goal_noise(noise_key, (d,))
        z = gce.sample_goal(noise, action)
        return state, env.goal_of_obs(s0) + z, EpisodeInfo(obs=s0, noise=noise, action=action)

    def _max_chunks(self) -> jax.Array:
        """Rollout calls that let every environment finish one episode at each root level."""
        cfg = self.cfg
        longest = np.cumprod(cfg.n)
        return jnp.asarray([math.ceil(t / cfg.chunk_steps) + 1 for t in longest] + [cfg.start_chunks])

    def _collect(self, state: HEState, root: jax.Array, mode: jax.Array, key: jax.Array):
        """Run the agent rooted at ``root`` and file what it saw into the right buffers.

        GC: every valid root transition goes to the level's replay. GS: every finished root
        episode goes to the goal-space replay. With ``learn_from_resets`` both also keep
        what a reset cut short; with a ``flip_cost`` the replay does. With ``fresh_replay`` the buffer an item
        fills is emptied first (the paper's fresh D per call). EVAL: nothing is stored
        (success and distance are read from each environment's first episode in every
        mode; an episode a reset cut short, a flipped Ant, counts as a failure scored at
        its last state before the reset). STARTS: continues the greedy chain; the state each
        level got a new goal in is a start state. Returns the new state and the call's
        :class:`CollectTotals`.
        """
        cfg, env, hierarchy = self.cfg, self.env, self.hierarchy
        params, start_params = self.rollout_inputs(state, root, mode)
        is_chain = mode == MODE_STARTS
        first = jax.lax.cond(
            is_chain,
            lambda: state.chain,
            lambda: init_rollout(hierarchy, params, self.start, start_params, key, cfg.num_envs, root),
        )
        def absorb(kept, transitions, episodes, stats):
            (replay, goal_space_replay, starts, last), totals = kept
            replay, last = zip(*(
                self._store_linked(replay[i], last[i], transitions[i], (root == i) & (mode == MODE_GC),
                                   keeps_cut_rows(cfg))
                for i in range(cfg.k)
            ))
            transitions = flatten_rows(transitions)
            episodes = flatten_rows(episodes)
            first_episode = episodes.first_ended
            scored = episodes.ended if cfg.learn_from_resets else episodes.valid
            goal_space_replay = tuple(
                replay_insert(goal_space_replay[i], self._goal_space_sample(i, episodes), scored & (root == i) & (mode == MODE_GS))
                for i in range(cfg.k)
            )
            starts = tuple(
                replay_insert(starts[i], transitions[i + 1].obs, transitions[i + 1].valid & is_chain)
                for i in range(cfg.k)
            )
            distance = jnp.linalg.norm(
                env.goal_of_obs(episodes.final_obs)
                - env.goal_of_obs(episodes.info.obs)
                - gce.sample_goal(episodes.info.noise, episodes.info.action),
                axis=-1,
            )
            root_valid = jnp.stack([t.valid for t in transitions])[root]
            totals = totals.add(stats, root_valid, first_episode, episodes.reached, distance, episodes.cut)
            return (replay, goal_space_replay, starts, last), totals

        replay, goal_space_replay = state.replay, state.goal_space_replay
        if cfg.fresh_replay:
            replay = tuple(replay_clear_where(b, (root == i) & (mode == MODE_GC)) for i, b in enumerate(replay))
            goal_space_replay = tuple(replay_clear_where(b, (root == i) & (mode == MODE_GS)) for i, b in enumerate(goal_space_replay))
        no_rows = tuple(jnp.full(first.episodes_done.shape, b.capacity, jnp.int32) for b in replay)  # episodes begin afresh
        rollout_state, ((replay, goal_space_replay, starts, _), totals) = collect(
            hierarchy, params, self.start, start_params, first, cfg.chunk_steps, self._max_chunks()[root], absorb,
            ((replay, goal_space_replay, state.starts, no_rows), CollectTotals.zero()), fixed_length=is_chain,
        )
        chain = jax.lax.cond(is_chain, lambda: rollout_state, lambda: state.chain)
        totals = shard_sum(totals, self.shard_axes)  # every shard counts the whole run's steps and episodes
        state = state.replace(
            replay=replay, goal_space_replay=goal_space_replay, starts=starts, chain=chain,
            env_steps=state.env_steps.add(totals.env_steps),
        )
        return state, totals

    @staticmethod
    def _store_linked(buffer: ReplayBuffer, last: jax.Array, transitions: Transition, store: jax.Array,
                      keep_cut: bool):
        """Insert a chunk's [T, B] transitions where valid (or, with ``keep_cut``, a reset ended
        them) and ``store``, linking each to the next row of its episode (for hindsight goals
        and n-step targets); returns the buffer and each environment's latest stored row of a
        running episode."""
        valid = stored_rows(transitions, keep_cut) & store
        slots, count = insertion_slots(buffer, valid.reshape(-1))
        none = jnp.full(valid.shape, buffer.capacity, jnp.int32)
        rows = flatten_rows(goal_transitions(transitions, successor=none, keep_cut=keep_cut))
        buffer = replay_write(buffer, rows, slots, count)
        successor, last = link_episode_rows(buffer.data.successor, slots.reshape(valid.shape), valid,
                                            transitions.final & store, last)
        return buffer.replace(data=buffer.data.replace(successor=successor)), last

    def _goal_space_sample(self, level: int, episodes: EpisodeEnd) -> GoalSpaceSample:
        """Goal-space samples from finished episodes, rewarded with the level's sigma_gs."""
        info = episodes.info
        z = gce.sample_goal(info.noise, info.action)
        final_obs = episodes.final_obs
        if self.cfg.reset_outcome == "start":  # a skill that fell over is scored as one that never moved
            final_obs = jnp.where(episodes.cut[..., None], info.obs, final_obs)
        reward = gce.goal_space_reward(
            self.env.goal_of_obs(info.obs), z, self.env.goal_of_obs(final_obs),
            info.action, self.cfg.sigma_gs[level],
        )
        reward = reward - self.cfg.flip_cost * episodes.cut  # a goal whose skill flipped the robot: a failure
        return GoalSpaceSample(obs=info.obs, noise=info.noise, action=info.action, reward=reward)

    # ---- learning -------------------------------------------------------------------
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

    def evaluate(self, state: HEState, level: int, key: jax.Array, rounds: int = 4,
                 starts: str = "buffer") -> dict[str, float]:
        """Greedy skills at ``level`` on goals drawn from its own (noise-free) goal space at their start.

        ``rounds`` x num_envs episodes start from the states ``starts`` names (see
        :data:`EVAL_STARTS`: the level's start buffer, only the initial state, or only the
        buffer's states that chaining reached); returns the fraction that ended within eps
        of their goal, the mean final distance, and the fraction a reset cut short (for
        the Ant: it flipped).
        """
        if starts not in EVAL_STARTS:
            raise ValueError(f"starts: {starts!r} is unknown; allowed values: {list(EVAL_STARTS)}")
        which = jnp.int32(EVAL_STARTS.index(starts))
        reached, distance, cut = _jit_evaluate(self, state, jnp.int32(level), key, rounds, which)
        return {"success": float(reached), "final_distance": float(distance), "cut_short": float(cut)}

    def _evaluate(self, state: HEState, level: jax.Array, key: jax.Array, rounds: int, starts: jax.Array):
        initial = jnp.asarray(self.initial_obs)
        state = state.replace(starts=tuple(start_subset(buffer, initial, starts) for buffer in state.starts))

        def one(_, round_key):
            _, totals = self._collect(state, level, jnp.int32(MODE_EVAL), round_key)
            return None, (totals.success(), totals.mean_distance(), totals.cut_fraction())

        _, (reached, distance, cut) = jax.lax.scan(one, None, jax.random.split(key, rounds))
        return reached.mean(), distance.mean(), cut.mean()

    def skill_paths(self, state: HEState, key: jax.Array, skills: int = 48) -> tuple[np.ndarray, np.ndarray]:
        """h(s) along ``skills`` greedy top-level skills from the initial state.

        Each skill's goal is drawn from the top goal space at the initial state (no noise)
        and pursued greedily by every level. Returns positions [T + 1, skills, d] (the
        start, then every primitive step) and a mask [T + 1, skills] that is True up to and
        including the step that ended each skill (its first root episode; steps of later
        episodes and a flip reset's aftermath are masked out). METRA's coverage count and
        the robots benchmark read these paths.
        """
        positions, mask = _jit_skill_paths(self, state, key, skills)
        return np.asarray(positions), np.asarray(mask)

    def _skill_paths(self, state: HEState, key: jax.Array, skills: int):
        top = self.cfg.k - 1
        initial = jnp.asarray(self.initial_obs)
        only_initial = replay_insert(replay_init(initial, 1), initial[None], jnp.ones(1, bool))
        probe = state.replace(starts=state.starts[:top] + (only_initial,))
        params, start_params = self.rollout_inputs(probe, jnp.int32(top), jnp.int32(MODE_EVAL))
        rollout_state = init_rollout(self.hierarchy, params, self.start, start_params, key, skills, top)
        steps = int(np.prod(self.cfg.n))
        _, transitions, _, _ = rollout(self.hierarchy, params, self.start, start_params, rollout_state, steps)
        ended = transitions[top].final
        ended_before = jnp.cumsum(ended, axis=0) - ended.astype(jnp.int32)
        steps_mask = (ended_before == 0) & transitions[0].valid
        start = self.env.goal_of_obs(initial)
        positions = jnp.concatenate([
            jnp.broadcast_to(start, (1, skills, start.shape[-1])),
            self.env.goal_of_obs(transitions[0].next_obs),
        ])
        return positions, jnp.concatenate([jnp.ones((1, skills), bool), steps_mask])

    def goal_spaces(self, state: HEState, obs: jax.Array | None = None) -> list[dict[str, list[float]]]:
        """Each level's goal-space box at ``obs`` (default: the initial state), as plain floats."""
        obs = jnp.asarray(self.initial_obs) if obs is None else obs
        boxes = []
        for level in range(self.cfg.k):
            action = self.nets.goal_space_action(level, state.goal_spaces[level].actor, obs)
            shift, log_half_width = gce.split_goal_space_action(action)
            boxes.append({
                "shift": np.asarray(shift).tolist(),
                "half_width": np.exp(np.asarray(log_half_width)).tolist(),
                "volume": float(gce.box_volume(action)),
            })
        return boxes

    def boxes_where_used(self, state: HEState, rows: int = 1024) -> list[dict[str, float] | None]:
        """Each level's goal-space box at the states the level above chose subgoals in.

        Level i's box is level i+1's action space at whatever state level i+1 acts from.
        Where the box is wrong there (too far out, say, at fast-moving states the
        goal-space critic has seen little of), level i+1 asks for subgoals level i cannot
        reach. ``rows`` states are drawn from level i+1's replay; the top level (nothing
        above it) and an empty replay give None.
        """
        found: list[dict[str, float] | None] = []
        for level in range(self.cfg.k - 1):
            above = state.replay[level + 1]
            if int(above.size) == 0:
                found.append(None)
                continue
            obs = replay_sample(above, jax.random.fold_in(jax.random.key(0), state.epoch), rows).obs
            shift, half_width = self.nets.learned_box(level)(state.goal_spaces[level].actor, obs)
            found.append({"max_abs_shift": float(jnp.abs(shift).max()),
                          "mean_half_width": float(half_width.mean()),
                          "max_half_width": float(half_width.max())})
        return found + [None]

    def metrics(self, state: HEState, stats: ItemStats, seconds: float) -> dict[str, Any]:
        """One JSON-ready line of per-epoch metrics: goal spaces, success, losses, throughput."""
        s = jax.tree.map(np.asarray, stats)
        levels = []
        where_used = self.boxes_where_used(state)
        for level, box in enumerate(self.goal_spaces(state)):
            def pick(mode, field, reducer=np.mean):
                rows = (s.root == level) & (s.mode == mode)
                return float(reducer(getattr(s, field)[rows])) if rows.any() else None

            levels.append({
                "level": level,
                **box,
                "success": pick(MODE_EVAL, "reached"),
                "final_distance": pick(MODE_EVAL, "final_distance"),
                "gs_success": pick(MODE_GS, "reached"),
                "gc_critic_loss": pick(MODE_GC, "critic_loss"),
                "gc_actor_loss": pick(MODE_GC, "actor_loss"),
                "gs_critic_loss": pick(MODE_GS, "critic_loss"),
                "gs_actor_loss": pick(MODE_GS, "actor_loss"),
                "transitions": pick(MODE_GC, "transitions", np.sum),
                "box_where_used": where_used[level],
            })
        header = epoch_header(state, float(s.env_steps.sum()), seconds)
        return {**header, "flip_resets": int(s.flip_resets.sum()), "levels": levels}

    def divergence(self, state: HEState, stats: ItemStats) -> str | None:
        """Why this epoch's result must not be kept (a non-finite loss or parameter), or None.

        Start-refresh and evaluation items carry NaN losses by design and are not checked.
        """
        s = jax.tree.map(np.asarray, stats)
        for i in np.flatnonzero((s.mode == MODE_GC) | (s.mode == MODE_GS)):
            for name in ("critic_loss", "actor_loss"):
                value = getattr(s, name)[i]
                if not np.isfinite(value):
                    kind = "goal-conditioned" if s.mode[i] == MODE_GC else "goal-space"
                    return f"level {int(s.root[i])} {kind} {name.replace('_', ' ')} is {value}"
        if not bool(all_finite((state.policies, state.goal_spaces))):
            return "a network parameter or optimizer state is not finite"
        return None

    def describe(self, metrics: dict) -> str:
        """A short human-readable summary of an epoch's metrics: throughput, then per level."""
        levels = "  ".join(
            f"L{m['level']} volume {m['volume']:.3g} success {m['success']:.2f}"
            if m["success"] is not None else f"L{m['level']} volume {m['volume']:.3g}"
            for m in metrics["levels"]
        )
        return f"{metrics['env_steps']:.3g} env steps  {metrics['env_steps_per_s']:.3g} steps/s  {levels}"


_jit_init = jax.jit(HEAgent._init, static_argnums=0)
_jit_train_epoch = jax.jit(HEAgent._train_epoch, static_argnums=0, donate_argnums=1)
_jit_evaluate = jax.jit(HEAgent._evaluate, static_argnums=(0, 4))
_jit_skill_paths = jax.jit(HEAgent._skill_paths, static_argnums=(0, 3))


