"""Counting traces of jitted functions: a retrace means a recompile, which benchmarks and
tests must be able to see without JAX's private cache internals."""

from __future__ import annotations

import collections

_TRACES: collections.Counter[str] = collections.Counter()


def count_trace(name: str) -> None:
    """Record one trace of ``name``; call it in the body of a jitted function (it runs only
    while JAX traces, never in the compiled program)."""
    _TRACES[name] += 1


def traces(name: str) -> int:
    """How many times ``name`` has been traced in this process."""
    return _TRACES[name]
