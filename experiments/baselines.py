"""Hierarchical Empowerment against the skill-learning baselines, one JSON row per (preset, seed).

For every preset (HE's or a baseline's, e.g. ``point-mass-k1`` and ``metra-point-mass``) and
seed, trains the preset (or resumes BASE/<preset>-s<seed>; a finished run is only
evaluated), trains phase 2 on its skills with the domain's CPU task (``--phase2``, as
`mjx-emp phase2 RUN_DIR` does), then evaluates both the same way for every method: METRA's
coverage (1 m cells of goal space visited by 48 greedy skills from the initial state), for
DIAYN and HIDIO the posterior's mean standard deviation, and phase 2's mean minimum
distance to goal on 400 goals. Rows carry ``algo``, ``env``, ``preset``, ``seed``,
``env_steps``, ``wall_s`` (phase-1 training time summed from the run's metrics, compile
included), ``coverage_cells``, ``posterior_std``, ``phase2_min_distance``,
``phase2_success``, ``phase2_cut_short`` (the fraction of phase-2 episodes a flip ended early),
``phase2_curve`` (phase-2 env steps and greedy mean minimum distance per epoch) and, for HE
and GCRL, the chaining diagnostic's scripted policies on the same goals
(``phase2_aimed_min_distance``, ``phase2_random_success``, ...).
``python experiments/baselines.py --presets point-mass-k1 metra-point-mass --seeds 0 1 2 3``;
rows are merged into ``--out``.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import jax
import numpy as np
import tyro

from mjx_emp.algos.registry import GOAL_SPACES, algorithm_of, all_presets, preset_or_retired_config, skill_kind
from mjx_emp.algos.retired import RETIRED
from mjx_emp.commands import Phase2Experiment, ResumeExperiment, TrainExperiment
from mjx_emp.envs.registry import DOMAINS
from mjx_emp.metrics import PHASE2_DIAGNOSTICS, PHASE2_REQUIRED_FIGURES, coverage_cells, mean_and_stderr
from mjx_emp.phase2.presets import PHASE2_PRESETS, phase2_preset_for
from mjx_emp.run import jobs, store
from mjx_emp.run.evaluate import COVERAGE_SKILLS, phase2_figures, skill_figures
from mjx_emp.viz.plots import colour_of, method_label, seed_band, shades

ALGOS = ("he", "diayn", "hidio", "dads", "metra")


@dataclasses.dataclass
class Args:
    """Presets x seeds, trained and evaluated alike."""

    presets: tuple[str, ...] = ("point-mass-k1", "diayn-point-mass", "hidio-point-mass", "dads-point-mass",
                                "metra-point-mass")
    seeds: tuple[int, ...] = (0, 1, 2, 3)
    epochs: int | None = None
    """Override the presets' epoch counts; None keeps them for a new run and a run's own count
    for one already there (it is resumed, never trained past it)."""
    max_env_steps: int | None = None
    """Stop every run at the end of its first epoch that reaches this many env steps (the
    epoch count stays the ceiling): one budget for methods whose epochs differ in size."""
    phase2: bool = True
    """Also train phase 2 (the domain's CPU task, `mjx-emp phase2 RUN_DIR`) on every run's skills."""
    base: str = "runs/baselines"
    out: str = "benchmarks/results/baselines_cpu.json"
    charts: str = "docs/img"
    """Where the charts go (baselines_<env>.png); empty draws none."""
    report_only: bool = False
    """Train and evaluate nothing: print the table and draw the charts of the rows in ``--out``."""
    include: tuple[str, ...] = ()
    """Result files whose rows join the table and charts (read, never written), e.g. the
    baselines' rows beside an equal-budget file's."""
    env_steps: float | None = None
    """Report only rows within ``--budget-tolerance`` of this many phase-1 env steps (an
    equal-budget table); None reports every row."""
    budget_tolerance: float = 0.01
    """How far (a fraction of ``--env-steps``) a row's env steps may be from the budget: a
    two-level run's epochs hold different numbers of steps, so its epoch count only comes near."""
    spread: tuple[str, ...] = ()
    """Coverage recounts (``experiments/coverage_spread.py`` output): a row whose run directory
    is recounted there reports the mean over its draws as its coverage, in the table and chart."""
    goal_half_width: float | None = None
    """GCRL presets only: a hand-set box of this half-width (m) instead of the preset's; runs
    go to BASE/<preset>-w<width>-s<seed> and rows are named <preset>-w<width>."""


def variant_name(preset: str, goal_half_width: float | None) -> str:
    """The row and run-directory name of PRESET, with its GCRL box half-width when overridden."""
    return preset if goal_half_width is None else f"{preset}-w{goal_half_width:g}"


def train_or_resume(base: Path, preset: str, seed: int, epochs: int | None,
                    goal_half_width: float | None = None, max_env_steps: int | None = None) -> Path:
    """The run directory of (preset, seed), trained to its epoch count or ``max_env_steps``
    (with GCRL's box half-width replaced when ``goal_half_width`` is given). A run already there
    resumes to its own epoch count and budget unless ``epochs`` or ``max_env_steps`` moves them,
    so evaluating a finished run never trains it further by surprise. A retired preset name
    (:data:`mjx_emp.algos.retired.RETIRED`) trains the config it had, so that the commands that
    produced the recorded rows still reproduce them."""
    presets = all_presets()
    if preset not in presets and preset not in RETIRED:
        raise SystemExit(f"presets: {preset!r} is unknown; allowed values: {sorted(presets)}")
    config = dataclasses.replace(preset_or_retired_config(preset), seed=seed)
    if epochs is not None:
        config = dataclasses.replace(config, epochs=epochs)
    if max_env_steps is not None:
        config = dataclasses.replace(config, max_env_steps=max_env_steps)
    if goal_half_width is not None:
        box = algorithm_of(config).hand_set_box
        if box is None:
            raise SystemExit(f"goal_half_width: only presets with a hand-set goal box take one; {preset!r} learns its "
                             f"goal space")
        config = dataclasses.replace(config, **{box: (goal_half_width,) * len(getattr(config, box))})
    run_dir = base / f"{variant_name(preset, goal_half_width)}-s{seed}"
    if (run_dir / store.CONFIG_FILE).exists():
        jobs.resume(ResumeExperiment(resume=str(run_dir), epochs=epochs, max_env_steps=max_env_steps))
    else:
        jobs.train(TrainExperiment(config=config, run_dir=str(run_dir)))
    return run_dir


def train_phase2(run_dir: Path, subdir: str = store.PHASE2_SUBDIR, **changes) -> None:
    """Phase 2 on the run's skills with its domain's preset, its fields replaced by ``changes``,
    into RUN_DIR/``subdir`` (resumed if it is there)."""
    phase2_dir = run_dir / subdir
    if (phase2_dir / store.CONFIG_FILE).exists():
        jobs.resume_phase2(ResumeExperiment(resume=str(phase2_dir)))
        return
    preset = phase2_preset_for(store.read_run_config(run_dir, "run_dir"))
    config = dataclasses.replace(PHASE2_PRESETS[preset][2], **changes)
    out = "" if subdir == store.PHASE2_SUBDIR else str(phase2_dir)  # empty: the CLI's own RUN_DIR/phase2
    jobs.train_phase2(Phase2Experiment(run_dir=str(run_dir), config=config, out=out))


def evaluate_run(run_dir: Path, preset: str, seed: int) -> dict:
    """One row: coverage for any method, the posterior's std for DIAYN and HIDIO."""
    agent, epoch, state = jobs.load_run(run_dir)
    algo = algorithm_of(agent.cfg).name
    key = jax.random.key(1000 + seed)
    if skill_kind(agent.cfg) == GOAL_SPACES:  # HE and GCRL: skill_paths of the hierarchy
        figures = {"coverage_cells": coverage_cells(*agent.skill_paths(state, key, COVERAGE_SKILLS)),
                   "posterior_std": None}
    else:
        figures = skill_figures(agent, state, key)
    metrics = [json.loads(line) for line in (run_dir / store.METRICS_FILE).read_text().splitlines() if line]
    return {
        "algo": algo, "env": agent.cfg.env, "preset": preset, "seed": seed, "run_dir": str(run_dir), "epoch": epoch,
        "env_steps": float(state.env_steps.value()), "wall_s": sum(m["seconds"] for m in metrics if m["epoch"] <= epoch),
        "coverage_cells": figures["coverage_cells"], "posterior_std": figures["posterior_std"],
        **phase2_of(run_dir, seed),
    }


def phase2_evaluation(run_dir: Path, seed: int, episodes: int = 400, loaded: tuple | None = None) -> dict | None:
    """The paper's phase-2 figures of RUN_DIR/phase2 (or of its ``loaded`` trainer, epoch and
    state), as `mjx-emp eval` reports them on the seed's goals, or None where the run has no phase 2."""
    if loaded is None:
        loaded = jobs.load_run_phase2(run_dir)
    return None if loaded is None else phase2_figures(*loaded, jax.random.key(1000 + seed), episodes)


def phase2_of(run_dir: Path, seed: int, episodes: int = 400) -> dict:
    """RUN_DIR/phase2's figures as a comparison row's fields (mean minimum distance, success, the
    fraction of episodes a flip ended early, the training curve), each None where it has none;
    where the skills have a goal space, also the scripted policies' minimum distance and success
    on the same goals (``phase2_aimed_min_distance``, ``phase2_random_success``, ...: the
    chaining diagnostic of :data:`mjx_emp.metrics.PHASE2_DIAGNOSTICS`)."""
    figures = phase2_evaluation(run_dir, seed, episodes)
    if figures is None:
        return {"phase2_min_distance": None, "phase2_success": None, "phase2_cut_short": None, "phase2_curve": None}
    steps, distances = phase2_curve(run_dir)
    scripted = {f"phase2_{policy}_{name}": figures[policy][name]
                for policy in PHASE2_DIAGNOSTICS if policy in figures for name in PHASE2_REQUIRED_FIGURES}
    return {"phase2_min_distance": figures["min_distance"], "phase2_success": figures["success"],
            "phase2_cut_short": figures["cut_short"], **scripted,
            "phase2_curve": [[float(a), float(b)] for a, b in zip(steps, distances)]}


def merge_row(out: Path, row: dict, key: tuple[str, ...] = ("preset", "seed")) -> list[dict]:
    """Replace OUT's row with ROW's ``key`` fields (preset and seed) by ROW, re-reading OUT first
    so that two comparison scripts running side by side keep each other's rows; written atomically."""
    rows = json.loads(out.read_text())["rows"] if out.exists() else []
    rows = [r for r in rows if tuple(r[f] for f in key) != tuple(row[f] for f in key)] + [row]
    out.parent.mkdir(parents=True, exist_ok=True)
    store.write_atomically(out, json.dumps({"backend": jax.default_backend(), "rows": rows}, indent=1))
    return rows


def rows_at_budget(rows: list[dict], env_steps: float | None, tolerance: float = 0.01) -> list[dict]:
    """The rows trained for ENV_STEPS phase-1 env steps, within ``tolerance`` of it (epochs of
    different methods hold different numbers of steps); every row when ENV_STEPS is None."""
    if env_steps is None:
        return rows
    return [r for r in rows if abs(r["env_steps"] - env_steps) <= tolerance * env_steps]


def with_spread_coverage(rows: list[dict], spread_rows: list[dict]) -> list[dict]:
    """ROWS with ``coverage_cells`` replaced by the mean over draws wherever SPREAD_ROWS recount
    the same run directory (``coverage_draws`` then holds the draws); other rows keep their one draw."""
    draws = {r["run_dir"]: r["cells"] for r in spread_rows}
    return [{**r, "coverage_cells": float(np.mean(draws[r["run_dir"]])), "coverage_draws": draws[r["run_dir"]]}
            if r["run_dir"] in draws else r for r in rows]


def draw_counts(rows: list[dict]) -> str:
    """How many skill draws ROWS' coverage figures average: one number, or the range where they differ."""
    counts = sorted({len(r.get("coverage_draws", [None])) for r in rows})
    return str(counts[0]) if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"


def report_table(rows: list[dict]) -> str:
    """A Markdown table of ROWS by preset: seeds, env steps, wall time, coverage and phase 2's
    mean min distance, success and flip-ended fraction (where rows have it), each as mean ± std
    (standard error)."""
    def cell(values: list[float], digits: str = ".3g") -> str:
        if not values:
            return "-"
        m = mean_and_stderr(values)
        return f"{m['mean']:{digits}} ± {m['std']:.2g} ({m['stderr']:.2g})"

    lines = ["| preset | seeds | env steps | wall s (mean) | coverage cells | coverage draws per seed | posterior std | "
             "phase-2 min distance (m) | phase-2 success | phase-2 episodes a flip ended | "
             "aimed subgoals' min distance (m) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for preset in dict.fromkeys(r["preset"] for r in rows):
        mine = [r for r in rows if r["preset"] == preset]
        stds = [r["posterior_std"] for r in mine if r["posterior_std"] is not None]
        done = [r for r in mine if r.get("phase2_min_distance") is not None]
        lines.append(
            f"| {preset} | {len(mine)} | {mine[0]['env_steps']:.4g} | {np.mean([r['wall_s'] for r in mine]):.0f} "
            f"| {cell([r['coverage_cells'] for r in mine])} | {draw_counts(mine)} "
            f"| {f'{np.mean(stds):.3g}' if stds else '-'} "
            f"| {cell([r['phase2_min_distance'] for r in done])} "
            f"| {cell([r['phase2_success'] for r in done], '.2f')} "
            f"| {cell([r['phase2_cut_short'] for r in done if r.get('phase2_cut_short') is not None], '.2f')} "
            f"| {cell([r['phase2_aimed_min_distance'] for r in done if 'phase2_aimed_min_distance' in r])} |")
    return "\n".join(lines)


def main(args: Args) -> None:
    out = Path(args.out)
    rows = json.loads(out.read_text())["rows"] if out.exists() else []
    for preset in [] if args.report_only else args.presets:
        for seed in args.seeds:
            run_dir = train_or_resume(Path(args.base), preset, seed, args.epochs, args.goal_half_width,
                                      args.max_env_steps)
            if args.phase2:
                train_phase2(run_dir)
            row = evaluate_run(run_dir, variant_name(preset, args.goal_half_width), seed)
            print(json.dumps(row), flush=True)
            rows = merge_row(out, row)
    for extra in args.include:
        rows = rows + json.loads(Path(extra).read_text())["rows"]
    rows = rows_at_budget(rows, args.env_steps, args.budget_tolerance)
    rows = with_spread_coverage(rows, [r for f in args.spread for r in json.loads(Path(f).read_text())["rows"]])
    print(report_table(rows))
    if not args.report_only:
        print(f"wrote {out}")
    if args.charts:
        for env in dict.fromkeys(r["env"] for r in rows):
            print(f"wrote {draw_charts([r for r in rows if r['env'] == env], Path(args.charts) / f'baselines_{env}.png')}")


def phase2_curve(run_dir: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(phase-2 env steps, greedy mean min distance) per epoch of RUN_DIR/phase2, or None."""
    path = Path(run_dir) / store.PHASE2_SUBDIR / store.METRICS_FILE
    if not path.exists():
        return None
    lines = [json.loads(line) for line in path.read_text().splitlines() if line]
    return np.array([m["env_steps"] for m in lines]), np.array([m["min_distance"] for m in lines])


def preset_and_box(preset: str) -> tuple[Any, float | None]:
    """A row's preset name read as (the preset's config, the ``-wW`` box half-width it was run
    with, None where it has no such suffix). Rows recorded under a retired name get the config
    that name had."""
    name, width = re.fullmatch(r"(.*?)(?:-w([0-9.]+))?", preset).groups()
    return preset_or_retired_config(name), float(width) if width else None


def chart_label(preset: str) -> str:
    """A preset's name in the charts: its method (``HE k=1``, ``METRA``), GCRL with its box side."""
    config, width = preset_and_box(preset)
    algorithm = algorithm_of(config)
    if algorithm.hand_set_box is None:
        return method_label(config)
    side = 2 * (width if width is not None else getattr(config, algorithm.hand_set_box)[0])
    box = f"{side:g} m box" if len(DOMAINS[config.env].goal_qpos) == 1 else f"{side:g}x{side:g} m"
    return f"{algorithm.name.upper()} {box}"


def chart_labels(presets: list[str]) -> list[str]:
    """Each preset's chart label (``chart_label``). Where several share one, the preset with the
    shortest name (the base its variants add suffixes to) keeps it, and each other one adds every
    config field in which it differs from the base (``HE k=1, tilt_cost 1.0``), or its preset
    name where the configs are the same."""
    labels = [chart_label(p) for p in presets]
    for label in set(labels):
        group = [i for i, other in enumerate(labels) if other == label]
        if len(group) < 2:
            continue
        base = min(group, key=lambda i: (len(presets[i]), i))
        base_config = dataclasses.asdict(preset_and_box(presets[base])[0])
        for i in group:
            if i == base:
                continue
            config = dataclasses.asdict(preset_and_box(presets[i])[0])
            differing = [field for field, value in config.items() if value != base_config[field]]
            told = ", ".join(f"{field} {_plain(config[field])}" for field in differing)
            labels[i] = f"{label}, {told or presets[i]}"
    return labels


def _plain(value) -> str:
    """A config value as a legend shows it: tuples without brackets."""
    return ", ".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)


def curve_of(row: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """A row's phase-2 curve: the one it stores, else read from its run directory if that is still there."""
    if row.get("phase2_curve"):
        steps, distances = np.array(row["phase2_curve"]).T
        return steps, distances
    return phase2_curve(row["run_dir"])


def chart_colours(presets: list[str]) -> list[str]:
    """Each row name's colour: its method's (see ``colour_of``), in shades where one method has
    several variants (GCRL's boxes), so a variant never takes another method's colour."""
    methods = [method_label(preset_and_box(p)[0]) for p in presets]
    method_colours: dict[str, str] = {}
    for method in methods:
        method_colours.setdefault(method, colour_of(method, list(method_colours.values())))
    variants = {m: shades(c, methods.count(m)) for m, c in method_colours.items()}
    return [variants[m][methods[:i].count(m)] for i, m in enumerate(methods)]


def draw_charts(rows: list[dict], path: Path) -> Path:
    """The paper's Fig. 3-style chart (phase-2 mean min distance against phase-2 steps, mean
    over seeds with a std band; a method whose rows keep no curve as a dashed line at its final
    distance, and where no row keeps one, the final distances as bars)
    beside a coverage bar chart (mean ± std over seeds); one colour and name per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (phase2, bars) = plt.subplots(1, 2, figsize=(11, 4.2))
    presets = list(dict.fromkeys(r["preset"] for r in rows))
    labels, colours = chart_labels(presets), chart_colours(presets)
    seeds = {p: [r for r in rows if r["preset"] == p] for p in presets}
    curves = {p: [c for c in map(curve_of, seeds[p]) if c is not None] for p in presets}
    if any(curves.values()):
        for preset, label, colour in zip(presets, labels, colours):
            if not curves[preset]:  # rows without their curve: the final distance as a dashed level
                finals = [r["phase2_min_distance"] for r in seeds[preset] if r["phase2_min_distance"] is not None]
                if finals:
                    phase2.axhline(np.mean(finals), color=colour, linestyle="--",
                                   label=f"{label} (n={len(finals)}, final only)")
                continue
            band = seed_band(curves[preset])
            phase2.plot(band["steps"], band["mean"], color=colour, label=f"{label} (n={band['count']})")
            if band["count"] > 1:
                phase2.fill_between(band["steps"], band["mean"] - band["std"], band["mean"] + band["std"],
                                    color=colour, alpha=0.2, linewidth=0)
        phase2.set_xlabel("phase-2 environment steps")
        phase2.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
    else:
        finals = [[r["phase2_min_distance"] for r in seeds[p] if r["phase2_min_distance"] is not None] for p in presets]
        phase2.bar(range(len(presets)), [np.mean(f) if f else np.nan for f in finals], color=colours,
                   yerr=[np.std(f, ddof=1) if len(f) > 1 else 0 for f in finals], capsize=3)
        phase2.set_xticks(range(len(presets)), [f"{label} (n={len(f)})" for label, f in zip(labels, finals)],
                          rotation=30, ha="right", fontsize=7)
    phase2.set_ylabel("greedy mean min distance to goal (m)")
    phase2.set_title("phase 2 after training: mean ± std over seeds")
    cells = [[r["coverage_cells"] for r in seeds[p]] for p in presets]
    bars.bar(range(len(presets)), [np.mean(c) for c in cells], color=colours,
             yerr=[np.std(c, ddof=1) if len(c) > 1 else 0 for c in cells], capsize=3)
    bars.set_xticks(range(len(presets)), [f"{label} (n={len(c)})" for label, c in zip(labels, cells)],
                    rotation=30, ha="right", fontsize=7)
    bars.set_ylabel("1 m cells visited by 48 greedy skills")
    drawn = draw_counts(rows)
    bars.set_title(f"coverage on {rows[0]['env']} ({drawn} draw{'' if drawn == '1' else 's'} of skills per seed)\n"
                   "mean ± std over seeds", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")  # the legend sits below the axes
    plt.close(fig)
    return path


if __name__ == "__main__":
    main(tyro.cli(Args))
