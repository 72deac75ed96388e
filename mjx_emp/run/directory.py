"""Training runs in their directories: config, metrics, checkpoints, progress, resume.

Layout of RUN_DIR: ``config.json`` (the resolved config and its algorithm), ``metrics.jsonl`` (one JSON
line per finished epoch) and ``checkpoints/<epoch>/`` (orbax; epoch 0 is the initial state).
A phase-2 directory (by default RUN_DIR/phase2) has the same layout with a Phase2Config,
plus ``skills.json``, the phase-1 config of the skills it builds on.
An epoch is kept only once its losses and parameters are finite; a run stopped at any point
(crash, SIGKILL, NaN) resumes from its newest complete checkpoint and then computes exactly
what the uninterrupted run would have.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mjx_emp.algos.he.config import Phase2Config, check_phase2_config
from mjx_emp.algos.registry import algorithm_of, config_from_json, config_to_json, make_agent
from mjx_emp.checks import config_from_dict
from mjx_emp.commands import Phase2Experiment, ResumeExperiment, TrainExperiment
from mjx_emp.errors import (
    CheckpointError,
    CheckpointWriteError,
    ConfigError,
    Interrupted,
    RenderError,
    TrainingDiverged,
)

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.jsonl"
PHASE2_SUBDIR = "phase2"
SKILLS_FILE = "skills.json"
"""In a phase-2 directory: the phase-1 config of the skills it builds on."""


def default_run_dir(cfg) -> str:
    """A fresh run directory name: runs/<env>-k<k>-<date>-<time> for HE, runs/<algorithm>-<env>-<date>-<time>
    for the others."""
    stamp = time.strftime('%Y%m%d-%H%M%S')
    name = algorithm_of(cfg).name
    return f"runs/{cfg.env}-k{cfg.k}-{stamp}" if name == "he" else f"runs/{name}-{cfg.env}-k{cfg.k}-{stamp}"


def prepare_run_dir(path: str, field: str = "run_dir") -> Path:
    """Create the run directory, or fail with a ConfigError naming ``field``."""
    run_dir = Path(path)
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / f".write-test-{os.getpid()}"  # one per process: several hosts may probe at once
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        raise ConfigError(f"{field}: cannot write to {str(run_dir)!r} ({err.strerror})") from err
    return run_dir


def write_atomically(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` so that a reader (or a crash) sees the old or the new file."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def read_run_config(run_dir: Path, field: str = "resume", config_type: type | None = None,
                    file: str = CONFIG_FILE):
    """The config saved in a run directory; errors name the file and the CLI ``field``.

    Without ``config_type`` the file holds an algorithm's config, which names its algorithm
    (see :mod:`mjx_emp.algos.registry`); phase-2 directories pass ``Phase2Config``.
    """
    path = run_dir / file
    try:
        values = json.loads(path.read_text())
        return config_from_json(values) if config_type is None else config_from_dict(values, config_type)
    except FileNotFoundError as err:
        raise ConfigError(f"{field}: {str(run_dir)!r} has no {file}; is it a run directory?") from err
    except (json.JSONDecodeError, TypeError, ConfigError) as err:
        raise ConfigError(f"{field}: {path} is not a valid run config ({err})") from err


def keep_metrics_through(path: Path, epoch: int) -> None:
    """Drop metric lines of epochs after ``epoch`` (written after the checkpoint we resume from)."""
    if not path.exists():
        return
    lines = [line for line in path.read_text().splitlines() if line.strip()]
    kept = []
    for line in lines:
        try:
            if json.loads(line)["epoch"] <= epoch:
                kept.append(line)
        except (json.JSONDecodeError, KeyError):
            break  # a line cut short by a kill: nothing after it is trustworthy
    write_atomically(path, "".join(line + "\n" for line in kept))


@contextlib.contextmanager
def progress_reporter(total_epochs: int, first_epoch: int,
                      describe: Callable[[dict], str]) -> Iterator[Callable[[dict], None]]:
    """Report each epoch: a live progress bar on a terminal, one plain line per epoch otherwise.

    ``describe`` turns an epoch's metrics into the short summary shown.
    """
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    console = Console()
    if not console.is_terminal:
        yield lambda metrics: print(f"epoch {metrics['epoch']:4d}  {describe(metrics)}", flush=True)
        return
    columns = (TextColumn("epoch"), MofNCompleteColumn(), BarColumn(), TimeRemainingColumn(),
               TextColumn("{task.fields[info]}"))
    with Progress(*columns, console=console) as bar:
        task = bar.add_task("train", total=total_epochs, completed=first_epoch, info="compiling")
        yield lambda metrics: bar.update(task, completed=metrics["epoch"], info=describe(metrics))


@dataclasses.dataclass(frozen=True)
class Member:
    """One run directory that a training program writes: the agent whose config it records
    (its metrics and divergence check), its checkpoints and its directory."""

    trainer: Any
    checkpoints: Any
    run_dir: Path


def _alone(state, stats) -> list[tuple[Any, Any]]:
    return [(state, stats)]


def _epoch_of(state) -> int:
    """A train state's epoch (a split run's state holds it once per shard, maybe on several hosts)."""
    import numpy as np

    epoch = state.epoch
    if not getattr(epoch, "is_fully_addressable", True):
        epoch = epoch.addressable_shards[0].data  # every shard holds the same epoch
    return int(np.asarray(epoch).reshape(-1)[0])


def train_members(program, state, members: list[Member], report: Callable[[dict], None],
                  split: Callable[[Any, Any], list[tuple[Any, Any]]] = _alone):
    """Train until the members' epoch count, checkpointing and logging each finished epoch.

    ``program.train_epoch(state) -> (state, stats)`` trains every member at once (one agent,
    or several seeds under one vmap); ``split(state, stats)`` gives each member's share.
    Raises TrainingDiverged, saving nothing of that epoch for any member, when a member's
    losses or parameters are not finite; each member's newest checkpoint is then its last
    good epoch. ``report`` sees the first member's metrics. ``seconds`` in a member's
    metrics is the wall time of the whole program's epoch.
    """
    from mjx_emp.run.hosts import gather_to_host, is_lead

    epochs = members[0].trainer.cfg.epochs
    lead = is_lead()  # with several hosts, process 0 alone writes metrics (and checkpoints)
    stops = _SignalStop()
    try:
        with stops.installed():
            return _train_members(program, state, members, report, split, gather_to_host, lead, epochs, stops)
    except Interrupted as stop:
        for member in members:
            member.checkpoints.wait()  # the write in flight completes before we go
        kept = members[0].checkpoints.epochs()
        newest = f"epoch {kept[-1]} in {members[0].checkpoints.directory}" if kept else "none"
        raise Interrupted(f"stopped by {signal.Signals(stop.signum).name}; the newest checkpoint is {newest}; "
                          f"continue with `--resume {members[0].run_dir}`", stop.signum) from None


class _SignalStop:
    """While training, SIGINT and SIGTERM raise :class:`Interrupted`: at once between two Python
    steps (a running epoch's compiled call finishes first), or, inside :meth:`held` (an epoch's
    checkpoint and metrics line, which belong together), as soon as it ends."""

    def __init__(self):
        self.holding, self.pending = False, None

    def _stop(self, signum, frame):
        if self.holding:
            self.pending = signum
            return
        raise Interrupted(signal.Signals(signum).name, signum)

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        try:
            previous = {signum: signal.signal(signum, self._stop) for signum in (signal.SIGINT, signal.SIGTERM)}
        except ValueError:  # not the main thread: signals are not ours to take
            yield
            return
        try:
            yield
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        self.holding = True
        try:
            yield
        finally:
            self.holding = False
        if self.pending is not None:
            raise Interrupted(signal.Signals(self.pending).name, self.pending)


def _train_members(program, state, members, report, split, gather_to_host, lead: bool, epochs: int,
                   stops: _SignalStop):
    import jax

    with contextlib.ExitStack() as stack:
        logs = [stack.enter_context(open(member.run_dir / METRICS_FILE, "a") if lead else open(os.devnull, "w"))
                for member in members]
        while _epoch_of(split(state, None)[0][0]) < epochs:
            start = time.perf_counter()
            state, stats = program.train_epoch(state)
            jax.block_until_ready(state)
            seconds = time.perf_counter() - start
            parts = split(*gather_to_host((state, stats)))
            epoch = _epoch_of(parts[0][0])
            problems = [(m, m.trainer.divergence(*part)) for m, part in zip(members, parts)]
            problems = [(m, problem) for m, problem in problems if problem]
            if problems:
                for member in members:
                    member.checkpoints.wait()
                member, problem = problems[0]
                kept = member.checkpoints.epochs()
                raise TrainingDiverged(
                    f"epoch {epoch}: {problem}. Stopped without saving this epoch; the last good "
                    f"checkpoint is epoch {kept[-1] if kept else None} in {member.checkpoints.directory}"
                    + (f" (and likewise for {len(members) - 1} other seed run(s))" if len(members) > 1 else "")
                )
            with stops.held():  # a checkpoint and its metrics line are written together
                for member, log, (member_state, member_stats) in zip(members, logs, parts):
                    save_seconds = member.checkpoints.save(epoch, member_state, member.trainer.cfg)
                    metrics = member.trainer.metrics(member_state, member_stats, seconds)
                    metrics["checkpoint_blocked_s"] = save_seconds  # the write itself continues in the background
                    log.write(json.dumps(metrics) + "\n")
                    log.flush()
                    if member is members[0] and lead:
                        report(metrics)
    for member in members:
        member.checkpoints.wait()
    return state


def train_epochs(trainer, state, checkpoints, run_dir: Path, report: Callable[[dict], None]):
    """Train one run until ``trainer.cfg.epochs`` (see :func:`train_members`).

    ``trainer`` is any algorithm's agent or a phase-2 trainer (each offers ``train_epoch``,
    ``divergence`` and ``metrics``).
    """
    return train_members(trainer, state, [Member(trainer, checkpoints, run_dir)], report)


def _holds_a_run(run_dir: Path) -> bool:
    from mjx_emp.run.checkpoint import CHECKPOINT_SUBDIR

    return (run_dir / METRICS_FILE).exists() or (run_dir / CHECKPOINT_SUBDIR).exists()


def _check_keep(keep_checkpoints: int) -> None:
    if keep_checkpoints < 1:
        raise ConfigError(f"keep_checkpoints: must be >= 1; got {keep_checkpoints}")


def _train_to_the_end(trainer, state, checkpoints, run_dir: Path):
    """Report progress while training to ``cfg.epochs``; then close ``checkpoints`` (waits for writes)."""
    with checkpoints, progress_reporter(trainer.cfg.epochs, _epoch_of(state), trainer.describe) as report:
        return train_epochs(trainer, state, checkpoints, run_dir, report)


LOCK_FILE = ".lock"
"""In a run directory while a process trains it: that process's id and host (flock-ed)."""


