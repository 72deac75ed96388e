"""Configuration checks shared by the library and the CLI.

Plain Python (no JAX import), so the CLI can reject bad input before compiling anything.
"""

from __future__ import annotations

from collections.abc import Sequence


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the field and what it allows."""


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
