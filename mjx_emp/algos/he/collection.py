"""How phase 1 collects experience: the episodes of a level (starts from its buffer, goals from
its noisy goal space), the greedy skill chain and greedy episodes for evaluation and pictures,
and the collection loop that fills the replays and start buffers."""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from mjx_emp import gce
from mjx_emp.algos.he.config import (
    keeps_cut_rows,
)
from mjx_emp.algos.he.state import (
    EVAL_STARTS,
    MODE_EVAL,
    MODE_GC,
    MODE_GS,
    MODE_STARTS,
    EpisodeInfo,
    HEState,
    StartParams,
    start_subset,
)
from mjx_emp.errors import ConfigError
from mjx_emp.learners.ddpg import (
    goal_transitions,
    stored_rows,
)
from mjx_emp.learners.goal_space import GoalSpaceSample
from mjx_emp.nets import (
    LevelParams,
    greedy_batch,
)
from mjx_emp.replay import (
    ReplayBuffer,
    flatten_rows,
    insertion_slots,
    link_episode_rows,
    replay_clear_where,
    replay_insert,
    replay_sample,
    replay_write,
)
from mjx_emp.rollout.collect import CollectTotals, collect
from mjx_emp.rollout.hierarchy import init_rollout
from mjx_emp.rollout.structures import EpisodeEnd, RolloutPlan, Transition
from mjx_emp.shards import shard_sum

TILT_STREAM = 7919
"""What a start's key is folded with for its tilted-start draws (``HEConfig.tilted_starts``)."""


class HECollection:
    """The collection methods of :class:`~mjx_emp.algos.he.agent.HEAgent` (``self`` is the agent)."""

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
            tilted=jnp.where((root == 0) & (mode == MODE_GC), cfg.tilted_starts, 0.0),
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
        if self.cfg.tilted_starts > 0.0:  # its own keys, so that without it every draw stays as it was
            s0 = self.tilted_start(s0, start_params.tilted, jax.random.fold_in(key, TILT_STREAM))
        state = env.restore(env_key, s0)
        actions = [self.nets.goal_space_action(level, p, s0) for level, p in enumerate(start_params.gs_actors)]
        action = jnp.stack(actions + [jnp.zeros(2 * d)])[start_params.root]
        shift, log_half_width = gce.split_goal_space_action(action)
        jitter = start_params.goal_noise * jax.random.normal(box_key, (2 * d,))
        action = jnp.concatenate([shift + jitter[:d] * jnp.exp(log_half_width), log_half_width + jitter[d:]])
        noise = gce.goal_noise(noise_key, (d,))
        z = gce.sample_goal(noise, action)
        return state, env.goal_of_obs(s0) + z, EpisodeInfo(obs=s0, noise=noise, action=action)

    def tilted_start(self, s0: jax.Array, share: jax.Array, key: jax.Array) -> jax.Array:
        """``s0``, or with probability ``share`` ``s0`` turned by an angle uniform up to
        ``tilted_start_angle`` about a horizontal axis of uniform heading (``Torso.turned``)."""
        use_key, angle_key, heading_key = jax.random.split(key, 3)
        angle = jax.random.uniform(angle_key, (), maxval=self.cfg.tilted_start_angle)
        heading = jax.random.uniform(heading_key, (), maxval=2.0 * jnp.pi)
        return jnp.where(jax.random.uniform(use_key) < share, self.env.torso.turned(s0, angle, heading), s0)

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
