"""The specs `mjx-emp sweep` runs and `mjx-emp report` reads: committed TOML files of rows,
read and checked whole in plain Python (no JAX).

A spec is a committed TOML file naming rows: a preset, the config fields it overrides, the
seeds, an env-step budget, the phase-2 task and the evaluation wanted::

    name = "smoke-point-mass"       # rows go to results/<name>.jsonl; default: the file's stem
    eval_seed = 0                   # evaluation key, as `mjx-emp eval --seed`
    eval_seed_per_run = false       # true: the run of seed s is evaluated with key eval_seed + s
    coverage_draws = 1              # draws of 48 skills coverage is averaged over (`mjx-emp eval --coverage-draws`)
    episodes = 400                  # evaluation episodes per level (and phase-2 episodes)

    [[row]]
    name = "he-k1"
    preset = "point-mass-k1"
    seeds = [0, 1, 2, 3]
    max_env_steps = 960000          # optional: stop at the first epoch past this budget
    overrides = { epochs = 30 }     # any config field of the preset, as `mjx-emp train` takes it
    phase2 = "auto"                 # a phase-2 preset, "auto" (the run's own task) or absent (none)
    phase2_overrides = { epochs = 10 }

    [[row]]
    name = "he-k1-flip-cost"
    skills_from = "he-k1"           # phase 2 (and evaluation) of another row's phase-1 runs
    phase2 = "auto"
    phase2_overrides = { epochs = 10, flip_cost = 5.0 }

Each (row, seed) is a run directory RUNS/<spec>/<row>-s<seed>. The seeds of a row train as one
vmapped program (`mjx-emp train --seeds`) and resume as one, so an interrupted sweep ends with
the same numbers as one that was never stopped. A second call trains nothing that is finished
and evaluates nothing whose row is in the store. Rows are evaluated by
:func:`mjx_emp.run.evaluate.evaluation_row`, the evaluation `mjx-emp eval` runs.

The spec is read and checked whole in plain Python (no JAX), so a bad spec is refused, naming
the row and the field, before anything trains. Jobs (one per row) run in local worker
processes, or through submitit: on Slurm, or with its local executor, which takes the same
path without a cluster.
"""

from __future__ import annotations

import dataclasses
import difflib
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mjx_emp.algos.registry import algorithm_of, all_presets
from mjx_emp.checks import config_from_dict
from mjx_emp.commands import MAX_COVERAGE_DRAWS
from mjx_emp.errors import ConfigError
from mjx_emp.phase2.config import Phase2Config, check_phase2_config
from mjx_emp.phase2.presets import PHASE2_PRESETS, phase2_preset_for

SPEC_KEYS = ("name", "eval_seed", "eval_seed_per_run", "coverage_draws", "episodes", "runs", "slurm", "report", "row")
ROW_KEYS = ("name", "preset", "seeds", "overrides", "max_env_steps", "phase2", "phase2_overrides", "episodes",
            "group_seeds", "skills_from")
PHASE1_KEYS = ("preset", "overrides", "max_env_steps", "group_seeds")
"""What a row whose skills come from another row (``skills_from``) takes from that row instead."""
REPORT_KEYS = ("metrics", "baseline", "reps", "rows")
"""What a spec's ``[report]`` table may set: `mjx-emp report`'s defaults for the spec."""
AUTO = "auto"
"""``phase2 = "auto"``: the phase-2 preset `mjx-emp phase2 RUN_DIR` would pick for the run."""
EXECUTORS = ("local", "submitit-local", "slurm")


@dataclasses.dataclass(frozen=True)
class Row:
    """One row of a spec, checked: the phase-1 config (preset with overrides and budget), its
    seeds, and the phase-2 config (None: no phase 2)."""

    name: str
    preset: str
    overrides: dict[str, Any]
    seeds: tuple[int, ...]
    config: Any
    phase2_preset: str | None
    phase2_overrides: dict[str, Any]
    phase2: Phase2Config | None
    episodes: int
    group_seeds: bool
    skills_from: str | None = None
    """Another row whose phase-1 runs this row's phase 2 builds on (a copy of each seed's run,
    so that its phase 2 gets a run directory of its own); None: the row trains its own."""


