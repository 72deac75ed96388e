"""The four flat skill learners as objects: what each one's model is, sees, learns and rewards.

:class:`~mjx_emp.algos.skills.agent.SkillAgent` is one agent for all four; everything in
which DIAYN, HIDIO, DADS and METRA differ is asked of their :class:`SkillMethod` here
(chosen by the config's type in :data:`METHODS`), never of a name. The formulas themselves
are the pure functions of :mod:`mjx_emp.algos.skills.objectives`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from mjx_emp.algos.skills import objectives as obj
from mjx_emp.algos.skills.config import (
    DadsConfig,
    DiaynConfig,
    HidioConfig,
    MetraConfig,
)
from mjx_emp.envs.env import Env
from mjx_emp.nets import MLP

Params = Any


@struct.dataclass
class ModelInfo:
    """What one model step reports; NaN where a method has no such figure."""

    loss: jax.Array
    posterior_std: jax.Array
    dual_lambda: jax.Array
    constraint: jax.Array

    @classmethod
    def nan(cls) -> ModelInfo:
        """Every figure NaN (an iteration that did not learn)."""
        return cls(*(jnp.float32(jnp.nan),) * 4)


@dataclasses.dataclass(frozen=True)
class ModelContext:
    """What a method's model step needs of its agent: the domain, the config, the model's
    network and optimiser, and the prior over skills."""

    env: Env
    cfg: Any
    net: Any
    tx: optax.GradientTransformation
    sample_skill: Callable[[jax.Array, tuple[int, ...]], jax.Array]


def fit_model(ctx: ModelContext, model, loss: Callable[[Params], jax.Array]):
    """One Adam step of the model on ``loss``: (updated model, the loss before the step)."""
    value, grad = jax.value_and_grad(loss)(model.params)
    updates, opt = ctx.tx.update(grad, model.opt, model.params)
    return model.replace(params=optax.apply_updates(model.params, updates), opt=opt), value


@dataclasses.dataclass(frozen=True)
class SkillMethod:
    """A flat skill learner's objective. Subclasses say what differs; the defaults are DIAYN's."""

    name: str
    reports: str | None = None
    """The method's own figure in the progress line (a metrics field), if any."""

    @property
    def has_posterior(self) -> bool:
        """Whether the model is a posterior q(z | ...) whose spread Levy et al. report."""
        return False

    def initial_dual(self, cfg) -> float:
        """The dual variable's first value: 1.0 (unused) for a method without a constraint."""
        del cfg
        return 1.0

    def model_net(self, hidden: tuple[int, ...], skill_dim: int, descriptor_size: int):
        """The model's network."""
        raise NotImplementedError

    def model_input(self, env: Env, batch) -> jax.Array:
        """What the model sees of a minibatch (at the state it judges)."""
        raise NotImplementedError

    def sample_skill(self, key: jax.Array, shape: tuple[int, ...], skill_dim: int) -> jax.Array:
        """z from the prior: uniform on [-1, 1]^d."""
        return jax.random.uniform(key, shape + (skill_dim,), minval=-1.0, maxval=1.0)

    def as_skill(self, unit: jax.Array) -> jax.Array:
        """A point of [-1, 1]^d (phase 2's action) as a skill of the prior's support: itself."""
        return unit

    def model_step(self, ctx: ModelContext, model, batch, key: jax.Array):
        """Train the model on ``batch``, then reward ``batch`` with the new model:
        (model, reward [B], :class:`ModelInfo`)."""
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class Posterior(SkillMethod):
    """DIAYN (q(z | s0, s')) and HIDIO (q(z | s0, a, s'), ``with_action``)."""

    with_action: bool = False
    reports: str | None = "posterior_std"

    @property
    def has_posterior(self) -> bool:
        return True

    def model_net(self, hidden, skill_dim, descriptor_size):
        return obj.GaussianHead(hidden, skill_dim)

    def model_input(self, env, batch):
        after = obj.descriptor(env, batch.next_obs, batch.s0)
        return jnp.concatenate([after, batch.action], axis=-1) if self.with_action else after

    def model_step(self, ctx, model, batch, key):
        del key
        x, nan = self.model_input(ctx.env, batch), jnp.float32(jnp.nan)

        def log_q(params):
            mean, log_std = ctx.net.apply(params, x)
            return obj.diagonal_gaussian_log_prob(batch.skill, mean, log_std), log_std

        model, value = fit_model(ctx, model, lambda params: -log_q(params)[0].mean())
        log_q_new, log_std = log_q(model.params)
        reward = obj.posterior_reward(log_q_new, ctx.cfg.skill_dim)
        return model, reward, ModelInfo(value, jnp.exp(log_std).mean(), nan, nan)


