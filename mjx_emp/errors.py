"""Every error type the library raises on purpose, each with a message a user can act on.

The CLI maps them to exit codes (cli.exit_codes): bad input and unusable
checkpoints exit 2, a diverged run or a failed checkpoint write 1, a failed file write 1 (2 for a
path the user chose), no offscreen GL 3, a run stopped by SIGINT or SIGTERM 128 + the signal's
number (130, 143).
"""


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the field and what it allows."""


class CheckpointError(RuntimeError):
    """A checkpoint cannot be used; the message names the file and what is wrong with it."""


class CheckpointWriteError(RuntimeError):
    """A checkpoint could not be written (a full disk, a lost mount); the previous checkpoint is
    intact and the message names it."""


class WriteError(RuntimeError):
    """A file could not be written (a full disk, no permission, a read-only filesystem); the
    message names the file, the reason and the run's newest intact checkpoint. ``exit_code`` is 2
    where the user chose the path (``--out``), 1 otherwise."""

    def __init__(self, message: str, exit_code: int = 1):
        super().__init__(message)
        self.exit_code = exit_code


class TrainingDiverged(RuntimeError):
    """An epoch produced a non-finite loss or parameter; the run stopped before keeping it."""


class RenderError(RuntimeError):
    """No offscreen OpenGL context could be made; the message says which system package helps."""


class Interrupted(RuntimeError):
    """SIGINT or SIGTERM stopped a run; its checkpoint writes were finished first. ``signum``
    is the signal's number; the message names the newest checkpoint."""

    def __init__(self, message: str, signum: int):
        super().__init__(message)
        self.signum = signum

    def __reduce__(self):  # whole across processes: a sweep's worker hands it to the sweep
        return type(self), (str(self), self.signum)


class JobFailed(RuntimeError):
    """A sweep's job failed in its worker (a diverged run, a full disk, a bug); the message names
    the row, the failure and the job's log, which holds the whole traceback. Rows of other jobs
    already written stay; calling the sweep again resumes."""
