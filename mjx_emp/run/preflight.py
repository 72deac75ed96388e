"""Memory preflight: refuse a run that cannot fit before allocating anything.

The train state's size is exact (``jax.eval_shape`` of the program's ``init``: parameters,
optimiser states, every buffer). One epoch's working set is estimated from the config: a
collection chunk of transitions at every level, and a minibatch through the networks
(forward and backward, actor and critic). Their sum is compared with the memory of the
device the state lives on (on a CPU, the host's available RAM). When it does not fit, the
run is refused with the estimate and the fields to lower; an out-of-memory error that
still happens while training is explained by :func:`explain_out_of_memory`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mjx_emp.errors import ConfigError

LOWER = ("replay_capacity", "num_envs", "batch_size", "gs_replay_capacity", "start_capacity", "hidden")
"""Config fields that size the state and the working set, in the order to try lowering them."""
HEADROOM = 0.9
"""Fraction of the free memory a run may plan to use (XLA and the Python process need the rest)."""


def state_bytes(program: Any) -> int:
    """Bytes of ``program``'s whole train state (its ``init``'s shapes; nothing allocated)."""
    import jax

    return tree_bytes(jax.eval_shape(program.init))


def tree_bytes(shapes: Any) -> int:
    """Bytes of a pytree of arrays or shapes (a PRNG key counted as its 8 bytes of key data)."""
    import jax
    import numpy as np

    total = 0
    for leaf in jax.tree.leaves(shapes):
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            total += int(np.prod(leaf.shape)) * 8
        else:
            total += int(np.prod(leaf.shape)) * np.dtype(leaf.dtype).itemsize
    return total


def env_state_bytes(env: Any) -> int:
    """Bytes of one environment's simulation state (the shapes of its reset; nothing runs)."""
    import jax

    return tree_bytes(jax.eval_shape(env.reset, jax.random.key(0)))


def working_set_bytes(cfg: Any, env: Any) -> int:
    """An estimate of one epoch's transient memory: the batched simulation state twice (a
    rollout step's input and output), a collection chunk of transitions at every level (obs,
    next obs, goal, action in float32) and a minibatch through actor and critic, forward and
    backward."""
    obs_size = env.obs_size
    steps = getattr(cfg, "chunk_steps", None) or getattr(cfg, "collect_steps", 1)
    levels = getattr(cfg, "k", 1)
    row = 4 * (3 * obs_size + 16)
    chunk = cfg.num_envs * steps * levels * row
    widest = max(cfg.hidden) if cfg.hidden else 1
    minibatch = cfg.batch_size * 4 * (obs_size + widest * len(cfg.hidden)) * 2 * 3
    return 2 * cfg.num_envs * env_state_bytes(env) + chunk + minibatch


def available_bytes() -> tuple[int, str]:
    """Free memory where the state lives: the default device's limit (GPU), or the host's
    available RAM (CPU); and its name."""
    import jax

    device = jax.local_devices()[0]
    stats = device.memory_stats() if hasattr(device, "memory_stats") else None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0)), f"{device.device_kind} memory"
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemAvailable:"):
            return int(line.split()[1]) * 1024, "available host RAM"
    return 2**63 - 1, "memory (unknown size)"


def _gib(count: float) -> str:
    return f"{count / 2**30:.3g} GiB"


def preflight(program: Any, cfg: Any, env: Any, devices: int = 1) -> dict[str, int]:
    """Refuse (ConfigError, exit 2) a run whose state and working set exceed the free memory of
    one of its ``devices`` (a split run's state is divided among them), naming the estimate
    and the fields to lower; returns the estimate otherwise."""
    state = state_bytes(program) // devices
    work = working_set_bytes(cfg, env) // devices
    free, where = available_bytes()
    if state + work > HEADROOM * free:
        fields = [name for name in LOWER if hasattr(cfg, name)]
        sizes = ", ".join(f"{name}={getattr(cfg, name)}" for name in fields)
        raise ConfigError(
            f"memory: this run needs about {_gib(state + work)} (train state {_gib(state)}, one epoch's working "
            f"set about {_gib(work)}) but {where} is {_gib(free)}; lower one of {', '.join(fields)} "
            f"(now {sizes})"
        )
    return {"state_bytes": state, "working_set_bytes": work, "free_bytes": free if free < 2**62 else -1}


def explain_out_of_memory(err: BaseException) -> str | None:
    """What to lower, when ``err`` is XLA running out of memory; else None."""
    text = str(err)
    if "RESOURCE_EXHAUSTED" not in text or "memory" not in text.lower():
        return None
    first = text.splitlines()[0][:300]
    return (f"out of memory ({first}); the preflight estimate fitted, so the compiled epoch needs more than "
            f"estimated: lower one of {', '.join(LOWER)}")
