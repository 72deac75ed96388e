"""Neural networks of a Hierarchical Empowerment agent.

Per level there is a deterministic goal-conditioned actor pi(s, z) with its critic
Q(s, z, a), and a goal-space actor mu(s0) with its critic R(s0, noise, a). Following
the paper's architecture figure, a goal-conditioned actor squashes its output with a
tanh, then scales and shifts it into its action box: the primitive bounds [-1, 1] at
level 0, the child's goal-space box mu_{i-1}(s) (half-widths and shift, relative to
h(s)) above it. Goals enter every network as the offset goal - h(s), so what a skill
does is expressed where it is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from mjx_emp.envs.env import Env
from mjx_emp.rollout.structures import LevelPolicy, Params

# (box_params, obs) -> (shift, half_width): the box a level's actions are squashed into.
BoxFn = Callable[[Any, jax.Array], tuple[jax.Array, jax.Array]]


class MLP(nn.Module):
    """ReLU MLP with a linear output layer; ``out_scale`` shrinks the output layer's init.

    With ``layer_norm`` every hidden layer is normalised before its ReLU (Ball et al.
    2023), which bounds the features a critic extrapolates from and keeps its values
    from running away under many gradient steps per transition.
    """

    hidden: Sequence[int]
    out: int
    out_scale: float = 1.0
    layer_norm: bool = False

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden:
            x = nn.Dense(width)(x)
            if self.layer_norm:
                x = nn.LayerNorm()(x)
            x = nn.relu(x)
        init = nn.initializers.variance_scaling(self.out_scale, "fan_avg", "uniform")
        return nn.Dense(self.out, kernel_init=init)(x)


@struct.dataclass
class LevelParams:
    """What a level policy reads at run time: its actor, its action box, its noise.

    ``box`` is the child level's goal-space actor params (or a fixed box, or None at
    level 0); ``noise`` is the exploration std in units of the box half-width.
    """

    actor: Params
    box: Any
    noise: jax.Array


def goal_features(env: Env, obs: jax.Array, goal: jax.Array) -> jax.Array:
    """Network input for (state, goal): the state's features and the offset goal - h(s)."""
    return jnp.concatenate([env.features(obs), env.goal_offset(obs, goal)], axis=-1)