@contextlib.contextmanager
def run_lock(run_dir: Path, field: str) -> Iterator[None]:
    """Hold RUN_DIR/.lock while a command writes the run: a second writer (train, resume, phase
    2) is refused with a ConfigError naming the process that holds it. The lock is the
    kernel's (``flock``), so it goes with its process however that ends; a lock file left by a
    killed process is taken over with a note. With several hosts only the lead locks."""
    import fcntl
    import socket

    from mjx_emp.run.hosts import is_lead

    if not is_lead():
        yield
        return
    path = Path(run_dir) / LOCK_FILE
    handle = open(path, "a+")
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            raise ConfigError(f"{field}: {str(run_dir)!r} is in use by process {holder} (lock {path}); wait for it "
                              f"to end or stop it") from None
        handle.seek(0)
        left = handle.read().strip()
        if left:
            print(f"note: taking over the lock of {run_dir} left by process {left}, which no longer holds it",
                  flush=True)
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()} on {socket.gethostname()}\n")
        handle.flush()
        try:
            yield
        finally:
            handle.seek(0)
            handle.truncate()  # an empty lock file: released on purpose, nothing to take over
            handle.flush()
            fcntl.flock(handle, fcntl.LOCK_UN)
    finally:
        handle.close()


def fresh_run_dir(path: str, field: str, what: str, command: str) -> Path:
    """Create the directory of a new run; one that already holds ``what`` is refused, naming ``field``."""
    run_dir = prepare_run_dir(path, field)
    if _holds_a_run(run_dir):
        raise ConfigError(
            f"{field}: {str(run_dir)!r} already holds {what}; continue it with "
            f"`{command} --resume {run_dir}` or choose another --{field.replace('_', '-')}"
        )
    return run_dir


