"""`mjx-emp sweep SPEC`: train, resume and evaluate every run of a study, with provenance.

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

import concurrent.futures
import ctypes
import dataclasses
import difflib
import functools
import json
import multiprocessing
import os
import shlex
import shutil
import signal
import sys
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax

from mjx_emp.algos.registry import algorithm_of, all_presets
from mjx_emp.checks import compile_identity, config_from_dict
from mjx_emp.commands import (
    MAX_COVERAGE_DRAWS,
    Phase2Experiment,
    ResumeExperiment,
    TrainExperiment,
)
from mjx_emp.errors import ConfigError, JobFailed
from mjx_emp.phase2.config import Phase2Config, check_phase2_config
from mjx_emp.phase2.presets import PHASE2_PRESETS, phase2_preset_for
from mjx_emp.run import jobs, store
from mjx_emp.run.evaluate import evaluation_row
from mjx_emp.run.provenance import run_record
from mjx_emp.run.rows import RESULTS_DIR, append_row, read_rows
from mjx_emp.run.seeds import resume_seeds

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


@dataclasses.dataclass(frozen=True)
class Job:
    """What one worker does: a row's seeds trained (as one program where they can be), their
    phase 2 and their evaluation rows. Plain data, so that it pickles to a worker or to Slurm."""

    spec: str
    row: Row
    base: str
    """The row's runs' common stem: each seed's run is BASE-s<seed>."""
    run_dirs: tuple[str, ...]
    eval_seeds: tuple[int, ...]
    """Each run's evaluation key, in the order of ``run_dirs``."""
    coverage_draws: int
    log: str
    command: str
    skills_base: str | None = None
    """The stem of the runs a ``skills_from`` row copies its phase 1 from (None: it trains its own)."""


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


def row_base(runs_root: Path, spec: Spec, row: Row) -> str:
    """Where ``row``'s runs live: RUNS/<spec>/<row>, each seed's run BASE-s<seed> (:func:`store.seed_run_dirs`)."""
    return str(runs_root / spec.name / row.name)


def seed_config(row: Row, seed: int) -> Any:
    """The config of ``row``'s run of ``seed``."""
    return dataclasses.replace(row.config, seed=seed)


def finished(run_dir: Path, cfg: Any) -> bool:
    """Whether a run directory's training is done for ``cfg``: its newest complete checkpoint is
    at ``cfg.epochs``, or its metrics at that checkpoint reach ``cfg.max_env_steps``."""
    newest = store.newest_checkpoint_on_disk(Path(run_dir))
    if newest is None:
        return False
    if newest >= cfg.epochs:
        return True
    budget = getattr(cfg, "max_env_steps", None)
    if budget is None:
        return False
    lines = [line for line in store.read_metrics(Path(run_dir)) if line.get("epoch") == newest]
    return bool(lines) and lines[-1].get("env_steps", 0) >= budget


def stored_rows(results: Path, spec: Spec) -> dict[tuple[str, int], dict]:
    """The store's rows of ``spec``, by (row name, seed)."""
    return {(row["row"], row["seed"]): row for row in read_rows(results) if row.get("spec") == spec.name}


def row_is_current(stored: dict | None, row: Row, seed: int, eval_seed: int, coverage_draws: int = 1) -> bool:
    """Whether a stored row answers ``row``'s run of ``seed`` as the spec asks it now: the same
    resolved config, phase-2 config and evaluation."""
    if stored is None:
        return False

    def task(phase2: dict | None) -> dict | None:  # the phase-1 epoch it ran on is the run's, not the spec's
        return None if phase2 is None else {**phase2, "phase1_epoch": None}

    phase2 = None if row.phase2 is None else json.loads(json.dumps(dataclasses.asdict(row.phase2)))
    train, evaluation = stored.get("train", {}), stored.get("evaluation", {})
    return (train.get("config") == json.loads(json.dumps(store.config_json(seed_config(row, seed))))
            and task(stored.get("phase2_config")) == task(phase2)
            and evaluation.get("seed") == eval_seed and evaluation.get("episodes") == row.episodes
            and evaluation.get("coverage_draws", 1) == coverage_draws)


# ---- a job: train, phase 2, evaluate -----------------------------------------------------------


def _same_config(run_dir: Path, cfg: Any, where: str) -> None:
    """Refuse to continue a run directory trained for another config (the spec's row changed in
    more than when it stops): its runs would not be the row's."""
    if not (run_dir / store.CONFIG_FILE).exists():
        return
    held = store.read_run_config(run_dir, "run_dir")
    if type(held) is not type(cfg) or compile_identity(held) != compile_identity(cfg):
        raise ConfigError(f"{where}: {run_dir} holds a run of another config than the row asks for; move it away "
                          f"or give the row another name")


