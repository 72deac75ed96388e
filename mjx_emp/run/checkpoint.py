"""Orbax checkpoints of a whole train state (phase 1 or phase 2), one per epoch.

A checkpoint holds every array of the state (for phase 1's ``HEState``: parameters,
target parameters, optimizer states, replay, goal-space and start-state buffers, the start
chain's simulator state, RNG keys as ``jax.random.key_data``, epoch and step counters),
packed into one flat array per dtype (item ``state``), the path, shape and dtype of each
array (item ``layout``, JSON) and the run's config (item ``config``, JSON: a
``HEConfig``, or a ``Phase2Config`` for phase 2). ``Checkpoints.restore`` gives the
pytree back. Orbax writes each step into a temporary directory and renames it when
complete, so a process killed mid-write leaves the previous checkpoint as the latest one;
the half-written directory is ignored and cleaned up when the run directory is next opened.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import jax
import numpy as np
import orbax.checkpoint as ocp

from mjx_emp.checks import LOOP_FIELDS, config_from_dict
from mjx_emp.errors import CheckpointError, CheckpointWriteError
from mjx_emp.run.packing import (
    LEFT_OUT,
    array_digests,
    arrays_by_path,
    layout_in_order,
    layout_mismatch,
    layout_of,
    left_out_of,
    pack,
    packed_shapes,
    tree_from_arrays,
    verify_digests,
    with_zeros_for,
    without_fields,
)
from mjx_emp.run.store import CHECKPOINT_SUBDIR, REJECTED_SUBDIR

RESUMABLE_CHANGES = LOOP_FIELDS
"""Config fields a resumed run may change: they do not alter what one epoch computes."""

FORMAT = 1
"""The checkpoint format this version writes and reads, kept in each checkpoint's digests item.
A checkpoint without the number was written before formats were numbered (format 0); it is
read when its arrays are laid out as format 1's are, and refused, naming its format, when not."""

FORMAT_KEY = "format"

T = TypeVar("T")


def config_mismatches(saved: dict, expected: Any) -> list[str]:
    """Fields (other than the resumable ones) whose saved value differs from ``expected``; a
    field the checkpoint predates counts as saved with its default (what runs did before it)."""
    want = json.loads(json.dumps(dataclasses.asdict(expected)))
    defaults = json.loads(json.dumps({f.name: f.default for f in dataclasses.fields(expected)
                                      if f.default is not dataclasses.MISSING}))
    saved = {**{name: value for name, value in defaults.items() if name not in saved}, **saved}
    fields = sorted(set(saved) | set(want))
    return [
        f"{name}: checkpoint has {saved.get(name, '(missing)')}, run has {want.get(name, '(missing)')}"
        for name in fields
        if name not in RESUMABLE_CHANGES and saved.get(name) != want.get(name)
    ]


def format_of(digests: dict | None) -> int:
    """The format a checkpoint was written in (0: before formats were numbered)."""
    return int((digests or {}).get(FORMAT_KEY, 0))


def check_format(step_dir: Path, digests: dict | None) -> None:
    """Refuse a checkpoint written in a format newer than :data:`FORMAT` (by a later mjx-emp)."""
    written = format_of(digests)
    if written > FORMAT:
        raise CheckpointError(f"{step_dir}: checkpoint format {written} was written by a newer mjx-emp; this one "
                              f"reads format {FORMAT}")


@contextlib.contextmanager
def _quiet_reader(read_only: bool) -> Iterator[None]:
    """Hold back absl's warnings while a read-only manager is made (they say it is read-only)."""
    absl = logging.getLogger("absl")
    level = absl.level
    if read_only:
        absl.setLevel(logging.ERROR)
    try:
        yield
    finally:
        absl.setLevel(level)


def stored_epoch(state: Any) -> int | None:
    """The epoch counter a restored state carries (one per seed or shard, all equal), if it has one."""
    epoch = getattr(state, "epoch", None)
    return None if epoch is None else int(np.asarray(epoch).reshape(-1)[0])


def short_reason(err: BaseException, most: int = 300) -> str:
    """An error's message on one line, without tensorstore's spec dump, cut at a word (with an
    ellipsis) only when it is longer than ``most`` characters."""
    text = " ".join(str(err).split(" [tensorstore_spec=")[0].split())
    code = re.search(r"os_error_code='?(\d+)", text)
    cause = f"{os.strerror(int(code.group(1)))}: " if code else ""  # the reason a user can act on, first
    if len(text) > most:
        text = text[:most].rsplit(" ", 1)[0] + " ..."
    return cause + text


