"""Where a run's skills flip the robot: the flip table `mjx-emp eval` prints and rows keep.

A flip is the end of an attempt with the torso's up axis below the horizon: for the Ant the
reset that ends its episode (a ``cut`` row), for the Half Cheetah, which is never reset, an
action that leaves it on its back. The table follows greedy episodes, each environment's
first, and counts flips

- per level of skills, by start kind (the initial state s0, or the states chaining reached),
  and by the goal's place in the level's box (centre to edge, in half-widths);
- by the step within the skill at which the flip happened, as a hazard: flips at index i
  over the actions that reached index i (per level: level 0's primitive steps within its
  skill, a level above's attempts within its own);
- against the torso's tilt (1 - z of its up axis: 0 upright, 1 on its side, 2 on its back)
  and angular speed in the steps before the flip, beside the same steps before the end of
  the episodes that stayed upright, with how early a threshold at the upright episodes' 99th
  percentile would have warned;
- in phase 2, by attempt index (:func:`attempt_rows`) and by the size of the subgoal the
  policy on top asked for.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import numpy as np

from mjx_emp.flip_tables import WARNING_QUANTILE
from mjx_emp.rollout.hierarchy import jit_init_rollout, jit_rollout
from mjx_emp.rollout.structures import RolloutPlan, Transition

STEPS_BEFORE = 10
"""Steps before an episode's end that the tilt and angular-speed table follows."""
GOAL_PLACE_EDGES = (0.0, 0.25, 0.5, 0.75, 1.0)
"""Bins of a goal's place in its box: the largest |noise| over goal dimensions (0 the centre, 1 the edge)."""
SUBGOAL_EDGES = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, math.inf)
"""Bins of a phase-2 subgoal's distance from h(s), in goal-space units (m)."""


@dataclasses.dataclass(frozen=True)
class FirstEpisodes:
    """Each environment's first greedy episode of a rollout, on the host.

    ``levels``: every level's rows up to the root, [T, B] each, bottom level first;
    ``first_end``: the step at which each environment's first episode ended; ``info``: what the
    start function returned for it ([B, ...] leaves)."""

    levels: tuple[Transition, ...]
    first_end: np.ndarray
    info: Any

    def __len__(self) -> int:
        return int(self.first_end.shape[0])


def roll_first_episodes(plan: RolloutPlan, key: jax.Array, envs: int) -> FirstEpisodes:
    """``envs`` greedy episodes of ``plan``, rolled out long enough for every environment to
    finish its first (every level of the root's episode to its last action)."""
    steps = math.prod(plan.hierarchy.actions_per_episode(i) for i in range(plan.root + 1)) + 1
    begin = jit_init_rollout(plan.hierarchy, plan.params, plan.start, plan.start_params, key, envs, plan.root)
    _, transitions, episodes, _ = jit_rollout(plan.hierarchy, plan.params, plan.start, plan.start_params, begin,
                                              steps)
    levels, episodes = jax.device_get((tuple(transitions[: plan.root + 1]), episodes))
    ended = np.asarray(episodes.first_ended)
    first_end = np.where(ended, np.arange(steps)[:, None], steps).min(axis=0)
    at_end = np.minimum(first_end, steps - 1)
    info = jax.tree.map(lambda leaf: np.asarray(leaf)[at_end, np.arange(envs)], episodes.info)
    return FirstEpisodes(levels, first_end, info)


def joined(parts: list[FirstEpisodes]) -> FirstEpisodes:
    """Several rollouts of one plan's shape as one batch (environments side by side)."""
    levels = jax.tree.map(lambda *leaves: np.concatenate(leaves, axis=1), *[p.levels for p in parts])
    info = jax.tree.map(lambda *leaves: np.concatenate(leaves, axis=0), *[p.info for p in parts])
    return FirstEpisodes(levels, np.concatenate([p.first_end for p in parts]), info)


def in_first_episode(rows: Transition, first_end: np.ndarray) -> np.ndarray:
    """[T, B]: the steps that belong to each environment's first episode."""
    return np.arange(np.shape(rows.valid)[0])[:, None] <= first_end[None, :]


def tilt(env, obs) -> np.ndarray:
    """1 - z of the torso's up axis: 0 upright, 1 on its side, 2 on its back."""
    return np.asarray(env.torso.tilt(np.asarray(obs)))


