"""What a flat skill learner reports of its skills: their paths and recordings, the posterior's
spread, an epoch's metrics line, its divergence check and its one-line summary."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mjx_emp.algos.skills.state import (
    IterationStats,
    SkillState,
)
from mjx_emp.learners.common import all_finite
from mjx_emp.metrics import epoch_header
from mjx_emp.replay import (
    replay_sample,
)
from mjx_emp.rollout.flat import flat_init, flat_rollout


class SkillEvaluation:
    """The evaluation and reporting methods of :class:`~mjx_emp.algos.skills.agent.SkillAgent` (``self`` is the agent)."""

    def skill_paths(self, state: SkillState, key: jax.Array, skills: int = 48) -> tuple[np.ndarray, np.ndarray]:
        """h(s) along ``skills`` greedy skills from the prior, each from the initial state.

        Returns positions [n + 1, skills, d] (the start, then every action) and a mask that
        is False after a reset cut a skill short (METRA's coverage count reads these).
        """
        positions, mask = _jit_skill_paths(self, state, key, skills)
        return np.asarray(positions), np.asarray(mask)

    def _skill_paths(self, state: SkillState, key: jax.Array, skills: int):
        rollout = flat_init(self.env, self.start, None, key, skills)
        _, steps = flat_rollout(self.env, self.greedy, state.sac.actor, self.start, None, rollout,
                                self.cfg.n, self.cfg.n)
        alive = jnp.cumsum(steps.cut, axis=0) == 0
        start = self.env.goal_of_obs(jnp.asarray(self.initial_obs))
        positions = jnp.concatenate([jnp.broadcast_to(start, (1, skills, start.shape[-1])),
                                     self.env.goal_of_obs(steps.next_obs)])
        return positions, jnp.concatenate([jnp.ones((1, skills), bool), alive])

    def record_skills(self, state: SkillState, key: jax.Array, steps: int) -> tuple[np.ndarray, np.ndarray]:
        """One environment running greedy skills from the prior, one after another, each from
        a fresh start state: its joint positions [steps, nq] and mocap bodies [steps, nmocap, 3]
        after every primitive step (what ``mjx-emp render`` draws), in one jitted scan."""
        qpos, mocap = _jit_record_skills(self, state, key, steps)
        return np.asarray(qpos), np.asarray(mocap)

    def _record_skills(self, state: SkillState, key: jax.Array, steps: int):
        def one_step(rollout, _):
            rollout, _ = flat_rollout(self.env, self.greedy, state.sac.actor, self.start, None, rollout, 1, self.cfg.n)
            return rollout, (rollout.env.data.qpos[0], rollout.env.data.mocap_pos[0])

        _, (qpos, mocap) = jax.lax.scan(one_step, flat_init(self.env, self.start, None, key, 1), None, length=steps)
        return qpos, mocap

    def posterior_std(self, state: SkillState, key: jax.Array, rows: int = 4096) -> float | None:
        """DIAYN and HIDIO: the mean standard deviation of q(z | ...) over ``rows`` replayed
        transitions (Levy et al.'s diagnostic: it stays large when skills overlap); None for
        the other methods or an empty replay."""
        if not self.skill_method.has_posterior or int(state.replay.size) == 0:
            return None
        batch = replay_sample(state.replay, key, rows)
        _, log_std = self.model_net.apply(state.model.params, self.model_input(batch))
        return float(jnp.exp(log_std).mean())

    def metrics(self, state: SkillState, stats: IterationStats, seconds: float) -> dict[str, Any]:
        """One JSON-ready line of per-epoch metrics."""
        s = jax.tree.map(np.asarray, stats)

        def mean(values) -> float | None:
            values = np.asarray(values)[np.isfinite(values)]
            return float(values.mean()) if values.size else None

        header = epoch_header(state, float(s.env_steps.sum()), seconds)
        return {
            **header, "algorithm": self.method, "learned_iterations": int(s.learned.sum()),
            "critic_loss": mean(s.sac.critic_loss), "actor_loss": mean(s.sac.actor_loss), "alpha": mean(s.sac.alpha),
            "entropy": mean(s.sac.entropy), "model_loss": mean(s.model_loss), "reward": mean(s.reward),
            "posterior_std": mean(s.posterior_std), "dual_lambda": mean(s.dual_lambda),
            "constraint": mean(s.constraint), "episodes": int(s.episodes.sum()),
            "displacement": mean(np.where(s.episodes > 0, s.displacement, np.nan)),
            "flip_resets": int(s.flip_resets.sum()),
        }

    def divergence(self, state: SkillState, stats: IterationStats) -> str | None:
        """Why this epoch must not be kept (a non-finite loss or parameter), or None."""
        s = jax.tree.map(np.asarray, stats)
        learned = s.learned.astype(bool)
        for name, values in (("critic loss", s.sac.critic_loss), ("actor loss", s.sac.actor_loss),
                             ("model loss", s.model_loss)):
            if not np.isfinite(values[learned]).all():
                return f"the {self.method} {name} is not finite"
        if not bool(all_finite((state.sac, state.model))):
            return "a network parameter or optimizer state is not finite"
        return None

    def describe(self, metrics: dict) -> str:
        """A short human-readable summary of an epoch's metrics."""
        def show(name):
            value = metrics[name]
            return "-" if value is None else f"{value:.3g}"

        extra = self.skill_method.reports
        tail = f"  {extra.replace('_', ' ')} {show(extra)}" if extra else ""
        return (f"{metrics['env_steps']:.3g} env steps  {metrics['env_steps_per_s']:.3g} steps/s  "
                f"reward {show('reward')}  displacement {show('displacement')}  alpha {show('alpha')}{tail}")


_jit_skill_paths = jax.jit(SkillEvaluation._skill_paths, static_argnums=(0, 3))
_jit_record_skills = jax.jit(SkillEvaluation._record_skills, static_argnums=(0, 3))
