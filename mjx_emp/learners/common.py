"""What every actor-critic learner shares: the critic-then-actor step and a finiteness check."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax


def actor_critic_step(critic_loss, actor_loss, actor, critic, actor_opt, critic_opt, actor_tx, critic_tx):
    """One critic step, then one actor step through the updated critic; returns both losses.

    ``critic_loss(critic)`` and ``actor_loss(actor, critic)`` are the minibatch losses; the
    goal-conditioned (DPG) and goal-space (SVG) learners share this step.
    """
    c_loss, c_grad = jax.value_and_grad(critic_loss)(critic)
    c_updates, critic_opt = critic_tx.update(c_grad, critic_opt, critic)
    critic = optax.apply_updates(critic, c_updates)
    a_loss, a_grad = jax.value_and_grad(actor_loss)(actor, critic)
    a_updates, actor_opt = actor_tx.update(a_grad, actor_opt, actor)
    actor = optax.apply_updates(actor, a_updates)
    return actor, critic, actor_opt, critic_opt, jnp.stack([c_loss, a_loss])


@jax.jit
def all_finite(tree: Any) -> jax.Array:
    """Whether every floating-point array of ``tree`` (parameters, optimizer states) is finite."""
    leaves = [x for x in jax.tree.leaves(tree) if jnp.issubdtype(x.dtype, jnp.floating)]
    return jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]).all()
