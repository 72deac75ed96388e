"""Fixed-size on-device replay buffers that take masked rows.

The rollout returns every level's transitions as dense [T, B] arrays with a ``valid``
mask; upper levels fill only a few rows per step. Insertion therefore has to write a
data-dependent number of rows under jit, which ring buffers built for fixed batch adds
(flashbax's flat buffer, for one) do not offer: here the valid rows are packed in order
with a prefix sum and scattered into a ring, padding rows are dropped.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

Rows = Any  # a pytree whose leaves share a leading row axis


@struct.dataclass
class ReplayBuffer:
    """Ring buffer of ``capacity`` rows; ``size`` rows are filled, ``insert_pos`` is written next."""

    data: Rows
    insert_pos: jax.Array
    size: jax.Array

    @property
    def capacity(self) -> int:
        return jax.tree.leaves(self.data)[0].shape[0]


def replay_init(example_row: Rows, capacity: int) -> ReplayBuffer:
    """An empty buffer whose rows look like ``example_row`` (a pytree of one row's arrays)."""
    data = jax.tree.map(lambda x: jnp.zeros((capacity,) + jnp.shape(x), jnp.asarray(x).dtype), example_row)
    return ReplayBuffer(data=data, insert_pos=jnp.zeros((), jnp.int32), size=jnp.zeros((), jnp.int32))


def flatten_rows(tree: Rows, leading_axes: int = 2) -> Rows:
    """Merge the first ``leading_axes`` axes (e.g. the rollout's [T, B]) into one row axis."""
    return jax.tree.map(lambda x: x.reshape((-1,) + x.shape[leading_axes:]), tree)


def insertion_slots(buffer: ReplayBuffer, valid: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Where :func:`replay_insert` puts each row (``capacity`` where a row is not kept) and how
    many valid rows there are; ``valid`` is flat."""
    capacity = buffer.capacity
    order = jnp.cumsum(valid.astype(jnp.int32)) - 1
    count = order[-1] + 1 if valid.size else jnp.zeros((), jnp.int32)
    keep = valid & (order >= count - capacity)
    return jnp.where(keep, (buffer.insert_pos + order) % capacity, capacity), count


def replay_insert(buffer: ReplayBuffer, rows: Rows, valid: jax.Array) -> ReplayBuffer:
    """Append the rows where ``valid`` (in order), overwriting the oldest once full.

    When one call brings more valid rows than the capacity, only the newest
    ``capacity`` of them are kept, as if they had been inserted one by one.
    """
    dest, count = insertion_slots(buffer, valid.reshape(-1))
    return replay_write(buffer, rows, dest, count)


def replay_write(buffer: ReplayBuffer, rows: Rows, dest: jax.Array, count: jax.Array) -> ReplayBuffer:
    """``rows`` written at the slots :func:`insertion_slots` gave (``dest``, ``count``), for a
    caller that needs the slots too (episode links)."""
    capacity = buffer.capacity
    data = jax.tree.map(lambda buf, x: buf.at[dest].set(x, mode="drop"), buffer.data, rows)
    return ReplayBuffer(
        data=data,
        insert_pos=(buffer.insert_pos + count) % capacity,
        size=jnp.minimum(buffer.size + count, capacity),
    )


def link_episode_rows(successor: jax.Array, slots: jax.Array, valid: jax.Array, final: jax.Array,
                      last: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Record, for rows just stored, which stored row comes next in the same episode.

    ``successor`` [capacity] holds per slot the slot of the episode's next row (``capacity``:
    none, yet or ever). ``slots``, ``valid`` and ``final`` are a chunk's [T, B] insertion
    slots, stored-row mask and episode-end flags (final rows need not be valid: a reset
    ends an episode without a stored row); ``last`` [B] is each environment's latest
    stored row of an episode still running (``capacity``: none). Steps run in time order,
    so each environment's rows are chained as they were lived. Returns both updated.

    The ring overwrites its oldest rows first, so a row's successor, being newer, is
    still stored while the row is.
    """
    capacity = successor.shape[0]

    def step(carry, row):
        successor, last = carry
        slot, stored, ends = row
        slot = jnp.where(stored, slot, capacity)
        successor = successor.at[slot].set(capacity, mode="drop")  # a reused slot forgets its old link
        successor = successor.at[jnp.where(stored, last, capacity)].set(slot, mode="drop")
        last = jnp.where(ends, capacity, jnp.where(stored, slot, last))
        return (successor, last), None

    (successor, last), _ = jax.lax.scan(step, (successor, last), (slots, valid, final))
    return successor, last


def episode_walk(successor: jax.Array, index: jax.Array, steps: int) -> tuple[jax.Array, jax.Array]:
    """Slots [steps, B] of rows ``index`` [B] and their successors, and a mask [steps, B] of
    which exist (row j of a walk is the episode's j-th row after ``index``)."""
    capacity = successor.shape[0]

    def step(current, _):
        nxt = successor[jnp.minimum(current, capacity - 1)]
        nxt = jnp.where(current < capacity, nxt, capacity)
        return nxt, current

    _, slots = jax.lax.scan(step, index.astype(jnp.int32), None, length=steps)
    return jnp.minimum(slots, capacity - 1), slots < capacity


def replay_clear_where(buffer: ReplayBuffer, clear: jax.Array) -> ReplayBuffer:
    """``buffer`` emptied where ``clear`` (a traced bool), unchanged otherwise; the rows stay
    allocated and are overwritten by the next inserts."""
    zero = jnp.zeros((), jnp.int32)
    return buffer.replace(insert_pos=jnp.where(clear, zero, buffer.insert_pos),
                          size=jnp.where(clear, zero, buffer.size))


def sample_slots(buffer: ReplayBuffer, key: jax.Array, batch_size: int) -> jax.Array:
    """``batch_size`` slots drawn uniformly (with replacement) from the filled part."""
    return jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size, 1))


def replay_sample(buffer: ReplayBuffer, key: jax.Array, batch_size: int) -> Rows:
    """``batch_size`` rows drawn uniformly (with replacement) from the filled part.

    The buffer must hold at least one row; an empty buffer returns zero rows' worth of
    padding, so callers check ``size`` before learning from a sample.
    """
    index = sample_slots(buffer, key, batch_size)
    return jax.tree.map(lambda x: x[index], buffer.data)
