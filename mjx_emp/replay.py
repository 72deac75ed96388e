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


def replay_insert(buffer: ReplayBuffer, rows: Rows, valid: jax.Array) -> ReplayBuffer:
    """Append the rows where ``valid`` (in order), overwriting the oldest once full.

    When one call brings more valid rows than the capacity, only the newest
    ``capacity`` of them are kept, as if they had been inserted one by one.
    """
    capacity = buffer.capacity
    valid = valid.reshape(-1)
    order = jnp.cumsum(valid.astype(jnp.int32)) - 1
    count = order[-1] + 1 if valid.size else jnp.zeros((), jnp.int32)
    keep = valid & (order >= count - capacity)
    dest = jnp.where(keep, (buffer.insert_pos + order) % capacity, capacity)
    data = jax.tree.map(lambda buf, x: buf.at[dest].set(x, mode="drop"), buffer.data, rows)
    return ReplayBuffer(
        data=data,
        insert_pos=(buffer.insert_pos + count) % capacity,
        size=jnp.minimum(buffer.size + count, capacity),
    )


def replay_clear_where(buffer: ReplayBuffer, clear: jax.Array) -> ReplayBuffer:
    """``buffer`` emptied where ``clear`` (a traced bool), unchanged otherwise; the rows stay
    allocated and are overwritten by the next inserts."""
    zero = jnp.zeros((), jnp.int32)
    return buffer.replace(insert_pos=jnp.where(clear, zero, buffer.insert_pos),
                          size=jnp.where(clear, zero, buffer.size))


def replay_sample(buffer: ReplayBuffer, key: jax.Array, batch_size: int) -> Rows:
    """``batch_size`` rows drawn uniformly (with replacement) from the filled part.

    The buffer must hold at least one row; an empty buffer returns zero rows' worth of
    padding, so callers check ``size`` before learning from a sample.
    """
    index = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size, 1))
    return jax.tree.map(lambda x: x[index], buffer.data)
