"""``mjx-emp`` command line (tyro): parse, dispatch to the command's handler, map errors to exit codes.

The parser and the requests it builds (:mod:`mjx_emp.commands`) are plain Python; JAX, MuJoCo
and the rest load only once a command's handler (:mod:`mjx_emp.handlers`) is imported, so
``--help``, ``presets`` and a refused command line answer at once. Bad input exits with code 2
and a message naming the field and what it allows.
"""

from __future__ import annotations

import contextlib
import functools
import io
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Union

import tyro

from mjx_emp.algos.names import close_names, listing_lines, unknown_preset
from mjx_emp.algos.registry import all_presets
from mjx_emp.algos.retired import RETIRED
from mjx_emp.commands import (
    EvalExperiment,
    ExportExperiment,
    Phase2Experiment,
    PlotExperiment,
    PresetsExperiment,
    RenderExperiment,
    ReportExperiment,
    ResumeExperiment,
    RolloutExperiment,
    SweepExperiment,
    TrainExperiment,
)
from mjx_emp.errors import (
    CheckpointError,
    CheckpointWriteError,
    ConfigError,
    Interrupted,
    JobFailed,
    RenderError,
    TrainingDiverged,
    WriteError,
)
from mjx_emp.phase2.presets import PHASE2_PRESETS, PHASE2_RETIRED, phase2_preset_for
from mjx_emp.run import store
from mjx_emp.run.noise import quiet_libraries
from mjx_emp.run.preflight import explain_out_of_memory
from mjx_emp.run.provenance import command_line, overrides_of, run_record
from mjx_emp.viz.gl import configure_headless_gl, prefer_headless_gl


def preset_commands() -> Any:
    """``mjx-emp train``'s subcommands: one per preset, typed by its algorithm's config, so
    every field of that config is a flag (tyro reads the type from the annotation)."""
    commands = [
        Annotated[TrainExperiment[type(cfg)],
                  tyro.conf.subcommand(name, default=TrainExperiment(config=cfg), description=description)]
        for name, (description, cfg) in all_presets().items()
    ]
    return Union[tuple(commands)]  # noqa: UP007 (a runtime union of Annotated types)


def phase2_commands() -> Any:
    """``mjx-emp phase2``'s subcommands: one per Table-2 preset, every Phase2Config field a flag."""
    commands = [
        Annotated[Phase2Experiment, tyro.conf.subcommand(
            name, default=Phase2Experiment(run_dir=tyro.MISSING, config=cfg), description=f"{description} (on {phase1})")]
        for name, (description, phase1, cfg) in PHASE2_PRESETS.items()
    ]
    return Union[tuple(commands)]  # noqa: UP007


COMMANDS: dict[str, tuple[Callable[[], Any], str]] = {
    "train": (preset_commands, "Train a new run of a preset; every config field is a flag (`train --resume RUN_DIR` "
              "is `resume RUN_DIR`)."),
    "resume": (lambda: ResumeExperiment, "Continue a run or phase-2 directory from its newest good checkpoint, bit "
               "for bit."),
    "phase2": (phase2_commands, "Phase 2: reach goals of a region with a run's skills as actions (`phase2 RUN_DIR` "
               "picks the run's own preset)."),
    "export": (lambda: ExportExperiment, "Copy a run's skills without its replays into a small run directory that "
               "phase2, eval, plot and render read (to move trained skills between machines)."),
    "presets": (lambda: PresetsExperiment, "List every phase-1 and phase-2 preset."),
    "eval": (lambda: EvalExperiment, "Figures of runs' newest checkpoints (goal spaces, success, coverage; phase 2's "
             "distance), mean over runs."),
    "plot": (lambda: PlotExperiment, "Draw a run's pictures into RUN_DIR/plots/, or compare several runs (seeds, "
             "methods)."),
    "render": (lambda: RenderExperiment, "Film a run's greedy skills (or its phase-2 policy) as an MP4 or a GIF."),
    "rollout": (lambda: RolloutExperiment, "Roll out a random-init k-level agent and print throughput."),
    "report": (lambda: ReportExperiment, "Tables (n, mean ± std (se), IQM with its 95 % bootstrap interval, "
               "probability of improvement) and seed-band figures of a spec's rows; --into writes a Markdown block."),
    "sweep": (lambda: SweepExperiment, "Train, resume and evaluate every run of a spec (rows x seeds), each run's "
              "evaluation row with its provenance appended to results/<spec>.jsonl."),
}
"""Every command: (its request type, built on demand; its one-line help)."""


