"""The one collect loop: roll out in chunks until every environment has finished an episode.

Phase 1 (every level and mode) and phase 2 gather experience the same way: a
``lax.while_loop`` over rollout calls of ``chunk_steps`` primitive steps that stops
once every environment has ended its first root episode (or after ``max_chunks``
calls, or, for a chain that must run a fixed length, only then). What a caller keeps
from each chunk (replay inserts, counts) is its ``absorb`` function; the figures every
caller reports are summed in :class:`CollectTotals`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from mjx_emp.rollout.hierarchy import rollout
from mjx_emp.rollout.structures import (
    EpisodeEnd,
    Hierarchy,
    RolloutState,
    RolloutStats,
    StartFn,
    Transition,
)


@struct.dataclass
class CollectTotals:
    """Running sums over a collect call: primitive steps (int32, exact: one call is far below
    2^31 steps), transitions kept, first episodes, how many of those reached their goal, the
    sum of their distances to goal, flip resets, how many first episodes a reset cut short (a
    flipped Ant or broken physics), and the sum of those cut episodes' distances."""

    env_steps: jax.Array
    transitions: jax.Array
    episodes: jax.Array
    reached: jax.Array
    distance: jax.Array
    flip_resets: jax.Array
    cut_short: jax.Array
    cut_distance: jax.Array

    @classmethod
    def zero(cls) -> CollectTotals:
        return cls(env_steps=jnp.int32(0), transitions=jnp.int32(0), episodes=jnp.int32(0), reached=jnp.int32(0),
                   distance=jnp.zeros((), jnp.float32), flip_resets=jnp.int32(0), cut_short=jnp.int32(0),
                   cut_distance=jnp.zeros((), jnp.float32))

    def add(self, stats: RolloutStats, transitions: jax.Array, first_episode: jax.Array,
            reached: jax.Array, distance: jax.Array, cut: jax.Array | None = None) -> CollectTotals:
        """These totals plus one chunk: its stats, kept-transition mask, first-episode mask
        (with per-row reached flags, distances and cut-short flags, counted only where
        first_episode)."""
        cut = jnp.zeros_like(first_episode) if cut is None else cut
        return CollectTotals(
            env_steps=self.env_steps + stats.primitive_steps,
            transitions=self.transitions + transitions.sum(),
            episodes=self.episodes + first_episode.sum(),
            reached=self.reached + (first_episode & reached).sum(),
            distance=self.distance + jnp.where(first_episode, distance, 0.0).sum(),
            flip_resets=self.flip_resets + stats.flip_resets,
            cut_short=self.cut_short + (first_episode & cut).sum(),
            cut_distance=self.cut_distance + jnp.where(first_episode & cut, distance, 0.0).sum(),
        )

    def success(self) -> jax.Array:
        """Fraction of first episodes that reached their goal (0 when none ended)."""
        return self.reached / jnp.maximum(self.episodes, 1)

    def cut_fraction(self) -> jax.Array:
        """Fraction of first episodes a reset cut short (0 when none ended)."""
        return self.cut_short / jnp.maximum(self.episodes, 1)

    def mean_distance(self) -> jax.Array:
        """Mean distance to goal over first episodes (0 when none ended)."""
        return self.distance / jnp.maximum(self.episodes, 1)

    def uncut_mean_distance(self) -> jax.Array:
        """Mean distance to goal over first episodes no reset cut short (NaN when every one was
        cut): what the distance is on the episodes a flip did not end."""
        uncut = self.episodes - self.cut_short
        return jnp.where(uncut > 0, (self.distance - self.cut_distance) / jnp.maximum(uncut, 1), jnp.nan)


# (carry, transitions, episodes, stats) -> carry: what a caller keeps from one chunk.
Absorb = Callable[[Any, tuple[Transition, ...], EpisodeEnd, RolloutStats], Any]


def collect(hierarchy: Hierarchy, params: tuple, start: StartFn, start_params: Any, first: RolloutState,
            chunk_steps: int, max_chunks: jax.Array, absorb: Absorb, carry: Any,
            fixed_length: jax.Array | bool = False) -> tuple[RolloutState, Any]:
    """Roll ``first`` forward chunk by chunk, handing each chunk to ``absorb``.

    Stops when every environment has finished at least one root episode, or after
    ``max_chunks`` chunks; with ``fixed_length`` (may be traced) it always runs
    ``max_chunks``. Returns the rollout state and ``absorb``'s final carry.
    """

    def unfinished(loop):
        state, _, chunks = loop
        return (chunks < max_chunks) & (fixed_length | jnp.any(state.episodes_done == 0))

    def chunk(loop):
        state, kept, chunks = loop
        state, transitions, episodes, stats = rollout(hierarchy, params, start, start_params, state, chunk_steps)
        return state, absorb(kept, transitions, episodes, stats), chunks + 1

    state, kept, _ = jax.lax.while_loop(unfinished, chunk, (first, carry, jnp.zeros((), jnp.int32)))
    return state, kept