RETENTION_RETRIES = 20
"""How often a reader starts again after the checkpoint it read was removed under it."""


def listed_again_while_removed(list_steps: Callable[[], T]) -> T:
    """``list_steps()`` (orbax listing a run's checkpoints), listed again where a step vanished
    during it: orbax lists the step folders and then reads each one's time, so a writer's
    retention removing a step between the two raises FileNotFoundError for a folder that simply
    is no longer there. After :data:`RETENTION_RETRIES` such listings the error stands."""
    for attempt in range(RETENTION_RETRIES):
        try:
            return list_steps()
        except FileNotFoundError:
            if attempt == RETENTION_RETRIES - 1:
                raise
    raise AssertionError("unreachable")


@dataclasses.dataclass
class Checkpoints:
    """The checkpoints of one run directory: save every epoch, restore the latest good one."""

    run_dir: Path
    keep: int = 3
    read_only: bool = False
    """A reader (eval, plot, render, phase 2 loading its skills): it saves, prunes and cleans up
    nothing, so a run that another process is writing is left as it is. Only the run's writer
    (train or resume, holding the run's lock) removes a half-written checkpoint."""
    manager: ocp.CheckpointManager | None = dataclasses.field(init=False, repr=False)
    """None on a process other than the lead of a several-host run: only the lead writes."""

    def __post_init__(self):
        if self.keep < 1:
            raise ValueError(f"keep_checkpoints: must be >= 1; got {self.keep}")
        several_hosts = {}
        if jax.process_count() > 1:  # the lead (process 0) alone reads and writes, the whole state gathered to it
            self.directory.mkdir(parents=True, exist_ok=True)
            several_hosts = dict(create=False, multiprocessing_options=ocp.options.MultiprocessingOptions(
                primary_host=0, active_processes={0}))
        if self.read_only:
            several_hosts = {**several_hosts, "create": False}
        with _quiet_reader(self.read_only):  # orbax warns that a reader's manager is read-only: it is meant to be
            options = ocp.CheckpointManagerOptions(
                max_to_keep=None if self.read_only else self.keep, cleanup_tmp_directories=not self.read_only,
                read_only=self.read_only, enable_async_checkpointing=True, **several_hosts,
            )
            self.manager = None if jax.process_index() != 0 else listed_again_while_removed(
                lambda: ocp.CheckpointManager(self.directory.absolute(), options=options,
                                              item_names=("state", "layout", "config", "digests")))

    @property
    def directory(self) -> Path:
        """RUN_DIR/checkpoints, where orbax keeps one directory per epoch."""
        return Path(self.run_dir) / CHECKPOINT_SUBDIR

    def step_dir(self, epoch: int) -> Path:
        """Where the checkpoint of ``epoch`` lives."""
        return self.directory / str(epoch)

    def epochs(self) -> list[int]:
        """Epochs with a complete checkpoint, oldest first (none known to a process that is not the lead)."""
        return sorted(self.manager.all_steps()) if self.manager else []

    def save(self, epoch: int, state: Any, config: Any, leave_out: tuple[str, ...] = ()) -> float:
        """Start writing ``state`` as ``epoch``'s checkpoint; returns the seconds this call blocked.

        ``leave_out`` names state fields not written (a skills export, see
        :func:`without_fields`); a restore gives them back as zeros and a resume refuses such a
        checkpoint. The write finishes in the background; ``wait`` blocks until it is on disk. A
        process that is not the lead writes nothing.
        """
        if self.manager is None:
            return 0.0
        start = time.perf_counter()
        kept = without_fields(state, leave_out)
        packed, layout = pack(kept), layout_of(kept)
        digests = {FORMAT_KEY: FORMAT, "algorithm": "crc32", "arrays": array_digests(packed, layout),
                   LEFT_OUT: list(leave_out)}
        with self._write_errors():
            self.manager.save(epoch, args=ocp.args.Composite(
                state=ocp.args.StandardSave(packed),
                layout=ocp.args.JsonSave(layout),
                config=ocp.args.JsonSave(dataclasses.asdict(config)),
                digests=ocp.args.JsonSave(digests),
            ))
        return time.perf_counter() - start

    @contextlib.contextmanager
    def _write_errors(self) -> Iterator[None]:
        """A failed write (here or one still running in the background) as a CheckpointWriteError
        naming the newest complete checkpoint, which it leaves intact."""
        try:
            yield
        except Exception as err:  # OSError, or tensorstore's ValueError (RESOURCE_EXHAUSTED) for a full disk
            kept = sorted(self.manager.all_steps()) if self.manager else []
            newest = f"epoch {kept[-1]}" if kept else "none"
            reason = short_reason(err)
            raise CheckpointWriteError(
                f"writing a checkpoint to {self.directory} failed ({type(err).__name__}: {reason}); the newest "
                f"complete checkpoint is {newest}, left intact: free space, then continue with "
                f"`--resume {self.run_dir}`"
            ) from err

    def wait(self) -> None:
        """Block until every started save is committed to disk."""
        if self.manager:
            with self._write_errors():
                self.manager.wait_until_finished()

    def close(self) -> None:
        """Finish pending writes and release orbax's background threads."""
        if self.manager:
            with self._write_errors():
                self.manager.close()

    def __enter__(self) -> Checkpoints:
        return self

    def __exit__(self, exc_type, *exc_info) -> None:
        try:
            self.close()
        except CheckpointWriteError:
            if exc_type is None:  # nothing else is being reported: this is the news
                raise

    def read_config(self, epoch: int, config_type: type) -> Any:
        """The config stored with ``epoch``'s checkpoint, as a ``config_type``."""
        path = self.step_dir(epoch) / "config"
        try:
            saved = self.manager.restore(epoch, args=ocp.args.Composite(config=ocp.args.JsonRestore())).config
            return config_from_dict(saved, config_type)
        except Exception as err:  # orbax and JSON raise many types; all mean "unreadable"
            raise CheckpointError(f"{path}: unreadable config ({type(err).__name__}: {err})") from err

    def restore(self, epoch: int, template: Any, expected: Any) -> Any:
        """Epoch ``epoch``'s state, checked against ``expected`` (the run's config).

        ``template`` is a state (or its ``jax.eval_shape``) of the expected config.
        """
        step_dir = self.step_dir(epoch)
        saved = dataclasses.asdict(self.read_config(epoch, type(expected)))
        mismatches = config_mismatches(json.loads(json.dumps(saved)), expected)
        if mismatches:
            raise CheckpointError(f"{step_dir / 'config'} does not match the run's config.json: " + "; ".join(mismatches))
        layout = layout_of(template)
        try:
            saved_layout = self.manager.restore(epoch, args=ocp.args.Composite(layout=ocp.args.JsonRestore())).layout
        except Exception as err:  # orbax and JSON raise many types; all mean "unreadable"
            raise CheckpointError(f"{step_dir / 'layout'}: unreadable ({type(err).__name__}: {err})") from err
        written = self._digests(epoch)
        check_format(step_dir, written)
        try:
            restored = self.manager.restore(epoch, args=ocp.args.Composite(
                state=ocp.args.StandardRestore(packed_shapes(saved_layout)),
            ))
        except Exception as err:  # truncated or missing files surface as many error types
            reason = str(err).split(" [tensorstore_spec=")[0]  # drop tensorstore's long spec dump
            raise CheckpointError(f"{step_dir / 'state'}: unreadable ({type(err).__name__}: {reason})") from err
        arrays = arrays_by_path(restored.state, saved_layout)
        verify_digests(step_dir, arrays, written)
        arrays = with_zeros_for(arrays, layout, left_out_of(written))
        mismatch = layout_mismatch(layout_in_order(arrays, layout), layout)
        if mismatch:
            raise CheckpointError(f"{step_dir / 'layout'} (checkpoint format {format_of(written)}) does not fit this "
                                  f"config's train state in format {FORMAT}: {mismatch}; a checkpoint of an earlier "
                                  "format is read by the mjx-emp version that wrote it")
        state = tree_from_arrays(arrays, template, layout)
        stored = stored_epoch(state)
        if stored is not None and stored != epoch:
            raise CheckpointError(f"{step_dir} holds the state of epoch {stored}, not {epoch}: a checkpoint folder "
                                  "must keep the number it was written under (was it renamed?)")
        return state

    def _digests(self, epoch: int) -> dict | None:
        """The digests item written with ``epoch``'s checkpoint (None for a checkpoint written without one)."""
        step_dir = self.step_dir(epoch)
        if not (step_dir / "digests").exists():
            return None
        try:
            return self.manager.restore(epoch, args=ocp.args.Composite(digests=ocp.args.JsonRestore())).digests
        except Exception as err:  # orbax and JSON raise many types; all mean "unreadable"
            raise CheckpointError(f"{step_dir / 'digests'}: unreadable ({type(err).__name__}: {err})") from err

    def left_out(self, epoch: int) -> list[str]:
        """The state fields ``epoch``'s checkpoint was written without (empty for a whole state)."""
        return left_out_of(self._digests(epoch))

    def restore_latest(self, template: Any, expected: Any, fallback: bool = False) -> tuple[int, Any]:
        """The newest checkpoint that restores, as ``(epoch, state)``.

        Without ``fallback`` a bad newest checkpoint raises CheckpointError; with it, older
        checkpoints are tried in turn (each skipped one is logged). A reader beside a live trainer
        may see the checkpoint it reads removed by the trainer's retention (``--keep-checkpoints``)
        halfway: a checkpoint whose folder is gone after a failed read was not damaged, it was
        removed, and the reader starts again from the newest checkpoint there is then.
        """
        for _ in range(RETENTION_RETRIES):
            found = self._restore_newest(template, expected, fallback)
            if found is not None:
                return found
            listed_again_while_removed(self.manager.reload)  # the trainer moved on: read its listing again
        raise CheckpointError(f"{self.directory}: every checkpoint was removed while it was read, "
                              f"{RETENTION_RETRIES} times; is a trainer keeping very few (--keep-checkpoints)?")

    def _superseded(self, epoch: int) -> bool:
        """Whether ``epoch``'s checkpoint, which failed to read, is one the run's writer is
        removing: its folder is gone, or the writer has since finished a newer checkpoint (its
        retention removes the older ones right after, so a read can meet one half deleted)."""
        if not self.step_dir(epoch).exists():
            return True
        listed_again_while_removed(self.manager.reload)
        return any(newer > epoch for newer in self.epochs())

    def _restore_newest(self, template: Any, expected: Any, fallback: bool) -> tuple[int, Any] | None:
        """:meth:`restore_latest`'s one pass over the listing; None where a checkpoint it read was
        removed meanwhile (by the run's writer, never damaged)."""
        epochs = self.epochs()
        if not epochs:
            raise CheckpointError(f"{self.directory}: no complete checkpoint to resume from")
        errors = []
        for epoch in reversed(epochs):
            try:
                state = self.restore(epoch, template, expected)
                if not self.read_only:
                    self.set_aside_newer_than(epoch)
                return epoch, state
            except CheckpointError as err:
                if self.read_only and self._superseded(epoch):
                    return None
                if not fallback:
                    older = [e for e in epochs if e < epoch]
                    use = "`mjx-emp resume --fallback` continues from" if self.read_only else "pass --fallback to use"
                    hint = f" ({use} an older one: epochs {older})" if older else ""
                    raise CheckpointError(f"{err}{hint}") from err
                logging.warning("skipping checkpoint of epoch %d: %s", epoch, err)
                errors.append(str(err))
        raise CheckpointError("no checkpoint restores: " + " | ".join(errors))

    def set_aside_newer_than(self, epoch: int) -> None:
        """Move checkpoints newer than ``epoch`` (skipped as unusable) to RUN_DIR/rejected-checkpoints.

        They are kept for inspection, not deleted, and no longer block the resumed run from
        writing those epochs again.
        """
        newer = [e for e in self.epochs() if e > epoch]
        if not newer:
            return
        rejected = Path(self.run_dir) / REJECTED_SUBDIR
        rejected.mkdir(exist_ok=True)
        for e in newer:
            target = rejected / f"{e}-{time.strftime('%Y%m%d-%H%M%S')}"
            self.step_dir(e).rename(target)
            logging.warning("moved unusable checkpoint of epoch %d to %s", e, target)
        listed_again_while_removed(self.manager.reload)