def config_json(cfg) -> dict:
    """config.json's form of ``cfg``: an algorithm's config records its algorithm; a phase-2
    config is its fields alone."""
    return dataclasses.asdict(cfg) if isinstance(cfg, Phase2Config) else config_to_json(cfg)


def write_config(run_dir: Path, cfg) -> None:
    """RUN_DIR/config.json of ``cfg`` (see :func:`config_json`), written atomically."""
    write_atomically(Path(run_dir) / CONFIG_FILE, json.dumps(config_json(cfg), indent=1))


def _train_new(trainer, state, run_dir: Path, keep_checkpoints: int, config_type: type):
    """Write the config, checkpoint ``state`` as epoch 0, and train to the end (with several
    hosts, the lead writes)."""
    from mjx_emp.run.checkpoint import Checkpoints
    from mjx_emp.run.hosts import gather_to_host, is_lead

    if is_lead():
        write_config(run_dir, trainer.cfg)
    checkpoints = Checkpoints(run_dir, keep_checkpoints, config_type)
    checkpoints.save(0, gather_to_host(state), trainer.cfg)
    return _train_to_the_end(trainer, state, checkpoints, run_dir)


def training_program(cfg, num_devices: int = 0):
    """What trains a run of ``cfg``: its agent, or for a run split into shards a
    :class:`~mjx_emp.run.devices.ShardedAgent` over ``num_devices`` local devices (0: as
    many as divide the shards)."""
    if cfg.shards == 1 and num_devices <= 1:
        return make_agent(cfg)
    from mjx_emp.run.devices import ShardedAgent, choose_devices

    return ShardedAgent(cfg, choose_devices(cfg.shards, num_devices))