def list_presets(_: PresetsExperiment) -> None:
    """Print the preset catalogue (`mjx-emp train NAME --help` gives one preset's description and fields)."""
    print("\n".join(listing_lines(all_presets(), PHASE2_PRESETS)))


def run_command(name: str, exp: Any, **extra: Any) -> Any:
    """Command ``name``'s handler (:data:`mjx_emp.handlers.HANDLERS`) run on its request; the
    catalogue (``presets``, plain Python) is listed here."""
    if name == "presets":
        return list_presets(exp)
    from mjx_emp.handlers import HANDLERS  # deferred: JAX and MuJoCo load once a command runs, not for --help

    return HANDLERS[name](exp, **extra)


def parse(argv: list[str]) -> tuple[Callable[[Any], Any], Any]:
    """(what runs the command, its parsed request) for a canonical command line; a new run
    (``train``, ``phase2``) also gets the record of how it was asked for."""
    choices = Union[tuple(  # noqa: UP007
        Annotated[make_type(), tyro.conf.subcommand(name, description=" ".join(help_text.split()))]
        for name, (make_type, help_text) in COMMANDS.items()
    )]
    exp = parse_quietly(choices, argv)
    run = functools.partial(run_command, argv[0])
    if argv[0] in ("train", "phase2"):  # the preset a new run is made from, kept beside it with its overrides
        base = PHASE2_PRESETS[argv[1]][2] if argv[0] == "phase2" else all_presets()[argv[1]][1]
        run = functools.partial(run, record=run_record(argv[1], overrides_of(base, exp.config),
                                                       command_line(["mjx-emp", *argv])))
    return run, exp


def parse_quietly(choices: Any, argv: list[str]) -> Any:
    """tyro's parse of ``argv``; what it refuses (a value of the wrong type, an unknown flag, a
    missing command) becomes one ConfigError line naming the flag, instead of tyro's panel."""
    panel = io.StringIO()
    try:
        with contextlib.redirect_stderr(panel):
            return tyro.cli(choices, args=argv, prog="mjx-emp")
    except SystemExit as stop:
        if stop.code in (0, None):
            sys.stderr.write(panel.getvalue())
            raise
        raise ConfigError(panel_line(panel.getvalue()) or f"arguments: cannot parse {' '.join(argv)}") from None


def panel_line(panel: str) -> str:
    """The message of a tyro error panel on one line: its title's and first lines' text, without
    the box, the flag's help and the pointer to --help."""
    lines = []
    for raw in panel.splitlines():
        text = raw.strip().strip("│╭╮╰╯─┌┐└┘ ").strip()
        if not text or set(text) <= set("─━ "):
            continue
        if text.startswith(("Argument helptext", "For full helptext", "Perhaps you meant")):
            break
        lines.append(text)
    return "; ".join(lines)


def with_phase2_preset(args: list[str]) -> list[str]:
    """``phase2`` arguments with a preset first: given ``RUN_DIR ...``, the run's own task
    (:func:`mjx_emp.phase2.presets.phase2_preset_for`: of its preset, else of its domain, size
    and depth). A retired task name is refused with the task that replaced it.
    """
    if not args or args[0] in PHASE2_PRESETS or args[0].startswith("-"):
        return args
    if not Path(args[0]).exists() and (args[0] in PHASE2_RETIRED or close_names(args[0], PHASE2_PRESETS)):
        raise unknown_preset(args[0], PHASE2_PRESETS, "mjx-emp phase2 PRESET RUN_DIR", PHASE2_RETIRED)
    skills = store.read_run_config(Path(args[0]), "run_dir")
    preset = phase2_preset_for(skills)
    if preset is None:
        raise ConfigError(
            f"run_dir: no phase-2 preset is built on env={skills.env} n={tuple(skills.n)}; name one "
            f"before the run directory (mjx-emp phase2 PRESET RUN_DIR); presets: {sorted(PHASE2_PRESETS)}"
        )
    return [preset, *args]


def canonical_args(argv: list[str]) -> list[str]:
    """The command line in the one form the parser reads: ``train --resume RUN_DIR ...`` is
    ``resume RUN_DIR ...`` and ``phase2 --resume DIR ...`` is ``resume DIR ... --phase2``; ``phase2 RUN_DIR ...`` names the
    run's own Table-2 preset (:func:`with_phase2_preset`)."""
    command, rest = argv[:1], argv[1:]
    if command in (["train"], ["phase2"]):
        phase2 = ["--phase2"] if command == ["phase2"] else []  # continue phase 2, never phase 1
        for i, arg in enumerate(rest):
            if arg == "--resume" and i + 1 < len(rest):
                return ["resume", rest[i + 1], *rest[:i], *rest[i + 2:], *phase2]
            if arg.startswith("--resume="):
                return ["resume", arg.split("=", 1)[1], *rest[:i], *rest[i + 1:], *phase2]
    if command == ["phase2"]:
        return ["phase2", *with_phase2_preset(rest)]
    if command == ["train"] and rest and not rest[0].startswith("-"):
        presets = all_presets()
        if rest[0] not in presets:
            raise unknown_preset(rest[0], presets, "mjx-emp train PRESET", RETIRED)
    return argv