def upside_down(env, obs) -> np.ndarray:
    """Whether the torso's up axis points below the horizon (``Torso.upside_down``)."""
    return np.asarray(env.torso.upside_down(np.asarray(obs)))


def turned_over(env, rows: Transition) -> np.ndarray:
    """[T, B]: the rows whose action took the torso from upright to upside down."""
    return ~upside_down(env, rows.obs) & upside_down(env, rows.next_obs)


def flip_steps(env, episodes: FirstEpisodes) -> np.ndarray:
    """[B]: the primitive step at which each first episode flipped, -1 where it did not: the
    first step in it that a reset cut short (for the Ant a flip; broken physics, as rare as it
    is, counts too) or that turned the torso from upright to upside down (an episode begun on
    its back, as a Half Cheetah's chained start may be, has not flipped by staying there)."""
    low = episodes.levels[0]
    down = np.asarray(low.cut) | (np.asarray(low.valid) & turned_over(env, low))
    down &= in_first_episode(low, episodes.first_end)
    return np.where(down.any(axis=0), down.argmax(axis=0), -1)


def action_index(rows: Transition) -> np.ndarray:
    """[T, B]: the index, within its level's pursuit of the current goal, of the action in
    progress at each primitive step (0 for the first action toward a goal)."""
    ended = np.asarray(rows.valid) | np.asarray(rows.cut)
    final = np.asarray(rows.final) | np.asarray(rows.cut)
    index = np.zeros(ended.shape, np.int64)
    counter = np.zeros(ended.shape[1], np.int64)
    for t in range(ended.shape[0]):
        index[t] = counter
        counter = np.where(final[t], 0, counter + ended[t])
    return index


def hazard_by_index(rows: Transition, episodes: FirstEpisodes, flipped_at: np.ndarray, actions: int) -> dict:
    """One level's flips by the index of its action in progress at the flip (0..``actions``-1):
    ``attempts`` (actions of that index in the first episodes: those that ended before any
    flip, and the one in progress at it), ``flips`` and ``hazard`` (flips / attempts; None
    where no action got that far)."""
    index = action_index(rows)
    steps = np.arange(index.shape[0])[:, None]
    flipped = flipped_at >= 0
    before = np.where(flipped, steps < flipped_at[None, :], in_first_episode(rows, episodes.first_end))
    ended = (np.asarray(rows.valid) | np.asarray(rows.cut)) & before
    at_flip = index[np.maximum(flipped_at, 0), np.arange(len(flipped_at))][flipped]
    flips = np.bincount(at_flip, minlength=actions)[:actions]
    attempts = np.bincount(index[ended], minlength=actions)[:actions] + flips
    return {"index": list(range(actions)), "attempts": attempts.tolist(), "flips": flips.tolist(),
            "hazard": [float(f / a) if a else None for f, a in zip(flips, attempts)]}


def steps_before_end(values: np.ndarray, end: np.ndarray, steps: int = STEPS_BEFORE) -> np.ndarray:
    """[steps, B]: ``values`` ([T, B]) at 0, 1, ... ``steps``-1 steps before each column's
    ``end`` step; NaN before the episode began (step 0)."""
    at = end[None, :] - np.arange(steps)[:, None]
    picked = values[np.maximum(at, 0), np.arange(values.shape[1])[None, :]]
    return np.where(at >= 0, picked, np.nan)


def _mean_or_none(values: np.ndarray) -> list[float | None]:
    counts = np.sum(~np.isnan(values), axis=1)
    sums = np.nansum(values, axis=1)
    return [float(s / c) if c else None for s, c in zip(sums, counts)]


def warning(flipped_series: np.ndarray, upright_values: np.ndarray) -> dict:
    """How early a threshold at the upright episodes' :data:`WARNING_QUANTILE` of one signal
    would have warned of the flips: ``threshold`` (None without upright steps), ``warned`` (the
    share of flips whose last :data:`STEPS_BEFORE` steps passed it) and ``median_lead`` (steps
    between the first passing and the flip, over the warned ones)."""
    upright_values = upright_values[~np.isnan(upright_values)]
    if upright_values.size == 0 or flipped_series.shape[1] == 0:
        return {"threshold": None, "warned": None, "median_lead": None}
    threshold = float(np.quantile(upright_values, WARNING_QUANTILE))
    above = np.nan_to_num(flipped_series, nan=-np.inf) > threshold  # [steps before, flips]
    warned = above.any(axis=0)
    lead = np.where(above, np.arange(above.shape[0])[:, None], -1).max(axis=0)
    return {"threshold": threshold, "warned": float(warned.mean()),
            "median_lead": float(np.median(lead[warned])) if warned.any() else None}


