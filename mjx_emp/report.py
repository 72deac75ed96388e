"""Reports of sweep results: evaluation rows (``results/<spec>.jsonl``) turned into Markdown
tables and seed-band figures, with the statistics the field reports for few-seed RL results
(Agarwal et al., 2021): the interquartile mean with a 95 % stratified-bootstrap interval and the
probability of improvement (:mod:`mjx_emp.report_stats`).

Rows are read with :func:`mjx_emp.run.rows.read_rows`. Everything here is pure except the
figure and block writers (``seed_band_figure``, and :mod:`mjx_emp.blocks` for ``--into``).
``rliable``, ``matplotlib`` and the plots, which load JAX, are imported inside the functions
that use them, so a table costs neither.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

import numpy as np

from mjx_emp import tables
from mjx_emp.algos.retired import flag_text
from mjx_emp.blocks import read_text, write_block
from mjx_emp.commands import ReportExperiment
from mjx_emp.errors import ConfigError
from mjx_emp.flip_tables import flip_text, pooled
from mjx_emp.report_stats import (
    DEFAULT_REPS,
    METRICS,
    Metric,
    metric_named,
    metric_values,
    probability_of_improvement,
    summary,
)
from mjx_emp.run.provenance import UNKNOWN
from mjx_emp.run.rows import RESULTS_DIR, read_rows
from mjx_emp.run.specs import check_report_table, load_spec
from mjx_emp.run.store import output_target, replace_file

MISSING = "-"
"""A table cell with no value."""


# --------------------------------------------------------------------------- tables


def sig3(x: float) -> str:
    """``x`` with 3 significant digits, written out in full up to 10¹⁵ (1234 -> "1230", not
    "1.23e+03"), and no "-0"."""
    rounded = float(f"{x:.3g}") + 0.0
    if 1000 <= abs(rounded) < 1e15:
        return f"{rounded:.0f}"
    return f"{rounded:.3g}"


def millions(x: float) -> str:
    """Env steps in millions: 960000 -> "0.96 M"."""
    return f"{sig3(x / 1e6)} M"


def group_rows(rows: Sequence[dict], group_by: str = "row") -> dict[str, list[dict]]:
    """Rows by their ``group_by`` field (as text), groups in order of first appearance."""
    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(str(row.get(group_by, MISSING)), []).append(row)
    return groups


def command_text(row: dict) -> str:
    """A row's preset and overrides as a compact command tail: ``point-mass-k1 --epochs 3``."""
    overrides = row.get("overrides") or {}
    flags = [flag_text(key, tuple(value) if isinstance(value, list) else value)
             for key, value in sorted(overrides.items())]
    return " ".join([str(row.get("preset") or MISSING), *flags])


def distinct_commands(group: Sequence[dict]) -> str:
    """Every distinct command of a group's rows, in first-appearance order ("; " between; a
    group is normally one command over several seeds)."""
    commands = [command_text(row) for row in group if row.get("preset") not in (None, UNKNOWN)]
    return "; ".join(dict.fromkeys(commands)) or MISSING


def spread_cell(stat: dict | None, group_size: int) -> str:
    """``mean ± std (se)``; ``n=K`` follows where fewer than all the group's rows have it."""
    if stat is None:
        return MISSING
    if stat["n"] == 1:
        return sig3(stat["mean"]) if group_size == 1 else f"{sig3(stat['mean'])} n=1"
    cell = f"{sig3(stat['mean'])} ± {sig3(stat['std'])} ({sig3(stat['se'])})"
    return cell if stat["n"] == group_size else f"{cell} n={stat['n']}"


def interval_cell(point: float, low: float, high: float) -> str:
    """``point [low, high]``."""
    return f"{sig3(point)} [{sig3(low)}, {sig3(high)}]"


def iqm_cell(stat: dict | None) -> str:
    """The IQM with its interval, or the missing mark (also for one run, which has no interval)."""
    if stat is None or stat["n"] == 1:
        return MISSING
    return interval_cell(stat["iqm"], stat["iqm_low"], stat["iqm_high"])