@dataclasses.dataclass(frozen=True)
class Spec:
    """A checked spec: its name (the rows file's), evaluation seed, rows and where it came from."""

    name: str
    path: str
    eval_seed: int
    rows: tuple[Row, ...]
    runs: str
    slurm: dict[str, Any]
    report: dict[str, Any]
    """``mjx-emp report``'s defaults for this spec: ``metrics`` (a list) and ``baseline`` (a row name)."""
    eval_seed_per_run: bool = False
    """Each run's goals drawn with its own key, ``eval_seed`` plus its seed, instead of one key for all."""
    coverage_draws: int = 1
    """Draws of coverage skills each evaluation averages over."""

    def run_eval_seed(self, seed: int) -> int:
        """The evaluation key of the run of ``seed``."""
        return self.eval_seed + seed if self.eval_seed_per_run else self.eval_seed


def _fail(where: str, message: str) -> ConfigError:
    return ConfigError(f"{where}: {message}")


def _integer(value: Any, where: str, field: str, low: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise _fail(where, f"{field}: must be an integer >= {low}; got {value!r}")
    return value


def _table(value: Any, where: str, field: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _fail(where, f"{field}: must be a table of config fields, e.g. {{ epochs = 10 }}; got {value!r}")
    return dict(value)


def _with_overrides(base: Any, overrides: dict[str, Any], where: str, field: str) -> Any:
    """``base`` with ``overrides`` (config field -> value, as TOML gives it) applied and their
    types checked; an unknown field or a wrong type is refused naming the row and the field."""
    values = dataclasses.asdict(base)
    for name, value in overrides.items():
        if name not in values:
            allowed = ", ".join(sorted(values))
            raise _fail(where, f"{field}.{name}: not a field of {type(base).__name__}; allowed: {allowed}")
        values[name] = value
    try:
        return config_from_dict(values, type(base))
    except ConfigError as err:
        raise _fail(where, f"{field}.{err}") from None


def check_row(raw: Any, index: int, default_episodes: int, earlier: dict[str, Row] | None = None) -> Row:
    """One ``[[row]]`` table as a :class:`Row`, every field checked (errors name the row);
    ``earlier``: the rows before it, by name, which ``skills_from`` may name."""
    if not isinstance(raw, dict):
        raise _fail(f"row {index}", f"must be a table ([[row]]); got {raw!r}")
    name = raw.get("name")
    if not isinstance(name, str) or not name or any(c in name for c in "/\\ ") or name.startswith("."):
        raise _fail(f"row {index}", f"name: give each row a name without spaces or slashes; got {name!r}")
    where = f"row {name!r}"
    unknown = sorted(set(raw) - set(ROW_KEYS))
    if unknown:
        raise _fail(where, f"{unknown[0]}: not a row field; allowed: {', '.join(ROW_KEYS)}")
    if "skills_from" in raw:
        return _skills_from_row(raw, where, default_episodes, earlier or {})
    presets = all_presets()
    preset = raw.get("preset")
    if preset not in presets:
        close = difflib.get_close_matches(str(preset), list(presets), n=3, cutoff=0.6)
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        raise _fail(where, f"preset: {preset!r} is not a preset{hint}; `mjx-emp presets` lists them")
    seeds = raw.get("seeds")
    if not isinstance(seeds, list) or not seeds:
        raise _fail(where, f"seeds: give a non-empty list of seeds, e.g. [0, 1, 2, 3]; got {seeds!r}")
    seeds = tuple(_integer(seed, where, "seeds") for seed in seeds)
    if len(set(seeds)) != len(seeds):
        raise _fail(where, f"seeds: each seed once; got {list(seeds)}")
    overrides = _table(raw.get("overrides", {}), where, "overrides")
    for loop_field in ("seed",):
        if loop_field in overrides:
            raise _fail(where, f"overrides.{loop_field}: seeds come from the row's seeds list")
    config = _with_overrides(presets[preset][1], overrides, where, "overrides")
    if "max_env_steps" in raw:
        config = dataclasses.replace(config, max_env_steps=_integer(raw["max_env_steps"], where, "max_env_steps", 1))
    try:
        algorithm_of(config).check(config)
    except ConfigError as err:
        raise _fail(where, f"overrides: {err}") from None
    phase2_preset, phase2_overrides, phase2 = _phase2_of_row(raw, config, where)
    episodes = _integer(raw.get("episodes", default_episodes), where, "episodes", 1)
    group_seeds = raw.get("group_seeds", True)
    if not isinstance(group_seeds, bool):
        raise _fail(where, f"group_seeds: must be true or false; got {group_seeds!r}")
    return Row(name, preset, overrides, seeds, config, phase2_preset, phase2_overrides, phase2, episodes,
               group_seeds and config.shards == 1 and len(seeds) > 1)


def _skills_from_row(raw: dict, where: str, default_episodes: int, earlier: dict[str, Row]) -> Row:
    """A row that builds its phase 2 on an earlier row's phase-1 runs: that row's preset,
    overrides and budget, its seeds or some of them, and a phase 2 of its own."""
    if not isinstance(raw["skills_from"], str):
        raise _fail(where, f"skills_from: the name of a row before this one; got {raw['skills_from']!r}")
    source = earlier.get(raw["skills_from"])
    if source is None:
        raise _fail(where, f"skills_from: {raw['skills_from']!r} is not a row before this one; rows before it: "
                           f"{', '.join(earlier) or 'none'}")
    taken = [key for key in PHASE1_KEYS if key in raw]
    if taken:
        raise _fail(where, f"{taken[0]}: a row with skills_from takes its phase 1 from row {source.name!r}; "
                           f"leave out {', '.join(PHASE1_KEYS)}")
    seeds = raw.get("seeds", list(source.seeds))
    if (not isinstance(seeds, list) or not seeds or not all(isinstance(seed, int) for seed in seeds)
            or not set(seeds) <= set(source.seeds) or len(set(seeds)) != len(seeds)):
        raise _fail(where, f"seeds: some of row {source.name!r}'s seeds {list(source.seeds)}, each once; got {seeds!r}")
    phase2_preset, phase2_overrides, phase2 = _phase2_of_row(raw, source.config, where)
    if phase2 is None:
        raise _fail(where, "phase2: a row with skills_from needs a phase 2 (without one it is its source row)")
    episodes = _integer(raw.get("episodes", default_episodes), where, "episodes", 1)
    return dataclasses.replace(source, name=raw["name"], seeds=tuple(seeds), phase2_preset=phase2_preset,
                               phase2_overrides=phase2_overrides, phase2=phase2, episodes=episodes,
                               group_seeds=False, skills_from=source.name)


def _phase2_of_row(raw: dict, config: Any, where: str) -> tuple[str | None, dict[str, Any], Phase2Config | None]:
    """A row's phase-2 preset (``auto`` resolved for ``config``), its overrides and the config
    they make (None without a phase 2)."""
    phase2_preset, phase2 = raw.get("phase2"), None
    phase2_overrides = _table(raw.get("phase2_overrides", {}), where, "phase2_overrides")
    if phase2_preset == AUTO:
        phase2_preset = phase2_preset_for(config)
        if phase2_preset is None:
            raise _fail(where, f"phase2: no phase-2 task is built for env={config.env}; name one of "
                               f"{', '.join(PHASE2_PRESETS)}")
    if phase2_preset is not None:
        if phase2_preset not in PHASE2_PRESETS:
            raise _fail(where, f"phase2: {phase2_preset!r} is not a phase-2 preset; allowed: \"{AUTO}\", "
                               f"{', '.join(PHASE2_PRESETS)}")
        phase2 = _with_overrides(PHASE2_PRESETS[phase2_preset][2], phase2_overrides, where, "phase2_overrides")
        try:
            check_phase2_config(phase2)
        except ConfigError as err:
            raise _fail(where, f"phase2_overrides: {err}") from None
    elif phase2_overrides:
        raise _fail(where, "phase2_overrides: given without a phase2 preset")
    return phase2_preset, phase2_overrides, phase2


def check_report_table(report: Any) -> dict[str, Any]:
    """A spec's ``[report]`` table (a sweep's or a benchmark's) checked: only the keys of
    :data:`REPORT_KEYS`, ``reps`` an integer >= 1, ``rows`` a list of row-name patterns; a
    ConfigError naming the field otherwise. The baseline is checked against the rows by the
    caller that knows them."""
    if not isinstance(report, dict) or sorted(set(report) - set(REPORT_KEYS)):
        raise ConfigError(f"spec: report: a table of metrics (a list), baseline (a row name), reps (bootstrap "
                          f"resamples) and rows (row-name patterns); got {report!r}")
    if "reps" in report:
        _integer(report["reps"], "spec", "report.reps", 1)
    if not isinstance(report.get("rows", []), list) or not all(isinstance(p, str) for p in report.get("rows", [])):
        raise ConfigError(f"spec: report.rows: a list of row-name patterns, e.g. [\"he-*\"]; got {report['rows']!r}")
    return dict(report)


def load_spec(path: str | Path) -> Spec:
    """Read and check a spec file (see the module docstring); a bad spec raises ConfigError
    naming the row and the field, before anything is trained."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"spec: {str(path)!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"spec: cannot read {path} ({err})") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"spec: {path} is not valid TOML ({err})") from None
    unknown = sorted(set(raw) - set(SPEC_KEYS))
    if unknown:
        raise ConfigError(f"spec: {unknown[0]}: not a spec field; allowed: {', '.join(SPEC_KEYS)}")
    name = raw.get("name", path.stem)
    if not isinstance(name, str) or not name or "/" in name:
        raise ConfigError(f"spec: name: must be a file-name-like string; got {name!r}")
    eval_seed = _integer(raw.get("eval_seed", 0), "spec", "eval_seed")
    coverage_draws = _integer(raw.get("coverage_draws", 1), "spec", "coverage_draws", 1)
    if coverage_draws > MAX_COVERAGE_DRAWS:  # the bound `mjx-emp eval --coverage-draws` holds
        raise ConfigError(f"spec: coverage_draws: must be in [1, {MAX_COVERAGE_DRAWS}]; got {coverage_draws}")
    per_run = raw.get("eval_seed_per_run", False)
    if not isinstance(per_run, bool):
        raise ConfigError(f"spec: eval_seed_per_run: must be true or false; got {per_run!r}")
    episodes = _integer(raw.get("episodes", 400), "spec", "episodes", 1)
    runs = raw.get("runs", "runs/sweeps")
    if not isinstance(runs, str) or not runs:
        raise ConfigError(f"spec: runs: must be a directory path; got {runs!r}")
    slurm = raw.get("slurm", {})
    if not isinstance(slurm, dict):
        raise ConfigError(f"spec: slurm: must be a table of submitit parameters; got {slurm!r}")
    report = check_report_table(raw.get("report", {}))
    rows = raw.get("row")
    if not isinstance(rows, list) or not rows:
        raise ConfigError("spec: row: give at least one [[row]] table")
    seen: dict[str, Row] = {}
    checked = []
    for index, raw_row in enumerate(rows):
        row = check_row(raw_row, index, episodes, seen)
        checked.append(row)
        if row.name in seen:
            raise ConfigError(f"row {row.name!r}: name: given twice; each row needs its own name")
        twin = next((other for other in seen.values() if (other.config, other.phase2) == (row.config, row.phase2)
                     and other.episodes == row.episodes), None)
        if twin is not None:
            raise ConfigError(f"row {row.name!r}: overrides: the same runs as row {twin.name!r} (a duplicate row)")
        seen[row.name] = row
    names = [row.name for row in checked]
    if "baseline" in report and report["baseline"] not in names:
        raise ConfigError(f"spec: report.baseline: {report['baseline']!r} is not a row; rows: {', '.join(names)}")
    return Spec(name, str(path), eval_seed, tuple(checked), runs, slurm, report, per_run, coverage_draws)


# ---- what is done -----------------------------------------------------------------------------


def describe_plan(spec: Spec) -> Iterator[str]:
    """One line per row of a checked spec: what it trains, how far and what follows."""
    for row in spec.rows:
        budget = f", stop at {row.config.max_env_steps:,} env steps" if row.config.max_env_steps else ""
        overrides = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in row.overrides.items())
        phase2 = f"; phase 2 {row.phase2_preset}" if row.phase2 is not None else ""
        if row.phase2_overrides:
            phase2 += " " + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in row.phase2_overrides.items())
        if row.skills_from is not None:
            yield (f"  {row.name}: the phase 1 of row {row.skills_from}, seeds {list(row.seeds)}{phase2}; "
                   f"eval {row.episodes} episodes")
            continue
        yield (f"  {row.name}: {row.preset} {overrides}".rstrip() + f", seeds {list(row.seeds)}, "
               f"{row.config.epochs} epochs{budget}{phase2}; eval {row.episodes} episodes")