def split_for_devices(cfg, num_devices: int):
    """A new run's config with its shards set from ``--num-devices``: an unsplit config
    becomes one shard per device (``num_devices`` 0: every local device); a config that
    sets its shards keeps them."""
    if cfg.shards > 1:
        return cfg
    if num_devices == 0:
        import jax

        num_devices = jax.device_count()  # every device of every process
    return dataclasses.replace(cfg, shards=num_devices) if num_devices > 1 else cfg


def train(exp: TrainExperiment):
    """Train a new run of the config's algorithm (with ``exp.seeds``, one run per seed under one
    vmap: :mod:`mjx_emp.run.seeds`; split over devices per ``exp.num_devices``: :mod:`mjx_emp.run.devices`);
    returns the final state."""
    from mjx_emp.run.hosts import join_hosts, wait_for_all

    several = join_hosts(exp.coordinator_address, exp.num_processes, exp.process_id)
    if exp.seeds:
        if several:
            raise ConfigError("seeds: a seed group trains in one process; drop --seeds or the coordinator")
        from mjx_emp.run.seeds import train_seeds

        return train_seeds(exp)
    algorithm = algorithm_of(exp.config)
    algorithm.check(exp.config)
    _check_keep(exp.keep_checkpoints)
    cfg = split_for_devices(exp.config, exp.num_devices)
    algorithm.check(cfg)
    if several and not exp.run_dir:
        raise ConfigError("run_dir: several hosts must be given the same --run-dir (on a shared filesystem)")
    trainer = training_program(cfg, exp.num_devices)
    check_memory(trainer)  # before anything is allocated or written
    run_dir = fresh_run_dir(exp.run_dir or default_run_dir(cfg), "run_dir", "a run", "mjx-emp train")
    wait_for_all("mjx-emp: every process checked the run directory")  # before the lead writes into it
    print(f"run directory: {run_dir}", flush=True)
    with run_lock(run_dir, "run_dir"):
        if cfg.shards > 1:
            print(f"split into {cfg.shards} shards on {trainer.num_devices} device(s)", flush=True)
        return _train_new(trainer, trainer.init(), run_dir, exp.keep_checkpoints, algorithm.config_type)


