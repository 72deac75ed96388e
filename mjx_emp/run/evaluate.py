"""The figures a saved agent is judged by: phase-1 goal spaces, success and coverage; phase 2's
minimum distance to goal. `mjx-emp eval` and the experiment scripts report these."""

from __future__ import annotations

import dataclasses
import math

import jax

from mjx_emp.metrics import coverage_cells

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
