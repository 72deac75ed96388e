"""A run directory on disk: its layout, its lock, and the config and metrics files in it.

Layout of RUN_DIR: ``config.json`` (the resolved config and its algorithm), ``metrics.jsonl`` (one JSON
line per finished epoch) and ``checkpoints/<epoch>/`` (orbax, :mod:`mjx_emp.run.checkpoint`; epoch 0
is the initial state). A phase-2 directory (by default RUN_DIR/phase2) has the same layout with a
Phase2Config, plus ``skills.json``, the phase-1 config of the skills it builds on.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import json
import os
import socket
import stat
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mjx_emp.algos.registry import (
    GOAL_SPACES,
    algorithm_of,
    config_from_json,
    config_to_json,
    skill_kind,
)
from mjx_emp.checks import config_from_dict
from mjx_emp.errors import ConfigError, WriteError
from mjx_emp.phase2.config import Phase2Config
from mjx_emp.run.provenance import EXPORT_OF, PROVENANCE_FILE, UNKNOWN

CONFIG_FILE = "config.json"


METRICS_FILE = "metrics.jsonl"


PHASE2_SUBDIR = "phase2"


CHECKPOINT_SUBDIR = "checkpoints"
"""In a run directory: one orbax checkpoint folder per kept epoch (:mod:`mjx_emp.run.checkpoint`)."""


REJECTED_SUBDIR = "rejected-checkpoints"
"""In a run directory: checkpoints a resume skipped as unusable, set aside rather than deleted."""


SKILLS_FILE = "skills.json"
"""In a phase-2 directory: the phase-1 config of the skills it builds on."""


def default_run_dir(cfg) -> str:
    """A fresh run directory name: runs/<prefix>-<env>-k<k>-<date>-<time>, the prefix the
    algorithm's registry entry gives (``run_dir_prefix``; HE's is empty, so runs/<env>-k<k>-...)."""
    algorithm = algorithm_of(cfg)
    prefix = algorithm.name if algorithm.run_dir_prefix is None else algorithm.run_dir_prefix
    return f"runs/{prefix + '-' if prefix else ''}{cfg.env}-k{cfg.k}-{time.strftime('%Y%m%d-%H%M%S')}"


def seed_run_dirs(base: str, seeds: tuple[int, ...]) -> list[str]:
    """The run directory of each seed of a seed group: BASE-s<seed>."""
    return [f"{base}-s{seed}" for seed in seeds]


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


UNWRITABLE = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS})
"""Reasons a write fails that the user can fix (space, permission, a read-only filesystem)."""


def newest_checkpoint_on_disk(run_dir: Path) -> int | None:
    """The newest epoch with a complete checkpoint folder in RUN_DIR/checkpoints (orbax renames
    a folder to its epoch only once it is written), or None."""
    folder = Path(run_dir) / CHECKPOINT_SUBDIR
    epochs = [int(p.name) for p in folder.iterdir() if p.name.isdigit()] if folder.is_dir() else []
    return max(epochs, default=None)


@contextlib.contextmanager
def writing(path: Path, run_dir: Path | None = None, chosen: bool = False) -> Iterator[None]:
    """Where writing ``path`` fails for want of space or permission, raise one
    :class:`~mjx_emp.errors.WriteError` naming the file, the reason and ``run_dir``'s newest
    intact checkpoint (exit code 2 if the user ``chosen`` the path, else 1)."""
    try:
        yield
    except OSError as err:
        if err.errno not in UNWRITABLE:
            raise
        message = f"cannot write {path}: {err.strerror or os.strerror(err.errno)}"
        if run_dir is not None:
            newest = newest_checkpoint_on_disk(run_dir)
            message += (f"; the newest intact checkpoint is epoch {newest} in {Path(run_dir) / CHECKPOINT_SUBDIR}"
                        if newest is not None else f"; {run_dir} holds no complete checkpoint")
        raise WriteError(message, exit_code=2 if chosen else 1) from None


KIND_OF_FILE = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
                (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


def output_target(path: Path, field: str = "out", make_folder: bool = False) -> Path:
    """The file a write to ``path`` replaces: ``path`` when it is absent or a regular file; the
    regular file a symlink leads to (written through the link, which stays). Anything else is
    refused with a ConfigError naming ``field``, before any work is done: a device, a FIFO, a
    socket or a directory (every file here is replaced whole, by a rename, and renaming over
    such a thing would destroy it: ``--out /dev/null`` run as root would replace the machine's
    /dev/null), a dangling symlink or a loop, a folder that does not exist (``make_folder``
    creates it instead: for paths the library chooses) or a folder that is a file."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            raise ConfigError(f"{field}: {str(path)!r} is a symlink to nothing ({os.readlink(path)!r}); give a "
                              f"file path") from None
        info = None
    except OSError as err:  # a symlink loop, a path through a file
        raise ConfigError(f"{field}: cannot use {str(path)!r} ({err.strerror}); give a file path") from None
    if info is not None:
        kind = next((what for test, what in KIND_OF_FILE if test(info.st_mode)), None)
        if kind is not None:
            raise ConfigError(f"{field}: {str(path)!r} is {kind}, not a regular file; mjx-emp replaces a file whole "
                              f"(write, then rename over it), which would destroy {kind}: give a file path")
        return path.resolve() if path.is_symlink() else path
    folder = path.parent
    if make_folder:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ConfigError(f"{field}: cannot create the folder {str(folder)!r} ({err.strerror})") from None
    elif not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise ConfigError(f"{field}: the folder of {str(path)!r} {what}; create it first or choose another path")
    return path


