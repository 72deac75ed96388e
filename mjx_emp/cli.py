"""``mjx-emp`` command line (tyro): parse, dispatch to the command's handler, map errors to exit codes.

The parser and the requests it builds (:mod:`mjx_emp.commands`) are plain Python; JAX, MuJoCo
and the rest load only once a command's handler (:mod:`mjx_emp.handlers`) is imported, so
``--help``, ``presets`` and a refused command line answer at once. Bad input exits with code 2
and a message naming the field and what it allows.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import json
import signal
import sys
from collections.abc import Callable, Iterator
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
from mjx_emp.phase2.config import Phase2Config
from mjx_emp.phase2.presets import OWN_TASK, PHASE2_PRESETS, PHASE2_RETIRED
from mjx_emp.report import report_command
from mjx_emp.run.compile_cache import use_compile_cache
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
    own = Annotated[Phase2Experiment, tyro.conf.subcommand(
        OWN_TASK, default=Phase2Experiment(run_dir=tyro.MISSING, config=Phase2Config()),
        description="the run's own task (its preset's, else its domain's, size's and depth's); each flag given "
                    "replaces that task's field")]
    return Union[(own, *commands)]  # noqa: UP007


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
    """Command ``name`` run on its request: :data:`mjx_emp.handlers.HANDLERS`' entry, imported
    only now (after the OpenGL set-up); the catalogue and the reports, which need no JAX, run here."""
    if name in ("presets", "report"):
        return (list_presets if name == "presets" else report_command)(exp)
    from mjx_emp.handlers import HANDLERS  # deferred: JAX loads here

    return HANDLERS[name](exp, **extra)


def parse(argv: list[str]) -> tuple[Callable[[Any], Any], Any]:
    """(what runs the command, its parsed request) for a canonical command line; a new run
    (``train``, ``phase2``) also gets the record of how it was asked for."""
    choices = Union[tuple(  # noqa: UP007
        Annotated[make_type(), tyro.conf.subcommand(name, description=" ".join(help_text.split()))]
        for name, (make_type, help_text) in COMMANDS.items()
    )]
    exp = parse_quietly(choices, argv)
    if argv[:2] == ["phase2", OWN_TASK]:  # the run's own task, with the fields the command line names
        exp = dataclasses.replace(exp, own_task=tuple(given_fields(argv[2:], Phase2Config)))
    run = functools.partial(run_command, argv[0])
    if argv[0] in ("train", "phase2"):
        run = functools.partial(run, record=new_run_record(argv, exp))
    return run, exp


def given_fields(args: list[str], config_type: type) -> list[str]:
    """The fields of ``config_type`` that ``args`` name as flags (``--field``, ``--field=V``, ``--no-field``)."""
    names = {field.name for field in dataclasses.fields(config_type)}
    flags = [arg[2:].split("=", 1)[0].replace("-", "_") for arg in args if arg.startswith("--")]
    return [flag if flag in names else flag.removeprefix("no_") for flag in flags
            if flag in names or flag.removeprefix("no_") in names]


def new_run_record(argv: list[str], exp: Any) -> dict:
    """What a new run directory keeps of how it was asked for: its preset and the fields given beyond it."""
    if argv[0] == "phase2" and exp.own_task is not None:
        overrides = json.loads(json.dumps({name: getattr(exp.config, name) for name in exp.own_task}))
    else:
        base = PHASE2_PRESETS[argv[1]][2] if argv[0] == "phase2" else all_presets()[argv[1]][1]
        overrides = overrides_of(base, exp.config)
    return run_record(argv[1], overrides, command_line(["mjx-emp", *argv]))


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


def canonical_args(argv: list[str]) -> list[str]:
    """The command line in the one form the parser reads: ``train --resume RUN_DIR ...`` is
    ``resume RUN_DIR ...``, ``phase2 --resume DIR ...`` is ``resume DIR ... --phase2`` and ``phase2 RUN_DIR ...``
    is ``phase2 own RUN_DIR ...`` (the run's own task, which the job picks once it reads the run)."""
    command, rest = argv[:1], argv[1:]
    if command in (["train"], ["phase2"]):
        phase2 = ["--phase2"] if command == ["phase2"] else []  # continue phase 2, never phase 1
        for i, arg in enumerate(rest):
            if arg == "--resume" and i + 1 < len(rest):
                return ["resume", rest[i + 1], *rest[:i], *rest[i + 2:], *phase2]
            if arg.startswith("--resume="):
                return ["resume", arg.split("=", 1)[1], *rest[:i], *rest[i + 1:], *phase2]
    if command == ["phase2"] and rest and rest[0] not in (*PHASE2_PRESETS, OWN_TASK) and not rest[0].startswith("-"):
        if not Path(rest[0]).exists() and (rest[0] in PHASE2_RETIRED or close_names(rest[0], PHASE2_PRESETS)):
            raise unknown_preset(rest[0], PHASE2_PRESETS, "mjx-emp phase2 PRESET RUN_DIR", PHASE2_RETIRED)
        return ["phase2", OWN_TASK, *rest]
    if command == ["train"] and rest and not rest[0].startswith("-"):
        presets = all_presets()
        if rest[0] not in presets:
            raise unknown_preset(rest[0], presets, "mjx-emp train PRESET", RETIRED)
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


@contextlib.contextmanager
def exit_codes() -> Iterator[None]:
    """Run a command inside: bad input exits 2, divergence, a failed checkpoint write or running out
    of memory 1, a failed file write 1 (2 for a path the user chose), no offscreen GL 3,
    SIGINT/SIGTERM 130/143 (Ctrl-C anywhere, not only in training), each with a one-line reason."""
    try:
        yield
    except Interrupted as stop:
        say(str(stop))
        sys.exit(128 + stop.signum)
    except KeyboardInterrupt:  # Ctrl-C where no checkpoint is being kept (eval, phase 2's figures, a report)
        say("stopped by SIGINT before it finished; run it again for its outputs")
        sys.exit(128 + signal.SIGINT)
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


def run(args: list[str], noise: Any) -> None:
    """Parse a command line, choose the OpenGL backend where the command films (before anything
    imports MuJoCo), and run the command; the libraries' messages go to its run directory."""
    command, exp = parse(canonical_args(args))  # imports no mujoco
    tracking = getattr(exp, "tracking", None)
    if args[:1] == ["render"]:
        configure_headless_gl()
    elif tracking is not None and tracking.on() and tracking.video_steps:
        prefer_headless_gl()  # the trackers' video at the end
    try:
        command(exp)
    finally:
        noise.write(run_folder(exp))  # RUN_DIR/library.log, for whoever debugs the libraries


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``mjx-emp`` console script: one parser, every command a subcommand
    (``mjx-emp --help`` lists them, ``mjx-emp COMMAND --help`` shows every flag).

    Compiled programs are cached (:mod:`mjx_emp.run.compile_cache`; ``--no-compile-cache``
    compiles afresh). Bad input exits 2 naming the field (:func:`exit_codes`).
    """
    argv = use_compile_cache(sys.argv[1:] if argv is None else list(argv))
    noise = quiet_libraries()  # orbax's thread tracebacks and asyncio's exit noise go to a log file
    with exit_codes():
        run(argv, noise)


if __name__ == "__main__":
    main()
