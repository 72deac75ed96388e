"""What a report reads from evaluation rows and the statistics it gives over seeds: the named
metrics (a path into a row, a unit, which way is better), and per metric n, mean, std, standard
error and the interquartile mean with its stratified-bootstrap interval, and the probability of
improvement of one row over another (Agarwal et al., 2021, computed by ``rliable``, which is
imported where it is used: an optional dependency, ``mjx-emp[report]``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from mjx_emp.errors import ConfigError
from mjx_emp.flip_tables import flips_per_100m

DEFAULT_REPS = 2000
"""Bootstrap resamples per interval: a few tenths of a second per metric, and an interval
whose ends move by well under the third significant digit from seed to seed at 3-10 runs."""

CONFIDENCE = 0.95
"""Coverage of every bootstrap interval."""

# --------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class Metric:
    """One number a row may carry: where it sits in the row, how tables and axes name it, and
    which way is better (the probability of improvement reads it)."""

    name: str
    path: tuple[str, ...]
    label: str
    unit: str
    lower_is_better: bool | None
    """Which way is better: True for lower, False for higher, None where the metric does not
    say (a figure named by its path); a table marks it ↓, ↑ or nothing."""
    derive: Callable[[Any], float | None] | None = None
    """A figure computed from what rows already hold at ``path`` (rows recorded before the
    figure was named get it too); None: the value at ``path`` is the metric."""

    @property
    def heading(self) -> str:
        """The label with its unit, as an axis or a column names the metric."""
        return f"{self.label} ({self.unit})" if self.unit else self.label


def _metric(name: str, path: tuple[str, ...], label: str, unit: str = "",
            lower_is_better: bool | None = False, derive: Callable[[Any], float | None] | None = None) -> Metric:
    return Metric(name, path, label, unit, lower_is_better, derive)


METRICS: dict[str, Metric] = {m.name: m for m in (
    _metric("phase2_min_distance", ("figures", "phase2", "min_distance"), "phase-2 min distance", "m", True),
    _metric("phase2_success", ("figures", "phase2", "success"), "phase-2 success", "fraction"),
    _metric("phase2_cut_short", ("figures", "phase2", "cut_short"),
            "phase-2 episodes ended by a flip", "fraction", True),
    _metric("phase2_aimed_min_distance", ("figures", "phase2", "aimed", "min_distance"),
            "phase-2 aimed min distance", "m", True),
    _metric("phase2_aimed_success", ("figures", "phase2", "aimed", "success"), "phase-2 aimed success", "fraction"),
    _metric("phase2_random_min_distance", ("figures", "phase2", "random", "min_distance"),
            "phase-2 random-goal min distance", "m", True),
    _metric("phase2_random_success", ("figures", "phase2", "random", "success"),
            "phase-2 random-goal success", "fraction"),
    _metric("phase2_random_cut_short", ("figures", "phase2", "random", "cut_short"),
            "phase-2 random-goal episodes ended by a flip", "fraction", True),
    _metric("top_volume", ("figures", "top_volume"), "top-level goal-space volume", "m² or m"),
    _metric("top_success", ("figures", "top_success"), "top-level success", "fraction"),
    _metric("volume_x_success", ("figures", "volume_x_success"), "top volume × success", "m² or m"),
    _metric("coverage_cells", ("figures", "coverage_cells"), "coverage", "cells"),
    _metric("posterior_std", ("figures", "posterior_std"), "skill posterior std", ""),
    _metric("flips", ("figures", "flips"), "flips per episode", "", True),
    _metric("top_flip_share", ("figures", "flip_table", "-1", "flip_share"),
            "top-level greedy episodes that flip the robot (flip table)", "fraction", True),
    _metric("phase2_flip_share", ("figures", "phase2", "flip_table", "flip_share"),
            "phase-2 greedy episodes that flip the robot (flip table)", "fraction", True),
    _metric("phase2_flips_per_100m", ("figures", "phase2", "flip_table", "by_attempt"),
            "phase-2 flips per 100 m gained toward the goal (flip table)", "", True, flips_per_100m),
    _metric("env_steps", ("figures", "env_steps"), "env steps", ""),
    _metric("top_success_training", ("figures", "top_success_training"),
            "top-level success in training (mean of the last epochs)", "fraction"),
    _metric("phase2_aimed_half_min_distance", ("figures", "phase2", "aimed_half", "min_distance"),
            "phase-2 aimed-within-half min distance", "m", True),
    _metric("phase2_aimed_cut_short", ("figures", "phase2", "aimed", "cut_short"),
            "phase-2 aimed episodes ended by a flip", "fraction", True),
    _metric("phase2_aimed_half_cut_short", ("figures", "phase2", "aimed_half", "cut_short"),
            "phase-2 aimed-within-half episodes ended by a flip", "fraction", True),
)}
"""Every metric a report can show, by name. The volume's unit is m² for (x, y) goals and m for
x goals; one table never mixes environments, so the unit is named once for both."""


def metric_named(name: str | Metric) -> Metric:
    """``name``'s entry in :data:`METRICS` (a :class:`Metric` passes through), or for a dotted
    path into the row (``figures.cage.phase2.reached_beyond``) a metric reading that path,
    labelled by the path after ``figures``, its better direction unsaid; any other name is a
    ConfigError listing the known ones."""
    if isinstance(name, Metric):
        return name
    if name in METRICS:
        return METRICS[name]
    path = tuple(name.split("."))
    if len(path) > 1 and path[0] == "figures" and all(path):
        return _metric(name, path, " ".join(path[1:]).replace("_", " "), lower_is_better=None)
    raise ConfigError(f"metric: {name!r} is not one of {', '.join(METRICS)}, nor a path figures.NAME[.NAME...]")


def lookup(row: dict, path: Sequence[str]) -> Any:
    """The value at ``path`` in a nested row (a step into a list is its index, -1 the last),
    or None where any step is missing."""
    value: Any = row
    for key in path:
        if isinstance(value, list) and key.lstrip("-").isdigit() and -len(value) <= int(key) < len(value):
            value = value[int(key)]
        elif isinstance(value, dict):
            value = value.get(key)
        else:
            return None
    return value


def as_number(value: Any) -> float | None:
    """``value`` as a finite float, or None for a missing, non-numeric or non-finite value."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def metric_values(rows: Sequence[dict], metric: str | Metric) -> list[float]:
    """The metric's value in each row that has one, in row order; rows where it is missing,
    null or not a finite number are skipped (so ``len`` is the n an aggregate stands on)."""
    chosen = metric_named(metric)
    held = (lookup(row, chosen.path) for row in rows)
    numbers = (as_number(value if chosen.derive is None or value is None else chosen.derive(value)) for value in held)
    return [x for x in numbers if x is not None]


