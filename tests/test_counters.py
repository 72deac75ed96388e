"""Step counters stay exact where float32 and int32 counters fail."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_emp.counters import StepCounter


def test_counts_exactly_past_float32_and_int32_limits():
    add = jax.jit(StepCounter.add)
    counter = StepCounter.of(2**24 - 3)
    counter = add(counter, jnp.int32(5))
    assert counter.value() == 2**24 + 2  # float32 would have rounded this to 2**24 + 2 or lost the 1s
    assert float(np.float32(2**24) + np.float32(1)) == 2**24  # the failure being avoided
    big = StepCounter.of(2**31 - 1)
    for _ in range(3):
        big = add(big, jnp.int32(2**31 - 1))
    assert big.value() == 4 * (2**31 - 1)
    assert 0 <= int(big.lo) < 2**24


def test_adds_under_a_scan_match_python_integers():
    increments = jnp.asarray(np.random.default_rng(0).integers(0, 2**30, size=200), jnp.int32)
    total, _ = jax.lax.scan(lambda c, n: (c.add(n), None), StepCounter.zero(), increments)
    assert total.value() == int(np.asarray(increments, np.int64).sum())


def test_rejects_counts_it_cannot_hold():
    with pytest.raises(ValueError, match="count must be in"):
        StepCounter.of(-1)
    with pytest.raises(ValueError, match="count must be in"):
        StepCounter.of(2**55)