def table_headers(group_by: str, metrics: Sequence[Metric], baseline: str | None) -> list[str]:
    """Columns: group, command, seeds, env steps, then per metric its spread and IQM, then (with
    a baseline) per metric the probability of improvement over it."""
    headers = [group_by, "preset", "seeds", "env steps"]
    for metric in metrics:
        arrow = {True: " ↓", False: " ↑", None: ""}[metric.lower_is_better]
        headers += [f"{metric.heading}{arrow} mean ± std (se)", f"{metric.label} IQM [95% CI]"]
    if baseline is not None:
        headers += [f"P({metric.label} better than {baseline}) [95% CI]" for metric in metrics]
    return headers


def table_line(name: str, group: Sequence[dict], metrics: Sequence[Metric], baseline_rows: Sequence[dict] | None,
               reps: int, seed: int) -> list[str]:
    """One group's cells (see :func:`table_headers`); ``baseline_rows`` None for the baseline
    itself or where there is no baseline."""
    steps = metric_values(group, METRICS["env_steps"])
    cells = [name, distinct_commands(group), str(len(group)), millions(float(np.mean(steps))) if steps else MISSING]
    for metric in metrics:
        stat = summary(metric_values(group, metric), reps, seed)
        cells += [spread_cell(stat, len(group)), iqm_cell(stat)]
    if baseline_rows is not None:
        for metric in metrics:
            p = probability_of_improvement(metric_values(group, metric), metric_values(baseline_rows, metric),
                                           bool(metric.lower_is_better), reps, seed)
            cells.append(MISSING if p is None else interval_cell(*p))
    return cells


def markdown_table(rows: Sequence[dict], metrics: Sequence[str | Metric], group_by: str = "row",
                   baseline: str | None = None, reps: int = DEFAULT_REPS, seed: int = 0) -> str:
    """A Markdown table of ``rows``: one line per ``group_by`` value (first-appearance order)
    with its command, seed count, mean env steps, and per metric ``mean ± std (se)`` and the
    IQM with its 95 % interval over the rows that have the metric. With ``baseline`` (a group
    name), per metric also P(a run of the group beats a run of the baseline) with its interval
    ("-" on the baseline's own line). Numbers carry 3 significant digits; the same rows, reps
    and seed give the same text."""
    chosen = [metric_named(m) for m in metrics]
    groups = group_rows(rows, group_by)
    if baseline is not None and baseline not in groups:
        raise ConfigError(f"baseline: {baseline!r} is not a {group_by} of these rows "
                          f"({', '.join(groups) or 'there are none'})")
    with_baseline = baseline is not None
    lines = []
    for name, group in groups.items():
        against = groups[baseline] if with_baseline and name != baseline else None
        cells = table_line(name, group, chosen, against, reps, seed)
        if with_baseline and against is None:
            cells += [MISSING] * len(chosen)
        lines.append(cells)
    headers = table_headers(group_by, chosen, baseline)
    held = [i for i in range(len(headers)) if i == 0 or any(line[i] != MISSING for line in lines)]
    return tables.markdown_table([headers[i] for i in held], [[line[i] for i in held] for line in lines])


# --------------------------------------------------------------------------- figures


@dataclass(frozen=True)
class Band:
    """One group's curve over its seeds on a common grid of env steps."""

    n: int
    x: list[float]
    mean: list[float]
    std: list[float]


@dataclass(frozen=True)
class Chart:
    """A saved seed-band figure and what it shows, read back from its axes: the texts, and per
    legend entry the plotted mean line."""

    path: Path
    title: str
    xlabel: str
    ylabel: str
    legend: list[str]
    series: dict[str, Band]


def curve_steps_key(curve: str) -> str:
    """The ``curves`` entry holding a curve's x values: phase-2 curves run on phase 2's own env
    steps."""
    return "phase2_env_steps" if curve.startswith("phase2_") else "env_steps"


