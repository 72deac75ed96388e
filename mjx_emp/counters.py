"""Exact step counters on device without 64-bit integers.

JAX runs with 32-bit numbers by default: a float32 counter stops counting single steps
at 2^24 (16.8 M), an int32 one overflows at 2^31 (2.1 G), and a paper-scale run takes
billions of environment steps. :class:`StepCounter` keeps a count as two int32 digits
in base 2^24, exact up to 2^55.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

DIGIT_BITS = 24
_DIGIT = 1 << DIGIT_BITS


def digits(count: int) -> tuple[int, int]:
    """``(hi, lo)`` with ``count == hi * 2^24 + lo`` and 0 <= lo < 2^24, for 0 <= count < 2^55."""
    if not 0 <= count < 1 << (31 + DIGIT_BITS):
        raise ValueError(f"count must be in [0, 2^55); got {count}")
    return divmod(int(count), _DIGIT)


@struct.dataclass
class StepCounter:
    """A non-negative count ``hi * 2^24 + lo`` with 0 <= lo < 2^24 (both int32 arrays)."""

    hi: jax.Array
    lo: jax.Array

    @classmethod
    def zero(cls) -> StepCounter:
        return cls(hi=jnp.zeros((), jnp.int32), lo=jnp.zeros((), jnp.int32))

    @classmethod
    def of(cls, count: int) -> StepCounter:
        """The counter holding ``count`` (a host integer, 0 <= count < 2^55)."""
        hi, lo = digits(count)
        return cls(hi=jnp.asarray(hi, jnp.int32), lo=jnp.asarray(lo, jnp.int32))

    def add(self, steps: jax.Array) -> StepCounter:
        """This count plus ``steps`` (a non-negative int32 scalar), exactly; works under jit."""
        steps = jnp.asarray(steps, jnp.int32)
        lo = self.lo + (steps & (_DIGIT - 1))  # < 2^25: no overflow
        hi = self.hi + (steps >> DIGIT_BITS) + (lo >> DIGIT_BITS)
        return StepCounter(hi=hi, lo=lo & (_DIGIT - 1))

    def value(self) -> int:
        """The count as a Python integer (reads the device arrays)."""
        return int(self.hi) * _DIGIT + int(self.lo)
