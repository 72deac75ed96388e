"""The flip figure: where a run's skills flip the robot, drawn from the pooled flip tables
(:mod:`mjx_emp.flip_tables`) that `mjx-emp eval` prints."""

from __future__ import annotations

from pathlib import Path

from mjx_emp.flip_tables import flips_per_100m
from mjx_emp.viz.plots import LEVEL_COLOURS, pyplot, save_figure

PHASE2_COLOUR = "#000000"


def flip_figure(levels: list[dict], phase2: dict | None):
    """Six panels: the flip hazard by primitive step within the skill, the torso's tilt and its
    angular speed in the steps before a flip against before the end of an upright episode
    (phase 1's levels, and phase 2 in black), flips by the goal's place in the box, and phase 2's
    flips by attempt and by subgoal size. Returns the figure."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    (hazard, tilt, spin), (place, attempt, size) = axes
    tables = [(f"level {t['level']}", LEVEL_COLOURS[t["level"] % len(LEVEL_COLOURS)], t) for t in levels]
    if phase2 is not None:
        tables.append(("phase 2", PHASE2_COLOUR, phase2))
    for label, colour, table in tables:
        low = table["by_index"][0]
        steps = [i for i, h in zip(low["index"], low["hazard"]) if h is not None]
        hazard.plot(steps, [h for h in low["hazard"] if h is not None], "o-", color=colour, label=label)
        before = table["before_flip"]
        for ax, name in ((tilt, "tilt"), (spin, "angular_speed")):
            for group, style in (("flipped", "-"), ("upright", ":")):
                points = [(d, v) for d, v in zip(before["steps_before"], before[f"{group}_{name}"]) if v is not None]
                if points:
                    ax.plot(*zip(*points), style, color=colour, label=f"{label}, {group}")
    for t in levels:
        bins = t["by_goal_place"]
        centres = [(lo + hi) / 2 for lo, hi in zip(bins["edges"], bins["edges"][1:])]
        shown = [(c, s) for c, s in zip(centres, bins["share"]) if s is not None]
        if shown:
            place.plot(*zip(*shown), "o-", color=LEVEL_COLOURS[t["level"] % len(LEVEL_COLOURS)],
                       label=f"level {t['level']}")
    if phase2 is not None:
        rows = phase2["by_attempt"]
        attempt.plot([r["attempt"] for r in rows], [r["flipped"] for r in rows], "o-",
                     color=PHASE2_COLOUR, label="phase 2")
        bins = phase2["by_subgoal_size"]
        shown = [(i, s) for i, s in enumerate(bins["share"]) if s is not None]
        if shown:
            size.plot(*zip(*shown), "o-", color=PHASE2_COLOUR, label="phase 2")
        size.set_xticks(range(len(bins["share"])))
        size.set_xticklabels([f"{lo:g}-" + ("" if hi is None else f"{hi:g}")
                              for lo, hi in zip(bins["edges"], bins["edges"][1:])])  # the last bin is open
    texts = ((hazard, "flips per primitive step by step in the skill", "step within the level-0 skill", "flip hazard"),
             (tilt, "torso tilt before the end", "steps before the end (0: the last action's start)", "1 - up z"),
             (spin, "torso angular speed before the end", "steps before the end", "rad/s"),
             (place, "flips by the goal's place in the box", "largest |noise| (0 centre, 1 edge)", "share flipped"),
             (attempt, "phase 2: flips by attempt" + _rate_text(phase2), "attempt index", "share flipped"),
             (size, "phase 2: flips by subgoal size", "subgoal distance from h(s) (m)", "share flipped"))
    for ax, title, xlabel, ylabel in texts:
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        if ax.get_lines():
            ax.legend(fontsize=7)
    runs = levels[0].get("runs", 1)
    fig.suptitle(f"Where the skills flip the robot ({runs} run(s) pooled, greedy episodes)")
    fig.tight_layout()
    return fig


def _rate_text(phase2: dict | None) -> str:
    rate = None if phase2 is None else flips_per_100m(phase2["by_attempt"])
    return "" if rate is None else f" ({rate:.2f} per 100 m gained)"


def plot_flips(levels: list[dict], phase2: dict | None, path: Path) -> Path:
    """:func:`flip_figure` saved to ``path`` (PNG)."""
    return save_figure(flip_figure(levels, phase2), path)
