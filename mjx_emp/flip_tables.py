"""Flip tables as rows keep them (:mod:`mjx_emp.run.flips` measures them): several runs' tables
pooled into one, the rate of flips per distance gained toward phase 2's goals, and the lines
`mjx-emp eval` and `mjx-emp report --flip-table` print. NumPy only, so reports read them
without loading JAX.
"""

from __future__ import annotations

from typing import Any

import numpy as np

WARNING_QUANTILE = 0.99
"""The upright episodes' quantile of tilt (and of angular speed) taken as a warning threshold."""


def flips_per_100m(by_attempt: list[dict]) -> float | None:
    """Phase 2's flips per 100 m gained toward its goals: over the attempts of a flip table's
    ``by_attempt`` rows, the flips (count x share flipped) over the summed progress (distance to
    the goal before less after, in goal-space units, metres for the robots), times 100. It
    separates a gait's risk from how far the policy asks it to go: an option that cuts the share
    of flipped episodes while this rate stays put makes the robot move less, not fall less.
    None where the attempts gained nothing."""
    flips = sum(a["episodes"] * a["flipped"] for a in by_attempt)
    gained = sum(a["episodes"] * a["progress"] for a in by_attempt)
    return 100.0 * flips / gained if gained > 0 else None


def _pooled_bins(tables: list[dict]) -> dict:
    episodes = np.sum([t["episodes"] for t in tables], axis=0)
    flips = np.sum([t["flips"] for t in tables], axis=0)
    return {"edges": tables[0]["edges"], "episodes": episodes.tolist(), "flips": flips.tolist(),
            "share": [float(f / e) if e else None for f, e in zip(flips, episodes)]}


def _run_mean(values: list) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def pooled(tables: list[dict]) -> dict:
    """Flip tables of several runs as one: counts summed (episodes, flips, the bins, the hazard's
    attempts), shares recomputed from them; the tilt and speed series, the shares by start and
    the warnings as means over the runs that have them."""
    first = tables[0]
    flips, episodes = sum(t["flips"] for t in tables), sum(t["episodes"] for t in tables)
    table: dict[str, Any] = {"level": first.get("level"), "runs": len(tables), "episodes": episodes, "flips": flips,
                             "flip_share": flips / episodes if episodes else None}
    table["by_index"] = []
    for level, row in enumerate(first["by_index"]):
        attempts = np.sum([t["by_index"][level]["attempts"] for t in tables], axis=0)
        level_flips = np.sum([t["by_index"][level]["flips"] for t in tables], axis=0)
        table["by_index"].append({"level": level, "index": row["index"], "attempts": attempts.tolist(),
                                  "flips": level_flips.tolist(),
                                  "hazard": [float(f / a) if a else None for f, a in zip(level_flips, attempts)]})
    before = first["before_flip"]
    table["before_flip"] = {"steps_before": before["steps_before"]}
    for name in ("tilt", "angular_speed"):
        for group in ("flipped", "upright"):
            series = [t["before_flip"][f"{group}_{name}"] for t in tables]
            table["before_flip"][f"{group}_{name}"] = [_run_mean(list(at)) for at in zip(*series)]
        table["before_flip"][f"{name}_warning"] = {
            field: _run_mean([t["before_flip"][f"{name}_warning"][field] for t in tables])
            for field in ("threshold", "warned", "median_lead")}
    for name in ("by_goal_place", "by_subgoal_size"):
        if name in first:
            table[name] = _pooled_bins([t[name] for t in tables])
    if "by_start" in first:
        table["by_start"] = {starts: _run_mean([t["by_start"][starts] for t in tables]) for starts in first["by_start"]}
    if "by_attempt" in first:
        table["by_attempt"] = _pooled_attempts([t["by_attempt"] for t in tables])
    return table


