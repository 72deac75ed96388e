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
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeRemainingColumn,
)
from rich.table import Column

from mjx_emp.counters import StepCounter
from mjx_emp.errors import Interrupted, TrainingDiverged
from mjx_emp.run.checkpoint import Checkpoints
from mjx_emp.run.hosts import gather_to_host, is_lead
from mjx_emp.run.store import METRICS_FILE, writing


@contextlib.contextmanager
def progress_reporter(total_epochs: int, first_epoch: int, describe: Callable[[dict], str],
                      console: Any = None) -> Iterator[Callable[[dict], None]]:
    """Report each epoch: a live progress bar on a terminal, one plain line per epoch otherwise.

    ``describe`` turns an epoch's metrics into the short summary shown; on a narrow terminal
    (80 columns) the summary wraps under the bar instead of being cut. ``console``: rich's
    console to draw on (default: standard output).
    """
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
    """One run directory that a training program writes, and the agent whose config it records
    (its checkpoints' config, its metrics and divergence check)."""

    trainer: Any
    run_dir: Path


def _alone(state, stats) -> list[tuple[Any, Any]]:
    return [(state, stats)]


def _first(array) -> int:
    """A per-run scalar of a train state as a Python integer: shard 0's where a split run holds
    it once per shard, maybe on several hosts."""
    if not getattr(array, "is_fully_addressable", True):
        array = array.addressable_shards[0].data
    return int(np.asarray(array).reshape(-1)[0])


def epoch_of(state) -> int:
    """A train state's epoch (every shard of a split run holds the same)."""
    return _first(state.epoch)


def env_steps_of(state) -> int:
    """A train state's environment steps so far (shard 0 of a split run holds the whole run's)."""
    return StepCounter(hi=_first(state.env_steps.hi), lo=_first(state.env_steps.lo)).value()


def training_done(epoch: int, env_steps: float, epochs: int, max_env_steps: int | None) -> bool:
    """Whether a run's training is over: at its epoch count, or with its ``max_env_steps`` spent
    (None: no budget). The loop stops here, and the sweep reads a run directory by it."""
    return epoch >= epochs or (max_env_steps is not None and env_steps >= max_env_steps)


def _all_done(states: list, epochs: int, budgets: list[int | None]) -> bool:
    """Whether every member's training is over (:func:`training_done`; they share one epoch)."""
    return all(training_done(epoch_of(state), env_steps_of(state), epochs, budget)
               for state, budget in zip(states, budgets))


def train(program, state, members: list[Member], keep_checkpoints: int = 3,
          on_epoch: Sequence[Callable[[dict], None] | None] = (),
          split: Callable[[Any, Any], list[tuple[Any, Any]]] = _alone):
    """The training loop: train until the members' epoch count, or until every member has spent
    its ``max_env_steps``, writing each member's checkpoint and metrics line for every epoch;
    returns the final state.

    It owns every checkpoint of the run: it opens each member's (keeping the newest
    ``keep_checkpoints``), writes the state it starts from when that epoch has none yet (a new
    run's epoch 0), and closes them, waiting for the writes, when it returns or raises.
    ``program.train_epoch(state) -> (state, stats)`` trains every member at once (one agent, a
    split run's shards, or several seeds under one vmap); ``split(state, stats)`` gives each
    member's share. Each callable of ``on_epoch`` (None skipped) sees the first member's metrics
    once its epoch is on disk: progress, trackers, a caller's own. A member whose losses or
    parameters are not finite raises TrainingDiverged and nothing of that epoch is kept for
    any member; SIGINT and SIGTERM raise Interrupted once the epoch being written is complete.
    ``seconds`` in a member's metrics is the wall time of the whole program's epoch.
    """
    report = [call for call in on_epoch if call is not None]
    epochs = members[0].trainer.cfg.epochs
    budgets = [member.trainer.cfg.max_env_steps for member in members]
    lead = is_lead()  # with several hosts, process 0 alone writes metrics (and checkpoints)
    stops = SignalStop()
    with contextlib.ExitStack() as stack:
        kept = [stack.enter_context(Checkpoints(member.run_dir, keep_checkpoints)) for member in members]
        logs = [stack.enter_context(_metrics_log(member.run_dir) if lead else open(os.devnull, "wb"))
                for member in members]
        stack.enter_context(stops.installed())
        try:
            parts = split(gather_to_host(state), None)
            for member, checkpoints, (member_state, _) in zip(members, kept, parts):
                if epoch_of(member_state) not in checkpoints.epochs():  # a new run's epoch 0
                    checkpoints.save(epoch_of(member_state), member_state, member.trainer.cfg)
            while not _all_done([p[0] for p in parts], epochs, budgets):
                start = time.perf_counter()
                state, stats = program.train_epoch(state)
                jax.block_until_ready(state)
                seconds = time.perf_counter() - start
                parts = split(*gather_to_host((state, stats)))
                _refuse_divergence(members, kept, parts)
                with stops.held():  # a checkpoint and its metrics line are written together
                    for member, checkpoints, log, (member_state, member_stats) in zip(members, kept, logs, parts):
                        blocked = checkpoints.save(epoch_of(member_state), member_state, member.trainer.cfg)
                        metrics = member.trainer.metrics(member_state, member_stats, seconds)
                        metrics["checkpoint_blocked_s"] = blocked  # the write itself continues in the background
                        with writing(member.run_dir / METRICS_FILE, member.run_dir):
                            log.write((json.dumps(metrics) + "\n").encode())
                        if member is members[0] and lead:
                            for call in report:
                                call(metrics)
            for checkpoints in kept:
                checkpoints.wait()
            return state
        except Interrupted as stop:
            for checkpoints in kept:
                checkpoints.wait()  # the write in flight completes before we go
            newest = kept[0].epochs()
            where = f"epoch {newest[-1]} in {kept[0].directory}" if newest else "none"
            raise Interrupted(f"stopped by {signal.Signals(stop.signum).name}; the newest checkpoint is {where}; "
                              f"continue with `--resume {members[0].run_dir}`", stop.signum) from None


def _refuse_divergence(members: list[Member], kept: list, parts: list[tuple[Any, Any]]) -> None:
    """Raise TrainingDiverged, naming the first member's problem and its last good checkpoint,
    when any member's epoch is not finite (:meth:`divergence` of its agent)."""
    problems = [(checkpoints, problem) for member, checkpoints, part in zip(members, kept, parts)
                if (problem := member.trainer.divergence(*part))]
    if not problems:
        return
    for checkpoints in kept:
        checkpoints.wait()
    checkpoints, problem = problems[0]
    newest = checkpoints.epochs()
    raise TrainingDiverged(
        f"epoch {epoch_of(parts[0][0])}: {problem}. Stopped without saving this epoch; the last good "
        f"checkpoint is epoch {newest[-1] if newest else None} in {checkpoints.directory}"
        + (f" (and likewise for {len(members) - 1} other seed run(s))" if len(members) > 1 else "")
    )


class SignalStop:
    """Inside :meth:`installed`, SIGINT and SIGTERM raise :class:`Interrupted` (its message the
    signal's name): at once between two Python steps (a running compiled call finishes first),
    or, inside :meth:`held` (writes that belong together: an epoch's checkpoint and metrics
    line, a sweep's rows), as soon as it ends. Training and sweeps stop this way."""

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
