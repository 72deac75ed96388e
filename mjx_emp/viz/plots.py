"""Pictures of a run (matplotlib, PNG): goal-space growth over epochs, the learned
goal-space boxes at the start state drawn over the arena with sample trajectories, and
phase 2's learning curves; for the flat skill learners (no goal spaces), their learning
curves and the paths of the greedy skills that METRA's coverage count reads."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import jax
import matplotlib
import numpy as np
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from mjx_emp.algos.registry import GOAL_SPACES, LATENT_SKILLS, algorithm_of
from mjx_emp.envs.registry import DOMAINS
from mjx_emp.errors import ConfigError
from mjx_emp.metrics import coverage_cells
from mjx_emp.phase2.config import Phase2Config
from mjx_emp.run.jobs import load_run
from mjx_emp.run.store import (
    CHECKPOINT_SUBDIR,
    CONFIG_FILE,
    METRICS_FILE,
    PHASE2_SUBDIR,
    read_metrics,
    read_run_config,
    replace_file,
    run_skill_kind,
)
from mjx_emp.viz.render import first_skills, record_rollout


def pyplot():
    matplotlib.use("Agg")  # files only; no display needed
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path) -> Path:
    path = replace_file(Path(path), lambda temporary: fig.savefig(temporary, dpi=100))
    fig.clf()
    pyplot().close(fig)
    return path


@dataclass(frozen=True)
class AxesContent:
    """What one set of a figure's axes shows, read back from the axes: its texts, its y scale,
    its legend's entries and, per labelled line, the points plotted (x values, y values)."""

    title: str
    xlabel: str
    ylabel: str
    yscale: str
    legend: list[str]
    series: dict[str, tuple[list[float], list[float]]]


def axes_content(fig) -> list[AxesContent]:
    """Each of ``fig``'s axes, in the order they were made, as :class:`AxesContent` (lines
    without a label of their own, such as an unlabelled curve, are left out of ``series``)."""
    shown = []
    for ax in fig.axes:
        legend = ax.get_legend()
        series = {line.get_label(): ([float(x) for x in line.get_xdata()], [float(y) for y in line.get_ydata()])
                  for line in ax.get_lines() if not line.get_label().startswith("_")}
        shown.append(AxesContent(ax.get_title(), ax.get_xlabel(), ax.get_ylabel(), ax.get_yscale(),
                                 [text.get_text() for text in legend.get_texts()] if legend else [], series))
    return shown


METHOD_COLOURS = {"HE k=1": "#1f77b4", "HE k=2": "#d62728", "HE k=3": "#9467bd", "HE k=4": "#8c564b",
                  "GCRL k=1": "#2ca02c", "DIAYN": "#ff7f0e", "HIDIO": "#e377c2", "DADS": "#7f7f7f",
                  "METRA": "#17becf"}
"""One colour per method in every chart (matplotlib's tab10 values), so a method keeps its colour
from figure to figure; other labels take the next unused colour of the cycle."""
LEVEL_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728")
"""Per-level colours within one run's charts (level 0 first)."""


def method_label(cfg) -> str:
    """How a run's method is named in legends: ``HE k=2``, ``GCRL k=1``, ``METRA`` (goal-space
    algorithms with their level count, flat skill learners by name)."""
    algorithm = algorithm_of(cfg)
    return f"{algorithm.name.upper()} k={cfg.k}" if algorithm.skills == GOAL_SPACES else algorithm.name.upper()


def volume_unit(env: str) -> str:
    """The unit of a goal-space volume on ``env``: m² for (x, y) goals, m for x goals."""
    return "m²" if len(DOMAINS[env].goal_qpos) == 2 else "m"


def colour_of(label: str, taken: list[str]) -> str:
    """``label``'s colour: its fixed one, else the first colour of the cycle not ``taken``."""
    if label in METHOD_COLOURS:
        return METHOD_COLOURS[label]
    used = {to_hex(c) for c in taken}  # the cycle may hold RGB tuples where METHOD_COLOURS holds hex
    spare = [to_hex(c) for c in pyplot().rcParams["axes.prop_cycle"].by_key()["color"] if to_hex(c) not in used]
    return spare[0] if spare else "black"


def _steps(metrics: list[dict]) -> np.ndarray:
    """Each line's env steps (its epoch where a line has none)."""
    return np.array([m.get("env_steps", m["epoch"]) for m in metrics], float)


def _values(metrics: list[dict], read) -> np.ndarray:
    return np.array([np.nan if read(m) is None else read(m) for m in metrics], float)