def _budget(row: Row) -> dict[str, Any]:
    """The row's step budget as an override (empty without one)."""
    return {} if row.config.max_env_steps is None else {"max_env_steps": row.config.max_env_steps}


def train_row(job: Job) -> list[str]:
    """Phase 1 of every seed of the job's row: new seeds train as one vmapped program, an
    interrupted group resumes as one, a finished run is left alone. Returns what was done."""
    row = job.row
    dirs = [Path(d) for d in job.run_dirs]
    configs = [seed_config(row, seed) for seed in row.seeds]
    for run_dir, cfg in zip(dirs, configs):
        _same_config(run_dir, cfg, f"row {row.name!r}")
    if job.skills_base is not None:
        return copy_skills(job, dirs, configs)
    todo = [i for i, (d, cfg) in enumerate(zip(dirs, configs)) if not finished(d, cfg)]
    if not todo:
        return ["phase 1 finished earlier"]
    record = run_record(row.preset, {**row.overrides, **_budget(row)}, job.command)
    started = [i for i in todo if store.newest_checkpoint_on_disk(dirs[i]) is not None]
    if row.group_seeds and len(todo) == len(dirs) and not started:
        jobs.train(TrainExperiment(config=row.config, run_dir=job.base, seeds=row.seeds), record=record)
        return [f"trained seeds {', '.join(map(str, row.seeds))} as one program"]
    if row.group_seeds and len(started) == len(dirs):
        resume_seeds(dirs, configs)
        return [f"resumed seeds {', '.join(map(str, row.seeds))} as one program"]
    done = []
    for i in todo:
        if i in started:
            jobs.resume(ResumeExperiment(resume=str(dirs[i]), epochs=configs[i].epochs,
                                         max_env_steps=configs[i].max_env_steps or 0))
            done.append(f"resumed seed {row.seeds[i]}")
        else:
            jobs.train(TrainExperiment(config=configs[i], run_dir=str(dirs[i])), record=record)
            done.append(f"trained seed {row.seeds[i]}")
    return done


def copy_skills(job: Job, dirs: list[Path], configs: list[Any]) -> list[str]:
    """A ``skills_from`` row's phase 1: each seed's finished run of the source row copied (less
    its phase 2), so that this row's phase 2 has a run directory of its own. A source run not
    finished yet is refused: its row's job trains it, and a later call copies it."""
    done = []
    for seed, run_dir, cfg in zip(job.row.seeds, dirs, configs):
        if (run_dir / store.CONFIG_FILE).exists():
            if finished(run_dir, cfg):
                continue
            if (run_dir / store.PHASE2_SUBDIR).exists():
                raise ConfigError(f"row {job.row.name!r}: skills_from: {run_dir} holds a copy of row "
                                  f"{job.row.skills_from!r}'s seed {seed} that row has trained further since, and a "
                                  f"phase 2 on the old copy; move {run_dir} away to copy the new skills")
            shutil.rmtree(run_dir)  # an old copy with no phase 2 yet: copied again below
        source = Path(store.seed_run_dirs(job.skills_base, (seed,))[0])
        if not finished(source, cfg):
            raise ConfigError(f"row {job.row.name!r}: skills_from: row {job.row.skills_from!r} has not finished phase "
                              f"1 of seed {seed} ({source}); run the sweep again once it has")
        partial = run_dir.with_name(run_dir.name + ".partial")  # a copy cut short never looks like a run
        shutil.rmtree(partial, ignore_errors=True)
        shutil.copytree(source, partial, ignore=shutil.ignore_patterns(store.PHASE2_SUBDIR, store.LOCK_FILE))
        os.replace(partial, run_dir)
        done.append(f"copied phase 1 of seed {seed} from row {job.row.skills_from}")
    return done or ["phase 1 copied earlier"]


def phase2_row(job: Job) -> list[str]:
    """Phase 2 of every seed of the job's row (none without a phase-2 preset): trained, resumed
    or left alone when finished."""
    row = job.row
    if row.phase2 is None:
        return []
    done = []
    for seed, run_dir in zip(row.seeds, map(Path, job.run_dirs)):
        phase2_dir = run_dir / store.PHASE2_SUBDIR
        if (phase2_dir / store.CONFIG_FILE).exists():
            held = store.read_run_config(phase2_dir, "out", Phase2Config)
            if dataclasses.replace(held, phase1_epoch=-1, epochs=row.phase2.epochs) != \
                    dataclasses.replace(row.phase2, phase1_epoch=-1):
                raise ConfigError(f"row {row.name!r}: {phase2_dir} holds a phase 2 of another config than the row "
                                  f"asks for; move it away")
            if finished(phase2_dir, row.phase2):
                continue
            if store.newest_checkpoint_on_disk(phase2_dir) is not None:
                jobs.resume_phase2(ResumeExperiment(resume=str(phase2_dir), epochs=row.phase2.epochs))
                done.append(f"resumed phase 2 of seed {seed}")
                continue
        jobs.train_phase2(Phase2Experiment(run_dir=str(run_dir), config=row.phase2),
                          record=run_record(row.phase2_preset, row.phase2_overrides, job.command))
        jax.clear_caches()  # the next seed's phase 2 compiles its own
        done.append(f"trained phase 2 of seed {seed}")
    return done


