"""Collectives of a run split into shards (data parallelism), as no-ops for an unsplit run.

A run with ``shards > 1`` splits its environment batch, replay and start-state buffers into
equal parts, one agent of the per-shard config each (see :mod:`mjx_emp.run.devices`). The
shards run the same program side by side (under ``vmap`` on one device, ``shard_map``
across devices); they meet only where these functions are called: gradients are averaged
before every optimiser step (so the parameters stay equal on every shard), counts are
summed and reported losses averaged. Everything else, the rollout, the replay insert's
prefix sum and the sampling, stays within its shard. ``axes`` names the mapped axes the
shards run along; empty, every function returns its input.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax

ShardAxes = tuple[str, ...]


def shard_sum(tree: Any, axes: ShardAxes) -> Any:
    """Every leaf summed over the shards (counts: steps, episodes, successes)."""
    return jax.lax.psum(tree, axes) if axes else tree


def shard_mean(tree: Any, axes: ShardAxes) -> Any:
    """Every leaf averaged over the shards (reported losses and rates)."""
    return jax.lax.pmean(tree, axes) if axes else tree


def shard_all(flag: jax.Array, axes: ShardAxes) -> jax.Array:
    """True where ``flag`` holds on every shard: a decision all shards must take alike."""
    return jax.lax.pmin(flag.astype(jnp.int32), axes).astype(bool) if axes else flag


def mean_gradients(tx: optax.GradientTransformation, axes: ShardAxes) -> optax.GradientTransformation:
    """``tx`` fed the shards' average gradient, so every shard takes the same step.

    The optimiser state is ``tx``'s own, so a shard's state restores into an unsplit agent
    of the same per-shard config (evaluation, phase 2) and back.
    """
    if not axes:
        return tx

    def update(updates, state, params=None):
        return tx.update(jax.lax.pmean(updates, axes), state, params)

    return optax.GradientTransformation(tx.init, update)
