"""Phase 1's train state and what an epoch reports: the state pytree (parameters, buffers, keys,
counters), the per-item stats, the epoch's schedule of (level, mode) items and the start subsets
evaluation draws from."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjx_emp.algos.he.config import (
    HEConfig,
)
from mjx_emp.counters import StepCounter
from mjx_emp.learners.ddpg import (
    DDPGLearner,
)
from mjx_emp.learners.goal_space import GoalSpaceLearner
from mjx_emp.replay import (
    ReplayBuffer,
    replay_init,
    replay_insert,
)
from mjx_emp.rollout.structures import Params, RolloutState

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
    tilted: jax.Array | float = 0.0
    """The share of episodes begun from a tilted start (``HEConfig.tilted_starts``, level 0's training only)."""


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