def seed_band(curves: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray | int]:
    """Several seeds' curves (env steps, value) on one grid: the steps of the run that ends first,
    each run interpolated there over its finite points; mean and sample std over seeds (std 0
    for one seed)."""
    shortest = min(curves, key=lambda c: c[0][-1])[0]
    grid = shortest[shortest <= min(c[0][-1] for c in curves)]
    rows = []
    for steps, values in curves:
        finite = np.isfinite(values)
        rows.append(np.interp(grid, steps[finite], values[finite]) if finite.any() else np.full(len(grid), np.nan))
    rows = np.stack(rows)
    std = rows.std(axis=0, ddof=1) if len(rows) > 1 else np.zeros(len(grid))
    return {"steps": grid, "mean": rows.mean(axis=0), "std": std, "count": len(rows)}


def plot_seed_bands(groups: dict[str, list[list[dict]]], panels: list[tuple[str, object]], path: Path,
                    title: str = "", log_first: bool = False) -> Path:
    """Learning curves of several methods against env steps: per method (``groups``: label ->
    each seed's metrics lines) the mean over seeds with a shaded band of one sample standard
    deviation. ``panels`` are (y label with its unit, read(metrics line) -> value)."""
    plt = pyplot()
    if not groups or any(not runs or any(not m for m in runs) for runs in groups.values()):
        raise ValueError("no epochs to plot: a run has no metrics")
    fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(7, 2.6 * len(panels) + 0.8), squeeze=False)
    taken: list[str] = []
    for label, runs in groups.items():
        colour = colour_of(label, taken)
        taken.append(colour)
        for ax, (_, read) in zip(axes[:, 0], panels):
            band = seed_band([(_steps(m), _values(m, read)) for m in runs])
            legend = f"{label} ({band['count']} seed{'s' if band['count'] > 1 else ''})"
            ax.plot(band["steps"], band["mean"], color=colour, label=legend)
            if band["count"] > 1:
                ax.fill_between(band["steps"], band["mean"] - band["std"], band["mean"] + band["std"],
                                color=colour, alpha=0.2, linewidth=0)
    for ax, (ylabel, _) in zip(axes[:, 0], panels):
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    if log_first:
        axes[0, 0].set_yscale("log")
    axes[0, 0].legend(fontsize="small", title="mean ± 1 sample std over seeds", title_fontsize="small")
    axes[-1, 0].set_xlabel("environment steps")
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_goal_space_growth(metrics: list[dict], path: Path, unit: str = "", title: str = "") -> Path:
    """One run's goal-space volume at s0 (log scale) and greedy success per level against env
    steps (epochs where the lines have no env steps), saved as PNG: the figure of
    :func:`goal_space_growth_figure`."""
    return save_figure(goal_space_growth_figure(metrics, unit, title), path)


def goal_space_growth_figure(metrics: list[dict], unit: str = "", title: str = ""):
    """The figure :func:`plot_goal_space_growth` saves, drawn without saving it (a matplotlib
    Figure outside pyplot's figure registry; :func:`axes_content` reads back what it shows)."""
    if not metrics:
        raise ValueError("no epochs to plot: metrics is empty")
    steps = _steps(metrics)
    levels = len(metrics[0]["levels"])
    fig = Figure(figsize=(7, 6))
    volume_ax, success_ax = fig.subplots(2, 1, sharex=True)
    for level in range(levels):
        colour = LEVEL_COLOURS[level % len(LEVEL_COLOURS)]
        volume_ax.plot(steps, [m["levels"][level]["volume"] for m in metrics], color=colour, label=f"level {level}")
        success_ax.plot(steps, _values(metrics, lambda m, lv=level: m["levels"][lv]["success"]), color=colour,
                        label=f"level {level}")
    volume_ax.set_yscale("log")
    volume_ax.set_ylabel(f"goal-space volume at s0 ({unit})" if unit else "goal-space volume at s0")
    volume_ax.legend()
    volume_ax.set_title(title or "goal-space growth")
    success_ax.set_ylabel("greedy success in own goal space")
    success_ax.set_xlabel("environment steps" if "env_steps" in metrics[0] else "epoch")
    success_ax.set_ylim(0, 1.05)
    fig.tight_layout()
    return fig


