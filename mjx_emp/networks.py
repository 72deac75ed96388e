"""Neural networks for the goal-conditioned policies.

A deterministic goal-conditioned policy maps (observation, goal) through an MLP and a
tanh, then scales and shifts the result into its action box: the primitive action
bounds at level 0, the child's goal-space box (half-widths and shift) above it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from mjx_emp.envs import Env
from mjx_emp.hierarchy import LevelPolicy, Params


class MLP(nn.Module):
    """Plain ReLU MLP with a linear output layer."""

    hidden: Sequence[int]
    out: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden:
            x = nn.relu(nn.Dense(width)(x))
        return nn.Dense(self.out)(x)


def goal_policy(
    obs_size: int,
    goal_size: int,
    action_size: int,
    hidden: Sequence[int] = (256, 256),
    half_width: float | jax.Array = 1.0,
    shift: float | jax.Array = 0.0,
) -> tuple[LevelPolicy, Callable[[jax.Array], Params]]:
    """A fixed-box deterministic goal-conditioned policy and its initialiser.

    Returns ``(policy, init)`` with ``policy(params, obs, goal, key) -> action`` in
    ``shift ± half_width`` and ``init(key) -> params``. The goal enters as its offset
    from nothing in particular: the MLP sees (obs, goal) and learns the relation.
    """
    net = MLP(tuple(hidden), action_size)

    def policy(params: Params, obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
        del key  # deterministic
        raw = net.apply(params, jnp.concatenate([obs, goal], axis=-1))
        return jnp.tanh(raw) * half_width + shift

    def init(key: jax.Array) -> Params:
        return net.init(key, jnp.zeros(obs_size + goal_size))

    return policy, init


def mlp_agent(
    env: Env,
    k: int,
    hidden: Sequence[int],
    subgoal_half_widths: Sequence[float],
    key: jax.Array,
) -> tuple[tuple[LevelPolicy, ...], tuple[Params, ...]]:
    """Random-init MLP policies for a k-level agent and their params.

    Level 0 outputs primitive actions in [-1, 1]; level i > 0 outputs subgoals in a box of
    half-width ``subgoal_half_widths[i - 1]`` around h(s). Params of level i come from
    ``fold_in(key, i)``.
    """
    policies, params = [], []
    for level in range(k):
        out = env.action_size if level == 0 else env.goal_size
        width = 1.0 if level == 0 else subgoal_half_widths[level - 1]
        policy, init = goal_policy(env.obs_size, env.goal_size, out, hidden, half_width=width)
        policies.append(policy)
        params.append(init(jax.random.fold_in(key, level)))
    return tuple(policies), tuple(params)