def curve_heading(curve: str) -> str:
    """A curve's y-axis label: its metric's label and unit where the curve is a metric, else
    its name."""
    return METRICS[curve].heading if curve in METRICS else curve


def row_curve(row: dict, curve: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(env steps, values) of one row's curve (null values as NaN), or None where the row has
    no such curve; steps and values of unequal length are a ConfigError naming the row."""
    curves = row.get("curves") or {}
    steps, values = curves.get(curve_steps_key(curve)), curves.get(curve)
    if not steps or not values:
        return None
    if len(steps) != len(values):
        raise ConfigError(f"curves: row {row.get('row')!r} seed {row.get('seed')!r} has {len(steps)} "
                          f"{curve_steps_key(curve)} but {len(values)} {curve} values")
    return (np.asarray(steps, dtype=float),
            np.asarray([np.nan if v is None else v for v in values], dtype=float))


def seed_bands(rows: Sequence[dict], curve: str = "top_volume", group_by: str = "row") -> dict[str, Band]:
    """Per group (first-appearance order) the mean and sample std over its seeds of ``curve``,
    each seed interpolated onto the steps of the one that ends first
    (:func:`mjx_emp.viz.plots.seed_band`); groups whose rows lack the curve are left out."""
    from mjx_emp.viz.plots import seed_band  # deferred: the plots load JAX

    bands = {}
    for name, group in group_rows(rows, group_by).items():
        curves = [c for c in (row_curve(row, curve) for row in group) if c is not None]
        if curves:
            band = seed_band(curves)
            bands[name] = Band(int(band["count"]), band["steps"].tolist(), band["mean"].tolist(),
                               band["std"].tolist())
    return bands


def legend_text(name: str, band: Band) -> str:
    """A group's legend entry: ``GROUP (n=K)``."""
    return f"{name} (n={band.n})"


def seed_band_figure(rows: Sequence[dict], curve: str = "top_volume", out: Path | str = "seed_bands.png",
                     group_by: str = "row", title: str | None = None) -> Chart:
    """A PNG of ``curve`` against env steps: per group the mean over its seeds with a shaded
    band of one sample std, legend ``GROUP (n=K)``. Returns the path and what the axes show
    (read back from them), so a caller or a test can check the chart's content. No group with
    the curve is a ConfigError."""
    from matplotlib.figure import Figure  # deferred: only a figure needs matplotlib

    from mjx_emp.viz.plots import axes_content  # deferred: the plots load JAX

    bands = seed_bands(rows, curve, group_by)
    if not bands:
        raise ConfigError(f"figure: no row has a {curve!r} curve (with its {curve_steps_key(curve)})")
    fig = Figure(figsize=(7, 4))
    ax = fig.add_subplot()
    for name, band in bands.items():
        x, mean, std = (np.asarray(v) for v in (band.x, band.mean, band.std))
        (line,) = ax.plot(x, mean, label=legend_text(name, band))
        if band.n > 1:
            ax.fill_between(x, mean - std, mean + std, color=line.get_color(), alpha=0.2, linewidth=0)
    ax.set_xlabel("env steps")
    ax.set_ylabel(curve_heading(curve))
    ax.set_title(title if title is not None else f"{curve_heading(curve)}: mean ± 1 sample std over seeds")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    fig.tight_layout()
    path = replace_file(Path(out), lambda temporary: fig.savefig(temporary, dpi=100, format="png"), chosen=True,
                        field="figure")
    (shown,) = axes_content(fig)
    series = {name: Band(band.n, *shown.series[legend_text(name, band)], band.std) for name, band in bands.items()}
    return Chart(path, shown.title, shown.xlabel, shown.ylabel, shown.legend, series)


# --------------------------------------------------------------------------- a spec's report

DEFAULT_METRICS = ("top_volume", "top_success", "coverage_cells", "phase2_min_distance", "phase2_cut_short")
"""What a report shows when neither the command nor the spec names metrics: those of these the rows hold."""


def held_metrics(rows: Sequence[dict], names: Sequence[str] = DEFAULT_METRICS) -> list[str]:
    """The metrics of ``names`` that at least one row holds."""
    return [name for name in names if metric_values(rows, name)]


@dataclass(frozen=True)
class BenchmarkSpec:
    """A benchmark's report spec: the script command that appends its rows to
    ``results/<name>.jsonl`` (rows of the evaluation rows' schema, made by
    :func:`mjx_emp.run.rows.benchmark_row`) and ``mjx-emp report``'s defaults for them."""

    name: str
    path: str
    command: str
    report: dict[str, Any]


BENCHMARK_KEYS = ("name", "command", "report")


def load_report_spec(spec_path: str) -> Any:
    """The spec a report reads: a benchmark spec (a TOML file with a ``command``, see
    :class:`BenchmarkSpec`) or a sweep spec (:func:`mjx_emp.run.specs.load_spec`)."""
    path = Path(spec_path)
    try:
        raw = tomllib.loads(read_text(path, "spec"))
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"spec: {path} is not valid TOML ({err})") from None
    if "command" not in raw:
        return load_spec(spec_path)
    unknown = sorted(set(raw) - set(BENCHMARK_KEYS))
    if unknown:
        raise ConfigError(f"spec: {unknown[0]}: not a benchmark spec field; allowed: {', '.join(BENCHMARK_KEYS)}")
    if not isinstance(raw["command"], str):
        raise ConfigError(f"spec: {path}: command must be a string; got {raw['command']!r}")
    return BenchmarkSpec(str(raw.get("name", path.stem)), str(path), raw["command"],
                         check_report_table(raw.get("report", {})))