def plot_phase2_curves(metrics: list[dict], eps: float, path: Path) -> Path:
    """Phase 2's greedy mean minimum distance to goal (with eps marked) and success against env steps."""
    plt = pyplot()

    if not metrics:
        raise ValueError("no epochs to plot: metrics is empty")
    steps = [m["env_steps"] for m in metrics]
    fig, (distance_ax, success_ax) = plt.subplots(2, 1, sharex=True, figsize=(7, 6))
    distance_ax.plot(steps, [m["min_distance"] for m in metrics], label="greedy policy")
    distance_ax.axhline(eps, color="0.4", linestyle="--", label=f"eps = {eps:g}")
    distance_ax.set_ylabel("mean min distance to goal (m)")
    distance_ax.set_title("phase 2: reaching goals with the skills")
    distance_ax.set_ylim(bottom=0)
    distance_ax.legend()
    success_ax.plot(steps, [m["success"] for m in metrics])
    success_ax.set_ylabel("success (within eps)")
    success_ax.set_xlabel("phase-2 env steps")
    success_ax.set_ylim(0, 1.05)
    fig.tight_layout()
    return save_figure(fig, path)


SKILL_DIAGNOSTIC = {"diayn": "posterior_std", "hidio": "posterior_std", "metra": "dual_lambda"}
"""The per-epoch figure each flat skill learner adds to reward and displacement."""


def plot_skill_learning(metrics: list[dict], path: Path) -> Path:
    """A flat skill learner's mean intrinsic reward, skill displacement and (DIAYN, HIDIO:
    posterior std; METRA: dual lambda) against env steps, saved as PNG."""
    plt = pyplot()

    if not metrics:
        raise ValueError("no epochs to plot: metrics is empty")
    diagnostic = SKILL_DIAGNOSTIC.get(metrics[0]["algorithm"])
    names = ["reward", "displacement"] + ([diagnostic] if diagnostic else [])
    steps = [m["env_steps"] for m in metrics]
    fig, axes = plt.subplots(len(names), 1, sharex=True, figsize=(7, 2.2 * len(names) + 0.6))
    for ax, name in zip(axes, names):
        ax.plot(steps, [float("nan") if m[name] is None else m[name] for m in metrics])
        ax.set_ylabel(name.replace("_", " "))
    axes[0].set_title(f"{metrics[0]['algorithm']} phase 1")
    axes[-1].set_xlabel("env steps")
    fig.tight_layout()
    return save_figure(fig, path)


def draw_skills(ax, start: list[float], boxes: list[dict], trajectories: list, goals: list | None = None,
                cell: float = 1.0) -> None:
    """On ``ax``: the 1 m cells the trajectories visit (shaded: what the coverage count counts),
    each level's goal-space box around h(s0), the trajectories of h(s), each skill's goal and
    h(s0). ``boxes`` are ``goal_spaces`` entries (shift and half_width relative to h(s0)), none
    for a flat skill learner. 1-D goal spaces are drawn on the x axis, time running upward."""
    two_d = len(start) >= 2
    points = [np.asarray(t, float).reshape(-1, len(start)) for t in trajectories]
    visited = np.unique(np.floor(np.concatenate(points) / cell), axis=0) if points and len(np.concatenate(points)) else []
    for index, corner in enumerate(visited):
        ax.add_patch(Rectangle((corner[0] * cell, corner[1] * cell if two_d else -0.5), cell, cell if two_d else 1.0,
                               facecolor="0.85", edgecolor="0.7", linewidth=0.5, zorder=0,
                               label=f"visited {cell:g} m cells ({len(visited)})" if index == 0 else None))
    for level, box in reversed(list(enumerate(boxes))):
        low = [s + c - w for s, c, w in zip(start, box["shift"], box["half_width"])]
        width = [2 * w for w in box["half_width"]]
        ax.add_patch(Rectangle((low[0], low[1] if two_d else -0.5), width[0], width[1] if two_d else 1.0, fill=False,
                               edgecolor=LEVEL_COLOURS[level % len(LEVEL_COLOURS)], linewidth=2,
                               label=f"level {level} goal space", zorder=2))
    for index, trajectory in enumerate(points):
        xs = trajectory[:, 0]
        ys = trajectory[:, 1] if two_d else np.linspace(-0.5, 0.5, len(trajectory))
        ax.plot(xs, ys, color="0.3", linewidth=1, alpha=0.8, label="paths of h(s)" if index == 0 else None, zorder=3)
    for index, goal in enumerate(goals or []):
        ax.plot([goal[0]], [goal[1] if two_d else 0.5], marker="x", color="#d62728", markersize=6, linestyle="none",
                label="each skill's goal" if index == 0 else None, zorder=4)
    ax.plot([start[0]], [start[1] if two_d else 0.0], marker="o", color="black", label="h(s0)", zorder=5)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)" if two_d else "time (paths)")
    if two_d:
        ax.set_aspect("equal", adjustable="box")  # panels share their axes, so the box gives way, not the data
    ax.autoscale_view()


