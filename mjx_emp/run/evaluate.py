"""The figures a saved agent is judged by: phase-1 goal spaces, success and coverage; phase 2's
minimum distance to goal.

:func:`evaluation_row` is the one evaluation of a run: `mjx-emp eval` and `mjx-emp sweep` both
write its rows, from the same keys, so an eval of a sweep's run gives that run's row again.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np

from mjx_emp.algos.registry import GOAL_SPACES, algorithm_of
from mjx_emp.errors import CheckpointError, ConfigError
from mjx_emp.flip_tables import flip_text, pooled
from mjx_emp.metrics import (
    LEVEL_FIGURES,
    aggregate_agent,
    aggregate_phase2,
    aggregate_runs,
    coverage_cells,
    mean_and_stderr,
)
from mjx_emp.phase2.config import Phase2Config
from mjx_emp.run import jobs, store
from mjx_emp.run.flips import phase1_flips, phase2_flips
from mjx_emp.run.provenance import provenance
from mjx_emp.run.rows import ROW_SCHEMA
from mjx_emp.tables import spread_text

COVERAGE_SKILLS = 48
"""Skills per coverage count, as in METRA's Ant figures."""
FLIP_TABLE_KEY = 1_000_003
"""Folded into the evaluation key for the flip tables' episodes, so that they draw other goals
than the figures beside them (adding the tables changed none of those)."""
FLIP_TABLE_PHASE2_ENVS = 64
"""Greedy phase-2 episodes the flip table follows step by step."""


def coverage_figures(skill_paths, key, draws: int = 1) -> dict[str, Any]:
    """METRA's coverage over ``draws`` draws of :data:`COVERAGE_SKILLS` greedy skills from the
    initial state: ``coverage_cells`` (one draw's count with ``key``, or the mean over draws with
    keys ``fold_in(key, d)``), and with several draws ``coverage_cells_std`` (sample std over
    draws) and ``coverage_draws``. ``skill_paths(key, skills)`` gives one draw's paths."""
    if draws == 1:
        return {"coverage_cells": coverage_cells(*skill_paths(key, COVERAGE_SKILLS))}
    counts = np.array([coverage_cells(*skill_paths(jax.random.fold_in(key, d), COVERAGE_SKILLS))
                       for d in range(draws)], dtype=float)
    return {"coverage_cells": float(counts.mean()), "coverage_cells_std": float(counts.std(ddof=1)),
            "coverage_draws": draws}


def phase1_figures(trainer, state, key, episodes: int, coverage_draws: int = 1) -> dict:
    """Per level: the goal-space box at the initial state and greedy goal-conditioned results;
    for the agent: METRA's coverage and the top box's volume times its greedy success.

    Goals come from each level's own (noise-free) goal space at the episode's start;
    episodes start from the level's start-state buffer (``success``, ``final_distance``,
    ``cut_short``: the fraction a reset cut short, for the Ant a flip), and again from the
    initial state only (``from_initial``) and from the buffer's states that chaining
    reached only (``chained``); at least ``episodes`` episodes each (whole rounds of
    ``num_envs``). Coverage counts the 1 m cells of goal space visited by
    :data:`COVERAGE_SKILLS` greedy top-level skills from the initial state
    (:func:`coverage_figures`, over ``coverage_draws`` draws).
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
    coverage = coverage_figures(lambda k, n: trainer.skill_paths(state, k, n), jax.random.fold_in(key, len(levels)),
                                coverage_draws)
    top = levels[-1]
    return {"epoch": int(state.epoch), "env_steps": float(state.env_steps.value()), "levels": levels,
            **coverage, "volume_x_success": top["volume"] * top["success"]}


def skill_figures(agent, state, key, coverage_draws: int = 1) -> dict:
    """A flat skill learner's figures: METRA's coverage (:data:`COVERAGE_SKILLS` greedy skills
    from the initial state, over ``coverage_draws`` draws) and, for DIAYN and HIDIO, the
    posterior's mean standard deviation."""
    coverage = coverage_figures(lambda k, n: agent.skill_paths(state, k, n), jax.random.fold_in(key, 0),
                                coverage_draws)
    return {"epoch": int(state.epoch), "env_steps": float(state.env_steps.value()), **coverage,
            "posterior_std": agent.posterior_std(state, jax.random.fold_in(key, 1))}


