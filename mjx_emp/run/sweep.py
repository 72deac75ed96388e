"""`mjx-emp sweep SPEC`: train, resume and evaluate every run of a study (a spec,
:mod:`mjx_emp.run.specs`), one row per run with its provenance.

Each (row, seed) is a run directory RUNS/<spec>/<row>-s<seed>. The seeds of a row train as one
vmapped program (`mjx-emp train --seeds`) and resume as one, so an interrupted sweep ends with
the same numbers as one that was never stopped. A second call trains nothing that is finished
and evaluates nothing whose row is in the store. Rows are evaluated by
:func:`mjx_emp.run.evaluate.evaluation_row`, the evaluation `mjx-emp eval` runs. Jobs (one per
row) run in local worker processes, or through submitit: on Slurm, or with its local executor,
which takes the same path without a cluster.
"""

from __future__ import annotations

import concurrent.futures
import ctypes
import dataclasses
import functools
import json
import multiprocessing
import os
import shlex
import shutil
import signal
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax

from mjx_emp.algos.registry import config_from_json
from mjx_emp.checks import compile_identity, config_from_dict
from mjx_emp.commands import (
    Phase2Experiment,
    ResumeExperiment,
    TrainExperiment,
)
from mjx_emp.errors import ConfigError, Interrupted, JobFailed
from mjx_emp.phase2.config import Phase2Config
from mjx_emp.run import jobs, store
from mjx_emp.run.evaluate import evaluation_row
from mjx_emp.run.loop import SignalStop, training_done
from mjx_emp.run.provenance import run_record
from mjx_emp.run.rows import RESULTS_DIR, append_row, read_rows
from mjx_emp.run.seeds import resume_seeds
from mjx_emp.run.specs import EXECUTORS, Row, Spec, load_spec


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
    lines = [line for line in store.read_metrics(Path(run_dir)) if line.get("epoch") == newest]
    env_steps = lines[-1].get("env_steps", 0) if lines else 0
    return training_done(newest, env_steps, cfg.epochs, cfg.max_env_steps)


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

    phase2 = None if row.phase2 is None else recorded_form(row.phase2)
    train, evaluation = stored.get("train", {}), stored.get("evaluation", {})
    return (as_loaded_today(train.get("config")) == recorded_form(seed_config(row, seed))
            and task(as_loaded_today(stored.get("phase2_config"), Phase2Config)) == task(phase2)
            and evaluation.get("seed") == eval_seed and evaluation.get("episodes") == row.episodes
            and evaluation.get("coverage_draws", 1) == coverage_draws)


def as_loaded_today(config: Any, config_type: type | None = None) -> Any:
    """A row's recorded config as a run directory's config.json of it would load now, in JSON
    form: fields added since the row was made take their defaults (an option is off by default,
    so the row ran without it); ``config`` itself where it does not load (``unknown``, a field
    since removed), which matches no spec's config."""
    if not isinstance(config, dict):
        return config
    try:
        loaded = config_from_json(config) if config_type is None else config_from_dict(config, config_type)
    except (ConfigError, TypeError, ValueError):
        return config
    return recorded_form(loaded)


def recorded_form(cfg: Any) -> dict:
    """``cfg`` as a row records it: config.json's form, through JSON (tuples as lists)."""
    return json.loads(json.dumps(store.config_json(cfg)))


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


def same_phase2(held: Phase2Config, wanted: Phase2Config) -> bool:
    """Whether a phase-2 directory holding ``held`` is the row's ``wanted`` phase 2, differing at
    most in when it stops (epochs, step budget: what a resume may change) and in the phase-1
    epoch it was recorded to build on (the run's, where the row asks for the newest)."""
    return compile_identity(dataclasses.replace(held, phase1_epoch=-1)) == \
        compile_identity(dataclasses.replace(wanted, phase1_epoch=-1))