def plot_skill_panels(start: list[float], panels: list[dict], path: Path, title: str = "") -> Path:
    """Panels side by side on shared axes (e.g. epoch 0 and the newest epoch), each drawn by
    :func:`draw_skills` from its ``boxes``, ``trajectories``, ``goals`` and ``title``."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels), sharex=True, sharey=True, figsize=(6 * len(panels), 6), squeeze=False)
    for ax, panel in zip(axes[0], panels):
        draw_skills(ax, start, panel.get("boxes", []), panel["trajectories"], panel.get("goals"))
        ax.set_title(panel.get("title", ""))
    axes[0, -1].legend(loc="upper right", fontsize="small")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_goal_space_boxes(start: list[float], boxes: list[dict], trajectories: list, path: Path,
                          title: str = "", goals: list | None = None) -> Path:
    """One panel of :func:`plot_skill_panels`: the boxes per level around h(s0), paths of h(s), goals."""
    return plot_skill_panels(start, [{"boxes": boxes, "trajectories": trajectories, "goals": goals, "title": title}],
                             path)


def plot_run(run_dir: Path, chains: int = 8, skills_per_chain: int = 1) -> list[Path]:
    """Every picture of a goal-space run directory, written to RUN_DIR/plots/; returns their paths.

    Always the goal-space growth. With checkpoints, ``goal_spaces.png``: the boxes at the
    initial state before training (the run's own seed rebuilds epoch 0 exactly) and at the
    newest checkpoint on shared axes, each with ``chains`` greedy chains of ``skills_per_chain``
    top-level skills from the initial state, their goals marked. With a phase-2 directory
    (RUN_DIR/phase2), also its learning curves.
    """
    run_dir = Path(run_dir)
    name, unit = run_name(run_dir)
    paths = [plot_goal_space_growth(read_metrics(run_dir), run_dir / "plots" / "goal_space_growth.png", unit,
                                    f"{name}: goal-space growth")]
    paths += _phase2_plot(run_dir)
    if not (run_dir / CHECKPOINT_SUBDIR).exists():
        return paths
    trainer, epoch, state = load_run(run_dir)
    steps = skills_per_chain * int(np.prod(trainer.cfg.n))
    start = np.asarray(trainer.env.goal_of_obs(trainer.initial_obs)).tolist()
    panels = []
    for snapshot, shown_epoch in ((trainer.init(), 0), (state, epoch)):
        plan = trainer.skill_chain(snapshot)
        recordings = [first_skills(record_rollout(plan, jax.random.key(seed), steps), skills_per_chain)
                      for seed in range(chains)]
        top = trainer.goal_spaces(snapshot)[-1]
        panels.append({"boxes": trainer.goal_spaces(snapshot), "title": f"epoch {shown_epoch}: top box "
                       f"{top['volume']:.3g} {unit}",
                       "trajectories": [r.qpos[:, list(trainer.env.goal_qpos)] for r in recordings],
                       "goals": [goal for r in recordings for goal in _skill_goals(r)]})
    paths.append(plot_skill_panels(start, panels, run_dir / "plots" / "goal_spaces.png",
                                   f"{name}: {chains} greedy top-level skills from s0"))
    return paths


def run_name(run_dir: Path) -> tuple[str, str]:
    """How a run is titled (``HE k=2 on ant_field``) and the unit of its goal-space volume; a
    directory without config.json is plainly "run", without a unit."""
    if not (Path(run_dir) / CONFIG_FILE).exists():
        return "run", ""
    cfg = read_run_config(Path(run_dir), "run_dir")
    return f"{method_label(cfg)} on {cfg.env}", volume_unit(cfg.env)


def _skill_goals(recording) -> list[np.ndarray]:
    """The top-level goal of each skill in a recording (where the top goal changes)."""
    top = recording.goals[:, -1]
    starts = [0, *(np.flatnonzero(np.any(top[1:] != top[:-1], axis=-1)) + 1)]
    return [top[i] for i in starts]


def _phase2_plot(run_dir: Path) -> list[Path]:
    """RUN_DIR/phase2's learning curves as RUN_DIR/plots/phase2_curves.png, if it has any."""
    phase2_dir = run_dir / PHASE2_SUBDIR
    phase2_metrics = read_metrics(phase2_dir) if (phase2_dir / METRICS_FILE).exists() else []
    if not phase2_metrics:
        return []
    eps = read_run_config(phase2_dir, "run_dir", Phase2Config).eps
    return [plot_phase2_curves(phase2_metrics, eps, run_dir / "plots" / "phase2_curves.png")]


def plot_skill_run(run_dir: Path, skills: int = 48) -> list[Path]:
    """Every picture of a flat skill learner's run directory, written to RUN_DIR/plots/.

    Its learning curves; with checkpoints, ``skills.png``: the paths of ``skills`` greedy skills
    from the initial state before training (the run's seed rebuilds epoch 0) and at the newest
    checkpoint on shared axes, the visited cells shaded and counted; phase 2's curves where
    RUN_DIR/phase2 exists.
    """
    run_dir = Path(run_dir)
    paths = [plot_skill_learning(read_metrics(run_dir), run_dir / "plots" / "skill_learning.png")]
    paths += _phase2_plot(run_dir)
    if not (run_dir / CHECKPOINT_SUBDIR).exists():
        return paths
    agent, epoch, state = load_run(run_dir)
    start = np.asarray(agent.env.goal_of_obs(agent.initial_obs)).tolist()
    panels = []
    for snapshot, shown_epoch in ((agent.init(), 0), (state, epoch)):
        positions, mask = agent.skill_paths(snapshot, jax.random.key(0), skills)
        panels.append({"trajectories": [positions[mask[:, i], i] for i in range(skills)],
                       "title": f"epoch {shown_epoch}: {coverage_cells(positions, mask)} cells"})
    name, _ = run_name(run_dir)
    paths.append(plot_skill_panels(start, panels, run_dir / "plots" / "skills.png",
                                   f"{name}: {skills} greedy skills from s0"))
    return paths


def plot_any_run(run_dir: Path) -> list[Path]:
    """Every picture of a run directory of any algorithm, as its registry entry's kind of skills
    calls for (:func:`plot_run` for goal spaces, :func:`plot_skill_run` for latent skills)."""
    draw = {GOAL_SPACES: plot_run, LATENT_SKILLS: plot_skill_run}[run_skill_kind(Path(run_dir))]
    return draw(Path(run_dir))


def plot_runs(run_dirs: list[Path], out: Path) -> list[Path]:
    """Several runs (seeds, methods) of one domain compared in ``out``: ``learning_curves.png``
    (goal-space algorithms: the top box at s0 and its greedy success; flat skill learners: skill
    displacement and intrinsic reward) and, where runs have phase 2, ``phase2_curves.png``; each
    method (:func:`method_label`) as the mean over its seeds with a one-std band, against env steps."""
    configs = [read_run_config(Path(d), "run_dirs") for d in run_dirs]
    envs = sorted({cfg.env for cfg in configs})
    kinds = sorted({run_skill_kind(Path(d)) for d in run_dirs})
    if len(envs) > 1 or len(kinds) > 1:
        raise ConfigError(f"run_dirs: runs of one domain and one kind of skills share a chart; got domains {envs}, "
                          f"skills {kinds}")
    groups: dict[str, list[list[dict]]] = {}
    phase2: dict[str, list[list[dict]]] = {}
    eps = set()
    for run_dir, cfg in zip(run_dirs, configs):
        groups.setdefault(method_label(cfg), []).append(read_metrics(Path(run_dir)))
        phase2_dir = Path(run_dir) / PHASE2_SUBDIR
        if (phase2_dir / METRICS_FILE).exists() and read_metrics(phase2_dir):
            phase2.setdefault(method_label(cfg), []).append(read_metrics(phase2_dir))
            eps.add(read_run_config(phase2_dir, "run_dirs", Phase2Config).eps)
    if kinds == [GOAL_SPACES]:
        panels = [(f"top goal-space volume at s0 ({volume_unit(envs[0])})", lambda m: m["levels"][-1]["volume"]),
                  ("greedy success, top level", lambda m: m["levels"][-1]["success"])]
    else:
        panels = [("skill displacement (m)", lambda m: m["displacement"]), ("intrinsic reward", lambda m: m["reward"])]
    paths = [plot_seed_bands(groups, panels, Path(out) / "learning_curves.png", f"phase 1 on {envs[0]}",
                             log_first=kinds == [GOAL_SPACES])]
    if phase2:
        title = f"phase 2 on {envs[0]}" + (f" (eps {eps.pop():g})" if len(eps) == 1 else "")
        paths.append(plot_seed_bands(phase2, [("mean min distance to goal (m)", lambda m: m["min_distance"]),
                                              ("success (within eps)", lambda m: m["success"])],
                                     Path(out) / "phase2_curves.png", title))
    return paths

