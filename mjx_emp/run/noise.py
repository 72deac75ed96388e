"""What the libraries print on their own, kept out of the user's terminal.

Orbax writes checkpoints in background threads: when a write fails (a full disk), every thread
logs its traceback through absl before the failure reaches us, a few hundred lines ahead of the
one line that says what happened. asyncio adds "Event loop is closed" when the process exits with
orbax's loops half shut. The command's own message already says what failed and what is left;
these records are for whoever debugs orbax, so they go to a log file (in the run directory
where the command has one) and the terminal gets a pointer to it.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
import traceback
from pathlib import Path

LOGGERS = ("absl", "asyncio")
"""The loggers whose records are collected (orbax logs through absl's)."""

LOG_FILE = "library.log"
"""The file the records go to inside a run directory."""


class LibraryNoise(logging.Handler):
    """Collects the records of :data:`LOGGERS`, uncaught exceptions of library threads and
    exceptions Python can only report as unraisable (at exit), instead of printing them."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.lines: list[str] = []
        self.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.lines.append(self.format(record))
        except Exception:  # a record that cannot be formatted is not worth a second failure
            pass

    def thread_failed(self, args: threading.ExceptHookArgs) -> None:
        name = args.thread.name if args.thread else "a thread"
        self.lines.append(f"uncaught in {name}:\n" + "".join(
            traceback.format_exception(args.exc_type, args.exc_value, args.exc_traceback)))

    def unraisable(self, unraisable) -> None:
        self.lines.append(f"{unraisable.err_msg or 'unraisable'} {unraisable.object!r}:\n" + "".join(
            traceback.format_exception(unraisable.exc_type, unraisable.exc_value, unraisable.exc_traceback)))

    def write(self, folder: Path | None) -> Path | None:
        """Write what was collected to FOLDER/library.log (appended); None if nothing was collected,
        there is no folder, or it cannot be written (a full disk: the record is then dropped)."""
        if not self.lines or folder is None or not Path(folder).is_dir():
            return None
        path = Path(folder) / LOG_FILE
        try:
            with open(path, "a") as log:
                log.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} {' '.join(sys.argv)}\n")
                log.write("\n".join(self.lines) + "\n")
        except OSError:
            return None
        self.lines.clear()
        return path


def quiet_libraries() -> LibraryNoise:
    """Route the libraries' own output to a :class:`LibraryNoise` for the rest of the process."""
    noise = LibraryNoise()
    for name in LOGGERS:
        logger = logging.getLogger(name)
        logger.addHandler(noise)
        logger.propagate = False
    threading.excepthook = noise.thread_failed
    sys.unraisablehook = noise.unraisable
    return noise