def run_job(job: Job) -> list[dict]:
    """Everything a row needs, in one worker: phase 1, phase 2, then each seed's evaluation row.
    Its output goes to the job's log file."""
    with _output_to(Path(job.log)):
        print(f"== {time.strftime('%Y-%m-%d %H:%M:%S')} row {job.row.name} of {job.spec}", flush=True)
        done = train_row(job)
        jax.clear_caches()  # each step compiles its own programs; memory mappings are finite (vm.max_map_count)
        done += phase2_row(job)

        rows = []
        for run_dir, eval_seed in zip(job.run_dirs, job.eval_seeds):
            print(f"evaluating {run_dir} ...", flush=True)
            row = evaluation_row(Path(run_dir), eval_seed, job.row.episodes, job.command, job.spec,
                                 job.row.name, job.coverage_draws)
            row["evaluation"]["did"] = done
            rows.append(json.loads(json.dumps(row)))
        return rows


class _output_to:
    """Send this process's stdout and stderr (file descriptors too: JAX and orbax log there) to a
    log file for the duration, and back after."""

    def __init__(self, path: Path):
        self.path = path

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        sys.stdout.flush()
        sys.stderr.flush()
        self.log = open(self.path, "a")
        self.saved = [os.dup(1), os.dup(2)]
        os.dup2(self.log.fileno(), 1)
        os.dup2(self.log.fileno(), 2)
        return self

    def __exit__(self, *exc):
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, saved in zip((1, 2), self.saved):
            os.dup2(saved, fd)
            os.close(saved)
        self.log.close()


