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
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from mjx_emp.checks import LOOP_FIELDS, config_from_dict
from mjx_emp.counters import digits
from mjx_emp.errors import CheckpointError, CheckpointWriteError
from mjx_emp.run.store import CHECKPOINT_SUBDIR, REJECTED_SUBDIR

RESUMABLE_CHANGES = LOOP_FIELDS
"""Config fields a resumed run may change: they do not alter what one epoch computes."""


def _is_key(leaf: Any) -> bool:
    return jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key)


def layout_of(tree: Any) -> list[dict]:
    """Each array's path, shape, dtype and whether it is a PRNG key (stored as its key data).

    Works on arrays and on ``jax.eval_shape`` structs alike, so a config's layout is known
    without building its state.
    """
    layout = []
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        key = _is_key(leaf)
        if key:
            leaf = jax.eval_shape(jax.random.key_data, leaf)
        layout.append({"path": jax.tree_util.keystr(path), "shape": list(leaf.shape),
                       "dtype": np.dtype(leaf.dtype).name, "key": key})
    return layout


def pack(tree: Any) -> dict[str, np.ndarray]:
    """Host copy of a pytree as one flat array per dtype, in ``layout_of`` order.

    A few large arrays write far faster than hundreds of small ones (orbax pays about a
    millisecond per array), and the copy is taken now, so the device buffers may be donated
    while the write finishes in the background. PRNG keys go in as their raw key data; dtype
    groups with no elements are left out (orbax refuses zero-size arrays).
    """
    groups: dict[str, list[np.ndarray]] = {}
    for leaf in jax.tree.leaves(tree):
        if _is_key(leaf):
            leaf = jax.random.key_data(leaf)
        host = np.asarray(leaf)
        groups.setdefault(host.dtype.name, []).append(host.ravel())
    packed = {name: np.concatenate(parts) for name, parts in groups.items()}  # concatenate copies
    return {name: array for name, array in packed.items() if array.size}


def digest(array: np.ndarray) -> int:
    """CRC-32 of an array's bytes."""
    return zlib.crc32(np.ascontiguousarray(array).view(np.uint8).reshape(-1))


def array_digests(packed: dict[str, np.ndarray], layout: list[dict]) -> dict[str, int]:
    """:func:`digest` of every array, by layout path: written with each checkpoint so that a
    restore notices bytes that changed on disk (a flipped bit reads back without error)."""
    return {path: digest(array) for path, array in arrays_by_path(packed, layout).items()}


def data_files(item_dir: Path) -> list[str]:
    """The files under a checkpoint item's directory (where its arrays' bytes lie)."""
    return sorted(str(p) for p in Path(item_dir).rglob("*") if p.is_file())


def packed_shapes(layout: list[dict]) -> dict[str, jax.ShapeDtypeStruct]:
    """The flat per-dtype arrays that ``pack`` makes for a state of this layout."""
    sizes: dict[str, int] = {}
    for entry in layout:
        sizes[entry["dtype"]] = sizes.get(entry["dtype"], 0) + int(np.prod(entry["shape"]))
    return {name: jax.ShapeDtypeStruct((size,), np.dtype(name)) for name, size in sizes.items() if size}


def unpack(packed: dict[str, Any], template: Any) -> Any:
    """Inverse of ``pack``: ``template`` (a state or its ``jax.eval_shape``) gives the structure."""
    layout = layout_of(template)
    return tree_from_arrays(arrays_by_path(packed, layout), template, layout)


def tree_from_arrays(arrays: dict[str, np.ndarray], template: Any, layout: list[dict]) -> Any:
    """The pytree of ``template``'s structure (``layout`` is its layout) from one host array
    per path; PRNG keys are wrapped back from their key data."""
    leaves, treedef = jax.tree.flatten(template)
    rebuilt = []
    for like, entry in zip(leaves, layout):
        value = jnp.asarray(arrays[entry["path"]])
        if entry["key"]:
            impl = jax.random.key_impl(like) if isinstance(like, jax.Array) else None
            value = jax.random.wrap_key_data(value, impl=impl)
        rebuilt.append(value)
    return jax.tree.unflatten(treedef, rebuilt)