@dataclasses.dataclass(frozen=True)
class Dads(SkillMethod):
    """DADS: skill dynamics q(s' | s, z) over the descriptor's change."""

    def model_net(self, hidden, skill_dim, descriptor_size):
        return MLP(hidden, descriptor_size)

    def model_input(self, env, batch):
        return jnp.concatenate([obj.descriptor(env, batch.obs, batch.s0), batch.skill], axis=-1)

    def model_step(self, ctx, model, batch, key):
        x, d, nan = self.model_input(ctx.env, batch), ctx.cfg.skill_dim, jnp.float32(jnp.nan)
        change = obj.descriptor(ctx.env, batch.next_obs, batch.s0) - obj.descriptor(ctx.env, batch.obs, batch.s0)
        model, value = fit_model(
            ctx, model, lambda params: -obj.unit_gaussian_log_prob(change, ctx.net.apply(params, x)).mean())
        prior = ctx.sample_skill(key, (ctx.cfg.prior_samples, batch.skill.shape[0]))
        state_part = x[..., : -d]

        def log_q_with(skill):
            mean = ctx.net.apply(model.params, jnp.concatenate([state_part, skill], axis=-1))
            return obj.unit_gaussian_log_prob(change, mean)

        reward = obj.dads_reward(log_q_with(batch.skill), jax.vmap(log_q_with)(prior))
        return model, reward, ModelInfo(value, nan, nan, nan)


@dataclasses.dataclass(frozen=True)
class Metra(SkillMethod):
    """METRA: phi with ||phi(s') - phi(s)|| <= 1 by dual gradient descent; z on the unit sphere."""

    reports: str | None = "dual_lambda"

    def initial_dual(self, cfg) -> float:
        """lambda of the constraint ||phi(s') - phi(s)|| <= 1 starts at the config's ``dual_lam``."""
        return cfg.dual_lam

    def model_net(self, hidden, skill_dim, descriptor_size):
        return MLP(hidden, skill_dim)

    def model_input(self, env, batch):
        return obj.descriptor(env, batch.obs, batch.s0)

    def sample_skill(self, key, shape, skill_dim):
        """z from the prior: a direction uniform on the unit sphere."""
        z = jax.random.normal(key, shape + (skill_dim,))
        return z / jnp.linalg.norm(z, axis=-1, keepdims=True)

    def as_skill(self, unit):
        """The direction of ``unit``: METRA's skills are unit vectors."""
        return unit / jnp.maximum(jnp.linalg.norm(unit, axis=-1, keepdims=True), 1e-6)

    def model_step(self, ctx, model, batch, key):
        del key
        phi_inputs = (self.model_input(ctx.env, batch), obj.descriptor(ctx.env, batch.next_obs, batch.s0))

        def loss(params):
            phi_obs, phi_next = (ctx.net.apply(params, y) for y in phi_inputs)
            return obj.metra_phi_loss(phi_obs, phi_next, batch.skill, jnp.exp(model.log_lam), ctx.cfg.dual_slack)

        model, value = fit_model(ctx, model, loss)
        phi_obs, phi_next = (ctx.net.apply(model.params, y) for y in phi_inputs)
        constraint = obj.metra_constraint(phi_obs, phi_next, ctx.cfg.dual_slack)
        _, lam_grad = jax.value_and_grad(obj.metra_dual_loss)(model.log_lam, constraint)
        lam_updates, lam_opt = ctx.tx.update(lam_grad, model.lam_opt, model.log_lam)
        model = model.replace(log_lam=optax.apply_updates(model.log_lam, lam_updates), lam_opt=lam_opt)
        reward = obj.metra_reward(phi_obs, phi_next, batch.skill)
        return model, reward, ModelInfo(value, jnp.float32(jnp.nan), jnp.exp(model.log_lam), constraint.mean())


METHODS: dict[type, SkillMethod] = {
    DiaynConfig: Posterior("diayn"),
    HidioConfig: Posterior("hidio", with_action=True),
    DadsConfig: Dads("dads"),
    MetraConfig: Metra("metra"),
}
"""The method of each flat skill learner's config type."""