NO_COMPILE_CACHE = "--no-compile-cache"


def default_compile_cache() -> Path:
    """Where compiled programs are kept between runs: $XDG_CACHE_HOME/mjx-emp/xla (~/.cache/...)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mjx-emp" / "xla"


def use_compile_cache(argv: list[str]) -> list[str]:
    """Turn on JAX's persistent compilation cache for this process (before JAX is imported) and
    return ``argv`` without the ``--no-compile-cache`` flag that turns it off.

    A re-run, resume or second seed of the same config then loads its compiled epoch instead
    of compiling it again; what it computes is unchanged. A ``JAX_COMPILATION_CACHE_DIR``
    set by the user wins; programs that compile in under a second are not stored.
    """
    if NO_COMPILE_CACHE in argv:
        return [arg for arg in argv if arg != NO_COMPILE_CACHE]
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(default_compile_cache()))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")
    return argv


FAILURES = (
    (ConfigError, "invalid configuration", 2),
    (CheckpointError, "unusable checkpoint", 2),
    (TrainingDiverged, "training diverged", 1),
    (CheckpointWriteError, "checkpoint write failed", 1),
    (RenderError, "cannot render", 3),
    (JobFailed, "sweep job failed", 1),
)
"""(error type, what the message calls it, exit code) of every failure the CLI reports in one line."""


def main_guarded(command: Callable, exp) -> None:
    """Run a CLI command; bad input exits 2, divergence, a failed checkpoint write or running out of
    memory 1, a failed file write 1 (2 for a path the user chose), no offscreen GL 3,
    SIGINT/SIGTERM 130/143, each with a reason."""
    try:
        command(exp)
    except Interrupted as stop:
        say(str(stop))
        sys.exit(128 + stop.signum)
    except WriteError as err:
        say(f"write failed: {err}")
        sys.exit(err.exit_code)
    except tuple(kind for kind, _, _ in FAILURES) as err:
        what, code = next((what, code) for kind, what, code in FAILURES if isinstance(err, kind))
        say(f"{what}: {err}")
        sys.exit(code)
    except Exception as err:  # XLA's out-of-memory error is explained; anything else is a bug to report
        explanation = explain_out_of_memory(err)
        if explanation is None:
            raise
        say(explanation)
        sys.exit(1)


def say(message: str) -> None:
    """A failure's one line on stderr (whitespace and line breaks inside it folded)."""
    print(f"mjx-emp: {' '.join(message.split())}", file=sys.stderr, flush=True)


def run_folder(exp: Any) -> Path | None:
    """The run directory a command works in, where its libraries' messages are kept; None if it names none."""
    for name in ("resume", "run_dir", "out"):
        value = getattr(exp, name, None)
        if isinstance(value, str) and value and Path(value).is_dir():
            return Path(value)
    dirs = getattr(exp, "run_dirs", ())
    return Path(dirs[0]) if dirs and Path(dirs[0]).is_dir() else None


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``mjx-emp`` console script: one parser, every command a subcommand
    (``mjx-emp --help`` lists them, ``mjx-emp COMMAND --help`` shows every flag).

    Compiled programs are cached under ``default_compile_cache()``; ``--no-compile-cache``
    (any command) compiles afresh. Bad input exits 2 naming the field (:func:`main_guarded`).
    """
    argv = use_compile_cache(sys.argv[1:] if argv is None else list(argv))
    noise = quiet_libraries()  # orbax's thread tracebacks and asyncio's exit noise go to a log file

    def parse_and_run(args: list[str]) -> None:
        command, exp = parse(canonical_args(args))  # imports no mujoco
        tracking = getattr(exp, "tracking", None)
        if args[:1] == ["render"]:
            configure_headless_gl()  # before anything imports mujoco
        elif tracking is not None and tracking.on() and tracking.video_steps:
            prefer_headless_gl()  # the trackers' video at the end
        try:
            command(exp)
        finally:
            noise.write(run_folder(exp))  # RUN_DIR/library.log, for whoever debugs the libraries

    main_guarded(parse_and_run, argv)


if __name__ == "__main__":
    main()
