"""The figures a saved agent is judged by: phase-1 goal spaces, success and coverage; phase 2's
minimum distance to goal. `mjx-emp eval` and the experiment scripts report these."""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np

from mjx_emp.metrics import coverage_cells
from mjx_emp.rollout.hierarchy import jit_init_rollout, jit_rollout

COVERAGE_SKILLS = 48
"""Skills per coverage count, as in METRA's Ant figures."""


def phase1_figures(trainer, state, key, episodes: int) -> dict:
    """Per level: the goal-space box at the initial state and greedy goal-conditioned results;
    for the agent: METRA's coverage and the top box's volume times its greedy success.

    Goals come from each level's own (noise-free) goal space at the episode's start;
    episodes start from the level's start-state buffer (``success``, ``final_distance``,
    ``cut_short``: the fraction a reset cut short, for the Ant a flip), and again from the
    initial state only (``from_initial``) and from the buffer's states that chaining
    reached only (``chained``); at least ``episodes`` episodes each (whole rounds of
    ``num_envs``). Coverage counts the 1 m cells of goal space visited by
    :data:`COVERAGE_SKILLS` greedy top-level skills from the initial state.
    """
    rounds = max(1, math.ceil(episodes / trainer.cfg.num_envs))
    levels = []
    for level, box in enumerate(trainer.goal_spaces(state)):
        level_key = jax.random.fold_in(key, level)
        result = trainer.evaluate(state, level, level_key, rounds)
        by_start = {starts: trainer.evaluate(state, level, jax.random.fold_in(level_key, i + 1), rounds, starts)
                    for i, starts in enumerate(("initial", "chained"))}
        levels.append({"level": level, **box, **result, "episodes": rounds * trainer.cfg.num_envs,
                       "from_initial": by_start["initial"], "chained": by_start["chained"]})
    paths = trainer.skill_paths(state, jax.random.fold_in(key, len(levels)), COVERAGE_SKILLS)
    top = levels[-1]
    return {"epoch": int(state.epoch), "env_steps": float(state.env_steps.value()), "levels": levels,
            "coverage_cells": coverage_cells(*paths), "volume_x_success": top["volume"] * top["success"]}


def skill_figures(agent, state, key) -> dict:
    """A flat skill learner's figures: METRA's coverage (:data:`COVERAGE_SKILLS` greedy skills
    from the initial state) and, for DIAYN and HIDIO, the posterior's mean standard deviation."""
    paths = agent.skill_paths(state, jax.random.fold_in(key, 0), COVERAGE_SKILLS)
    return {"epoch": int(state.epoch), "env_steps": float(state.env_steps.value()), "algorithm": agent.method,
            "coverage_cells": coverage_cells(*paths),
            "posterior_std": agent.posterior_std(state, jax.random.fold_in(key, 1))}


def phase2_figures(trainer, epoch: int, state, key, episodes: int) -> dict:
    """The paper's phase-2 figure of a phase-2 state: its task and the greedy policy's mean
    minimum distance to goal and success on at least ``episodes`` goals from the region; where
    the trainer offers them (``diagnostic_tops``), the same figures of the scripted policies on
    the same goals (:data:`mjx_emp.metrics.PHASE2_DIAGNOSTICS`)."""
    cfg = trainer.cfg
    figures = {"epoch": epoch, "n": cfg.n, "eps": cfg.eps, "region": list(cfg.region),
               "region_offset": list(cfg.region_offset), **trainer.evaluate(state, key, episodes)}
    for top in trainer.diagnostic_tops:  # the same goals (same key) under the scripted policies
        figures[top] = dataclasses.replace(trainer, top=top).evaluate(state, key, episodes)
    return figures


def attempt_figures(trainer, state, key, envs: int = 64) -> list[dict]:
    """Phase 2's episodes attempt by attempt (:func:`attempt_rows`) for the first greedy episode
    of each of ``envs`` environments, with the trainer's policy on top (learned, or a scripted
    ``top``). It tells skills that chain (progress on every attempt) from skills that work once
    from the initial state and then no more, e.g. because the first left the robot on its back."""
    transitions, first_end = greedy_first_episodes(trainer, state, key, envs)
    return attempt_rows(trainer.env, jax.device_get(transitions[-1]), first_end, trainer.cfg.n)


def greedy_first_episodes(trainer, state, key, envs: int) -> tuple[tuple, np.ndarray]:
    """``envs`` greedy phase-2 episodes (the trainer's policy on top) rolled out long enough for
    each environment to finish its first: every level's transitions ([T, B] rows on the device,
    bottom level first; a caller fetches the levels it reads) and the step at which each
    environment's first episode ends."""
    plan = trainer.greedy_episodes(state)
    steps = trainer.longest_episode + 1  # the longest episode fits, with its ending step
    begin = jit_init_rollout(plan.hierarchy, plan.params, plan.start, plan.start_params, key, envs, plan.root)
    _, transitions, episodes, _ = jit_rollout(plan.hierarchy, plan.params, plan.start, plan.start_params, begin, steps)
    first_end = np.where(np.asarray(episodes.first_ended), np.arange(steps)[:, None], steps).min(axis=0)
    return tuple(transitions[: plan.root + 1]), first_end


def attempt_rows(env, top, first_end: np.ndarray, attempts: int) -> list[dict]:
    """Per attempt index i (0..``attempts``-1), over the top level's rows ``top`` ([T, B]
    arrays) up to each environment's ``first_end`` step: how many episodes made an i-th attempt,
    their mean progress toward the task goal (distance before less distance after, in goal-space
    units), the distance after, and the fractions that began and ended with the torso upside down
    (up axis below the horizon) or that a reset cut short."""
    ended = np.asarray(top.valid | top.cut) & (np.arange(top.valid.shape[0])[:, None] <= first_end[None, :])
    index = np.cumsum(ended, axis=0) - 1  # which attempt of its episode each ending row closes
    goal = np.asarray(top.goal)
    before = np.linalg.norm(np.asarray(env.goal_of_obs(np.asarray(top.obs))) - goal, axis=-1)
    after = np.linalg.norm(np.asarray(env.goal_of_obs(np.asarray(top.next_obs))) - goal, axis=-1)
    down_before, down_after = (np.asarray(env.up_axis_z(top.obs)) < 0, np.asarray(env.up_axis_z(top.next_obs)) < 0)
    rows = []
    for i in range(attempts):
        at = ended & (index == i)
        if not at.any():
            break
        rows.append({"attempt": i, "episodes": int(at.sum()), "progress": float((before - after)[at].mean()),
                     "distance_after": float(after[at].mean()),
                     "upside_down_before": float(down_before[at].mean()),
                     "upside_down_after": float(down_after[at].mean()),
                     "cut_short": float(np.asarray(top.cut)[at].mean())})
    return rows