def arrays_by_path(packed: dict[str, Any], layout: list[dict]) -> dict[str, np.ndarray]:
    """Split ``pack``'s flat per-dtype arrays back into one host array per layout path."""
    offsets = dict.fromkeys(packed, 0)
    arrays = {}
    for entry in layout:
        size = int(np.prod(entry["shape"]))
        start = offsets.get(entry["dtype"], 0)
        flat = np.asarray(packed[entry["dtype"]])[start:start + size] if size else np.zeros(0, entry["dtype"])
        offsets[entry["dtype"]] = start + size
        arrays[entry["path"]] = flat.reshape(entry["shape"])
    return arrays


def upgrade_float_step_counters(arrays: dict[str, np.ndarray], expected: list[dict]) -> dict[str, np.ndarray]:
    """Checkpoints written before step counters were exact hold ``env_steps`` as one float32;
    today's states hold a :class:`~mjx_emp.counters.StepCounter` (``.hi``, ``.lo`` int32)."""
    wanted = {entry["path"] for entry in expected}
    upgraded = dict(arrays)
    for path, value in arrays.items():
        if f"{path}.hi" in wanted and f"{path}.lo" in wanted and value.shape == () and value.dtype == np.float32:
            hi, lo = digits(int(value))
            del upgraded[path]
            upgraded[f"{path}.hi"], upgraded[f"{path}.lo"] = np.int32(hi), np.int32(lo)
    return upgraded


RENAMED_FIELDS = (
    (".gc[", ".policies["), (".gs[", ".goal_spaces["), (".gs_replay[", ".goal_space_replay["),
    (".skills[", ".skill_actors["), (".boxes[", ".goal_space_actors["),
)
"""(old, new) leading path parts of state fields renamed when the package was restructured:
phase 1's goal-conditioned and goal-space learners and goal-space replay, phase 2's frozen
actors."""


def upgrade_renamed_fields(arrays: dict[str, np.ndarray], expected: list[dict]) -> dict[str, np.ndarray]:
    """Arrays saved under a field's old name move to its new one (:data:`RENAMED_FIELDS`)."""
    wanted = {entry["path"] for entry in expected}
    upgraded = {}
    for path, value in arrays.items():
        for old, new in RENAMED_FIELDS:
            if path.startswith(old) and path not in wanted and new + path[len(old):] in wanted:
                path = new + path[len(old):]
                break
        upgraded[path] = value
    return upgraded


def upgrade_episode_links(arrays: dict[str, np.ndarray], expected: list[dict]) -> dict[str, np.ndarray]:
    """Replay rows saved before they linked to their episode's next row get no link (the
    buffer's capacity): hindsight goals and n-step targets then see each such row alone."""
    upgraded = dict(arrays)
    for entry in expected:
        path = entry["path"]
        if path.endswith(".data.successor") and path not in arrays:
            capacity = entry["shape"][-1]
            upgraded[path] = np.full(entry["shape"], capacity, np.dtype(entry["dtype"]))
    return upgraded


LEFT_OUT = "left_out"
"""The digests item's key listing the state fields a checkpoint was written without."""


def left_out_of(digests: dict | None) -> list[str]:
    """The state fields a checkpoint's digests item says were not written (empty for a whole state,
    or for a checkpoint older than digests)."""
    return list((digests or {}).get(LEFT_OUT, []))


def verify_digests(step_dir: Path, arrays: dict[str, np.ndarray], written: dict | None) -> None:
    """Check every restored array of ``step_dir`` against the digests written with it (checkpoints
    written before digests existed have none and are not checked)."""
    if written is None:
        return
    for path, expected in written["arrays"].items():
        found = digest(arrays[path]) if path in arrays else None
        if found != expected:
            raise CheckpointError(
                f"{step_dir}: array {path} does not match the checksum written with it (crc32 "
                f"{found if found is None else format(found, '08x')}, written {expected:08x}): the checkpoint "
                f"changed on disk; its bytes lie in {', '.join(data_files(step_dir / 'state'))}"
            )


def without_fields(state: Any, fields: tuple[str, ...]) -> Any:
    """``state`` (a dataclass pytree) with ``fields`` set to None, so that they hold no arrays;
    the other arrays keep their paths."""
    return dataclasses.replace(state, **dict.fromkeys(fields)) if fields else state


