"""What a k-level rollout is made of and gives back: the hierarchy of level policies (and the
driver above its top level), a plan to roll out, and the records of a rollout: transitions,
episode ends, the scan's carry and its statistics (:mod:`mjx_emp.rollout.hierarchy` runs it)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
from flax import struct

from mjx_emp.checks import check_levels
from mjx_emp.envs.env import Env, EnvState
from mjx_emp.errors import ConfigError

Params = Any
# (params, obs, goal, key) -> action, for ONE environment. Level 0 returns a primitive
# action in [-1, 1]^nu; level i > 0 returns a subgoal relative to h(s) (goal-space size).
LevelPolicy = Callable[[Params, jax.Array, jax.Array, jax.Array], jax.Array]
# (start_params, key) -> (env state, root goal, info), for ONE environment: where and with
# which goal a new root-level episode begins (e.g. a start-state buffer and a goal-space
# sample). ``info`` is any pytree; it is carried with the episode and handed back in the
# episode's :class:`EpisodeEnd` (the goal-space learner keeps its noise and box there).
StartFn = Callable[[Any, jax.Array], tuple[EnvState, jax.Array, Any]]


@dataclasses.dataclass(frozen=True, eq=False)
class Driver:
    """A goal-free chooser above a hierarchy's top level.

    Rooted at it (root = k), an episode is ``n`` top-level skills in a row, each goal
    from ``policy`` (called like a level policy; the goal it is handed is meaningless);
    the driver never reaches anything, so only ``n`` (or a reset) ends its episodes.
    """

    policy: LevelPolicy
    n: int

    def __post_init__(self):
        if self.n < 1:
            raise ConfigError(f"driver n: must be >= 1; got {self.n}")


@dataclasses.dataclass(frozen=True, eq=False)
class Hierarchy:
    """A k-level agent's static structure: env, one policy per level, n and eps per level,
    and optionally a :class:`Driver` above the top."""

    env: Env
    policies: tuple[LevelPolicy, ...]
    n: tuple[int, ...]
    eps: tuple[float, ...]
    driver: Driver | None = None
    reflex_tilt: float = 0.0
    """A reflex (0: none): every level below the root hands control back (its action ends,
    neither reached nor reset) at the first step after which the torso's tilt, 1 - z of its up
    axis, exceeds this, having been at most this when the root issued its current action; that
    action of the root ends with them (it counts as one of the root's n) and the root chooses
    again from where the robot is. The root's episode goes on."""

    def __post_init__(self):
        if not self.policies:
            raise ConfigError("policies: need at least one level (k >= 1)")
        check_levels(self.n, self.eps, k=len(self.policies))
        if not self.reflex_tilt >= 0.0:
            raise ConfigError(f"reflex_tilt: must be >= 0 (0: no reflex); got {self.reflex_tilt}")

    @property
    def k(self) -> int:
        """Levels of skills (the driver, if any, is not one)."""
        return len(self.policies)

    @property
    def rows(self) -> int:
        """Entries of the per-level carry: the k levels plus the driver's, if any."""
        return self.k + (self.driver is not None)

    def policy(self, i: int) -> LevelPolicy:
        """Policy of carry row ``i`` (row k is the driver)."""
        return self.driver.policy if i == self.k else self.policies[i]

    def actions_per_episode(self, i: int) -> int:
        """Most actions of carry row ``i`` before it finishes (row k: the driver's n)."""
        return self.driver.n if i == self.k else self.n[i]


@dataclasses.dataclass(frozen=True)
class RolloutPlan:
    """A rollout someone outside the agent can replay (a renderer, a plot): the hierarchy,
    per-row params, start function and its params, and the root (k for the driver)."""

    hierarchy: Hierarchy
    params: tuple
    start: StartFn
    start_params: Any
    root: int

    @property
    def levels_with_goals(self) -> int:
        """Levels 0..root that pursue goals (the driver, if rooted, has none)."""
        return min(self.root, self.hierarchy.k - 1) + 1


@struct.dataclass
class Transition:
    """One level's experience, stacked as [T, B, ...]; rows with ``valid`` False are padding.

    ``reached``: h(next_obs) within eps of ``goal``. ``final``: this action ended the
    level's pursuit of ``goal`` (reached, out of actions, or a physics reset). ``cut``: a
    reset (physics broke or the Ant flipped) ended this action; such a row is not valid,
    its ``next_obs`` is the last observation before the resetting step and it is never
    reached. A row is at most one of ``valid`` and ``cut``.
    """

    obs: jax.Array
    goal: jax.Array
    action: jax.Array
    next_obs: jax.Array
    reached: jax.Array
    final: jax.Array
    valid: jax.Array
    cut: jax.Array


@struct.dataclass
class EpisodeEnd:
    """One finished root episode per valid row, stacked as [T, B, ...].

    ``info`` is what the start function returned for the episode, ``final_obs`` the
    observation s_n it ended in, ``reached`` whether h(s_n) was within eps of the root
    goal, ``index`` how many root episodes the environment finished before this one
    since :func:`init_rollout` (0 for its first). ``valid`` rows ended normally;
    ``cut`` rows ended because the environment was reset (physics broke or the Ant
    flipped): their ``final_obs`` is the last observation before the resetting action
    and ``reached`` is False. A row is at most one of the two.
    """

    info: Any
    final_obs: jax.Array
    reached: jax.Array
    index: jax.Array
    valid: jax.Array
    cut: jax.Array

    @property
    def ended(self) -> jax.Array:
        """Rows where an episode ended, normally or cut short by a reset (for scoring)."""
        return self.valid | self.cut

    @property
    def first_ended(self) -> jax.Array:
        """Rows where an environment's first root episode since :func:`init_rollout` ended."""
        return self.ended & (self.index == 0)


@struct.dataclass
class RolloutState:
    """Batched environments plus the per-level controller state carried between steps.

    Tuples are indexed by carry row (level 0..k-1, then the driver's row k if there is
    one); rows above ``root`` are idle.
    ``issued_obs[i]``/``issued_action[i]`` hold the observation and action with which
    level i's current action began (for level 0 they are refreshed every step).
    ``episode`` is the start info of each environment's current root episode and
    ``episodes_done`` counts the root episodes each environment has finished.
    """

    env: EnvState
    goals: tuple[jax.Array, ...]
    counts: tuple[jax.Array, ...]
    issued_obs: tuple[jax.Array, ...]
    issued_action: tuple[jax.Array, ...]
    root: jax.Array
    episode: Any
    episodes_done: jax.Array
    key: jax.Array


@struct.dataclass
class RolloutStats:
    """Per-call totals: physics work done and how much of it served a live episode."""

    primitive_steps: jax.Array
    useful_steps: jax.Array
    episodes_finished: jax.Array
    nan_resets: jax.Array
    flip_resets: jax.Array
    decisions: tuple[jax.Array, ...]
