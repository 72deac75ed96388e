"""Hierarchical Empowerment in the cages on a CPU: does the goal space follow the walls and the button?

For every (preset, seed) (``ant-cage-k1-cpu``, ``half-cheetah-cage-k1-cpu``) trains phase 1
and phase 2 as ``baselines.py`` does (or resumes BASE/<preset>-s<seed>) and writes
``robots_cpu.py``'s row (top box, success, coverage, the box's growth per epoch in ``curve``,
phase 2) with ``cage``: the walls' inner bounds and the button, and every level's goal-space box
(the top one as ``boxes``, all from level 0 up as ``level_boxes``) in absolute goal-space
coordinates at three states: the start with the walls standing, the start
with them gone, and on the button (where pressing it leaves them gone). Each box says whether
it lies within the walls and whether it holds the button, so one reads off what the paper's
cage figures show: a box bounded by the walls that reaches toward the button, and one that
outgrows the walls once they open. Phase 2's greedy episodes are counted goal by goal
(``cage["phase2"]``): how many goals lie beyond the walls (farther than eps outside them, so
only a robot that left the cage can reach them), how many of those and of the others were
reached, and how often an episode pressed the button.
``python experiments/cages.py --presets ant-cage-k1-cpu --seeds 0``; rows merge into ``--out``, and
``--report-only`` prints the table of every row there.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np
import tyro
from baselines import merge_row, train_or_resume, train_phase2
from robots_cpu import loaded_run_row

from mjx_emp.run import jobs
from mjx_emp.run.evaluate import greedy_first_episodes


@dataclasses.dataclass
class Args:
    """Cage presets over seeds: phase 1, phase 2 and where the top box lies."""

    presets: tuple[str, ...] = ("ant-cage-k1-cpu", "half-cheetah-cage-k1-cpu")
    seeds: tuple[int, ...] = (0,)
    epochs: int | None = None
    """Override the presets' epoch counts (a shorter budget); None keeps them for a new run and a run's own count
    for one already there (it is resumed, never trained past it)."""
    phase2: bool = True
    """Also train phase 2 on the run's skills (the cage's CPU task)."""
    episodes: int = 400
    base: str = "runs/cages"
    out: str = "benchmarks/results/cages_cpu.json"
    report_only: bool = False
    """Train and evaluate nothing: print the table of the rows in ``--out``."""


def wall_bounds(wall_positions: np.ndarray, dims: int) -> tuple[list[float], list[float]]:
    """The walls' inner bounds per goal dimension, from the wall bodies' positions (each wall
    stands off the origin along one axis): (lower, upper), +-inf where no wall bounds that side."""
    lower, upper = [], []
    for d in range(dims):
        along = wall_positions[:, d]
        lower.append(float(along[along < 0].max()) if (along < 0).any() else -np.inf)
        upper.append(float(along[along > 0].min()) if (along > 0).any() else np.inf)
    return lower, upper


def absolute_box(box: dict, position: np.ndarray, walls: tuple[list[float], list[float]],
                 button_center: np.ndarray, button_half_size: np.ndarray) -> dict:
    """A goal-space box (shift and half-widths about the state's h(s)) in absolute coordinates,
    with whether it lies within the walls and whether it overlaps the button."""
    centre = position + np.asarray(box["shift"])
    half = np.asarray(box["half_width"])
    lower, upper = centre - half, centre + half
    return {"lower": lower.tolist(), "upper": upper.tolist(), "volume": box["volume"],
            "within_walls": bool(np.all(lower >= walls[0]) and np.all(upper <= walls[1])),
            "overlaps_button": bool(np.all(lower <= button_center + button_half_size)
                                    and np.all(upper >= button_center - button_half_size))}


def cage_figures(agent, state) -> dict:
    """The cage and the agent's goal-space boxes at the start (walls up), at the start with the
    walls gone, and on the button (walls gone), in absolute goal-space coordinates: ``boxes``
    for the top level, ``level_boxes`` for every level from 0 up (the top one repeated)."""
    env, cage = agent.env, agent.env.cage
    if cage is None:
        raise SystemExit(f"presets: {agent.cfg.env!r} has no cage; give a cage preset")
    dims = np.asarray(env.goal_qpos)
    walls = wall_bounds(np.asarray(env.home_mocap_pos)[list(cage.wall_mocap_ids)], len(dims))
    centre, half_size = np.asarray(cage.button_center), np.asarray(cage.button_half_size)
    start = np.asarray(agent.initial_obs)
    opened = env.obs_with_cage_open(start, True)
    on_button = opened.copy()
    on_button[dims] = centre
    level_boxes = [{} for _ in range(agent.cfg.k)]
    for name, obs in (("start_closed", start), ("start_open", opened), ("on_button", on_button)):
        for level, box in enumerate(agent.goal_spaces(state, obs)):
            level_boxes[level][name] = absolute_box(box, obs[dims], walls, centre, half_size)
    return {"walls_lower": walls[0], "walls_upper": walls[1], "button_center": centre.tolist(),
            "button_half_size": half_size.tolist(), "boxes": level_boxes[-1], "level_boxes": level_boxes}


def beyond_walls_counts(goal: np.ndarray, position: np.ndarray, live: np.ndarray, opened: np.ndarray,
                       walls: tuple[list[float], list[float]], eps: float) -> dict:
    """Phase-2 episodes goal by goal in a cage: ``goal`` [B, d] per episode, the robot's goal-space
    ``position`` [T, B, d] and whether the cage was ``opened`` [T, B] at every step, ``live`` [T, B]
    where the step belongs to the episode. A goal lies beyond the walls when it is more than eps
    outside their inner bounds along some dimension, so reaching it (coming within eps) means
    the robot left the cage. Returns the counts of goals within and beyond, of those reached,
    and the fraction of episodes (and of episodes with a goal beyond) that pressed the button."""
    distance = np.where(live, np.linalg.norm(position - goal[None], axis=-1), np.inf).min(axis=0)
    reached = distance <= eps
    beyond = np.any((goal > np.asarray(walls[1]) + eps) | (goal < np.asarray(walls[0]) - eps), axis=-1)
    pressed = np.any(opened & live, axis=0)
    return {"episodes": int(goal.shape[0]), "goals_beyond": int(beyond.sum()),
            "reached_beyond": int((reached & beyond).sum()), "goals_within": int((~beyond).sum()),
            "reached_within": int((reached & ~beyond).sum()), "opened": float(pressed.mean()),
            "opened_beyond": float(pressed[beyond].mean()) if beyond.any() else None}


def beyond_walls_figures(trainer, state, key: jax.Array, walls: tuple[list[float], list[float]],
                         envs: int = 400) -> dict:
    """:func:`beyond_walls_counts` of ``envs`` greedy phase-2 episodes (the first of each
    environment) from the phase-2 ``trainer`` and ``state``."""
    transitions, first_end = greedy_first_episodes(trainer, state, key, envs)
    bottom, top = jax.device_get((transitions[0], transitions[-1]))
    live = np.asarray(bottom.valid) & (np.arange(bottom.valid.shape[0])[:, None] <= first_end[None, :])
    next_obs = np.asarray(bottom.next_obs)
    position = np.asarray(trainer.env.goal_of_obs(next_obs))
    return beyond_walls_counts(np.asarray(top.goal)[0], position, live, trainer.env.cage_open_of_obs(next_obs), walls,
                               trainer.cfg.eps)


def phase2_cell(phase2: dict | None) -> str:
    """A row's phase-2 mean minimum distances: learned, then subgoals aimed at the goal and random
    subgoals on the same goals (``-`` where the run has no phase 2 or no diagnostic)."""
    if not phase2:
        return "-"
    figures = [phase2["min_distance"]] + [phase2[p]["min_distance"] if p in phase2 else None for p in ("aimed", "random")]
    return ", ".join("-" if f is None else f"{f:.2f}" for f in figures)


def report_table(rows: list[dict]) -> str:
    """The cage rows as a markdown table, robot by robot and seed by seed: the top box at the start
    (walls up) with its greedy success, the top box with the walls gone and whether it stays within
    them, phase 2 (learned, aimed, random), and the goals beyond and within the walls reached."""
    def box(cage: dict, name: str) -> str:
        b = cage["boxes"][name]
        return f"{b['volume']:.1f} ({'within' if b['within_walls'] else 'past the walls'})"

    lines = ["| preset | seed | env steps | top box (m² or m), success | top box, walls gone | "
             "phase 2 min distance (m): learned, aimed, random | goals beyond the walls reached | within |",
             "|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["preset"], r["seed"])):
        cage, counts = r["cage"], r["cage"].get("phase2")
        reached = (f"{counts['reached_beyond']} of {counts['goals_beyond']}", f"{counts['reached_within']} of "
                   f"{counts['goals_within']}") if counts else ("-", "-")
        lines.append(f"| {r['preset']} | {r['seed']} | {r['env_steps'] / 1e6:.2f} M | {box(cage, 'start_closed')}, "
                     f"{r['success']:.2f} | {box(cage, 'start_open')} | {phase2_cell(r['phase2'])} | "
                     f"{reached[0]} | {reached[1]} |")
    return "\n".join(lines)


def main(args: Args) -> None:
    out = Path(args.out)
    if args.report_only:
        if not out.exists():
            raise SystemExit(f"--out: {out} does not exist; nothing to report")
        print(report_table(json.loads(out.read_text())["rows"]))
        return
    rows: list[dict] = []
    for preset in args.presets:
        for seed in args.seeds:
            run_dir = train_or_resume(Path(args.base), preset, seed, args.epochs)
            if args.phase2:
                train_phase2(run_dir)
            loaded = jobs.load_run(run_dir)
            agent, _, state = loaded
            phase2_loaded = jobs.load_run_phase2(run_dir)
            row = {**loaded_run_row(run_dir, preset, seed, args.episodes, loaded, phase2_loaded),
                   "cage": cage_figures(agent, state)}
            if phase2_loaded is not None:
                trainer, _, phase2_state = phase2_loaded
                walls = (row["cage"]["walls_lower"], row["cage"]["walls_upper"])
                row["cage"]["phase2"] = beyond_walls_figures(trainer, phase2_state, jax.random.key(2000 + seed), walls,
                                                             args.episodes)
            rows = merge_row(out, row)  # every row of OUT, this one merged in
            cage = row["cage"]
            phase2_distance = row["phase2"] and row["phase2"]["min_distance"]
            print(json.dumps({"preset": preset, "seed": seed, "env_steps": row["env_steps"],
                              "top_area": row["top_area"], "success": row["success"],
                              "phase2_min_distance": phase2_distance, **cage}), flush=True)
    if rows:  # empty when no preset was given: nothing was written
        print(report_table(rows))
        print(f"wrote {out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