def replace_file(path: Path, content: str | bytes | Callable[[Path], None], run_dir: Path | None = None,
                 chosen: bool = False, field: str = "out") -> Path:
    """Write ``path`` whole so that a reader (or a crash) sees the old file or the new one, never
    half of one: the content (text, bytes, or a function that writes a file at the path it is
    given) goes to a temporary file beside it, is flushed to disk, then renamed over it. Only a
    regular file is ever replaced (:func:`output_target`: other things and missing folders are
    refused; a folder is created where the library chose the path, ``chosen`` False). A write that
    fails for want of space or permission raises one WriteError naming the file and ``run_dir``'s
    newest intact checkpoint (:func:`writing`) and leaves the old file. Returns the file written."""
    target = output_target(Path(path), field, make_folder=not chosen)
    with writing(target, run_dir, chosen):
        handle, temporary = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=target.suffix)
        os.close(handle)
        try:
            if callable(content):
                content(Path(temporary))
            else:
                with open(temporary, "wb") as f:
                    f.write(content.encode() if isinstance(content, str) else content)
            with open(temporary, "rb") as f:
                os.fsync(f.fileno())
            os.chmod(temporary, stat.S_IMODE(target.stat().st_mode) if target.exists() else 0o644)
            os.replace(temporary, target)
        finally:
            Path(temporary).unlink(missing_ok=True)
    return target


def write_atomically(path: Path, text: str, run_dir: Path | None = None, chosen: bool = False) -> None:
    """Replace ``path`` with ``text`` (:func:`replace_file`)."""
    replace_file(path, text, run_dir, chosen)


def read_run_config(run_dir: Path, field: str = "resume", config_type: type | None = None,
                    file: str = CONFIG_FILE):
    """The config saved in a run directory; errors name the file and the CLI ``field``.

    Without ``config_type`` the file holds an algorithm's config, which names its algorithm
    (see :mod:`mjx_emp.algos.registry`); phase-2 directories pass ``Phase2Config``.
    """
    path = Path(run_dir) / file
    if Path(run_dir).exists() and not Path(run_dir).is_dir():
        raise ConfigError(f"{field}: {str(run_dir)!r} is a file, not a run directory")
    try:
        values = json.loads(path.read_text())
    except FileNotFoundError as err:
        raise ConfigError(f"{field}: {str(run_dir)!r} has no {file}; is it a run directory?") from err
    except OSError as err:  # a symlink loop, a folder in its place, no permission
        raise ConfigError(f"{field}: cannot read {path} ({err.strerror}); is it a run directory?") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"{field}: {path} is not a valid run config ({err})") from None
    if not isinstance(values, dict):
        raise ConfigError(f"{field}: {path} is not a valid run config (a JSON {type(values).__name__}, "
                          f"not an object of config fields)")
    try:
        return config_from_json(values) if config_type is None else config_from_dict(values, config_type)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{field}: {path} is not a valid run config ({err})") from None


def parse_metrics(text: str) -> tuple[list[tuple[str, dict]], list[str]]:
    """metrics.jsonl's text read tolerantly: ``(valid, problems)``. ``valid`` holds each good
    line (the raw line and its dict, an object with an integer ``epoch``) in order; ``problems``
    names every other non-empty line by number and why (a line a kill cut short, garbled
    bytes, JSON of the wrong shape), so nothing is skipped without a word."""
    valid, problems = [], []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except json.JSONDecodeError as err:
            problems.append(f"line {number}: not JSON ({err.msg})")
            continue
        if not isinstance(entry, dict) or not isinstance(entry.get("epoch"), int):
            problems.append(f"line {number}: not an epoch's metrics (an object with an integer 'epoch')")
            continue
        valid.append((line, entry))
    return valid, problems


