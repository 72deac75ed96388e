"""The epoch loop: train an agent (or several seeds under one vmap) epoch by epoch, writing each
finished epoch's checkpoint and metrics line together, stopping cleanly on SIGINT/SIGTERM.

An epoch is kept only once its losses and parameters are finite; a run stopped at any point
(crash, SIGKILL, NaN) resumes from its newest complete checkpoint and then computes exactly
what the uninterrupted run would have.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mjx_emp.errors import Interrupted, TrainingDiverged
from mjx_emp.run.store import METRICS_FILE, writing


@contextlib.contextmanager
def progress_reporter(total_epochs: int, first_epoch: int, describe: Callable[[dict], str],
                      console: Any = None) -> Iterator[Callable[[dict], None]]:
    """Report each epoch: a live progress bar on a terminal, one plain line per epoch otherwise.

    ``describe`` turns an epoch's metrics into the short summary shown; on a narrow terminal
    (80 columns) the summary wraps under the bar instead of being cut. ``console``: rich's
    console to draw on (default: standard output).
    """
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )
    from rich.table import Column

    console = console or Console()
    if not console.is_terminal:
        yield lambda metrics: print(f"epoch {metrics['epoch']:4d}  {describe(metrics)}", flush=True)
        return
    columns = (TextColumn("epoch"), MofNCompleteColumn(), BarColumn(bar_width=12), TimeRemainingColumn(),
               TextColumn("{task.fields[info]}", table_column=Column(ratio=1, no_wrap=False, overflow="fold")))
    with Progress(*columns, console=console, expand=True) as bar:
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


def _first(array) -> int:
    """A per-run scalar of a train state as a Python integer: shard 0's where a split run holds
    it once per shard, maybe on several hosts."""
    import numpy as np

    if not getattr(array, "is_fully_addressable", True):
        array = array.addressable_shards[0].data
    return int(np.asarray(array).reshape(-1)[0])


def _epoch_of(state) -> int:
    """A train state's epoch (every shard of a split run holds the same)."""
    return _first(state.epoch)


def env_steps_of(state) -> int:
    """A train state's environment steps so far (shard 0 of a split run holds the whole run's)."""
    from mjx_emp.counters import StepCounter

    return StepCounter(hi=_first(state.env_steps.hi), lo=_first(state.env_steps.lo)).value()


def _budget_spent(states: list, budgets: list[int | None]) -> bool:
    """Whether training stops for its step budget: every member state has reached its
    ``max_env_steps`` (None: no budget, never spent)."""
    return all(budget is not None for budget in budgets) and all(
        env_steps_of(state) >= budget for state, budget in zip(states, budgets))


def train_members(program, state, members: list[Member], report: Callable[[dict], None],
                  split: Callable[[Any, Any], list[tuple[Any, Any]]] = _alone):
    """Train until the members' epoch count, or until every member has spent its
    ``max_env_steps``, checkpointing and logging each finished epoch.

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


def _metrics_log(run_dir: Path):
    """RUN_DIR/metrics.jsonl opened for appending, unbuffered: each line goes to the file in one
    write, so a write that fails (a full disk) leaves nothing buffered for closing the file to
    fail on again (a failure to open it names the run's newest intact checkpoint,
    :func:`~mjx_emp.run.store.writing`)."""
    with writing(run_dir / METRICS_FILE, run_dir):
        return open(run_dir / METRICS_FILE, "ab", buffering=0)


def _train_members(program, state, members, report, split, gather_to_host, lead: bool, epochs: int,
                   stops: _SignalStop):
    import jax

    with contextlib.ExitStack() as stack:
        logs = [stack.enter_context(_metrics_log(member.run_dir) if lead else open(os.devnull, "wb"))
                for member in members]
        budgets = [member.trainer.cfg.max_env_steps for member in members]
        while True:
            states = [part[0] for part in split(state, None)]
            if _epoch_of(states[0]) >= epochs or _budget_spent(states, budgets):
                break
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
                    with writing(member.run_dir / METRICS_FILE, member.run_dir):
                        log.write((json.dumps(metrics) + "\n").encode())
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


def train_to_the_end(trainer, state, checkpoints, run_dir: Path, on_epoch: Callable[[dict], None] | None = None):
    """Report progress while training to ``cfg.epochs`` (and hand each epoch's metrics to
    ``on_epoch``); then close ``checkpoints`` (waits for writes)."""
    with checkpoints, progress_reporter(trainer.cfg.epochs, _epoch_of(state), trainer.describe) as show:
        report = show if on_epoch is None else (lambda metrics: (show(metrics), on_epoch(metrics)))
        return train_epochs(trainer, state, checkpoints, run_dir, report)
