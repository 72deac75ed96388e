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

from typing import Any

import jax
import jax.numpy as jnp

from mjx_emp.envs.env import Env, EnvState, tree_where
from mjx_emp.errors import ConfigError
from mjx_emp.rollout.structures import (
    EpisodeEnd,
    Hierarchy,
    LevelPolicy,
    Params,
    RolloutState,
    RolloutStats,
    StartFn,
    Transition,
)
from mjx_emp.tracing import count_trace

ROLLOUT_TRACE = "rollout"
"""Name under which :mod:`mjx_emp.tracing` counts traces of :func:`rollout`."""
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
    tilt = hierarchy.env.torso.tilt
    return (tilt(last_obs) > hierarchy.reflex_tilt) & (tilt(jnp.stack(issued_obs)[root]) <= hierarchy.reflex_tilt)


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