def stayed_upright(env, episodes: FirstEpisodes, flipped_at: np.ndarray) -> np.ndarray:
    """[B]: the first episodes that did not flip and never had the torso upside down. An
    episode begun on its back (a Half Cheetah's chained start may be) has not flipped, and it
    has not stayed upright either: it is in neither group of :func:`before_flip`."""
    low = episodes.levels[0]
    on_back = upside_down(env, low.obs) & in_first_episode(low, episodes.first_end)
    return (flipped_at < 0) & ~on_back.any(axis=0)


def before_flip(env, episodes: FirstEpisodes, flipped_at: np.ndarray) -> dict:
    """Tilt and angular speed of the torso in the :data:`STEPS_BEFORE` states before each flip
    (0: the state the flipping action was taken in) against the same steps before the end of
    the episodes that stayed upright (:func:`stayed_upright`); those episodes' quantiles of
    both; and :func:`warning` for each."""
    low = episodes.levels[0]
    obs = np.asarray(low.obs)
    tilts, spins = tilt(env, obs), np.asarray(env.torso.angular_speed(obs))
    flipped, upright = flipped_at >= 0, stayed_upright(env, episodes, flipped_at)
    end = np.where(flipped, flipped_at, episodes.first_end)
    upright_steps = in_first_episode(low, episodes.first_end)[:, upright]
    table: dict[str, Any] = {"steps_before": list(range(STEPS_BEFORE))}
    for name, values in (("tilt", tilts), ("angular_speed", spins)):
        series = steps_before_end(values, end)
        upright_values = values[:, upright][upright_steps]
        table[f"flipped_{name}"] = _mean_or_none(series[:, flipped])
        table[f"upright_{name}"] = _mean_or_none(series[:, upright])
        table[f"upright_{name}_quantiles"] = (
            {f"q{int(q * 100)}": float(np.quantile(upright_values, q)) for q in (0.5, 0.95, WARNING_QUANTILE)}
            | {"max": float(upright_values.max())} if upright_values.size else None)
        table[f"{name}_warning"] = warning(series[:, flipped], upright_values)
    return table


def goal_place(noise: np.ndarray, flipped: np.ndarray) -> dict:
    """Flips by the goal's place in its box: the largest |noise| over goal dimensions binned
    by :data:`GOAL_PLACE_EDGES`; per bin the episodes and the share that flipped."""
    place = np.abs(np.asarray(noise)).max(axis=-1)
    bins = np.clip(np.digitize(place, GOAL_PLACE_EDGES[1:-1]), 0, len(GOAL_PLACE_EDGES) - 2)
    return _binned(bins, flipped, GOAL_PLACE_EDGES)


def _binned(bins: np.ndarray, flipped: np.ndarray, edges: tuple[float, ...]) -> dict:
    counts = np.bincount(bins, minlength=len(edges) - 1)
    flips = np.bincount(bins[flipped], minlength=len(edges) - 1)
    return {"edges": [float(e) for e in edges], "episodes": counts.tolist(), "flips": flips.tolist(),
            "share": [float(f / c) if c else None for f, c in zip(flips, counts)]}


def episode_flips(env, episodes: FirstEpisodes, actions_per_level: tuple[int, ...]) -> dict:
    """The flip table of a batch of first episodes: episodes, flips and their share; per level
    the hazard by action index (:func:`hazard_by_index`); tilt and angular speed before the
    flips (:func:`before_flip`)."""
    flipped_at = flip_steps(env, episodes)
    flipped = flipped_at >= 0
    return {"episodes": len(episodes), "flips": int(flipped.sum()), "flip_share": float(flipped.mean()),
            "by_index": [{"level": level, **hazard_by_index(rows, episodes, flipped_at, actions)}
                         for level, (rows, actions) in enumerate(zip(episodes.levels, actions_per_level))],
            "before_flip": before_flip(env, episodes, flipped_at)}