def phase2_row(job: Job) -> list[str]:
    """Phase 2 of every seed of the job's row (none without a phase-2 preset): trained, resumed
    or left alone when finished."""
    row = job.row
    if row.phase2 is None:
        return []
    done = []
    for seed, run_dir in zip(row.seeds, map(Path, job.run_dirs)):
        phase2_dir = store.own_phase2(run_dir)
        if phase2_dir is not None:
            if not same_phase2(store.read_run_config(phase2_dir, "out", Phase2Config), row.phase2):
                raise ConfigError(f"row {row.name!r}: {phase2_dir} holds a phase 2 of another config than the row "
                                  f"asks for; move it away")
            if finished(phase2_dir, row.phase2):
                continue
            if store.newest_checkpoint_on_disk(phase2_dir) is not None:
                jobs.resume_phase2(ResumeExperiment(resume=str(phase2_dir), epochs=row.phase2.epochs,
                                                    max_env_steps=row.phase2.max_env_steps))
                done.append(f"resumed phase 2 of seed {seed}")
                continue
        jobs.train_phase2(Phase2Experiment(run_dir=str(run_dir), config=row.phase2),
                          record=run_record(row.phase2_preset, row.phase2_overrides, job.command))
        jax.clear_caches()  # the next seed's phase 2 compiles its own
        done.append(f"trained phase 2 of seed {seed}")
    return done


def run_job(job: Job) -> list[dict]:
    """Everything a row needs, in one worker: phase 1, phase 2, then each seed's evaluation row.
    Its output goes to the job's log file. SIGINT or SIGTERM at any point of it raises
    :class:`Interrupted` (training stops at its newest checkpoint)."""
    with _output_to(Path(job.log)), SignalStop().installed():
        print(f"== {time.strftime('%Y-%m-%d %H:%M:%S')} row {job.row.name} of {job.spec}", flush=True)
        try:
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
        except Interrupted as stop:
            print(f"== {time.strftime('%Y-%m-%d %H:%M:%S')} {stop}", flush=True)
            raise
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


def _local_worker() -> None:
    """A local worker dies with the sweep that started it (Linux), so that a killed sweep leaves
    no orphan training behind the run locks of the next call; and between jobs it ignores SIGINT
    and SIGTERM, so that a stop passed on to every worker (:func:`signal_workers`) ends the jobs
    (each stops itself, :func:`run_job`) and leaves an idle worker alive for the pool's orderly
    shutdown, where its death would break the pool and leave the shutdown waiting."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)


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
            "spawn"), initializer=_local_worker)
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
    stops = SignalStop()
    try:
        with stops.installed():
            try:
                for job, future in schedule(todo.jobs, limit, lambda job: pool.submit(run_job, job),
                                            functools.partial(next_done, executor=executor)):
                    rows = job_rows(job, future)
                    with stops.held():  # a job's rows go to the store together
                        for row in rows:
                            append_row(results_path, row)
                    written += rows
                    done_runs += len(rows)
                    elapsed = time.monotonic() - started
                    left = todo.total - done_runs
                    per_run = elapsed / max(1, done_runs - len(todo.current))
                    eta = f"; about {_duration(per_run * left / workers)} left" if left else ""
                    did = "; ".join(rows[0]["evaluation"]["did"]) or "evaluated"
                    report(f"[{done_runs}/{todo.total} runs] row {job.row.name}: {did} ({_duration(elapsed)} so far"
                           f"{eta}); log {job.log}")
            except Interrupted as stop:
                if executor == "local":
                    signal_workers(stop.signum)
                raise
            finally:
                if hasattr(pool, "shutdown"):
                    pool.shutdown(wait=True, cancel_futures=True)
    except Interrupted as stop:
        running = ("its running jobs stopped at their newest checkpoints" if executor == "local"
                   else "jobs already handed to submitit go on until they end or are cancelled")
        raise Interrupted(f"sweep {spec.name} stopped by {signal.Signals(stop.signum).name} with {done_runs} of "
                          f"{todo.total} runs evaluated; {running}; `{command}` resumes it", stop.signum) from None
    return written


def signal_workers(signum: int) -> None:
    """Pass ``signum`` on to this process's local workers, so that a job training stops at its
    newest checkpoint (:class:`~mjx_emp.run.loop.SignalStop`) and the pool can shut down, whether
    the signal reached the whole process group (Ctrl-C) or the sweep alone (``kill``)."""
    for worker in multiprocessing.active_children():
        try:
            os.kill(worker.pid, signum)
        except ProcessLookupError:
            pass


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
    except Interrupted:  # the signal reached the worker too (Ctrl-C): the sweep stops, not a job failure
        raise
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