def check_memory(program) -> None:
    """The memory preflight (:mod:`mjx_emp.run.preflight`) of what trains a run, before it allocates."""
    from mjx_emp.run.preflight import preflight

    agent = getattr(program, "alone", program)  # a split run: one shard's agent sees the environment
    preflight(program, program.cfg, agent.env.obs_size, getattr(program, "num_devices", 1))


def _restore(run_dir: Path, trainer, template, fallback: bool = False, epoch: int | None = None):
    """``(epoch, state)`` of ``run_dir``'s newest good checkpoint, or of ``epoch``'s, for ``trainer``."""
    from mjx_emp.run.checkpoint import Checkpoints

    with Checkpoints(run_dir, config_type=type(trainer.cfg)) as checkpoints:
        if epoch is None:
            return checkpoints.restore_latest(template, trainer.cfg, fallback)
        if epoch not in checkpoints.epochs():
            raise ConfigError(f"phase1_epoch: {run_dir} has checkpoints of epochs {checkpoints.epochs()}; got {epoch}")
        return epoch, checkpoints.restore(epoch, template, trainer.cfg)


def _with_epochs(cfg, epochs: int | None):
    """``cfg`` with its epoch count replaced (the one setting a resume may change), if given."""
    return cfg if epochs is None else dataclasses.replace(cfg, epochs=epochs)


def load_run(run_dir: Path, fallback: bool = False, epochs: int | None = None, field: str = "run_dir",
             epoch: int | None = None):
    """A run's agent and its newest good checkpoint (or ``epoch``'s): ``(agent, epoch, state)``.

    ``epochs`` replaces the run's epoch count; ``field`` is the CLI field that errors about
    ``run_dir`` name.
    """
    import jax

    cfg = _with_epochs(read_run_config(Path(run_dir), field), epochs)
    if cfg.shards > 1:  # a split run: shard 0's state (its networks are every shard's) and agent
        from mjx_emp.run.devices import ShardedAgent, shard_slice

        program = ShardedAgent(cfg, 1)
        epoch, state = _restore(Path(run_dir), program, jax.eval_shape(program.init), fallback, epoch)
        return program.alone, epoch, shard_slice(state, 0)
    trainer = make_agent(cfg)
    epoch, state = _restore(Path(run_dir), trainer, jax.eval_shape(trainer.init), fallback, epoch)
    return trainer, epoch, state


def load_program(run_dir: Path, fallback: bool = False, epochs: int | None = None, field: str = "resume",
                 num_devices: int = 0):
    """What trains a run on (see :func:`training_program`) and its newest good checkpoint,
    placed on the program's devices: ``(program, epoch, state)``."""
    import jax

    program = training_program(_with_epochs(read_run_config(Path(run_dir), field), epochs), num_devices)
    epoch, state = _restore(Path(run_dir), program, jax.eval_shape(program.init), fallback)
    return program, epoch, (program.place(state) if hasattr(program, "place") else state)


def _resume(exp: ResumeExperiment, load: Callable):
    """Continue a run directory from its newest good checkpoint (``load`` restores it)."""
    _check_keep(exp.keep_checkpoints)
    run_dir = Path(exp.resume)
    if not (run_dir / CONFIG_FILE).exists():  # a directory that is no run is refused before anything is written
        raise ConfigError(f"resume: {str(run_dir)!r} has no {CONFIG_FILE}; is it a run directory?")
    with run_lock(run_dir, "resume"):
        trainer, epoch, state = load(run_dir, exp.fallback, exp.epochs, field="resume")
        from mjx_emp.run.checkpoint import Checkpoints

        print(f"resuming {run_dir} from epoch {epoch}", flush=True)
        keep_metrics_through(run_dir / METRICS_FILE, epoch)
        write_config(run_dir, trainer.cfg)
        checkpoints = Checkpoints(run_dir, exp.keep_checkpoints, type(trainer.cfg))
        return _train_to_the_end(trainer, state, checkpoints, run_dir)


def resume(exp: ResumeExperiment):
    """Continue a phase-1 run from its newest good checkpoint (a split run on ``exp.num_devices``
    devices); returns the final TrainState."""
    return _resume(exp, functools.partial(load_program, num_devices=exp.num_devices))