def _pooled_attempts(runs: list[list[dict]]) -> list[dict]:
    rows = []
    for attempt in range(max(len(r) for r in runs)):
        at = [r[attempt] for r in runs if len(r) > attempt]
        count = sum(a["episodes"] for a in at)
        rows.append({"attempt": attempt, "episodes": count,
                     **{field: sum(a[field] * a["episodes"] for a in at) / count
                        for field in ("progress", "distance_after", "upside_down_before", "upside_down_after",
                                      "cut_short", "flipped")}})
    return rows


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f}%"


def _number(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _bins_text(bins: dict, unit: str = "") -> str:
    edges = bins["edges"]
    spans = [f"{_number(lo, 2).rstrip('0').rstrip('.')}-{'' if hi is None else _number(hi, 2).rstrip('0').rstrip('.')}"
             f"{unit}" for lo, hi in zip(edges, edges[1:] + [None])][: len(bins["share"])]
    return ", ".join(f"{span} {_percent(share)} of {count}"
                     for span, share, count in zip(spans, bins["share"], bins["episodes"]) if count)


def _hazard_text(row: dict, what: str) -> str:
    return (f"  level {row['level']} flips per {what} by its index: "
            + " ".join(f"{i}:{_percent(h)}" for i, h in zip(row["index"], row["hazard"]) if h is not None))


def _before_text(before: dict) -> list[str]:
    shown = [d for d in (0, 1, 2, 3, 5, 9) if d < len(before["steps_before"])]
    lines = ["  | torso, steps before the end (0: the state the last action began in) | "
             + " | ".join(str(d) for d in shown) + " |", "  |---|" + "---|" * len(shown)]
    for name, label in (("tilt", "tilt (1 - up z)"), ("angular_speed", "angular speed (rad/s)")):
        for group in ("flipped", "upright"):
            lines.append(f"  | {label}, {group} | " + " | ".join(_number(before[f'{group}_{name}'][d]) for d in shown)
                         + " |")
    warned = [f"{label} above {_number(w['threshold'])} (the upright steps' {int(100 * WARNING_QUANTILE)}th "
              f"percentile) within the last {len(before['steps_before'])} steps of {_percent(w['warned'])} of flips, "
              f"a median {_number(w['median_lead'], 1)} steps before"
              for name, label in (("tilt", "tilt"), ("angular_speed", "angular speed"))
              if (w := before[f"{name}_warning"])["threshold"] is not None]
    return lines + ([f"  warning: {'; '.join(warned)}"] if warned else [])


def flip_text(levels: list[dict], phase2: dict | None) -> list[str]:
    """The pooled flip tables (:func:`pooled`) of phase 1's levels and of phase 2, as lines."""
    lines = [f"flips (the torso's up axis below the horizon; {levels[0]['runs']} run(s) pooled, greedy episodes):",
             "| level | episodes | flipped | from s0 | from chained starts | by the goal's place in the box "
             "(centre 0 to edge 1) |", "|---|---|---|---|---|---|"]
    lines += [f"| {t['level']} | {t['episodes']} | {_percent(t['flip_share'])} | {_percent(t['by_start']['initial'])} "
              f"| {_percent(t['by_start']['chained'])} | {_bins_text(t['by_goal_place'])} |" for t in levels]
    for t in levels:
        if t["flips"]:
            lines += [f"level {t['level']}'s episodes:", *_detail_lines(t)]
    if phase2 is not None:
        lines.append(f"phase 2: {_percent(phase2['flip_share'])} of {phase2['episodes']} greedy episodes flipped; "
                     "by attempt: " + " ".join(f"{a['attempt']}:{_percent(a['flipped'])}" for a in phase2["by_attempt"]))
        lines.append(f"  flips per 100 m gained toward the goal: {_number(flips_per_100m(phase2['by_attempt']))}")
        lines.append(f"  by subgoal size: {_bins_text(phase2['by_subgoal_size'], ' m')}")
        if phase2["flips"]:
            lines += _detail_lines(phase2)
    return lines


def _detail_lines(table: dict) -> list[str]:
    """Where in the skills the flips of a table happened, and the torso before them."""
    return [*(_hazard_text(row, "primitive step" if row["level"] == 0 else "action") for row in table["by_index"]),
            *_before_text(table["before_flip"])]