def spec_rows(spec: Any, results: Path) -> list[dict]:
    """The stored rows of ``spec``: for a sweep spec in the spec's order of rows, then seeds
    (rows of rows or seeds the spec no longer names are left out); for a benchmark spec every
    row of its name, in the order they were first stored."""
    mine = [row for row in read_rows(results) if row.get("spec") == spec.name]
    if isinstance(spec, BenchmarkSpec):
        return mine
    stored = {(row.get("row"), row.get("seed")): row for row in mine}
    return [stored[(row.name, seed)] for row in spec.rows for seed in row.seeds if (row.name, seed) in stored]


def chosen_rows(rows: Sequence[dict], patterns: Sequence[str]) -> list[dict]:
    """The rows whose row name matches one of ``patterns`` (shell-style, ``check/rollout/*``);
    every row where there are none. A spec's ``[report] rows`` names them, so that one store
    of a benchmark's rows can feed several tables."""
    if not patterns:
        return list(rows)
    return [row for row in rows if any(fnmatchcase(str(row.get("row")), pattern) for pattern in patterns)]


def row_flip_table(rows: Sequence[dict], name: str) -> str:
    """Row ``name``'s flip tables pooled over its runs (:func:`mjx_emp.flip_tables.pooled`), as
    `mjx-emp eval` prints them; a row without one is a ConfigError naming the rows that have one."""
    held = [row for row in rows if row["row"] == name and (row.get("figures") or {}).get("flip_table")]
    if not held:
        having = sorted({row["row"] for row in rows if (row.get("figures") or {}).get("flip_table")})
        raise ConfigError(f"flip_table: row {name!r} has no flip table in these rows; rows with one: "
                          f"{', '.join(having) or 'none'}")
    tables = [row["figures"]["flip_table"] for row in held]
    phase2 = [((row["figures"].get("phase2") or {}).get("flip_table")) for row in held]
    levels = [pooled([table[level] for table in tables]) for level in range(len(tables[0]))]
    return "\n".join(flip_text(levels, pooled(phase2) if all(phase2) else None))


def producing_command(spec: Any) -> str:
    """The command that makes a spec's rows: its sweep, or its benchmark script."""
    return spec.command if isinstance(spec, BenchmarkSpec) else f"mjx-emp sweep {spec.path}"