def phase2_figures(trainer, epoch: int, state, key, episodes: int) -> dict:
    """The paper's phase-2 figure of a phase-2 state: its task and the greedy policy's mean
    minimum distance to goal and success on at least ``episodes`` goals from the region; where
    the trainer offers them (``diagnostic_figures``), the same figures of the scripted policies on
    the same goals (:data:`mjx_emp.metrics.PHASE2_DIAGNOSTICS`); and the flip table of
    :data:`FLIP_TABLE_PHASE2_ENVS` greedy episodes (:func:`mjx_emp.run.flips.phase2_flips`; over
    goal-space skills only)."""
    cfg = trainer.cfg
    figures = {"epoch": epoch, "n": cfg.n, "eps": cfg.eps, "region": list(cfg.region),
               "region_offset": list(cfg.region_offset), **trainer.evaluate(state, key, episodes)}
    figures.update(trainer.diagnostic_figures(state, key, episodes))  # the same goals under the scripted policies
    if algorithm_of(trainer.phase1.cfg).skills == GOAL_SPACES:  # skills addressed by subgoals: followed step by step
        figures["flip_table"] = phase2_flips(trainer, state, jax.random.fold_in(key, FLIP_TABLE_KEY),
                                             FLIP_TABLE_PHASE2_ENVS)
    return figures


def phase2_of_run(run_dir: Path, key, episodes: int) -> dict | None:
    """RUN_DIR/phase2's figures (:func:`phase2_figures`), None without one; a phase-2 folder that
    cannot be loaded is reported on stderr and left out, so it never blocks the phase-1 figures."""
    try:
        loaded = jobs.load_run_phase2(run_dir)
    except (ConfigError, CheckpointError) as err:
        print(f"mjx-emp: {Path(run_dir) / store.PHASE2_SUBDIR} is unusable, its phase 2 is left out: {err}",
              file=sys.stderr, flush=True)
        return None
    return None if loaded is None else phase2_figures(*loaded, key, episodes)


def run_figures(run_dir: Path, key, episodes: int, coverage_draws: int = 1) -> dict[str, Any]:
    """A run's figures from its newest good checkpoint, in one layout for every algorithm:
    ``levels`` (goal-space algorithms; else empty), ``top_volume`` and ``top_success`` (the top
    level's box at s0 and its greedy success; None without levels), ``flips`` (the fraction of the
    top level's evaluation episodes a flip cut short), ``flip_table`` (where the skills flip the
    robot, per level: :func:`mjx_emp.run.flips.phase1_flips`; None for flat skill learners),
    ``coverage_cells``, ``volume_x_success``, ``posterior_std`` (DIAYN and HIDIO) and ``phase2``
    (None without RUN_DIR/phase2)."""
    agent, _, state = jobs.load_run(Path(run_dir))
    if algorithm_of(agent.cfg).skills == GOAL_SPACES:
        figures = phase1_figures(agent, state, key, episodes, coverage_draws)
        top = figures["levels"][-1]
        figures = {**figures, "top_volume": top["volume"], "top_success": top["success"],
                   "flips": top.get("cut_short"), "posterior_std": None,
                   "flip_table": phase1_flips(agent, state, jax.random.fold_in(key, FLIP_TABLE_KEY), episodes)}
    else:
        figures = skill_figures(agent, state, key, coverage_draws)
        figures = {**figures, "levels": [], "top_volume": None, "top_success": None, "flips": None,
                   "volume_x_success": None, "flip_table": None}
    return {**figures, "phase2": phase2_of_run(Path(run_dir), key, episodes)}


def coverage_asked(draws: int) -> dict[str, int]:
    """How an evaluation row records its coverage draws: nothing for the default one draw (so
    rows of one draw read as they always have), ``coverage_draws`` otherwise."""
    return {} if draws == 1 else {"coverage_draws": draws}


def run_curves(run_dir: Path, lines: list[dict]) -> dict[str, list]:
    """A run's learning curves from its metrics ``lines``: env steps, the top level's box volume
    and greedy success per epoch (goal-space algorithms), and phase 2's greedy min distance per
    epoch (from RUN_DIR/phase2's metrics)."""
    curves: dict[str, list] = {"env_steps": [line["env_steps"] for line in lines]}
    if lines and "levels" in lines[0]:
        curves["top_volume"] = [line["levels"][-1].get("volume") for line in lines]
        curves["top_success"] = [line["levels"][-1].get("success") for line in lines]
    phase2_dir = Path(run_dir) / store.PHASE2_SUBDIR
    if (phase2_dir / store.METRICS_FILE).exists():
        phase2 = store.read_metrics(phase2_dir)
        curves["phase2_env_steps"] = [line["env_steps"] for line in phase2]
        curves["phase2_min_distance"] = [line.get("min_distance") for line in phase2]
    return curves


