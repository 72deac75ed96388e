"""The flat skill rollout: one ``lax.scan`` over primitive steps of skill-conditioned policies.

Every environment pursues one skill z for ``n`` primitive actions, then starts a new
episode (a fresh start state and skill) in the same step, so no physics step idles. An
environment reset by the physics (non-finite state, an Ant on its back) ends its episode
early; that step is marked ``cut`` and is not a valid transition. This is the rollout of
the flat skill learners (DIAYN, HIDIO, DADS, METRA); Hierarchical Empowerment's levels
use :mod:`mjx_emp.rollout.hierarchy`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from mjx_emp.envs.env import Env, EnvState, tree_where
from mjx_emp.errors import ConfigError
from mjx_emp.tracing import count_trace

FLAT_ROLLOUT_TRACE = "flat_rollout"
"""Name under which :mod:`mjx_emp.tracing` counts traces of :func:`flat_rollout`."""
Params = Any
# (params, obs, s0, skill, key) -> primitive action in [-1, 1]^nu, for ONE environment
# (s0: the observation its episode began in).
SkillPolicy = Callable[[Params, jax.Array, jax.Array, jax.Array, jax.Array], jax.Array]
# (start_params, key) -> (env state, skill), for ONE environment: a new episode.
SkillStart = Callable[[Any, jax.Array], tuple[EnvState, jax.Array]]


@struct.dataclass
class FlatState:
    """Batched environments, each with its skill, the observation its episode began in
    (s0), how many actions it has taken in the episode, and how many episodes it finished."""

    env: EnvState
    skill: jax.Array
    s0: jax.Array
    count: jax.Array
    episodes_done: jax.Array
    key: jax.Array


@struct.dataclass
class SkillStep:
    """One primitive step per environment, stacked as [T, B, ...].

    ``valid``: a real transition (obs, action) -> next_obs under ``skill`` (False on the step
    a physics reset replaced the state). ``last``: this step ended the episode, by its
    n-th action (``valid``) or by a reset (``cut``).
    """

    s0: jax.Array
    obs: jax.Array
    skill: jax.Array
    action: jax.Array
    next_obs: jax.Array
    valid: jax.Array
    last: jax.Array
    cut: jax.Array


def flat_init(env: Env, start: SkillStart, start_params: Any, key: jax.Array, batch_size: int) -> FlatState:
    """``batch_size`` fresh episodes from ``start``."""
    key, start_key = jax.random.split(key)
    env_state, skill = jax.vmap(start, in_axes=(None, 0))(start_params, jax.random.split(start_key, batch_size))
    zeros = jnp.zeros(batch_size, jnp.int32)
    return FlatState(env=env_state, skill=skill, s0=jax.vmap(env.observe)(env_state), count=zeros,
                     episodes_done=zeros, key=key)


def _step(env: Env, policy: SkillPolicy, params: Params, start: SkillStart, start_params: Any, n: int,
          state: FlatState, _) -> tuple[FlatState, SkillStep]:
    """Act, simulate, and restart every environment whose episode just ended."""
    batch = state.count.shape[0]
    key, act_key, start_key = jax.random.split(state.key, 3)
    obs = jax.vmap(env.observe)(state.env)
    action = jax.vmap(policy, in_axes=(None, 0, 0, 0, 0))(params, obs, state.s0, state.skill,
                                                          jax.random.split(act_key, batch))
    env_state = jax.vmap(env.step)(state.env, action)
    broke = env_state.resets > state.env.resets
    count = state.count + 1
    last = broke | (count >= n)
    step = SkillStep(s0=state.s0, obs=obs, skill=state.skill, action=action,
                     next_obs=jax.vmap(env.observe)(env_state), valid=~broke, last=last, cut=broke)

    fresh, fresh_skill = jax.vmap(start, in_axes=(None, 0))(start_params, jax.random.split(start_key, batch))
    fresh = fresh.replace(nan_resets=env_state.nan_resets, flip_resets=env_state.flip_resets)
    env_state = tree_where(last, fresh, env_state)
    new_state = FlatState(
        env=env_state,
        skill=jnp.where(last[:, None], fresh_skill, state.skill),
        s0=jnp.where(last[:, None], jax.vmap(env.observe)(fresh), state.s0),
        count=jnp.where(last, 0, count),
        episodes_done=state.episodes_done + last.astype(jnp.int32),
        key=key,
    )
    return new_state, step


def flat_rollout(env: Env, policy: SkillPolicy, params: Params, start: SkillStart, start_params: Any,
                 state: FlatState, num_steps: int, n: int) -> tuple[FlatState, SkillStep]:
    """Advance every environment ``num_steps`` primitive actions, episodes of ``n`` actions.

    Jit with ``env``, ``policy``, ``start``, ``num_steps`` and ``n`` static.
    """
    count_trace(FLAT_ROLLOUT_TRACE)
    if n < 1:
        raise ConfigError(f"n: a skill needs at least one action; got {n}")
    return jax.lax.scan(lambda s, x: _step(env, policy, params, start, start_params, n, s, x),
                        state, None, length=num_steps)