# --------------------------------------------------------------------------- statistics


@contextmanager
def seeded_numpy(seed: int) -> Iterator[None]:
    """Run the block with numpy's global generator seeded by ``seed``, restoring its previous
    state afterwards. rliable draws its bootstrap resamples with ``np.random.choice`` (the
    global generator, not the ``random_state`` it accepts), so this is what makes its intervals
    reproducible without disturbing anyone else's use of the global generator."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def rliable_modules():
    """rliable's ``library`` and ``metrics`` modules; a ConfigError saying how to install them
    where the optional ``report`` extra is missing."""
    try:
        from rliable import library, metrics
    except ImportError as err:
        raise ConfigError(f"report: the statistics need rliable ({err}); pip install \"mjx-emp[report]\"") from None
    return library, metrics


def score_matrix(values: Sequence[float]) -> np.ndarray:
    """Runs as rliable's score matrix: shape (runs, 1), one task."""
    return np.asarray(values, dtype=float).reshape(-1, 1)


def iqm_interval(values: Sequence[float], reps: int, seed: int) -> tuple[float, float, float]:
    """(IQM, low, high): rliable's interquartile mean (the mean of the middle 50 % of runs)
    and its percentile stratified-bootstrap interval."""
    library, metrics = rliable_modules()

    def iqm(scores: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(scores)])

    with seeded_numpy(seed):
        points, intervals = library.get_interval_estimates(
            {"runs": score_matrix(values)}, iqm, reps=reps, confidence_interval_size=CONFIDENCE)
    return float(points["runs"][0]), float(intervals["runs"][0, 0]), float(intervals["runs"][1, 0])


def summary(values: Sequence[float], reps: int = DEFAULT_REPS, seed: int = 0) -> dict[str, float | int] | None:
    """n, mean, sample std (ddof 1; 0 for one run), standard error, and the IQM with its 95 %
    bootstrap interval [iqm_low, iqm_high] of ``values``; None for no values. One run's
    interval is the value itself (a bootstrap of one value has no spread to show)."""
    n = len(values)
    if n == 0:
        return None
    x = np.asarray(values, dtype=float)
    std = float(x.std(ddof=1)) if n > 1 else 0.0
    if n == 1:
        iqm = low = high = float(x[0])
    else:
        iqm, low, high = iqm_interval(x, reps, seed)
    return {"n": n, "mean": float(x.mean()), "std": std, "se": std / math.sqrt(n),
            "iqm": iqm, "iqm_low": low, "iqm_high": high}


def pairwise_improvement(a: np.ndarray, b: np.ndarray) -> float:
    """P(a run of A beats a run of B), ties counted half, over every pair of runs: the Mann-Whitney
    U statistic over the number of pairs, the figure rliable's ``probability_of_improvement``
    gives for one task (bit for bit: both are a count of halves over the same divisor), counted
    with one comparison of arrays instead of one statistical test per bootstrap sample."""
    beats = np.count_nonzero(a[:, None] > b[None, :])
    ties = np.count_nonzero(a[:, None] == b[None, :])
    return (beats + 0.5 * ties) / (len(a) * len(b))


def probability_of_improvement(x: Sequence[float], y: Sequence[float], lower_is_better: bool = False,
                               reps: int = DEFAULT_REPS, seed: int = 0) -> tuple[float, float, float] | None:
    """(P, low, high): the probability that a run of X beats a run of Y (ties count half), by
    rliable, with its 95 % bootstrap interval resampling X's and Y's runs independently. For a
    lower-is-better metric both are negated, so that "beats" means "is smaller". None where
    either side has no runs."""
    if len(x) == 0 or len(y) == 0:
        return None
    library, _ = rliable_modules()

    sign = -1.0 if lower_is_better else 1.0
    xs, ys = sign * score_matrix(x), sign * score_matrix(y)

    def improvement(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.array([pairwise_improvement(a[:, 0], b[:, 0])])

    with seeded_numpy(seed):
        points, intervals = library.get_interval_estimates(
            {"pair": [xs, ys]}, improvement, reps=reps, confidence_interval_size=CONFIDENCE)
    return float(points["pair"][0]), float(intervals["pair"][0, 0]), float(intervals["pair"][1, 0])