def training_seconds(lines: list[dict]) -> float:
    """Wall seconds of a run's epochs as its metrics ``lines`` record them (compilation included;
    for seeds trained together, each seed's epochs count the whole program's time)."""
    return float(sum(line.get("seconds", 0.0) for line in lines))


def evaluation_row(run_dir: Path, seed: int = 0, episodes: int = 400, command: str | None = None,
                   spec: str | None = None, row: str | None = None, coverage_draws: int = 1) -> dict[str, Any]:
    """The one evaluation of a run, as a row: what was trained (algorithm, env, seed, preset and
    overrides from the run's provenance), its figures (:func:`run_figures` with the evaluation
    key ``jax.random.key(seed)``, for phase 1 and phase 2 alike), its curves, and how it was made
    (the training's provenance and the evaluation's). ``spec`` and ``row`` name the sweep row it
    belongs to (None for a run evaluated on its own). The programs compiled for it are
    released at the end: no other run's agent can use them, and a process that evaluates
    runs one after another would otherwise run out of memory mappings (vm.max_map_count)."""
    run_dir = Path(run_dir)
    cfg = store.read_run_config(run_dir, "run_dir")
    trained = store.read_run_record(run_dir)
    try:
        figures = run_figures(run_dir, jax.random.key(seed), episodes, coverage_draws)
    finally:
        jax.clear_caches()
    lines = store.read_metrics(run_dir)
    return {
        "schema": ROW_SCHEMA, "spec": spec, "row": row, "seed": int(cfg.seed), "run_dir": str(run_dir),
        "algorithm": algorithm_of(cfg).name, "env": cfg.env, "k": getattr(cfg, "k", None),
        "preset": trained.get("preset"), "overrides": trained.get("overrides"),
        "phase2_preset": _phase2_preset(run_dir), "phase2_config": _phase2_config(run_dir),
        "figures": figures, "curves": run_curves(run_dir, lines),
        "train": {**trained, "env_steps": figures["env_steps"], "wall_s": training_seconds(lines),
                  "config": store.config_json(cfg)},
        "evaluation": {"seed": seed, "episodes": episodes, **coverage_asked(coverage_draws), **provenance(command)},
    }


def _phase2_preset(run_dir: Path) -> str | None:
    """The phase-2 preset RUN_DIR/phase2 was started from, where its provenance says."""
    phase2_dir = store.own_phase2(run_dir)
    return None if phase2_dir is None else store.read_run_record(phase2_dir).get("preset")


def _phase2_config(run_dir: Path) -> dict | None:
    """RUN_DIR/phase2's config as its config.json holds it, None without a phase 2."""
    phase2_dir = store.own_phase2(run_dir)
    return None if phase2_dir is None else dataclasses.asdict(store.read_run_config(phase2_dir, "run_dir", Phase2Config))


def row_figures(row: dict) -> dict:
    """What two evaluations of one run must agree on: the row less its provenance (timing, the
    command, the machine)."""
    return {name: value for name, value in row.items() if name not in ("train", "evaluation")}


def evaluate_runs(run_dirs: list[Path], seed: int = 0, episodes: int = 400, command: str | None = None,
                  coverage_draws: int = 1) -> dict:
    """Each run's :func:`evaluation_row` (``runs``) and their aggregate over runs as seeds (mean,
    sample std, standard error): per level and for the agent (goal-space algorithms) or coverage
    and posterior std (flat skill learners), and phase 2 where runs have one. Runs of one
    algorithm at a time (they are aggregated)."""
    algorithms = {algorithm.name: algorithm
                  for algorithm in (algorithm_of(store.read_run_config(Path(d), "run_dirs")) for d in run_dirs)}
    if len(algorithms) > 1:
        raise ConfigError(f"run_dirs: runs of one algorithm at a time (they are aggregated); got {sorted(algorithms)}")
    rows = []
    for index, run_dir in enumerate(run_dirs, 1):
        print(f"evaluating {run_dir} ({index} of {len(run_dirs)}) ...", flush=True)
        rows.append(evaluation_row(Path(run_dir), seed, episodes, command, coverage_draws=coverage_draws))
    figures = [row["figures"] for row in rows]
    latent = next(iter(algorithms.values())).skills != GOAL_SPACES
    report = {"runs": rows, **(_aggregate_skill_runs if latent else _aggregate_goal_space_runs)(figures)}
    with_phase2 = [f["phase2"] for f in figures if f.get("phase2") is not None]
    if with_phase2:
        report["phase2"] = aggregate_phase2(with_phase2)
    report["flip_table"] = pooled_flip_tables(rows)
    return report


