"""Pictures of a run (matplotlib, PNG): goal-space growth over epochs, the learned
goal-space boxes at the start state drawn over the arena with sample trajectories, and
phase 2's learning curves; for the flat skill learners (no goal spaces), their learning
curves and the paths of the greedy skills that METRA's coverage count reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mjx_emp.algos.registry import GOAL_SPACES, LATENT_SKILLS
from mjx_emp.run.store import METRICS_FILE, read_metrics, run_skill_kind


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only; no display needed
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    fig.clf()
    _pyplot().close(fig)
    return path


def plot_goal_space_growth(metrics: list[dict], path: Path) -> Path:
    """Goal-space volume (log scale) and greedy success per level against epoch, saved as PNG."""
    plt = _pyplot()

    if not metrics:
        raise ValueError("no epochs to plot: metrics is empty")
    epochs = [m["epoch"] for m in metrics]
    levels = len(metrics[0]["levels"])
    fig, (volume_ax, success_ax) = plt.subplots(2, 1, sharex=True, figsize=(7, 6))
    for level in range(levels):
        volume_ax.plot(epochs, [m["levels"][level]["volume"] for m in metrics], label=f"level {level}")
        success = [m["levels"][level]["success"] for m in metrics]
        success_ax.plot(epochs, [float("nan") if s is None else s for s in success], label=f"level {level}")
    volume_ax.set_yscale("log")
    volume_ax.set_ylabel("goal-space volume at s0")
    volume_ax.legend()
    success_ax.set_ylabel("greedy success in own goal space")
    success_ax.set_xlabel("epoch")
    success_ax.set_ylim(0, 1.05)
    fig.tight_layout()
    return _save(fig, path)


def plot_phase2_curves(metrics: list[dict], eps: float, path: Path) -> Path:
    """Phase 2's greedy mean minimum distance to goal (with eps marked) and success against env steps."""
    plt = _pyplot()

    if not metrics:
        raise ValueError("no epochs to plot: metrics is empty")
    steps = [m["env_steps"] for m in metrics]
    fig, (distance_ax, success_ax) = plt.subplots(2, 1, sharex=True, figsize=(7, 6))
    distance_ax.plot(steps, [m["min_distance"] for m in metrics], label="greedy policy")
    distance_ax.axhline(eps, color="0.4", linestyle="--", label=f"eps = {eps:g}")
    distance_ax.set_ylabel("mean min distance to goal")
    distance_ax.set_ylim(bottom=0)
    distance_ax.legend()
    success_ax.plot(steps, [m["success"] for m in metrics])
    success_ax.set_ylabel("success (within eps)")
    success_ax.set_xlabel("phase-2 env steps")
    success_ax.set_ylim(0, 1.05)
    fig.tight_layout()
    return _save(fig, path)


SKILL_DIAGNOSTIC = {"diayn": "posterior_std", "hidio": "posterior_std", "metra": "dual_lambda"}
"""The per-epoch figure each flat skill learner adds to reward and displacement."""


def plot_skill_learning(metrics: list[dict], path: Path) -> Path:
    """A flat skill learner's mean intrinsic reward, skill displacement and (DIAYN, HIDIO:
    posterior std; METRA: dual lambda) against env steps, saved as PNG."""
    plt = _pyplot()

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
    return _save(fig, path)


def plot_goal_space_boxes(start: list[float], boxes: list[dict], trajectories: list, path: Path,
                          title: str = "") -> Path:
    """Each level's goal-space box around h(s0) over the arena, with trajectories of h(s).

    ``boxes`` are ``HEAgent.goal_spaces`` entries (shift and half_width relative to
    h(s0)), none for a flat skill learner; ``trajectories`` are [T, d] arrays of h(s). 1-D goal spaces are drawn as
    intervals on the x axis, with time running upward for the trajectories.
    """
    from matplotlib.patches import Rectangle

    plt = _pyplot()
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig, ax = plt.subplots(figsize=(6, 6))
    two_d = len(start) >= 2
    for level, box in reversed(list(enumerate(boxes))):
        colour = colours[level % len(colours)]
        low = [s + c - w for s, c, w in zip(start, box["shift"], box["half_width"])]
        width = [2 * w for w in box["half_width"]]
        height = width[1] if two_d else 1.0
        ax.add_patch(Rectangle((low[0], low[1] if two_d else -0.5), width[0], height, fill=False,
                               edgecolor=colour, linewidth=2, label=f"level {level} goal space"))
    for index, trajectory in enumerate(trajectories):
        trajectory = list(map(list, trajectory))
        xs = [p[0] for p in trajectory]
        ys = [p[1] for p in trajectory] if two_d else [t / max(len(trajectory) - 1, 1) - 0.5 for t in range(len(trajectory))]
        ax.plot(xs, ys, color="0.3", linewidth=1, alpha=0.8, label="trajectories" if index == 0 else None)
    ax.plot([start[0]], [start[1] if two_d else 0.0], marker="o", color="black", label="h(s0)")
    ax.set_xlabel("x")
    ax.set_ylabel("y" if two_d else "time (trajectories)")
    if two_d:
        ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.legend(loc="upper right", fontsize="small")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return _save(fig, path)


