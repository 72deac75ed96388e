"""What phase 1 reports of its skills: greedy success on each level's own goal space, the skills'
paths, the goal spaces and where their boxes are used, an epoch's metrics line, its divergence
check and its one-line summary."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mjx_emp import gce
from mjx_emp.algos.he.state import (
    EVAL_STARTS,
    MODE_EVAL,
    MODE_GC,
    MODE_GS,
    HEState,
    ItemStats,
    start_subset,
)
from mjx_emp.learners.common import all_finite
from mjx_emp.metrics import epoch_header
from mjx_emp.replay import (
    replay_init,
    replay_insert,
    replay_sample,
)
from mjx_emp.rollout.hierarchy import (
    init_rollout,
    rollout,
)


class HEEvaluation:
    """The evaluation and reporting methods of :class:`~mjx_emp.algos.he.agent.HEAgent` (``self`` is the agent)."""

    def evaluate(self, state: HEState, level: int, key: jax.Array, rounds: int = 4,
                 starts: str = "buffer") -> dict[str, float]:
        """Greedy skills at ``level`` on goals drawn from its own (noise-free) goal space at their start.

        ``rounds`` x num_envs episodes start from the states ``starts`` names (see
        :data:`EVAL_STARTS`: the level's start buffer, only the initial state, or only the
        buffer's states that chaining reached); returns the fraction that ended within eps
        of their goal, the mean final distance, and the fraction a reset cut short (for
        the Ant: it flipped).
        """
        if starts not in EVAL_STARTS:
            raise ValueError(f"starts: {starts!r} is unknown; allowed values: {list(EVAL_STARTS)}")
        which = jnp.int32(EVAL_STARTS.index(starts))
        reached, distance, cut = _jit_evaluate(self, state, jnp.int32(level), key, rounds, which)
        return {"success": float(reached), "final_distance": float(distance), "cut_short": float(cut)}

    def _evaluate(self, state: HEState, level: jax.Array, key: jax.Array, rounds: int, starts: jax.Array):
        initial = jnp.asarray(self.initial_obs)
        state = state.replace(starts=tuple(start_subset(buffer, initial, starts) for buffer in state.starts))

        def one(_, round_key):
            _, totals = self._collect(state, level, jnp.int32(MODE_EVAL), round_key)
            return None, (totals.success(), totals.mean_distance(), totals.cut_fraction())

        _, (reached, distance, cut) = jax.lax.scan(one, None, jax.random.split(key, rounds))
        return reached.mean(), distance.mean(), cut.mean()

    def skill_paths(self, state: HEState, key: jax.Array, skills: int = 48) -> tuple[np.ndarray, np.ndarray]:
        """h(s) along ``skills`` greedy top-level skills from the initial state.

        Each skill's goal is drawn from the top goal space at the initial state (no noise)
        and pursued greedily by every level. Returns positions [T + 1, skills, d] (the
        start, then every primitive step) and a mask [T + 1, skills] that is True up to and
        including the step that ended each skill (its first root episode; steps of later
        episodes and a flip reset's aftermath are masked out). METRA's coverage count and
        the robots benchmark read these paths.
        """
        positions, mask = _jit_skill_paths(self, state, key, skills)
        return np.asarray(positions), np.asarray(mask)

    def _skill_paths(self, state: HEState, key: jax.Array, skills: int):
        top = self.cfg.k - 1
        initial = jnp.asarray(self.initial_obs)
        only_initial = replay_insert(replay_init(initial, 1), initial[None], jnp.ones(1, bool))
        probe = state.replace(starts=state.starts[:top] + (only_initial,))
        params, start_params = self.rollout_inputs(probe, jnp.int32(top), jnp.int32(MODE_EVAL))
        rollout_state = init_rollout(self.hierarchy, params, self.start, start_params, key, skills, top)
        steps = int(np.prod(self.cfg.n))
        _, transitions, _, _ = rollout(self.hierarchy, params, self.start, start_params, rollout_state, steps)
        ended = transitions[top].final
        ended_before = jnp.cumsum(ended, axis=0) - ended.astype(jnp.int32)
        steps_mask = (ended_before == 0) & transitions[0].valid
        start = self.env.goal_of_obs(initial)
        positions = jnp.concatenate([
            jnp.broadcast_to(start, (1, skills, start.shape[-1])),
            self.env.goal_of_obs(transitions[0].next_obs),
        ])
        return positions, jnp.concatenate([jnp.ones((1, skills), bool), steps_mask])

    def goal_spaces(self, state: HEState, obs: jax.Array | None = None) -> list[dict[str, list[float]]]:
        """Each level's goal-space box at ``obs`` (default: the initial state), as plain floats."""
        obs = jnp.asarray(self.initial_obs) if obs is None else obs
        boxes = []
        for level in range(self.cfg.k):
            action = self.nets.goal_space_action(level, state.goal_spaces[level].actor, obs)
            shift, log_half_width = gce.split_goal_space_action(action)
            boxes.append({
                "shift": np.asarray(shift).tolist(),
                "half_width": np.exp(np.asarray(log_half_width)).tolist(),
                "volume": float(gce.box_volume(action)),
            })
        return boxes

    def boxes_where_used(self, state: HEState, rows: int = 1024) -> list[dict[str, float] | None]:
        """Each level's goal-space box at the states the level above chose subgoals in.

        Level i's box is level i+1's action space at whatever state level i+1 acts from.
        Where the box is wrong there (too far out, say, at fast-moving states the
        goal-space critic has seen little of), level i+1 asks for subgoals level i cannot
        reach. ``rows`` states are drawn from level i+1's replay; the top level (nothing
        above it) and an empty replay give None.
        """
        found: list[dict[str, float] | None] = []
        for level in range(self.cfg.k - 1):
            above = state.replay[level + 1]
            if int(above.size) == 0:
                found.append(None)
                continue
            obs = replay_sample(above, jax.random.fold_in(jax.random.key(0), state.epoch), rows).obs
            shift, half_width = self.nets.learned_box(level)(state.goal_spaces[level].actor, obs)
            found.append({"max_abs_shift": float(jnp.abs(shift).max()),
                          "mean_half_width": float(half_width.mean()),
                          "max_half_width": float(half_width.max())})
        return found + [None]

    def metrics(self, state: HEState, stats: ItemStats, seconds: float) -> dict[str, Any]:
        """One JSON-ready line of per-epoch metrics: goal spaces, success, losses, throughput."""
        s = jax.tree.map(np.asarray, stats)
        levels = []
        where_used = self.boxes_where_used(state)
        for level, box in enumerate(self.goal_spaces(state)):
            def pick(mode, field, reducer=np.mean):
                rows = (s.root == level) & (s.mode == mode)
                return float(reducer(getattr(s, field)[rows])) if rows.any() else None

            levels.append({
                "level": level,
                **box,
                "success": pick(MODE_EVAL, "reached"),
                "final_distance": pick(MODE_EVAL, "final_distance"),
                "gs_success": pick(MODE_GS, "reached"),
                "gc_critic_loss": pick(MODE_GC, "critic_loss"),
                "gc_actor_loss": pick(MODE_GC, "actor_loss"),
                "gs_critic_loss": pick(MODE_GS, "critic_loss"),
                "gs_actor_loss": pick(MODE_GS, "actor_loss"),
                "transitions": pick(MODE_GC, "transitions", np.sum),
                "box_where_used": where_used[level],
            })
        header = epoch_header(state, float(s.env_steps.sum()), seconds)
        return {**header, "flip_resets": int(s.flip_resets.sum()), "levels": levels}

    def divergence(self, state: HEState, stats: ItemStats) -> str | None:
        """Why this epoch's result must not be kept (a non-finite loss or parameter), or None.

        Start-refresh and evaluation items carry NaN losses by design and are not checked.
        """
        s = jax.tree.map(np.asarray, stats)
        for i in np.flatnonzero((s.mode == MODE_GC) | (s.mode == MODE_GS)):
            for name in ("critic_loss", "actor_loss"):
                value = getattr(s, name)[i]
                if not np.isfinite(value):
                    kind = "goal-conditioned" if s.mode[i] == MODE_GC else "goal-space"
                    return f"level {int(s.root[i])} {kind} {name.replace('_', ' ')} is {value}"
        if not bool(all_finite((state.policies, state.goal_spaces))):
            return "a network parameter or optimizer state is not finite"
        return None

    def describe(self, metrics: dict) -> str:
        """A short human-readable summary of an epoch's metrics: throughput, then per level."""
        levels = "  ".join(
            f"L{m['level']} volume {m['volume']:.3g} success {m['success']:.2f}"
            if m["success"] is not None else f"L{m['level']} volume {m['volume']:.3g}"
            for m in metrics["levels"]
        )
        return f"{metrics['env_steps']:.3g} env steps  {metrics['env_steps_per_s']:.3g} steps/s  {levels}"


_jit_evaluate = jax.jit(HEEvaluation._evaluate, static_argnums=(0, 4))
_jit_skill_paths = jax.jit(HEEvaluation._skill_paths, static_argnums=(0, 3))