def read_metrics_text(path: Path) -> str:
    """A metrics file's text; bytes that are not UTF-8 become U+FFFD, so their line is reported, not fatal.
    A file that cannot be read at all (a symlink loop, a folder in its place) is a ConfigError."""
    try:
        return path.read_bytes().decode("utf-8", errors="replace")
    except FileNotFoundError:
        raise
    except OSError as err:
        raise ConfigError(f"run_dir: cannot read {path} ({err.strerror})") from None


def warn_metrics(path: Path, problems: list[str], what: str) -> None:
    """Say on stderr which lines of ``path`` were skipped and what happens to them."""
    for problem in problems:
        print(f"mjx-emp: {path}: {problem}; {what}", file=sys.stderr, flush=True)


def read_metrics(run_dir: Path) -> list[dict]:
    """The per-epoch metric lines of a run directory, in order; unreadable lines are reported
    on stderr and skipped (:func:`parse_metrics`); none for a run without a metrics file yet."""
    path = Path(run_dir) / METRICS_FILE
    if not path.exists() and not path.is_symlink():
        return []
    valid, problems = parse_metrics(read_metrics_text(path))
    warn_metrics(path, problems, "skipped")
    return [entry for _, entry in valid]


def keep_metrics_through(path: Path, epoch: int) -> None:
    """Rewrite metrics.jsonl (atomically) with the valid lines of epochs up to ``epoch``: lines
    written after the checkpoint a run resumes from are dropped, unreadable lines are reported
    and dropped, no valid line before them is lost. Epochs up to ``epoch`` without a line are
    named on stderr (their checkpoints exist; their metrics do not)."""
    if not path.exists():
        return
    valid, problems = parse_metrics(read_metrics_text(path))
    warn_metrics(path, problems, "dropped on resume")
    kept = [(line, entry) for line, entry in valid if entry["epoch"] <= epoch]
    missing = sorted(set(range(1, epoch + 1)) - {entry["epoch"] for _, entry in kept})
    if missing:
        print(f"mjx-emp: {path}: no metrics line for epochs {missing} (resuming from epoch {epoch})",
              file=sys.stderr, flush=True)
    write_atomically(path, "".join(line + "\n" for line, _ in kept), path.parent)


def holds_a_run(run_dir: Path) -> bool:
    """Whether RUN_DIR holds a run worth keeping: a complete checkpoint or a metrics line. A
    directory that a kill left before its first checkpoint (config.json, half-written
    checkpoint folders) holds none."""
    metrics = Path(run_dir) / METRICS_FILE
    return newest_checkpoint_on_disk(run_dir) is not None or (metrics.exists() and metrics.stat().st_size > 0)


LOCK_FILE = ".lock"
"""In a run directory while a process trains it: that process's id and host (flock-ed)."""


@contextlib.contextmanager
def run_lock(run_dir: Path, field: str) -> Iterator[None]:
    """Hold RUN_DIR/.lock while a command writes the run: a second writer (train, resume, phase
    2) is refused with a ConfigError naming the process that holds it. The lock is the
    kernel's (``flock``), so it goes with its process however that ends; a lock file left by a
    killed process is taken over with a note. With several hosts only the lead locks."""
    from mjx_emp.run.hosts import (
        is_lead,  # deferred: hosts imports JAX, and the CLI reads run files without it
    )

    if not is_lead():
        yield
        return
    path = Path(run_dir) / LOCK_FILE
    with writing(path, Path(run_dir)):  # a full or read-only disk: one line naming the run's newest checkpoint
        lock = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(lock, 256, 0).decode(errors="replace").strip() or "unknown"
            raise ConfigError(f"{field}: {str(run_dir)!r} is in use by process {holder} (lock {path}); wait for it "
                              f"to end or stop it") from None
        left = os.pread(lock, 256, 0).decode(errors="replace").strip()
        if left:
            print(f"note: taking over the lock of {run_dir} left by process {left}, which no longer holds it",
                  flush=True)
        with writing(path, Path(run_dir)):
            os.ftruncate(lock, 0)
            os.pwrite(lock, f"{os.getpid()} on {socket.gethostname()}\n".encode(), 0)
        try:
            yield
        finally:
            with contextlib.suppress(OSError):  # a second failure while letting go never hides the first
                os.ftruncate(lock, 0)  # an empty lock file: released on purpose, nothing to take over
            fcntl.flock(lock, fcntl.LOCK_UN)
    finally:
        os.close(lock)