def pooled_flip_tables(rows: list[dict]) -> dict | None:
    """The runs' flip tables pooled (:func:`mjx_emp.flip_tables.pooled`): ``levels`` (phase 1, per
    level) and ``phase2`` (None unless every run has one); None for flat skill learners."""
    tables = [row["figures"].get("flip_table") for row in rows]
    if not tables or not all(tables):
        return None
    phase2_tables = [(row["figures"].get("phase2") or {}).get("flip_table") for row in rows]
    return {"levels": [pooled([t[level] for t in tables]) for level in range(len(tables[0]))],
            "phase2": pooled(phase2_tables) if all(phase2_tables) else None}


def _aggregate_goal_space_runs(runs: list[dict]) -> dict:
    return {"levels": aggregate_runs(runs), **aggregate_agent(runs)}


def _aggregate_skill_runs(runs: list[dict]) -> dict:
    report = {"coverage_cells": mean_and_stderr([r["coverage_cells"] for r in runs])}
    stds = [r["posterior_std"] for r in runs if r["posterior_std"] is not None]
    if stds:
        report["posterior_std"] = mean_and_stderr(stds)
    return report


PHASE2_POLICIES = (("aimed", "subgoals aimed straight at each goal"),
                   ("aimed_half", "subgoals aimed within the top box's central half"),
                   ("random", "random subgoals"))
"""The scripted phase-2 policies an evaluation reports beside the learned one, and what each is."""


def evaluation_text(report: dict) -> str:
    """:func:`evaluate_runs`'s report as `mjx-emp eval` prints it: the per-level table or the
    coverage line, then phase 2's figures and the scripted policies' on the same goals."""
    rows = report["runs"]
    lines = [f"{len(rows)} run(s)" + ("" if len(rows) == 1 else "; mean ± sample std (se: standard error) over runs")]
    if "levels" in report:
        lines += ["| level | goal-space volume | greedy success | final distance | success from s0 | success from "
                  "chained starts | cut short (flipped) |", "|---|---|---|---|---|---|---|"]
        lines += [f"| {row['level']} | " + " | ".join(spread_text(row[name]) for name in LEVEL_FIGURES) + " |"
                  for row in report["levels"]]
        lines.append(f"coverage ({COVERAGE_SKILLS} greedy top-level skills from the initial state, 1 m cells of goal "
                     f"space): {spread_text(report['coverage_cells'])} cells; top volume x greedy success "
                     f"{spread_text(report['volume_x_success'])}")
    else:
        lines.append(f"{rows[0]['algorithm']}: coverage ({COVERAGE_SKILLS} greedy skills from the initial state, 1 m "
                     f"cells of goal space): {spread_text(report['coverage_cells'])} cells")
        if "posterior_std" in report:
            lines.append(f"posterior mean std: {spread_text(report['posterior_std'])}")
    if report.get("flip_table") is not None:
        lines += flip_text(report["flip_table"]["levels"], report["flip_table"]["phase2"])
    p2 = report.get("phase2")
    if p2 is None:
        lines.append("phase 2: no run has a phase-2 directory (train one with `mjx-emp phase2 RUN_DIR`)")
        return "\n".join(lines)
    first = next(row["figures"]["phase2"] for row in rows if row["figures"].get("phase2") is not None)
    lines.append(f"phase 2 ({p2['min_distance']['count']} run(s), {first['episodes']} episodes each, region "
                 f"{first['region']}, eps {first['eps']}): mean min distance to goal {spread_text(p2['min_distance'])}, "
                 f"success {spread_text(p2['success'])}"
                 + (f", ended early by a reset (a flip) {spread_text(p2['cut_short'])}" if "cut_short" in p2 else "")
                 + (f", mean min distance where no reset ended the episode {spread_text(p2['uncut_min_distance'])}"
                    if "uncut_min_distance" in p2 else ""))
    lines += [f"  the same goals with {what}: mean min distance {spread_text(p2[policy]['min_distance'])}, "
              f"success {spread_text(p2[policy]['success'])}" for policy, what in PHASE2_POLICIES if policy in p2]
    return "\n".join(lines)
