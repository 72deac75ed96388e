"""Hierarchical Empowerment's networks: per level a goal-conditioned actor and critic, and a
goal-space actor and critic, as functions of the config and the domain.

Plain network definitions and their forward passes, no state: :class:`HENetworks` is what
the agent (:mod:`mjx_emp.algos.he.agent`), the losses and phase 2 evaluate parameters with.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp

from mjx_emp import gce
from mjx_emp.algos.he.config import GcrlConfig, HEConfig
from mjx_emp.envs.env import Env
from mjx_emp.nets import MLP, GoalSpaceActor, goal_conditioned_q

Params = Any


@dataclasses.dataclass(frozen=True)
class HENetworks:
    """The networks of one HE (or GCRL) config on its domain."""

    cfg: HEConfig
    env: Env = dataclasses.field(compare=False, repr=False)

    def action_size(self, level: int) -> int:
        """Primitive action size at level 0, goal-space size above."""
        return self.env.action_size if level == 0 else self.env.goal_size

    def actor_net(self, level: int) -> MLP:
        return MLP(tuple(self.cfg.hidden), self.action_size(level), layer_norm=self.cfg.actor_layer_norm)

    @functools.cached_property
    def critic_net(self) -> MLP:
        """The goal-space critics' network."""
        return MLP(tuple(self.cfg.hidden), 1)

    @functools.cached_property
    def gc_critic_net(self) -> MLP:
        """The goal-conditioned critics' network."""
        return MLP(tuple(self.cfg.hidden), 1, layer_norm=self.cfg.critic_layer_norm)

    def gs_actor_net(self, level: int) -> GoalSpaceActor:
        c = self.cfg
        return GoalSpaceActor(tuple(c.hidden), self.env.goal_size, c.init_half_width[level], c.max_half_width[level])

    def goal_space_action(self, level: int, params: Params, obs: jax.Array) -> jax.Array:
        """mu_level(s0): the (shift, log half-width) of the level's goal space at ``obs``
        (for GCRL the fixed box, whatever the params)."""
        if isinstance(self.cfg, GcrlConfig):
            d = self.env.goal_size
            fixed = jnp.concatenate([jnp.zeros(d), jnp.full(d, math.log(self.cfg.goal_half_width[level]))])
            return jnp.broadcast_to(fixed, obs.shape[:-1] + (2 * d,))
        return self.gs_actor_net(level).apply(params, self.env.features(obs))

    def learned_box(self, level: int):
        """The (params, obs) -> (shift, half_width) box of ``level``'s goal space, absolute widths."""

        def box(params: Params, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
            shift, log_half_width = gce.split_goal_space_action(self.goal_space_action(level, params, obs))
            return shift, jnp.exp(log_half_width)

        return box

    def q_value(self, params: Params, obs: jax.Array, goal: jax.Array, action: jax.Array) -> jax.Array:
        """Q(s, z, a) of a level's goal-conditioned critic; [critics, ...] with several critics."""
        if self.cfg.critics == 1:
            return goal_conditioned_q(self.gc_critic_net, self.env, params, obs, goal, action)
        return jax.vmap(lambda p: goal_conditioned_q(self.gc_critic_net, self.env, p, obs, goal, action))(params)

    def gs_value(self, params: Params, obs: jax.Array, noise: jax.Array, action: jax.Array) -> jax.Array:
        """R(s0, noise, a) of a goal-space critic."""
        x = jnp.concatenate([self.env.features(obs), noise, action], axis=-1)
        return self.critic_net.apply(params, x)[..., 0]