def plot_run(run_dir: Path, chains: int = 8, skills_per_chain: int = 1) -> list[Path]:
    """Every picture of a run directory, written to RUN_DIR/plots/; returns their paths.

    Always the goal-space growth. With checkpoints, also the goal-space boxes at the
    initial state before training (the run's own seed rebuilds epoch 0 exactly) and at the
    newest checkpoint, each with ``chains`` greedy chains of ``skills_per_chain`` top-level
    skills from the initial state. With a phase-2 directory (RUN_DIR/phase2), also its
    learning curves.
    """
    import jax

    from mjx_emp.run.checkpoint import CHECKPOINT_SUBDIR
    from mjx_emp.run.jobs import load_run
    from mjx_emp.viz.render import first_skills, record_rollout

    run_dir = Path(run_dir)
    paths = [plot_goal_space_growth(read_metrics(run_dir), run_dir / "plots" / "goal_space_growth.png")]
    paths += _phase2_plot(run_dir)
    if not (run_dir / CHECKPOINT_SUBDIR).exists():
        return paths
    trainer, epoch, state = load_run(run_dir)
    steps = skills_per_chain * int(np.prod(trainer.cfg.n))
    start = np.asarray(trainer.env.goal_of_obs(trainer.initial_obs)).tolist()
    for name, snapshot, shown_epoch in (("goal_spaces_epoch0.png", trainer.init(), 0),
                                         ("goal_spaces.png", state, epoch)):
        plan = trainer.skill_chain(snapshot)
        recordings = [first_skills(record_rollout(plan, jax.random.key(seed), steps), skills_per_chain)
                      for seed in range(chains)]
        trajectories = [r.qpos[:, list(trainer.env.goal_qpos)] for r in recordings]
        paths.append(plot_goal_space_boxes(start, trainer.goal_spaces(snapshot), trajectories,
                                           run_dir / "plots" / name, title=f"{trainer.cfg.env}, epoch {shown_epoch}"))
    return paths


def _phase2_plot(run_dir: Path) -> list[Path]:
    """RUN_DIR/phase2's learning curves as RUN_DIR/plots/phase2_curves.png, if it has any."""
    from mjx_emp.phase2.config import Phase2Config
    from mjx_emp.run.store import PHASE2_SUBDIR, read_run_config

    phase2_dir = run_dir / PHASE2_SUBDIR
    phase2_metrics = read_metrics(phase2_dir) if (phase2_dir / METRICS_FILE).exists() else []
    if not phase2_metrics:
        return []
    eps = read_run_config(phase2_dir, "run_dir", Phase2Config).eps
    return [plot_phase2_curves(phase2_metrics, eps, run_dir / "plots" / "phase2_curves.png")]


def plot_skill_run(run_dir: Path, skills: int = 48) -> list[Path]:
    """Every picture of a flat skill learner's run directory, written to RUN_DIR/plots/.

    Its learning curves; with checkpoints, the paths of ``skills`` greedy skills from the
    initial state before training (the run's seed rebuilds epoch 0) and at the newest
    checkpoint, titled with their coverage count; phase 2's curves where RUN_DIR/phase2 exists.
    """
    import jax

    from mjx_emp.metrics import coverage_cells
    from mjx_emp.run.checkpoint import CHECKPOINT_SUBDIR
    from mjx_emp.run.jobs import load_run

    run_dir = Path(run_dir)
    paths = [plot_skill_learning(read_metrics(run_dir), run_dir / "plots" / "skill_learning.png")]
    paths += _phase2_plot(run_dir)
    if not (run_dir / CHECKPOINT_SUBDIR).exists():
        return paths
    agent, epoch, state = load_run(run_dir)
    start = np.asarray(agent.env.goal_of_obs(agent.initial_obs)).tolist()
    for name, snapshot, shown_epoch in (("skills_epoch0.png", agent.init(), 0), ("skills.png", state, epoch)):
        positions, mask = agent.skill_paths(snapshot, jax.random.key(0), skills)
        trajectories = [positions[mask[:, i], i] for i in range(skills)]
        title = (f"{agent.method}, {agent.cfg.env}, epoch {shown_epoch}: {skills} greedy skills, "
                 f"{coverage_cells(positions, mask)} cells")
        paths.append(plot_goal_space_boxes(start, [], trajectories, run_dir / "plots" / name, title=title))
    return paths


def plot_any_run(run_dir: Path) -> list[Path]:
    """Every picture of a run directory of any algorithm, as its registry entry's kind of skills
    calls for (:func:`plot_run` for goal spaces, :func:`plot_skill_run` for latent skills)."""
    draw = {GOAL_SPACES: plot_run, LATENT_SKILLS: plot_skill_run}[run_skill_kind(Path(run_dir))]
    return draw(Path(run_dir))
