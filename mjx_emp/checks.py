"""Configuration checks any algorithm's config shares, and configs back from JSON.

Plain Python (no JAX import), so the CLI can reject bad input before compiling anything.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Sequence

from mjx_emp.errors import ConfigError


def check_levels(n: Sequence[int], eps: Sequence[float], k: int | None = None) -> None:
    """Validate per-level n and eps for a k-level agent (k defaults to len(n))."""
    k = len(n) if k is None else k
    if k < 1:
        raise ConfigError("n: give at least one level (k >= 1), e.g. --n 20 10")
    if len(n) != k or len(eps) != k:
        raise ConfigError(
            f"n and eps: need one entry per level (k={k}); got n={tuple(n)}, eps={tuple(eps)}"
        )
    if any(int(v) != v or v < 1 for v in n):
        raise ConfigError(f"n: every entry must be an integer >= 1; got {tuple(n)}")
    if any(not v > 0 for v in eps):
        raise ConfigError(f"eps: every entry must be > 0; got {tuple(eps)}")


def check_counts(cfg, names: tuple[str, ...]) -> None:
    """Every named field (a count or size) is >= 1; one that is None is unset (a limit not asked for)."""
    for name in names:
        if getattr(cfg, name) is not None and getattr(cfg, name) < 1:
            raise ConfigError(f"{name}: must be >= 1; got {getattr(cfg, name)}")


def check_finite(cfg) -> None:
    """Every float field, and every float in a tuple field, is a finite number (an inf or NaN
    setting would only surface as a diverged run)."""
    for field in dataclasses.fields(cfg):
        value = getattr(cfg, field.name)
        if any(isinstance(v, float) and not math.isfinite(v) for v in (value if isinstance(value, tuple) else (value,))):
            raise ConfigError(f"{field.name}: must be a finite number; got {value}")


LOOP_BOUNDS = {"epochs": 10**7, "max_env_steps": 10**15, "seed": 2**63 - 1}
"""The largest value each of these config fields may take: far beyond any run (a million epochs
of the paper's Ant is years of GPU time), small enough that a typo (``--epochs 1e20``) or a
value JAX cannot hold (a seed of 2**64) is refused up front instead of running until killed
or failing deep inside JAX."""


def check_seed(seed: int) -> None:
    """A seed JAX can take: in [0, :data:`LOOP_BOUNDS` ``["seed"]``]."""
    most = LOOP_BOUNDS["seed"]
    if not 0 <= seed <= most:
        raise ConfigError(f"seed: must be in [0, {most:,}]; got {seed:,}")


def check_bounds(cfg) -> None:
    """Every field of :data:`LOOP_BOUNDS` the config has is within its bound (a seed also >= 0)."""
    for name, most in LOOP_BOUNDS.items():
        value = getattr(cfg, name, None)
        if value is None or isinstance(value, bool) or not isinstance(value, int):
            continue
        if name == "seed":
            check_seed(value)
        elif value > most:
            raise ConfigError(f"{name}: must be at most {most:,}; got {value:,}")


def check_capacity(cfg, name: str, least: dict[str, int]) -> None:
    """Buffer size ``name`` holds at least each of ``least`` (what -> rows): a minibatch, one
    collection; smaller, the buffer would be sampled before it could hold what it samples."""
    for what, rows in least.items():
        if getattr(cfg, name) < rows:
            raise ConfigError(f"{name}: must hold at least {what} ({rows} rows); got {getattr(cfg, name)}")


def check_shards(cfg, split_fields: tuple[str, ...]) -> None:
    """``shards`` >= 1 and each field that a shard takes its part of divisible by it."""
    if cfg.shards < 1:
        raise ConfigError(f"shards: must be >= 1; got {cfg.shards}")
    for name in split_fields:
        if getattr(cfg, name) % cfg.shards:
            raise ConfigError(f"{name}: must be a multiple of shards ({cfg.shards}); got {getattr(cfg, name)}")


def shard_config(cfg, split_fields: tuple[str, ...]):
    """One shard's config: each split field divided by ``shards``, and ``shards`` 1."""
    return dataclasses.replace(cfg, shards=1, **{name: getattr(cfg, name) // cfg.shards for name in split_fields})


def check_learning(cfg, learning_rates: tuple[str, ...], noises: tuple[str, ...]) -> None:
    """The actor-critic settings both phases share: hidden widths, rates, tau, gamma, noise stds."""
    if not cfg.hidden or any(w < 1 for w in cfg.hidden):
        raise ConfigError(f"hidden: give one or more widths >= 1; got {cfg.hidden}")
    for name in (*learning_rates, "tau"):
        if not 0 < getattr(cfg, name) <= 1:
            raise ConfigError(f"{name}: must be in (0, 1]; got {getattr(cfg, name)}")
    if not 0 <= cfg.gamma < 1:
        raise ConfigError(f"gamma: must be in [0, 1); got {cfg.gamma}")
    for name in noises:
        if getattr(cfg, name) < 0:
            raise ConfigError(f"{name}: must be >= 0; got {getattr(cfg, name)}")


LOOP_FIELDS = ("epochs", "max_env_steps")
"""Config fields only the epoch loop reads (when to stop): a resume may change them, and compiled
programs never see them."""


def compile_identity(cfg):
    """A config as far as compiled programs see it: every field but the :data:`LOOP_FIELDS`.
    Agents compare and hash by it, so a run resumed with a new epoch count or step budget (or
    one trained for another) reuses the programs already compiled in the process."""
    names = {f.name for f in dataclasses.fields(cfg)}
    return dataclasses.replace(cfg, **{name: None if name == "max_env_steps" else 0
                                       for name in LOOP_FIELDS if name in names})


def matches_type(value, annotation) -> bool:
    """Whether a JSON value fits a config field's annotation: ``int`` (not a bool, not 3.5),
    ``float`` (an int too), ``bool``, ``str``, ``tuple[X, ...]``, ``Literal[...]``, ``X | None``."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Literal:
        return value in args
    if origin in (typing.Union, types.UnionType):
        return any(matches_type(value, arg) for arg in args)
    if origin is tuple:
        element = args[0] if args else typing.Any
        return isinstance(value, (list, tuple)) and all(matches_type(v, element) for v in value)
    if annotation is type(None):
        return value is None
    if annotation is bool:
        return isinstance(value, bool)
    if annotation is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if annotation is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if annotation is str:
        return isinstance(value, str)
    return True  # any other annotation is the dataclass's own business


def config_from_dict(values: dict, config_type: type):
    """Rebuild a config dataclass from its JSON form (lists back to tuples); an unknown field, or
    a value of the wrong type (a fractional epoch count, a string where a number belongs), is a
    ConfigError naming the field."""
    fields = {f.name: f for f in dataclasses.fields(config_type)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ConfigError(f"{unknown[0]}: not a {config_type.__name__} field; allowed: {sorted(fields)}")
    hints = typing.get_type_hints(config_type)
    for name, value in values.items():
        if not matches_type(value, hints[name]):
            hint = hints[name]
            expected = str(hint).replace("typing.", "") if typing.get_origin(hint) else getattr(hint, "__name__", hint)
            raise ConfigError(f"{name}: must be {expected}; got {value!r}")
    return config_type(**{name: tuple(v) if isinstance(v, list) else v for name, v in values.items()})
