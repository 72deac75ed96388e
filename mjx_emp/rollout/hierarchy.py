"""The k-level hierarchical rollout as one ``lax.scan`` over primitive steps.

Level 0 picks a primitive action every step. A level i > 0 acts by handing a subgoal
to level i-1, which then has at most ``n[i-1]`` actions and stops early once h(s) is
within ``eps[i-1]`` of the subgoal. Instead of nesting one scan per level (which idles
every environment whose lower level finished early), each environment carries a small
controller state: per level its current goal, how many actions it has taken toward it,
and the state and action with which its current action was issued. One scan step is:

1. level 0 acts, physics advances one primitive action;
2. bottom-up, every level whose action just completed counts it and checks its goal;
   a level finishes when it reaches its goal, runs out of actions, or the environment
   was reset (physics broke, or the Ant flipped);
3. an environment whose root level finished starts a new episode at once;
4. top-down, every level whose child finished issues the child's next subgoal.

So each physics step computed advances a live episode, and the next subgoal is in
place before the next physics step. Upper-level policies are evaluated only for the
environments that need a decision: those rows are gathered into the smallest of a few
compiled batch sizes that holds them (the full batch when most need one).

Goals are absolute points in goal space; a level i > 0 policy returns the subgoal
relative to the current h(s), as the paper's policies output a point of the child's
goal-space box around the current state.

The root (the level whose episodes restart) is data, not structure: the carry always
holds all k levels and levels above the root stay idle. One compiled rollout therefore
serves training at every level, which keeps a whole curriculum epoch down to a single
copy of the physics in the compiled program.

A hierarchy may also have a :class:`Driver` above its top level: a goal-free chooser
that keeps handing the top level goals, ``n`` of them per driver episode, and is never
"reached" (Hierarchical Empowerment's start-state chain). It runs in the same scan as
the levels (rooted at index k), so the chain costs no second copy of the physics.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from mjx_emp.checks import check_levels
from mjx_emp.envs.env import Env, EnvState, tree_where
from mjx_emp.errors import ConfigError
from mjx_emp.tracing import count_trace

ROLLOUT_TRACE = "rollout"
"""Name under which :mod:`mjx_emp.tracing` counts traces of :func:`rollout`."""
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


def default_start(env: Env, goal_half_width: float) -> StartFn:
    """Start at the home pose with a root goal uniform in a box of half-width around it."""

    def start(_: Any, key: jax.Array) -> tuple[EnvState, jax.Array, tuple]:
        reset_key, goal_key = jax.random.split(key)
        state = env.reset(reset_key)
        offset = jax.random.uniform(
            goal_key, (env.goal_size,), minval=-goal_half_width, maxval=goal_half_width
        )
        return state, env.goal_of(state) + offset, ()

    return start


def _level_keys(key: jax.Array, batch: int, levels: int) -> jax.Array:
    """Independent keys per (level, env): [levels, B]. Env j's keys depend only on j."""
    return jax.vmap(lambda l: jax.random.split(jax.random.fold_in(key, l), batch))(
        jnp.arange(levels)
    )


def decision_buckets(batch: int, smallest: int = 8) -> tuple[int, ...]:
    """Row counts the gathered decision path is compiled for: powers of two up to the batch."""
    sizes = []
    size = min(smallest, batch)
    while size < batch:
        sizes.append(size)
        size *= 2
    return tuple(sizes) + (batch,)


