"""A run split into shards, placed on one or more devices (data parallelism).

A config with ``shards = S`` trains S agents of its per-shard config side by side (each
with 1/S of the environments, minibatch, replay and start buffers): their states stack on
a leading shard axis, the program is ``shard_map`` over a 1-D ``Mesh`` of D devices
(D divides S) of a ``vmap`` over the S/D shards each device holds. The shards meet only in
the collectives of :mod:`mjx_emp.shards` (averaged gradients, summed counts), along both
axes, so the parameters stay equal on every shard and the program computes the same on 1
device as on S (up to the order of the floating-point sums). The shard count is part of
the run's config; the device count is not, so a run resumes on any D that divides S.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from mjx_emp.algos.registry import make_agent
from mjx_emp.errors import ConfigError
from mjx_emp.run.hosts import place_on

DEVICE_AXIS = "devices"
"""The mesh axis the shards are spread over."""
LOCAL_AXIS = "local_shards"
"""The vmapped axis of the shards one device holds."""


def choose_devices(shards: int, requested: int) -> int:
    """How many devices a run of ``shards`` shards uses: ``requested`` (which must divide
    ``shards`` and exist), or with 0 the most devices that divide ``shards``. With several
    hosts, the devices of every process count."""
    available = jax.device_count()
    if requested < 0:
        raise ConfigError(f"num_devices: must be >= 0 (0: every local device that fits); got {requested}")
    if requested == 0:
        return max(d for d in range(1, min(available, shards) + 1) if shards % d == 0)
    if requested > available:
        raise ConfigError(f"num_devices: there are {available} device(s); got {requested}")
    if shards % requested:
        raise ConfigError(f"num_devices: must divide the run's shards ({shards}); got {requested}")
    return requested


@dataclasses.dataclass(frozen=True)
class ShardedAgent:
    """The run's config (``cfg.shards`` > 1 or not) trained as shards on ``num_devices`` devices.

    Offers what the run layer drives (``init``, ``train_epoch``, ``metrics``, ``divergence``,
    ``describe``, ``place``); ``alone`` is one shard's agent without collectives, for what
    reads a shard's state (evaluation, plots, phase 2). A static jit argument.
    """

    cfg: Any
    num_devices: int
    local: Any = dataclasses.field(init=False, repr=False)
    """One shard's agent, its collectives along the device and local-shard axes."""
    alone: Any = dataclasses.field(init=False, repr=False)
    """One shard's agent on its own (no collectives)."""
    mesh: Mesh = dataclasses.field(init=False, repr=False)
    _epoch: Any = dataclasses.field(init=False, repr=False)

    def __post_init__(self):
        # Built here, never inside a trace: an environment made while tracing would hold tracers.
        object.__setattr__(self, "local", make_agent(self.cfg, (LOCAL_AXIS, DEVICE_AXIS)))
        object.__setattr__(self, "alone", make_agent(self.cfg))
        for agent in (self.local, self.alone):  # constants computed outside any trace, on this process's device
            agent.initial_obs  # noqa: B018
        object.__setattr__(self, "mesh", Mesh(np.asarray(jax.devices()[: self.num_devices]), (DEVICE_AXIS,)))
        # Shardings fixed in and out, so the state an epoch returns is the state the next one
        # compiled for (left to propagation, the second epoch compiled again).
        epoch = jax.jit(functools.partial(_shards_epoch, self), in_shardings=(self.sharding,),
                        out_shardings=self.sharding, donate_argnums=0)
        object.__setattr__(self, "_epoch", epoch)

    @property
    def sharding(self) -> NamedSharding:
        """Leading (shard) axis split over the devices, the rest of each array whole."""
        return NamedSharding(self.mesh, PartitionSpec(DEVICE_AXIS))

    def __hash__(self) -> int:
        return hash((self.cfg, self.num_devices))

    def __eq__(self, other) -> bool:
        return isinstance(other, ShardedAgent) and (self.cfg, self.num_devices) == (other.cfg, other.num_devices)

    def init(self, key: jax.Array | None = None) -> Any:
        """The shards' fresh states, stacked and placed: equal networks (one shard's
        ``init``), every random key folded with its shard's index so the shards explore apart."""
        key = jax.random.key(self.cfg.seed) if key is None else key
        return self.place(_jit_fold_shards(self, self.alone.init(key)))

    def place(self, state: Any) -> Any:
        """``state`` (stacked on the shard axis, anywhere) on this program's devices."""
        return place_on(state, self.sharding)

    def train_epoch(self, state: Any) -> tuple[Any, Any]:
        """One epoch of every shard as one jitted program."""
        return self._epoch(state)

    def metrics(self, state: Any, stats: Any, seconds: float) -> dict[str, Any]:
        """Shard 0's metrics line: its counts are the whole run's (summed in the program) and
        its networks everyone's."""
        return self.alone.metrics(shard_slice(state, 0), shard_slice(stats, 0), seconds)

    def divergence(self, state: Any, stats: Any) -> str | None:
        """Shard 0's verdict (every shard holds the same networks and reported losses)."""
        return self.alone.divergence(shard_slice(state, 0), shard_slice(stats, 0))

    def describe(self, metrics: dict) -> str:
        return self.alone.describe(metrics)


def shard_slice(tree: Any, index: int) -> Any:
    """Shard ``index``'s part of a pytree stacked on the leading shard axis."""
    return jax.tree.map(lambda x: x[index], tree)


def _fold_keys(tree: Any, index: jax.Array) -> Any:
    def fold(leaf):
        if not jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            return leaf
        flat = jax.vmap(lambda key: jax.random.fold_in(key, index))(leaf.reshape(-1))
        return flat.reshape(leaf.shape)

    return jax.tree.map(fold, tree)


@functools.partial(jax.jit, static_argnums=0)
def _jit_fold_shards(program: ShardedAgent, one: Any) -> Any:
    return jax.vmap(lambda index: _fold_keys(one, index))(jnp.arange(program.cfg.shards))


def _shards_epoch(program: ShardedAgent, state: Any) -> tuple[Any, Any]:
    spec = PartitionSpec(DEVICE_AXIS)
    per_device = jax.vmap(program.local.train_epoch, axis_name=LOCAL_AXIS)
    return jax.shard_map(per_device, mesh=program.mesh, in_specs=spec, out_specs=spec, check_vma=False)(state)
