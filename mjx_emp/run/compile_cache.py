"""JAX's persistent compilation cache for a command's process, set in the environment before
JAX is imported (plain Python): a re-run, resume or second seed of a config loads its compiled
programs instead of compiling them again."""

from __future__ import annotations

import os
from pathlib import Path

NO_COMPILE_CACHE = "--no-compile-cache"


def default_compile_cache() -> Path:
    """Where compiled programs are kept between runs: $XDG_CACHE_HOME/mjx-emp/xla (~/.cache/...)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mjx-emp" / "xla"


def use_compile_cache(argv: list[str]) -> list[str]:
    """Turn on JAX's persistent compilation cache for this process (before JAX is imported) and
    return ``argv`` without the ``--no-compile-cache`` flag that turns it off.

    A re-run, resume or second seed of the same config then loads its compiled epoch instead
    of compiling it again; what it computes is unchanged. A ``JAX_COMPILATION_CACHE_DIR``
    set by the user wins; programs that compile in under a second are not stored.
    """
    if NO_COMPILE_CACHE in argv:
        return [arg for arg in argv if arg != NO_COMPILE_CACHE]
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(default_compile_cache()))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")
    return argv