def fresh_run_dir(path: str, field: str, what: str, command: str | None) -> Path:
    """Create the directory of ``what`` (a new run, to be made by ``command``); one that already
    holds a run (:func:`holds_a_run`) is refused, naming ``field`` and what it holds; one a kill
    left before its first checkpoint is reused. ``command`` None: what is made there is written
    once (an export), so the refusal offers no way to continue it."""
    run_dir = prepare_run_dir(path, field)
    held = "a phase-2 run" if (run_dir / SKILLS_FILE).exists() else "a run"
    if holds_a_run(run_dir):
        another = f"choose another --{field.replace('_', '-')}"
        exported = _export_source(run_dir)
        if exported is not None:
            raise ConfigError(f"{field}: {str(run_dir)!r} holds a skills export of {exported}, which phase 2, eval, "
                              f"plot and render read and nothing trains further; {another}")
        if command is None:
            raise ConfigError(f"{field}: {str(run_dir)!r} already holds {held}; {another}")
        resume = f"{command} --resume" if held == what else "mjx-emp resume"
        raise ConfigError(
            f"{field}: {str(run_dir)!r} already holds {held}; continue it with `{resume} {run_dir}` or {another}"
        )
    if (run_dir / CONFIG_FILE).exists() or (run_dir / CHECKPOINT_SUBDIR).exists():
        print(f"note: {run_dir} holds {held} stopped before its first checkpoint; it is started anew", flush=True)
    return run_dir


def write_run_record(run_dir: Path, record: dict) -> None:
    """Keep ``record`` (how a run was asked for, :func:`mjx_emp.run.provenance.run_record`) as
    RUN_DIR/provenance.json; the run's writer calls it once, when the run is made."""
    write_atomically(Path(run_dir) / PROVENANCE_FILE, json.dumps(record, indent=1), Path(run_dir))


def read_run_record(run_dir: Path) -> dict[str, Any]:
    """A run's ``provenance.json``, or a record of unknowns for a run started without one."""
    path = Path(run_dir) / PROVENANCE_FILE
    try:
        record = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        record = None
    if not isinstance(record, dict):
        return {"preset": UNKNOWN, "overrides": UNKNOWN, "commit": UNKNOWN, "dirty": UNKNOWN, "versions": UNKNOWN,
                "machine": UNKNOWN, "command": UNKNOWN, "time": UNKNOWN}
    return record


def _export_source(run_dir: Path) -> str | None:
    """The run a skills export was taken from, as its provenance says; None for a run."""
    source = read_run_record(run_dir).get(EXPORT_OF)
    return str(source) if source else None


def directory_megabytes(path: Path) -> float:
    """The size of the files under ``path`` in MB (10^6 bytes); 0 for a missing path."""
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file()) / 1e6


def config_json(cfg) -> dict:
    """config.json's form of ``cfg``: an algorithm's config records its algorithm; a phase-2
    config is its fields alone."""
    return dataclasses.asdict(cfg) if isinstance(cfg, Phase2Config) else config_to_json(cfg)


def write_config(run_dir: Path, cfg) -> None:
    """RUN_DIR/config.json of ``cfg`` (see :func:`config_json`), written atomically."""
    write_atomically(Path(run_dir) / CONFIG_FILE, json.dumps(config_json(cfg), indent=1), Path(run_dir))


def run_skill_kind(run_dir: Path, field: str = "run_dir") -> str:
    """What the skills of RUN_DIR's algorithm are (``registry.SKILL_KINDS``); a directory without
    config.json counts as goal spaces, left to the command to say what it lacks."""
    if not (Path(run_dir) / CONFIG_FILE).exists():
        return GOAL_SPACES
    return skill_kind(read_run_config(Path(run_dir), field))


def own_phase2(run_dir: Path | str) -> Path | None:
    """A phase-1 run's own phase-2 directory (RUN_DIR/phase2) where it holds a phase-2 run (its
    config), else None."""
    phase2_dir = Path(run_dir) / PHASE2_SUBDIR
    return phase2_dir if (phase2_dir / CONFIG_FILE).exists() else None