GOAL_SPACE_ALGORITHMS = ("he", "gcrl")
"""Algorithms whose runs have goal spaces (what plot and render draw)."""


def has_goal_spaces(run_dir: Path, field: str = "run_dir") -> bool:
    """Whether RUN_DIR's algorithm learns goal spaces (HE, GCRL) rather than flat skills; a
    directory without config.json counts as one, left to the command to say what it lacks."""
    if not (Path(run_dir) / CONFIG_FILE).exists():
        return True
    return algorithm_of(read_run_config(Path(run_dir), field)).name in GOAL_SPACE_ALGORITHMS


def train_phase2(exp: Phase2Experiment):
    """Train phase 2 on a phase-1 run's skills in a new phase-2 directory; returns the final state."""
    check_phase2_config(exp.config)
    _check_keep(exp.keep_checkpoints)
    if not exp.run_dir:
        raise ConfigError("run_dir: give the phase-1 run directory, e.g. `mjx-emp phase2 runs/pm1`")
    from mjx_emp.downstream_flat import make_phase2_trainer

    requested = None if exp.config.phase1_epoch < 0 else exp.config.phase1_epoch
    skills, epoch, skills_state = load_run(Path(exp.run_dir), field="run_dir", epoch=requested)
    cfg = dataclasses.replace(exp.config, phase1_epoch=epoch)
    trainer = make_phase2_trainer(skills, cfg)
    out = fresh_run_dir(exp.out or str(Path(exp.run_dir) / PHASE2_SUBDIR), "out", "a phase-2 run", "mjx-emp phase2")
    with run_lock(out, "out"):
        print(f"phase 2 on the skills of {exp.run_dir} (epoch {epoch}), writing to {out}", flush=True)
        write_atomically(out / SKILLS_FILE, json.dumps(config_json(skills.cfg), indent=1))
        return _train_new(trainer, trainer.init(skills_state), out, exp.keep_checkpoints, Phase2Config)


def load_phase2(phase2_dir: Path, fallback: bool = False, epochs: int | None = None, field: str = "run_dir"):
    """A phase-2 directory's trainer and newest good checkpoint: ``(trainer, epoch, state)``.

    The directory stands on its own: it holds the phase-1 config and the frozen skills.
    """
    import jax

    from mjx_emp.downstream_flat import make_phase2_trainer

    phase2_dir = Path(phase2_dir)
    cfg = _with_epochs(read_run_config(phase2_dir, field, Phase2Config), epochs)
    trainer = make_phase2_trainer(make_agent(read_run_config(phase2_dir, field, file=SKILLS_FILE)), cfg)
    template = jax.eval_shape(trainer.init, jax.eval_shape(trainer.phase1.init))
    epoch, state = _restore(phase2_dir, trainer, template, fallback)
    return trainer, epoch, state


def resume_phase2(exp: ResumeExperiment):
    """Continue a phase-2 directory from its newest good checkpoint; returns the final state."""
    return _resume(exp, load_phase2)


def main_guarded(command: Callable, exp) -> None:
    """Run a CLI command; bad input exits 2, divergence, a failed checkpoint write or running out of
    memory 1, no offscreen GL 3, SIGINT/SIGTERM 130/143, each with a reason."""
    failures = (
        (ConfigError, "invalid configuration", 2),
        (CheckpointError, "unusable checkpoint", 2),
        (TrainingDiverged, "training diverged", 1),
        (CheckpointWriteError, "checkpoint write failed", 1),
        (RenderError, "cannot render", 3),
    )
    from mjx_emp.run.preflight import explain_out_of_memory

    try:
        command(exp)
    except Interrupted as stop:
        print(f"mjx-emp: {stop}", file=sys.stderr)
        sys.exit(128 + stop.signum)
    except tuple(kind for kind, _, _ in failures) as err:
        what, code = next((what, code) for kind, what, code in failures if isinstance(err, kind))
        print(f"mjx-emp: {what}: {err}", file=sys.stderr)
        sys.exit(code)
    except Exception as err:  # XLA's out-of-memory error is explained; anything else is a bug to report
        explanation = explain_out_of_memory(err)
        if explanation is None:
            raise
        print(f"mjx-emp: {explanation}", file=sys.stderr)
        sys.exit(1)