def with_zeros_for(arrays: dict[str, np.ndarray], expected: list[dict], fields: list[str]) -> dict[str, np.ndarray]:
    """``arrays`` plus zeros for every array of ``expected`` that lies under one of ``fields``
    (the fields a checkpoint was written without): empty replays, environments never stepped."""
    if not fields:
        return arrays
    heads = tuple(f".{field}{after}" for field in fields for after in (".", "["))
    filled = dict(arrays)
    for entry in expected:
        path = entry["path"]
        if path not in arrays and (path.startswith(heads) or path in {f".{field}" for field in fields}):
            filled[path] = np.zeros(entry["shape"], np.dtype(entry["dtype"]))
    return filled


UPGRADES = (upgrade_renamed_fields, upgrade_float_step_counters, upgrade_episode_links)
"""Conversions of arrays saved by earlier versions, applied in order when a checkpoint's
layout is not today's. Each maps {path: array} to {path: array} given today's layout."""


def layout_in_order(arrays: dict[str, np.ndarray], expected: list[dict]) -> list[dict]:
    """The layout of ``arrays`` in ``expected``'s order, a missing path marked as such and
    paths ``expected`` lacks appended, so :func:`layout_mismatch` can compare the two."""
    known = {entry["path"] for entry in expected}
    found = [{**entry, "shape": list(arrays[entry["path"]].shape), "dtype": arrays[entry["path"]].dtype.name}
             if entry["path"] in arrays else {**entry, "shape": "(missing)"} for entry in expected]
    return found + [{"path": path, "shape": list(value.shape), "dtype": value.dtype.name, "key": False}
                    for path, value in arrays.items() if path not in known]


def layout_mismatch(saved: list[dict], expected: list[dict]) -> str | None:
    """The first array whose path, shape or dtype differs between two layouts, or None."""
    for have, want in zip(saved, expected):
        if have != want:
            return f"array {have['path']} is {have['shape']} {have['dtype']}, expected {want['shape']} {want['dtype']}"
    if len(saved) != len(expected):
        return f"{len(saved)} arrays, expected {len(expected)}"
    return None


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
            self.manager = None if jax.process_index() != 0 else ocp.CheckpointManager(
                self.directory.absolute(), options=options, item_names=("state", "layout", "config", "digests"),
            )

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
        digests = {"algorithm": "crc32", "arrays": array_digests(packed, layout), LEFT_OUT: list(leave_out)}
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
        try:
            restored = self.manager.restore(epoch, args=ocp.args.Composite(
                state=ocp.args.StandardRestore(packed_shapes(saved_layout)),
            ))
        except Exception as err:  # truncated or missing files surface as many error types
            reason = str(err).split(" [tensorstore_spec=")[0]  # drop tensorstore's long spec dump
            raise CheckpointError(f"{step_dir / 'state'}: unreadable ({type(err).__name__}: {reason})") from err
        arrays = arrays_by_path(restored.state, saved_layout)
        written = self._digests(epoch)
        verify_digests(step_dir, arrays, written)
        arrays = with_zeros_for(arrays, layout, left_out_of(written))
        if saved_layout != layout:  # written by an earlier version
            for upgrade in UPGRADES:
                arrays = upgrade(arrays, layout)
            mismatch = layout_mismatch(layout_in_order(arrays, layout), layout)
            if mismatch:
                raise CheckpointError(f"{step_dir / 'layout'} does not fit this version's train state: {mismatch}")
        state = tree_from_arrays(arrays, template, layout)
        stored = stored_epoch(state)
        if stored is not None and stored != epoch:
            raise CheckpointError(f"{step_dir} holds the state of epoch {stored}, not {epoch}: a checkpoint folder "
                                  "must keep the number it was written under (was it renamed?)")
        return state

    def _digests(self, epoch: int) -> dict | None:
        """The digests item written with ``epoch``'s checkpoint (None for checkpoints older than digests)."""
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
            self.manager.reload()  # the trainer moved on: read its listing again
        raise CheckpointError(f"{self.directory}: every checkpoint was removed while it was read, "
                              f"{RETENTION_RETRIES} times; is a trainer keeping very few (--keep-checkpoints)?")

    def _superseded(self, epoch: int) -> bool:
        """Whether ``epoch``'s checkpoint, which failed to read, is one the run's writer is
        removing: its folder is gone, or the writer has since finished a newer checkpoint (its
        retention removes the older ones right after, so a read can meet one half deleted)."""
        if not self.step_dir(epoch).exists():
            return True
        self.manager.reload()
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
        self.manager.reload()
