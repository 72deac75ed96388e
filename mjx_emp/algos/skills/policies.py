"""How a flat skill learner acts: its SAC networks and the method's model network, the inputs
they take, skills drawn from the prior, episode starts and the exploring and greedy policies."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from mjx_emp.algos.skills import objectives as obj
from mjx_emp.algos.skills.state import (
    Params,
    SkillState,
    SkillTransition,
)
from mjx_emp.envs.env import EnvState
from mjx_emp.learners.sac import SAC


class SkillPolicies:
    """The network and policy methods of :class:`~mjx_emp.algos.skills.agent.SkillAgent` (``self`` is the agent)."""

    @functools.cached_property
    def sac(self) -> SAC:
        c = self.cfg
        return SAC(hidden=tuple(c.hidden), action_size=self.env.action_size, actor_lr=c.actor_lr,
                   critic_lr=c.critic_lr, alpha_lr=c.alpha_lr, init_alpha=c.init_alpha, tau=c.tau,
                   target_entropy=-c.target_entropy_scale * self.env.action_size, shard_axes=self.shard_axes)

    @property
    def descriptor_size(self) -> int:
        return self.env.feature_size + self.env.goal_size

    @functools.cached_property
    def model_net(self):
        """DIAYN/HIDIO: posterior q(z|...); DADS: mean of the descriptor's change; METRA: phi."""
        return self.skill_method.model_net(tuple(self.cfg.hidden), self.cfg.skill_dim, self.descriptor_size)

    def model_input(self, batch: SkillTransition) -> jax.Array:
        """What the model sees of a minibatch (at the state it judges)."""
        return self.skill_method.model_input(self.env, batch)

    def policy_input(self, obs: jax.Array, s0: jax.Array, skill: jax.Array) -> jax.Array:
        """pi's and Q's input: the state's descriptor and the skill."""
        return jnp.concatenate([obj.descriptor(self.env, obs, s0), skill], axis=-1)

    def sample_skill(self, key: jax.Array, shape: tuple[int, ...] = ()) -> jax.Array:
        """z from the prior: uniform on [-1, 1]^d, or for METRA a direction on the unit sphere."""
        return self.skill_method.sample_skill(key, shape, self.cfg.skill_dim)

    def start(self, _: Any, key: jax.Array) -> tuple[EnvState, jax.Array]:
        """A new episode: the initial state and a skill from the prior."""
        env_key, skill_key = jax.random.split(key)
        return self.env.reset(env_key), self.sample_skill(skill_key)

    def explore(self, actor: Params, obs, s0, skill, key) -> jax.Array:
        """The stochastic SAC policy (training collection)."""
        return self.sac.sample(actor, self.policy_input(obs, s0, skill), key)[0]

    def greedy(self, actor: Params, obs, s0, skill, key) -> jax.Array:
        """The deterministic policy tanh(mean) (evaluation)."""
        del key
        return self.sac.greedy(actor, self.policy_input(obs, s0, skill))

    def greedy_policy(self, state: SkillState) -> Callable[[jax.Array, jax.Array, jax.Array], jax.Array]:
        """The greedy skill-conditioned policy, (obs [B, obs], s0 [B, obs], skill [B, d]) -> action:
        ``s0`` is the observation where the skill began (its descriptor counts from there)."""
        actor = state.sac.actor
        return jax.vmap(lambda obs, s0, skill: self.greedy(actor, obs, s0, skill, None))