def decide(
    policy: LevelPolicy,
    params: Params,
    obs: jax.Array,
    goals: jax.Array,
    keys: jax.Array,
    need: jax.Array,
    old: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """New actions where ``need``, old ones elsewhere.

    Only the rows that need a decision are evaluated: they are gathered into the
    smallest compiled bucket (a power of two) that holds them all, so the policy
    cost tracks the number of decisions, not the batch size, and no row is ever
    dropped or delayed.
    """
    batch = need.shape[0]
    act = jax.vmap(policy, in_axes=(None, 0, 0, 0))
    sizes = decision_buckets(batch)

    def gathered(size):
        def run(_):
            rows = jnp.nonzero(need, size=size, fill_value=batch)[0]
            safe = jnp.minimum(rows, batch - 1)
            new = act(params, obs[safe], goals[safe], keys[safe])
            return old.at[rows].set(new, mode="drop")

        return run

    def full(_):
        return jnp.where(need[:, None], act(params, obs, goals, keys), old)

    count = need.sum()
    branch = jnp.searchsorted(jnp.asarray(sizes), count)  # first bucket with size >= count
    return jax.lax.switch(branch, [gathered(s) for s in sizes[:-1]] + [full], None), count


def _issue_subgoals(
    hierarchy: Hierarchy,
    params: tuple[Params, ...],
    root: jax.Array,
    env_state: EnvState,
    goals: list,
    issued_obs: list,
    issued_action: list,
    finished: list,
    keys: jax.Array,
) -> list:
    """Top-down: each level i <= root whose child finished gives the child its next subgoal.

    Updates the per-level lists ``goals``, ``issued_obs`` and ``issued_action`` in place
    (they are the scan step's local working copies) and returns decisions per level.
    """
    env = hierarchy.env
    obs = jax.vmap(env.observe)(env_state)
    pos = jax.vmap(env.goal_of)(env_state)
    decisions = [jnp.zeros((), jnp.int32) for _ in range(hierarchy.rows)]
    for i in range(hierarchy.rows - 1, 0, -1):
        need = finished[i - 1] & (i <= root)
        z, decisions[i] = decide(
            hierarchy.policy(i), params[i], obs, goals[i], keys[i], need, issued_action[i]
        )
        issued_action[i] = z
        issued_obs[i] = jnp.where(need[:, None], obs, issued_obs[i])
        goals[i - 1] = jnp.where(need[:, None], pos + z, goals[i - 1])
    return decisions


def init_rollout(
    hierarchy: Hierarchy,
    params: tuple[Params, ...],
    start: StartFn,
    start_params: Any,
    key: jax.Array,
    batch_size: int,
    root: int | jax.Array | None = None,
) -> RolloutState:
    """Start ``batch_size`` episodes of the agent rooted at level ``root`` (default: the top
    level; k is the driver).

    ``root`` may be a traced integer: the rollout's compiled program does not depend on it.
    """
    root = hierarchy.k - 1 if root is None else root
    _check_root(hierarchy, root)
    root = jnp.asarray(root, jnp.int32)
    env = hierarchy.env
    key, start_key, level_key = jax.random.split(key, 3)
    env_state, root_goal, info = jax.vmap(start, in_axes=(None, 0))(
        start_params, jax.random.split(start_key, batch_size)
    )
    obs = jax.vmap(env.observe)(env_state)
    zeros_goal = jnp.zeros((batch_size, env.goal_size), obs.dtype)
    goals = [jnp.where(root == i, root_goal, zeros_goal) for i in range(hierarchy.rows)]
    issued_obs = [obs for _ in range(hierarchy.rows)]
    issued_action = [jnp.zeros((batch_size, env.action_size), obs.dtype)] + [
        zeros_goal for _ in range(hierarchy.rows - 1)
    ]
    everyone = [jnp.ones(batch_size, bool) for _ in range(hierarchy.rows)]
    _issue_subgoals(
        hierarchy, params, root, env_state, goals, issued_obs, issued_action, everyone,
        _level_keys(level_key, batch_size, hierarchy.rows),
    )
    return RolloutState(
        env=env_state,
        goals=tuple(goals),
        counts=tuple(jnp.zeros(batch_size, jnp.int32) for _ in range(hierarchy.rows)),
        issued_obs=tuple(issued_obs),
        issued_action=tuple(issued_action),
        root=root,
        episode=info,
        episodes_done=jnp.zeros(batch_size, jnp.int32),
        key=key,
    )


def _check_root(hierarchy: Hierarchy, root: int | jax.Array) -> None:
    """Reject a concrete root outside 0..k-1, or 0..k with a driver (a traced root is the
    caller's promise)."""
    if isinstance(root, jax.core.Tracer):
        return
    if not 0 <= int(root) < hierarchy.rows:
        driver = f" ({hierarchy.k} is the driver)" if hierarchy.driver is not None else ""
        raise ConfigError(f"root must be in 0..{hierarchy.rows - 1}{driver}; got {root}")


def _reflex(hierarchy: Hierarchy, root: jax.Array, issued_obs: list[jax.Array], last_obs: jax.Array) -> jax.Array:
    """[B]: where the reflex hands control back to the root this step (see
    :attr:`Hierarchy.reflex_tilt`): the tilt just passed the threshold, from at most it when the
    root issued its current action."""
    batch = last_obs.shape[0]
    if hierarchy.reflex_tilt == 0.0:
        return jnp.zeros(batch, bool)
    env = hierarchy.env
    tilt_at_issue = 1.0 - jax.vmap(env.up_axis_z)(jnp.stack(issued_obs)[root])
    return (1.0 - jax.vmap(env.up_axis_z)(last_obs) > hierarchy.reflex_tilt) & (tilt_at_issue <= hierarchy.reflex_tilt)


def _scan_step(hierarchy, params, start, start_params, state: RolloutState, _):
    """One primitive step of every environment: act, simulate, hand back, restart, re-issue."""
    env = hierarchy.env
    root = state.root
    batch = state.counts[0].shape[0]
    key, policy_key, start_key = jax.random.split(state.key, 3)
    keys = _level_keys(policy_key, batch, hierarchy.rows)
    goals, counts = list(state.goals), list(state.counts)
    issued_obs, issued_action = list(state.issued_obs), list(state.issued_action)

    # 1. Level 0 acts; physics advances one primitive action.
    obs = jax.vmap(env.observe)(state.env)
    action = jax.vmap(hierarchy.policies[0], in_axes=(None, 0, 0, 0))(params[0], obs, goals[0], keys[0])
    issued_obs[0], issued_action[0] = obs, action
    env_state = jax.vmap(env.step)(state.env, action)
    broke = env_state.resets > state.env.resets
    next_obs = jax.vmap(env.observe)(env_state)
    pos = jax.vmap(env.goal_of)(env_state)
    last_obs = jnp.where(broke[:, None], obs, next_obs)  # a reset's step ends where it began
    handed_back = _reflex(hierarchy, root, issued_obs, last_obs) & ~broke

    # 2. Bottom-up: levels whose action completed count it and check their goal.
    transitions, finished, reached_by_level = [], [], []
    completed = jnp.ones(batch, bool)
    for i in range(hierarchy.rows):
        completed = completed & (i <= root)
        count = counts[i] + completed.astype(jnp.int32)
        if i < hierarchy.k:
            reached = completed & (jnp.linalg.norm(pos - goals[i], axis=-1) < hierarchy.eps[i])
        else:  # the driver has no goal to reach
            reached = jnp.zeros(batch, bool)
        done = completed & (reached | (count >= hierarchy.actions_per_episode(i)) | broke | (handed_back & (i < root)))
        transitions.append(
            Transition(
                obs=issued_obs[i], goal=goals[i], action=issued_action[i], next_obs=last_obs,
                reached=reached & ~broke, final=done, valid=completed & ~broke, cut=completed & broke,
            )
        )
        counts[i] = jnp.where(done, 0, count)
        finished.append(done)
        reached_by_level.append(reached)
        completed = done
    episode_over = jnp.stack(finished)[root]
    episode_end = EpisodeEnd(
        info=state.episode,
        final_obs=last_obs,
        reached=jnp.stack(reached_by_level)[root] & ~broke,
        index=state.episodes_done,
        valid=episode_over & ~broke,
        cut=episode_over & broke,
    )

    # 3. Environments whose root episode ended start a new one in the same step.
    def restart(args):
        env_state, goals, episode = args
        fresh, fresh_goal, fresh_info = jax.vmap(start, in_axes=(None, 0))(
            start_params, jax.random.split(start_key, batch)
        )
        fresh = fresh.replace(nan_resets=env_state.nan_resets, flip_resets=env_state.flip_resets)
        goals = tuple(
            jnp.where((episode_over & (root == i))[:, None], fresh_goal, g)
            for i, g in enumerate(goals)
        )
        return (
            tree_where(episode_over, fresh, env_state),
            goals,
            tree_where(episode_over, fresh_info, episode),
        )

    env_state, goals, episode = jax.lax.cond(
        episode_over.any(), restart, lambda args: args, (env_state, tuple(goals), state.episode)
    )
    goals = list(goals)

    # 4. Top-down: parents of finished levels issue the next subgoals.
    decisions = _issue_subgoals(
        hierarchy, params, root, env_state, goals, issued_obs, issued_action, finished, keys
    )
    new_state = RolloutState(
        env=env_state, goals=tuple(goals), counts=tuple(counts),
        issued_obs=tuple(issued_obs), issued_action=tuple(issued_action), root=root,
        episode=episode, episodes_done=state.episodes_done + episode_over.astype(jnp.int32),
        key=key,
    )
    per_step = (tuple(transitions), episode_end, episode_over.sum(), tuple(decisions))
    return new_state, per_step


def rollout(
    hierarchy: Hierarchy,
    params: tuple[Params, ...],
    start: StartFn,
    start_params: Any,
    state: RolloutState,
    num_steps: int,
) -> tuple[RolloutState, tuple[Transition, ...], EpisodeEnd, RolloutStats]:
    """Advance every environment ``num_steps`` primitive actions.

    Returns the new state, per-row transitions (all k levels and the driver's row, if
    any; those above the root are never valid), the root episodes that ended, and totals. Jit with ``hierarchy``, ``start`` and
    ``num_steps`` static (see :func:`jit_rollout`); everything else, the root included,
    may change between calls without recompiling. Static arguments hash by identity, so
    keep one ``Hierarchy`` and one ``start`` function object per agent: a freshly built
    closure compiles anew.
    """
    count_trace(ROLLOUT_TRACE)
    nan_before, flips_before = state.env.nan_resets.sum(), state.env.flip_resets.sum()

    def body(carry, x):
        return _scan_step(hierarchy, params, start, start_params, carry, x)

    state, (transitions, episodes, finished, decisions) = jax.lax.scan(
        body, state, None, length=num_steps
    )
    batch = state.counts[0].shape[0]
    steps = jnp.asarray(num_steps * batch, jnp.int32)
    stats = RolloutStats(
        primitive_steps=steps,
        useful_steps=transitions[0].valid.sum(dtype=jnp.int32),
        episodes_finished=finished.sum(dtype=jnp.int32),
        nan_resets=state.env.nan_resets.sum() - nan_before,
        flip_resets=state.env.flip_resets.sum() - flips_before,
        decisions=tuple(d.sum(dtype=jnp.int32) for d in decisions),
    )
    return state, transitions, episodes, stats


_jit_init_rollout = jax.jit(init_rollout, static_argnames=("hierarchy", "start", "batch_size"))


def jit_init_rollout(hierarchy, params, start, start_params, key, batch_size, root=None) -> RolloutState:
    """Jitted :func:`init_rollout`; a concrete ``root`` is checked before tracing."""
    if root is not None:
        _check_root(hierarchy, root)
    return _jit_init_rollout(hierarchy, params, start, start_params, key, batch_size, root)
jit_rollout = jax.jit(rollout, static_argnames=("hierarchy", "start", "num_steps"))
