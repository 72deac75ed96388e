"""Several hosts (processes) training one split run, through ``jax.distributed``.

Every process runs the same command with its own process id; together their devices form
the mesh a split run's shards are spread over (:mod:`mjx_emp.run.devices`). Process 0 is
the lead: it alone writes the run directory (config, metrics, checkpoints, through orbax
restricted to it) and reads checkpoints back, handing the restored state to the others.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
from jax.experimental import multihost_utils

from mjx_emp.errors import ConfigError

COORDINATOR_ENV, PROCESSES_ENV, PROCESS_ID_ENV = "JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"
"""Environment variables read when the flags are not given (JAX itself reads the first)."""


def join_hosts(coordinator_address: str = "", num_processes: int = 0, process_id: int = -1,
               timeout_s: int = 300) -> bool:
    """Start ``jax.distributed`` when a coordinator is given (flag or ``JAX_COORDINATOR_ADDRESS``),
    with the process count and id from the flags or ``JAX_NUM_PROCESSES`` / ``JAX_PROCESS_ID``.
    Must run before JAX is used. Says that it is joining; a coordinator that does not answer
    within ``timeout_s`` is a ConfigError naming the address. Returns whether this process joined several."""
    coordinator = coordinator_address or os.environ.get(COORDINATOR_ENV, "")
    if not coordinator:
        return False
    try:
        count = num_processes or int(os.environ.get(PROCESSES_ENV, "0"))
        index = process_id if process_id >= 0 else int(os.environ.get(PROCESS_ID_ENV, "-1"))
    except ValueError as err:
        raise ConfigError(f"num_processes / process_id: {PROCESSES_ENV} and {PROCESS_ID_ENV} must be integers ({err})")
    if count < 1:
        raise ConfigError(f"num_processes: give the number of processes (>= 1) with a coordinator; got {count}")
    if not 0 <= index < count:
        raise ConfigError(f"process_id: must be in [0, {count}); got {index}")
    if timeout_s < 1:
        raise ConfigError(f"join_timeout: must be >= 1 second; got {timeout_s}")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU devices of several processes
    print(f"joining {coordinator} as process {index} of {count} (waiting up to {timeout_s} s) ...", flush=True)
    try:
        jax.distributed.initialize(coordinator_address=coordinator, num_processes=count, process_id=index,
                                   initialization_timeout=timeout_s)
    except Exception as err:  # jaxlib raises its own error types for an unreachable or refused coordinator
        reason = " ".join(str(err).split())[:300]
        raise ConfigError(f"coordinator_address: could not join {coordinator} as process {index} of {count} within "
                          f"{timeout_s} s ({type(err).__name__}: {reason}); start process 0 first and check the "
                          f"address and port") from None
    return True


def several_hosts() -> bool:
    """Whether this program runs over several processes."""
    return jax.process_count() > 1


def is_lead() -> bool:
    """Whether this process writes the run directory (process 0, or the only one)."""
    return jax.process_index() == 0


def wait_for_all(name: str) -> None:
    """A barrier across the processes (nothing with one)."""
    if several_hosts():
        multihost_utils.sync_global_devices(name)


def _keys_as_data(move, tree: Any) -> Any:
    """``move`` applied to ``tree`` with its PRNG keys as raw key data, the keys wrapped back after."""
    def is_key(x):
        return jnp.issubdtype(x.dtype, jax.dtypes.prng_key)

    moved = move(jax.tree.map(lambda x: jax.random.key_data(x) if is_key(x) else x, tree))
    return jax.tree.map(lambda like, x: jax.random.wrap_key_data(x, impl=jax.random.key_impl(like)) if is_key(like)
                        else x, tree, moved)


def gather_to_host(tree: Any) -> Any:
    """``tree`` whole on every process (each array's every shard), as host arrays; PRNG keys stay
    keys. With one process, ``tree`` itself. Every process must call it."""
    if not several_hosts():
        return tree
    return _keys_as_data(lambda data: multihost_utils.process_allgather(data, tiled=True), tree)


def place_on(tree: Any, sharding: Any) -> Any:
    """``tree`` (its whole value, the same on every process) on ``sharding``, which may span the
    devices of several processes: each keeps the shards on its own devices."""
    if not several_hosts():
        return jax.device_put(tree, sharding)
    return _keys_as_data(lambda data: jax.device_put(jax.device_get(data), sharding), tree)