def _die_with_parent() -> None:
    """A local worker dies with the sweep that started it (Linux), so that a killed sweep leaves
    no orphan training behind the run locks of the next call."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


# ---- the sweep ----------------------------------------------------------------------------------


@dataclasses.dataclass
class Plan:
    """The jobs a call runs and the (row, seed) pairs the store already answers."""

    jobs: list[Job]
    current: list[tuple[str, int]]
    total: int


def plan(spec: Spec, runs_root: Path, results: Path, command: str) -> Plan:
    """What a call must do: a job for each row with a seed whose stored row is missing or no
    longer what the spec asks (its training resumes or is left alone as its run directory says)."""
    stored = stored_rows(results, spec)
    by_name = {row.name: row for row in spec.rows}
    jobs, current = [], []
    logs = runs_root / spec.name / "logs"
    for row in spec.rows:
        fresh = [(row.name, seed) for seed in row.seeds
                 if row_is_current(stored.get((row.name, seed)), row, seed, spec.run_eval_seed(seed),
                                  spec.coverage_draws)]
        current += fresh
        if len(fresh) < len(row.seeds):
            base = row_base(runs_root, spec, row)
            skills = None if row.skills_from is None else row_base(runs_root, spec, by_name[row.skills_from])
            jobs.append(Job(spec.name, row, base, tuple(store.seed_run_dirs(base, row.seeds)),
                            tuple(spec.run_eval_seed(seed) for seed in row.seeds), spec.coverage_draws,
                            str(logs / f"{row.name}.log"), command, skills))
    return Plan(jobs, current, sum(len(row.seeds) for row in spec.rows))


def schedule(jobs: list[Job], limit: int, submit: Callable[[Job], Any],
             next_done: Callable[[dict], Any]) -> Iterator[tuple[Job, Any]]:
    """Run ``jobs`` in the spec's order, at most ``limit`` at a time, and yield (job, its
    finished future) as each ends. A row whose skills come from another row's runs
    (``skills_from``) starts only once that row's job of this call has ended, and then before
    the rows after it. ``submit(job)`` starts one; ``next_done(running)`` waits for one of the
    running futures to end and returns it."""
    waiting, running, ended = list(jobs), {}, set()
    with_jobs = {job.row.name for job in jobs}
    while waiting or running:
        while waiting and len(running) < limit:
            ready = next((job for job in waiting
                          if job.row.skills_from not in with_jobs or job.row.skills_from in ended), None)
            if ready is None:
                break
            waiting.remove(ready)
            running[submit(ready)] = ready
        future = next_done(running)
        job = running.pop(future)
        ended.add(job.row.name)
        yield job, future


def _executor(kind: str, workers: int, folder: Path, slurm: dict[str, Any]):
    """The executor that runs jobs: local worker processes, or submitit (Slurm, or its local
    executor) writing its files under ``folder``."""
    if kind == "local":
        return concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(
            "spawn"), initializer=_die_with_parent)
    try:
        import submitit
    except ImportError:
        raise ConfigError(f"executor: {kind} needs submitit; pip install \"mjx-emp[cluster]\"") from None
    if kind == "submitit-local":
        executor = submitit.LocalExecutor(folder=str(folder))
        executor.update_parameters(timeout_min=int(slurm.get("timeout_min", 24 * 60)))
        return executor
    try:
        executor = submitit.AutoExecutor(folder=str(folder), cluster="slurm")
    except RuntimeError as err:  # no srun/sbatch here
        raise ConfigError(f"executor: slurm: {err} (`--executor local` runs the spec on this machine)") from None
    try:
        executor.update_parameters(**slurm)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"spec: slurm: {err}") from None
    return executor


def sweep(spec_path: str, runs: str = "", results: str = "", workers: int = 1, executor: str = "local",
          dry_run: bool = False, report: Callable[[str], None] = print) -> list[dict]:
    """Run a spec: every (row, seed) trained, resumed or left alone, its phase 2, its evaluation
    row appended to the store. Returns the rows this call wrote."""
    if executor not in EXECUTORS:
        raise ConfigError(f"executor: {executor!r} is unknown; allowed: {', '.join(EXECUTORS)}")
    if workers < 1:
        raise ConfigError(f"workers: must be >= 1; got {workers}")
    spec = load_spec(spec_path)
    runs_root = Path(runs or spec.runs)
    results_path = store.output_target(Path(results or Path(RESULTS_DIR) / f"{spec.name}.jsonl"), "results",
                                       make_folder=not results)
    command = shlex.join(["mjx-emp", "sweep", spec_path, "--runs", str(runs_root), "--results", str(results_path)])
    todo = plan(spec, runs_root, results_path, command)
    report(f"sweep {spec.name}: {len(spec.rows)} rows, {todo.total} runs; {len(todo.current)} evaluated already, "
           f"{todo.total - len(todo.current)} to do in {len(todo.jobs)} job(s); runs in {runs_root / spec.name}, "
           f"rows to {results_path}")
    if dry_run or not todo.jobs:
        return []
    (runs_root / spec.name).mkdir(parents=True, exist_ok=True)
    written: list[dict] = []
    started = time.monotonic()
    pool = _executor(executor, workers, runs_root / spec.name / "submitit", spec.slurm)
    done_runs = len(todo.current)
    limit = len(todo.jobs) if executor == "slurm" else workers  # Slurm queues them; local workers take `workers`
    try:
        for job, future in schedule(todo.jobs, limit, lambda job: pool.submit(run_job, job),
                                    functools.partial(next_done, executor=executor)):
            rows = job_rows(job, future)
            for row in rows:
                append_row(results_path, row)
            written += rows
            done_runs += len(rows)
            elapsed = time.monotonic() - started
            left = todo.total - done_runs
            per_run = elapsed / max(1, done_runs - len(todo.current))
            eta = f"; about {_duration(per_run * left / workers)} left" if left else ""
            did = "; ".join(rows[0]["evaluation"]["did"]) or "evaluated"
            report(f"[{done_runs}/{todo.total} runs] row {job.row.name}: {did} ({_duration(elapsed)} so far{eta}); "
                   f"log {job.log}")
    finally:
        if hasattr(pool, "shutdown"):
            pool.shutdown(wait=True, cancel_futures=True)
    return written


def next_done(running: dict, executor: str) -> Any:
    """Wait for one of the ``running`` futures (concurrent.futures' or submitit's jobs) to end;
    return it."""
    if executor == "local":
        done, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
        return next(future for future in running if future in done)  # the first submitted of those done
    while True:
        finished = next((future for future in running if future.done()), None)
        if finished is not None:
            return finished
        time.sleep(1.0)


def job_rows(job: Job, future: Any) -> list[dict]:
    """A finished job's rows; a job that failed raises here, naming its row and log."""
    try:
        return future.result()
    except ConfigError as err:
        raise ConfigError(f"{err} (log: {job.log})") from None
    except Exception as err:  # a worker's failure: its row is named, its log holds the traceback
        raise JobFailed(f"row {job.row.name!r} failed ({type(err).__name__}: {err}); see {job.log}; calling the "
                        f"sweep again resumes") from err


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


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