def reproduce_line(spec: Any, options: str = "") -> str:
    """The commands that rebuild a report: the rows' command, then the report itself."""
    return f"Reproduce: `{producing_command(spec)}`, then `mjx-emp report {spec.path}{options}`."


def report_spec(spec_path: str, results: str = "", metrics: Sequence[str] = (), baseline: str = "",
                figure: str = "", curve: str = "top_volume", into: str = "", block: str = "",
                reps: int = DEFAULT_REPS, write: bool = True, flip_table: str = "") -> str:
    """A spec's report as Markdown: its stored rows' table (:func:`markdown_table`) and the command
    that reproduces it; with ``figure``, a seed-band PNG of ``curve`` too (linked under the
    table); with ``into``, the text replaces block ``block`` (default: the spec's name) of that
    Markdown file (``write`` False: the text only, as a check of a committed block makes it). The
    spec's ``[report]`` table may name ``metrics`` and ``baseline``. With ``flip_table`` (a row
    name) the text is that row's flip table pooled over its runs instead of the table."""
    if reps < 1:
        raise ConfigError(f"reps: must be >= 1; got {reps}")
    for path, field in ((into, "into"), (figure, "figure")):
        if path and write:
            output_target(Path(path), field)  # before anything is read: a FIFO would block, a device be lost
    spec = load_report_spec(spec_path)
    results_path = Path(results or Path(RESULTS_DIR) / f"{spec.name}.jsonl")
    rows = chosen_rows(spec_rows(spec, results_path), spec.report.get("rows", ()))
    if not rows and not results_path.exists():
        raise ConfigError(f"results: {results_path} does not exist (looked for from {Path.cwd()}); run "
                          f"`{producing_command(spec)}` first, or name the rows file with --results")
    if not rows:
        raise ConfigError(f"results: {results_path} holds no row of spec {spec.name!r}; run "
                          f"`{producing_command(spec)}` first")
    chosen = list(metrics or spec.report.get("metrics", ()) or held_metrics(rows))
    baseline_asked, reps_asked = baseline, reps
    baseline = baseline or spec.report.get("baseline", "")
    reps = spec.report.get("reps", reps) if reps == DEFAULT_REPS else reps
    table = row_flip_table(rows, flip_table) if flip_table else markdown_table(rows, chosen, baseline=baseline or None,
                                                                               reps=reps)
    asked_options = (("flip-table", flip_table), ("metrics", " ".join(metrics)), ("baseline", baseline_asked),
                     ("reps", str(reps_asked) if reps_asked != DEFAULT_REPS else ""), ("figure", figure),
                     ("curve", curve if figure else ""), ("into", into), ("block", block))
    options = "".join(f" --{flag} {value}" for flag, value in asked_options if value)
    asked = set() if isinstance(spec, BenchmarkSpec) else {(row.name, seed) for row in spec.rows for seed in row.seeds}
    missing = sorted(asked - {(row["row"], row["seed"]) for row in rows})
    parts = [table]
    if missing:
        parts.append(f"Not yet in {results_path}: " + ", ".join(f"{name} seed {seed}" for name, seed in missing) + ".")
    if figure:
        chart = seed_band_figure(rows, curve, figure, title=f"{spec.name}: {curve_heading(curve)}")
        link = os.path.relpath(chart.path, Path(into).parent) if into else str(chart.path)
        parts.append(f"![{spec.name}: {curve_heading(curve)}]({link})")
    parts.append(reproduce_line(spec, options))
    text = "\n\n".join(parts)
    if into and write:
        write_block(into, block or spec.name, text)
    return text


def report_command(exp: ReportExperiment) -> None:
    """`mjx-emp report`: print a spec's table (and write its figure and block where asked)."""
    print(report_spec(exp.spec, exp.results, exp.metrics, exp.baseline, exp.figure, exp.curve, exp.into, exp.block,
                      exp.reps, flip_table=exp.flip_table))
    if exp.into:
        print(f"wrote block {exp.block or Path(exp.spec).stem} of {exp.into}")