def primitive_box(_: Any, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Level 0's action box: the primitive bounds [-1, 1]."""
    del obs
    return jnp.zeros(()), jnp.ones(())


def fixed_box(box: jax.Array, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """A state-independent box given as (shift, half_width) stacked in ``box`` [2, d]."""
    del obs
    return box[0], box[1]


AIM_EDGE = 0.95
"""How far toward its box's edge an aim prior places a subgoal (in half-widths), so the tanh
around it keeps a gradient."""


def level_policy(env: Env, actor: MLP, box_fn: BoxFn, aim_prior: bool = False) -> LevelPolicy:
    """A deterministic goal-conditioned policy (plus optional Gaussian exploration).

    action = clip(tanh(f(s, z) + prior) + noise * N(0, 1), -1, 1) * half_width + shift, with
    (shift, half_width) = box_fn(params.box, s). With ``noise`` = 0 and no prior it is the
    paper's pi_theta; the clip keeps noisy actions inside the box. With ``aim_prior`` the
    prior is the pre-tanh value of the aimed subgoal (see :func:`aimed_policy`, kept within
    ``AIM_EDGE`` of the box's edge), so a network whose output starts near zero starts as the
    scripted policy and learns a correction to it.
    """

    def policy(params: LevelParams, obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
        shift, half_width = box_fn(params.box, obs)
        logit = actor.apply(params.actor, goal_features(env, obs, goal))
        if aim_prior:
            aimed = jnp.clip((env.goal_offset(obs, goal) - shift) / half_width, -AIM_EDGE, AIM_EDGE)
            logit = logit + jnp.arctanh(aimed)
        unit = jnp.tanh(logit)
        unit = unit + params.noise * jax.random.normal(key, unit.shape, unit.dtype)
        return jnp.clip(unit, -1.0, 1.0) * half_width + shift

    return policy


def central_box(box_fn: BoxFn, reach: float) -> BoxFn:
    """``box_fn``'s box shrunk about its centre: the same shift, half-widths times ``reach``
    (1: the box itself). Subgoals in it are shorter, away from the edge, where skills miss
    and flip most."""
    if reach == 1.0:
        return box_fn

    def box(params: Any, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        shift, half_width = box_fn(params, obs)
        return shift, reach * half_width

    return box


def aimed_policy(env: Env, box_fn: BoxFn) -> LevelPolicy:
    """A scripted policy that aims every subgoal straight at its goal: clip(goal - h(s), the box
    at s). Put on top of frozen skills, it bounds what they can do on a goal-reaching task
    without any learning above them (the chaining diagnostic)."""

    def policy(params: LevelParams, obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
        del key
        shift, half_width = box_fn(params.box, obs)
        return jnp.clip(env.goal_offset(obs, goal), shift - half_width, shift + half_width)

    return policy


def random_policy(box_fn: BoxFn) -> LevelPolicy:
    """Subgoals uniform in the box at s, whatever the goal: what chance alone reaches."""

    def policy(params: LevelParams, obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
        shift, half_width = box_fn(params.box, obs)
        return shift + half_width * jax.random.uniform(key, jnp.shape(goal), minval=-1.0, maxval=1.0)

    return policy


def scripted_policy(branches: Sequence[LevelPolicy]) -> LevelPolicy:
    """One of several scripted policies, picked at run time: ``params.actor`` is the index of
    the branch to follow (a scripted policy has no network, so its actor slot is free). The
    branches then share one compiled rollout instead of one program each."""

    def policy(params: LevelParams, obs: jax.Array, goal: jax.Array, key: jax.Array) -> jax.Array:
        return jax.lax.switch(params.actor, branches, params, obs, goal, key)

    return policy


def greedy_batch(policy: LevelPolicy, actor: Params, box: Any) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """``policy`` without exploration noise over a batch of (obs, goal), in the action box ``box``."""
    params = LevelParams(actor=actor, box=box, noise=jnp.zeros(()))
    dummy = jax.random.key(0)
    return lambda obs, goal: jax.vmap(policy, (None, 0, 0, None))(params, obs, goal, dummy)


def goal_conditioned_q(critic: MLP, env: Env, params: Params, obs: jax.Array, goal: jax.Array,
                       action: jax.Array) -> jax.Array:
    """Q(s, z, a) of a goal-conditioned critic network."""
    x = jnp.concatenate([goal_features(env, obs, goal), action], axis=-1)
    return critic.apply(params, x)[..., 0]


class GoalSpaceActor(nn.Module):
    """mu(s0) -> goal-space action (shift, log half-width) per goal dimension.

    The output layer starts near zero, so every level begins with a box of
    ``init_half_width`` centred on h(s0); log half-widths keep the entropy reward
    linear in the box size (the paper's appendix). Both halves are softly bounded by
    ``max_half_width`` (|shift| and half-width): well inside the bound the output is the
    raw network's, near it the gradient fades, so a critic that extrapolates at a rare
    start state cannot send goals to infinity.
    """

    hidden: Sequence[int]
    goal_size: int
    init_half_width: float
    max_half_width: float

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        raw = MLP(tuple(self.hidden), 2 * self.goal_size, out_scale=1e-4)(obs)
        shift, log_half_width = raw[..., : self.goal_size], raw[..., self.goal_size :]
        shift = self.max_half_width * jnp.tanh(shift / self.max_half_width)
        # log_hw = log_max - softplus(c - raw), with c chosen so that raw = 0 gives init_half_width.
        log_max = math.log(self.max_half_width)
        c = math.log(math.expm1(log_max - math.log(self.init_half_width)))
        log_half_width = log_max - jax.nn.softplus(c - log_half_width)
        return jnp.concatenate([shift, log_half_width], axis=-1)


def mlp_agent(
    env: Env,
    k: int,
    hidden: Sequence[int],
    subgoal_half_widths: Sequence[float],
    key: jax.Array,
) -> tuple[tuple[LevelPolicy, ...], tuple[LevelParams, ...]]:
    """Random-init MLP policies for a k-level agent with fixed subgoal boxes, and their params.

    Level 0 outputs primitive actions in [-1, 1]; level i > 0 outputs subgoals in a box of
    half-width ``subgoal_half_widths[i - 1]`` around h(s). Used to exercise and benchmark
    the rollout without training. Params of level i come from ``fold_in(key, i)``.
    """
    policies, params = [], []
    for level in range(k):
        out = env.action_size if level == 0 else env.goal_size
        net = MLP(tuple(hidden), out)
        if level == 0:
            policies.append(level_policy(env, net, primitive_box))
            box = None
        else:
            policies.append(level_policy(env, net, fixed_box))
            half_width = jnp.full(env.goal_size, subgoal_half_widths[level - 1])
            box = jnp.stack([jnp.zeros(env.goal_size), half_width])
        actor = net.init(jax.random.fold_in(key, level), jnp.zeros(env.feature_size + env.goal_size))
        params.append(LevelParams(actor=actor, box=box, noise=jnp.zeros(())))
    return tuple(policies), tuple(params)