def level_flips(agent, state, level: int, key: jax.Array, episodes: int) -> dict:
    """The flip table of ``level``'s greedy skills (goals from its own noise-free box),
    ``episodes`` from s0 and as many from the states chaining reached: the shares by start
    kind and by the goal's place in the box, then :func:`episode_flips` over both."""
    rolled = {starts: roll_first_episodes(agent.greedy_episodes(state, level, starts),
                                          jax.random.fold_in(key, i), episodes)
              for i, starts in enumerate(("initial", "chained"))}
    both = joined(list(rolled.values()))
    flipped = flip_steps(agent.env, both) >= 0
    by_start = {starts: float((flip_steps(agent.env, part) >= 0).mean()) for starts, part in rolled.items()}
    return {"level": level, "by_start": by_start, "by_goal_place": goal_place(both.info.noise, flipped),
            **episode_flips(agent.env, both, tuple(agent.cfg.n[: level + 1]))}


def phase1_flips(agent, state, key: jax.Array, episodes: int) -> list[dict]:
    """:func:`level_flips` of every level, bottom first."""
    return [level_flips(agent, state, level, jax.random.fold_in(key, level), episodes) for level in range(agent.cfg.k)]


def subgoal_flips(env, top: Transition, first_end: np.ndarray) -> dict:
    """Phase 2's attempts by the size of the subgoal asked for (its distance from h(s), binned
    by :data:`SUBGOAL_EDGES`): attempts and the share that flipped the robot (a reset cut it
    short, or it began upright and ended upside down)."""
    ended = (np.asarray(top.valid) | np.asarray(top.cut)) & in_first_episode(top, first_end)
    size = np.linalg.norm(np.asarray(top.action), axis=-1)[ended]
    flipped = (np.asarray(top.cut) | turned_over(env, top))[ended]
    bins = np.clip(np.digitize(size, SUBGOAL_EDGES[1:-1]), 0, len(SUBGOAL_EDGES) - 2)
    return {**_binned(bins, flipped, SUBGOAL_EDGES), "edges": [float(e) for e in SUBGOAL_EDGES[:-1]] + [None]}


def phase2_flips(trainer, state, key: jax.Array, envs: int = 64) -> dict:
    """The flip table of phase 2's greedy episodes (the learned policy on top): attempt by
    attempt (:func:`attempt_rows`), by subgoal size (:func:`subgoal_flips`), and
    :func:`episode_flips` over every level below."""
    episodes = roll_first_episodes(trainer.greedy_episodes(state), key, envs)
    top = episodes.levels[-1]
    return {"by_attempt": attempt_rows(trainer.env, top, episodes.first_end, trainer.cfg.n),
            "by_subgoal_size": subgoal_flips(trainer.env, top, episodes.first_end),
            **episode_flips(trainer.env, episodes, tuple(trainer.phase1.cfg.n) + (trainer.cfg.n,))}


def attempt_rows(env, top: Transition, first_end: np.ndarray, attempts: int) -> list[dict]:
    """Per attempt index i (0..``attempts``-1), over the top level's rows ``top`` ([T, B]
    arrays) up to each environment's ``first_end`` step: how many episodes made an i-th attempt,
    their mean progress toward the task goal (distance before less distance after, in goal-space
    units), the distance after, and the fractions that began and ended with the torso upside down
    (up axis below the horizon), that a reset cut short, and that flipped the robot (``flipped``:
    cut short, or begun upright and ended upside down)."""
    ended = np.asarray(top.valid | top.cut) & in_first_episode(top, first_end)
    index = np.cumsum(ended, axis=0) - 1  # which attempt of its episode each ending row closes
    goal = np.asarray(top.goal)
    before = np.linalg.norm(np.asarray(env.goal_of_obs(np.asarray(top.obs))) - goal, axis=-1)
    after = np.linalg.norm(np.asarray(env.goal_of_obs(np.asarray(top.next_obs))) - goal, axis=-1)
    down_before, down_after = upside_down(env, top.obs), upside_down(env, top.next_obs)
    rows = []
    for i in range(attempts):
        at = ended & (index == i)
        if not at.any():
            break
        rows.append({"attempt": i, "episodes": int(at.sum()), "progress": float((before - after)[at].mean()),
                     "distance_after": float(after[at].mean()),
                     "upside_down_before": float(down_before[at].mean()),
                     "upside_down_after": float(down_after[at].mean()),
                     "cut_short": float(np.asarray(top.cut)[at].mean()),
                     "flipped": float((np.asarray(top.cut) | (~down_before & down_after))[at].mean())})
    return rows
