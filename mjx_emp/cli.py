"""``mjx-emp`` command line (tyro).

Bad input exits with code 2 and a message naming the field and what it allows.
"""

from __future__ import annotations

import difflib
import functools
import json
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Union

import tyro

from mjx_emp.algos.names import listing_lines
from mjx_emp.algos.registry import all_presets
from mjx_emp.algos.retired import RETIRED, Retired
from mjx_emp.checks import LOOP_BOUNDS, check_levels
from mjx_emp.commands import (
    MAX_COVERAGE_DRAWS,
    MAX_EPISODES,
    MAX_FRAME_SIDE,
    MAX_FRAMES,
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
from mjx_emp.run import jobs, store
from mjx_emp.run.preflight import explain_out_of_memory


def validate_rollout(cfg: RolloutExperiment) -> None:
    """Reject configurations that cannot describe a k-level agent."""
    check_levels(cfg.n, cfg.eps)
    k = len(cfg.n)
    if len(cfg.subgoal_half_width) < k - 1 or any(not v > 0 for v in cfg.subgoal_half_width):
        raise ConfigError(
            f"subgoal_half_width: needs k-1={k - 1} positive entries; got {cfg.subgoal_half_width}"
        )
    for name in ("batch_size", "steps", "calls"):
        if getattr(cfg, name) < 1:
            raise ConfigError(f"{name}: must be >= 1; got {getattr(cfg, name)}")
    if not cfg.root_goal_half_width > 0:
        raise ConfigError(f"root_goal_half_width: must be > 0; got {cfg.root_goal_half_width}")


def run_rollout(cfg: RolloutExperiment) -> dict:
    """Roll out a random-init k-level agent; return per-level statistics and throughput."""
    import jax  # deferred: keeps `--help` fast

    from mjx_emp.envs.env import make_env
    from mjx_emp.nets import mlp_agent
    from mjx_emp.rollout.hierarchy import (
        Hierarchy,
        default_start,
        jit_init_rollout,
        jit_rollout,
    )

    env = make_env(cfg.env)
    key = jax.random.key(cfg.seed)
    policies, params = mlp_agent(env, len(cfg.n), cfg.hidden, cfg.subgoal_half_width, key)
    hierarchy = Hierarchy(env, policies, n=cfg.n, eps=cfg.eps)
    start = default_start(env, cfg.root_goal_half_width)

    t0 = time.perf_counter()
    state = jit_init_rollout(hierarchy, params, start, None, jax.random.fold_in(key, 99), cfg.batch_size)
    state, _, _, stats = jit_rollout(hierarchy, params, start, None, state, cfg.steps)
    jax.block_until_ready(stats)
    compile_s = time.perf_counter() - t0

    totals = {"useful": 0, "steps": 0, "episodes": 0, "nan": 0, "flip": 0}
    reached = [0] * hierarchy.k
    finals = [0] * hierarchy.k
    elapsed = 0.0
    for _ in range(cfg.calls):
        t0 = time.perf_counter()
        state, transitions, _, stats = jit_rollout(hierarchy, params, start, None, state, cfg.steps)
        jax.block_until_ready(stats)
        elapsed += time.perf_counter() - t0
        totals["useful"] += int(stats.useful_steps)
        totals["steps"] += int(stats.primitive_steps)
        totals["episodes"] += int(stats.episodes_finished)
        totals["nan"] += int(stats.nan_resets)
        totals["flip"] += int(stats.flip_resets)
        for level, tr in enumerate(transitions):
            reached[level] += int((tr.reached & tr.valid).sum())
            finals[level] += int((tr.final & tr.valid).sum())
    return {
        "env": cfg.env,
        "k": hierarchy.k,
        "n": list(hierarchy.n),
        "batch_size": cfg.batch_size,
        "primitive_steps": totals["steps"],
        "useful_step_fraction": totals["useful"] / totals["steps"],
        "useful_physics_steps_per_s": totals["useful"] * env.action_repeat / elapsed,
        "primitive_steps_per_s": totals["steps"] / elapsed,
        "compile_and_first_call_s": compile_s,
        "root_episodes_finished": totals["episodes"],
        "goals_ended_per_level": finals,
        "goals_reached_per_level": reached,
        "nan_resets": totals["nan"],
        "flip_resets": totals["flip"],
        "backend": jax.default_backend(),
    }


def rollout(cfg: RolloutExperiment) -> None:
    """Roll out a random-init k-level agent and print statistics as JSON."""
    validate_rollout(cfg)
    print(json.dumps(run_rollout(cfg), indent=1))


def plot(exp: PlotExperiment) -> None:
    """Draw one run's pictures into RUN_DIR/plots/, or compare several runs in ``--out``; print the paths."""
    from mjx_emp.viz.plots import plot_any_run, plot_runs

    check_distinct_runs(exp.run_dirs, "plot")
    for run_dir in map(Path, exp.run_dirs):
        if not (run_dir / store.METRICS_FILE).exists():
            raise ConfigError(f"run_dir: {str(run_dir)!r} has no {store.METRICS_FILE}; is it a run directory?")
        if not store.read_metrics(run_dir):
            raise ConfigError(f"run_dir: {str(run_dir)!r} has no finished epoch to plot; plot it once an epoch has "
                              f"ended")
    print(f"plotting {', '.join(exp.run_dirs)} ...", flush=True)
    paths = plot_any_run(Path(exp.run_dirs[0])) if len(exp.run_dirs) == 1 else \
        plot_runs([Path(d) for d in exp.run_dirs], Path(exp.out or "plots"))
    for path in paths:
        print(path)


def check_render(exp: RenderExperiment) -> None:
    """Refuse a render request's numbers before anything loads: frames, frame size, seed, fps, distance."""
    for name, most in (("steps", MAX_FRAMES), ("width", MAX_FRAME_SIDE), ("height", MAX_FRAME_SIDE)):
        if not 1 <= getattr(exp, name) <= most:
            raise ConfigError(f"{name}: must be in [1, {most}]; got {getattr(exp, name)}")
    check_seed(exp.seed)
    for name in ("fps", "distance"):
        if not (math.isfinite(getattr(exp, name)) and getattr(exp, name) > 0):
            raise ConfigError(f"{name}: must be a finite number > 0; got {getattr(exp, name)}")


def render(exp: RenderExperiment) -> None:
    """Write a video of a run's greedy top-level skill chain (or phase-2 policy), every level's goal
    drawn; for a flat skill learner, its greedy skills from the prior one after another."""
    check_render(exp)
    from mjx_emp.viz.render import (
        check_video,
        record_trained,
        render_frames,
        video_name,
        write_video,
    )

    out = Path(exp.out or Path(exp.run_dir) / video_name(exp.phase2))
    check_video(out, exp.width, exp.height)  # before the run is loaded
    if exp.out:
        store.output_target(out, "out")
    import jax

    if exp.phase2:
        phase2_dir = Path(exp.run_dir) / store.PHASE2_SUBDIR
        if not (phase2_dir / store.CONFIG_FILE).exists():
            raise ConfigError(f"phase2: {str(phase2_dir)!r} holds no phase-2 run; train one with "
                              f"`mjx-emp phase2 {exp.run_dir}`")
        trainer, epoch, state = jobs.load_phase2(phase2_dir)
    else:
        trainer, epoch, state = jobs.load_run(Path(exp.run_dir))
    what = "the phase-2 policy" if exp.phase2 else "the greedy skills"
    print(f"recording {exp.steps} steps of {what} (epoch {epoch}) ...", flush=True)
    recording = record_trained(trainer, state, exp.phase2, jax.random.key(exp.seed), exp.steps)
    print(f"rendering {len(recording.qpos)} frames of {exp.width}x{exp.height} ...", flush=True)
    frames = render_frames(trainer.env, recording, exp.width, exp.height, exp.camera, exp.distance)
    out = write_video(frames, out, exp.fps)
    print(f"{out}: {len(frames)} frames of {exp.width}x{exp.height} (epoch {epoch})")


def sweep(exp: SweepExperiment) -> None:
    """`mjx-emp sweep`: check the spec, say what it holds, then run what is not done."""
    from mjx_emp.run.sweep import describe_plan, load_spec
    from mjx_emp.run.sweep import sweep as run_sweep

    spec = load_spec(exp.spec)  # a bad spec exits 2 here, before anything trains
    for line in describe_plan(spec):
        print(line)
    written = run_sweep(exp.spec, exp.runs, exp.results, exp.workers, exp.executor, exp.dry_run)
    if not exp.dry_run:
        print(f"sweep {spec.name}: {len(written)} row(s) written this call")


def report(exp: ReportExperiment) -> None:
    """`mjx-emp report`: print a spec's table (and write its figure and block where asked)."""
    from mjx_emp.report import report_spec

    print(report_spec(exp.spec, exp.results, exp.metrics, exp.baseline, exp.figure, exp.curve, exp.into, exp.block,
                      exp.reps, flip_table=exp.flip_table))
    if exp.into:
        print(f"wrote block {exp.block or Path(exp.spec).stem} of {exp.into}")


def check_seed(seed: int) -> None:
    """An evaluation or render seed JAX can take: the configs' seed bound (:data:`LOOP_BOUNDS`)."""
    if not 0 <= seed <= LOOP_BOUNDS["seed"]:
        raise ConfigError(f"seed: must be in [0, 2**63); got {seed}")


def check_distinct_runs(run_dirs: tuple[str, ...], command: str) -> None:
    """At least one run directory, and none given twice: runs are aggregated as seeds, and the
    same run twice would count as two (``command`` names the CLI command in the message)."""
    if not run_dirs:
        raise ConfigError(f"run_dirs: give at least one run directory, e.g. `mjx-emp {command} runs/pm1`")
    resolved = [Path(d).resolve() for d in run_dirs]
    twice = sorted({d for d, r in zip(run_dirs, resolved) if resolved.count(r) > 1})
    if twice:
        raise ConfigError(f"run_dirs: each run counts once (they are aggregated as seeds); given twice: {twice}")


def check_eval(exp: EvalExperiment) -> None:
    """Refuse an eval request before anything loads: episodes, and a run given twice (it
    would count as two seeds)."""
    if not 1 <= exp.episodes <= MAX_EPISODES:
        raise ConfigError(f"episodes: must be in [1, {MAX_EPISODES}]; got {exp.episodes}")
    check_seed(exp.seed)
    if not 1 <= exp.coverage_draws <= MAX_COVERAGE_DRAWS:
        raise ConfigError(f"coverage_draws: must be in [1, {MAX_COVERAGE_DRAWS}]; got {exp.coverage_draws}")
    check_distinct_runs(exp.run_dirs, "eval")
    if exp.out:
        store.output_target(Path(exp.out), "out")  # a place it cannot write is refused before the evaluation runs
    if exp.flip_figure:
        store.output_target(Path(exp.flip_figure), "flip_figure")


def evaluate(exp: EvalExperiment) -> dict:
    """`mjx-emp eval`: each run's evaluation row (:func:`mjx_emp.run.evaluate.evaluate_runs`, the
    evaluation `mjx-emp sweep` writes its rows with), aggregated over runs, printed and written as
    JSON (``runs`` holds the rows)."""
    check_eval(exp)
    from mjx_emp.run.evaluate import evaluate_runs, evaluation_text
    from mjx_emp.run.provenance import command_line

    out = Path(exp.out or Path(exp.run_dirs[0]) / "eval.json")
    report = evaluate_runs([Path(d) for d in exp.run_dirs], exp.seed, exp.episodes,
                           command_line(["mjx-emp", *sys.argv[1:]]), exp.coverage_draws)
    store.write_atomically(out, json.dumps(report, indent=1), chosen=bool(exp.out))
    print(evaluation_text(report))
    print(f"wrote {out}")
    if report.get("flip_table") is not None:
        from mjx_emp.viz.flips import plot_flips

        figure = Path(exp.flip_figure or out.with_name("flips.png"))
        print(f"wrote {plot_flips(report['flip_table']['levels'], report['flip_table']['phase2'], figure)}")
    return report


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


def close_names(name: str, known) -> list[str]:
    """The known names closest to a misspelt one (at most three)."""
    return difflib.get_close_matches(name, list(known), n=3, cutoff=0.6)


def unknown_preset(name: str, known, usage: str, retired: dict[str, Retired] | None = None) -> ConfigError:
    """The error for a preset name that does not exist: for a name in ``retired``, the command
    that gives its config; else the closest names."""
    if retired and name in retired:
        return ConfigError(f"preset: {name!r} left the catalogue; its config is "
                           f"`{usage.replace('PRESET', retired[name].command)}`")
    closest = close_names(name, known)
    hint = f"did you mean {', '.join(closest)}? " if closest else ""
    return ConfigError(f"preset: {name!r} is unknown ({usage}); {hint}`mjx-emp presets` lists all {len(known)}")


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


def export(exp: ExportExperiment) -> None:
    """`mjx-emp export`: write the skills export and say how big it is beside the run's checkpoints."""
    out, epoch = jobs.export_skills(exp)
    whole = store.directory_megabytes(Path(exp.run_dir) / store.CHECKPOINT_SUBDIR / str(epoch))
    print(f"exported the skills of {exp.run_dir} (epoch {epoch}) to {out}: {store.directory_megabytes(out):.1f} MB, "
          f"against {whole:.1f} MB for the run's checkpoint", flush=True)


def list_presets(_: PresetsExperiment) -> None:
    """Print the preset catalogue: the name grammar, the recommended recipes first, then the
    paper's Table-1 configs, the baselines and the phase-2 tasks (`mjx-emp train NAME --help`
    gives one preset's description and fields)."""
    print("\n".join(listing_lines(all_presets(), PHASE2_PRESETS)))


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


def film_for_trackers(trainer, state, run_dir: Path, steps: int):
    """The video a tracked run hands its trackers when it ends (:func:`mjx_emp.viz.render.film_for_trackers`)."""
    from mjx_emp.viz.render import film_for_trackers as film

    return film(trainer, state, run_dir, steps)


COMMANDS: dict[str, tuple[Any, Any, str]] = {
    "train": (preset_commands, functools.partial(jobs.train, film=film_for_trackers),
              "Train a new run of a preset; every config field is a flag (`train --resume RUN_DIR` is `resume "
              "RUN_DIR`)."),
    "resume": (lambda: ResumeExperiment, functools.partial(jobs.resume, film=film_for_trackers),
               "Continue a run or phase-2 directory from its newest good checkpoint, bit for bit."),
    "phase2": (phase2_commands, functools.partial(jobs.train_phase2, film=film_for_trackers),
               "Phase 2: reach goals of a region with a run's skills as actions (`phase2 RUN_DIR` picks the run's "
               "own preset)."),
    "export": (lambda: ExportExperiment, export, "Copy a run's skills without its replays into a small run directory "
               "that phase2, eval, plot and render read (to move trained skills between machines)."),
    "presets": (lambda: PresetsExperiment, list_presets, "List every phase-1 and phase-2 preset."),
    "eval": (lambda: EvalExperiment, evaluate, "Figures of runs' newest checkpoints (goal spaces, success, "
             "coverage; phase 2's distance), mean over runs."),
    "plot": (lambda: PlotExperiment, plot, "Draw a run's pictures into RUN_DIR/plots/, or compare several runs (seeds, methods)."),
    "render": (lambda: RenderExperiment, render, "Film a run's greedy skills (or its phase-2 policy) as an MP4 or a GIF."),
    "rollout": (lambda: RolloutExperiment, rollout, "Roll out a random-init k-level agent and print throughput."),
    "report": (lambda: ReportExperiment, report, "Tables (n, mean ± std (se), IQM with its 95 % bootstrap interval, "
               "probability of improvement) and seed-band figures of a spec's rows; --into writes a Markdown block."),
    "sweep": (lambda: SweepExperiment, sweep, "Train, resume and evaluate every run of a spec (rows x seeds), each "
              "run's evaluation row with its provenance appended to results/<spec>.jsonl."),
}
"""Every command: (its type, built on demand; what runs it; its one-line help)."""


def parse(argv: list[str]) -> tuple[Any, Any]:
    """(what runs the command, its parsed experiment) for a canonical command line."""
    choices = Union[tuple(  # noqa: UP007
        Annotated[make_type(), tyro.conf.subcommand(name, description=" ".join(help_text.split()))]
        for name, (make_type, _, help_text) in COMMANDS.items()
    )]
    exp = parse_quietly(choices, argv)
    run = COMMANDS[argv[0]][1]
    if argv[0] in ("train", "phase2"):  # the preset a new run is made from, kept beside it with its overrides
        run = functools.partial(run, record=new_run_record(argv[1], exp.config, argv))
    return run, exp


def parse_quietly(choices: Any, argv: list[str]) -> Any:
    """tyro's parse of ``argv``; what it refuses (a value of the wrong type, an unknown flag, a
    missing command) becomes one ConfigError line naming the flag, instead of tyro's panel."""
    import contextlib
    import io

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


def new_run_record(preset: str, cfg: Any, argv: list[str]) -> dict:
    """What a new run directory keeps of how it was asked for (:mod:`mjx_emp.run.provenance`)."""
    from mjx_emp.run.provenance import command_line, overrides_of, run_record

    base = PHASE2_PRESETS[preset][2] if argv[0] == "phase2" else all_presets()[preset][1]
    return run_record(preset, overrides_of(base, cfg), command_line(["mjx-emp", *argv]))


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


def main_guarded(command: Callable, exp) -> None:
    """Run a CLI command; bad input exits 2, divergence, a failed checkpoint write or running out of
    memory 1, a failed file write 1 (2 for a path the user chose), no offscreen GL 3,
    SIGINT/SIGTERM 130/143, each with a reason."""
    failures = (
        (ConfigError, "invalid configuration", 2),
        (CheckpointError, "unusable checkpoint", 2),
        (TrainingDiverged, "training diverged", 1),
        (CheckpointWriteError, "checkpoint write failed", 1),
        (RenderError, "cannot render", 3),
        (JobFailed, "sweep job failed", 1),
    )
    try:
        command(exp)
    except Interrupted as stop:
        say(str(stop))
        sys.exit(128 + stop.signum)
    except WriteError as err:
        say(f"write failed: {err}")
        sys.exit(err.exit_code)
    except tuple(kind for kind, _, _ in failures) as err:
        what, code = next((what, code) for kind, what, code in failures if isinstance(err, kind))
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
    from mjx_emp.run.noise import quiet_libraries

    noise = quiet_libraries()  # orbax's thread tracebacks and asyncio's exit noise go to a log file

    def parse_and_run(args: list[str]) -> None:
        command, exp = parse(canonical_args(args))  # imports no mujoco
        try:
            run(command, exp, args)
        finally:
            noise.write(run_folder(exp))  # RUN_DIR/library.log, for whoever debugs the libraries

    def run(command, exp, args: list[str]) -> None:
        tracking = getattr(exp, "tracking", None)
        if args[:1] == ["render"]:
            from mjx_emp.viz.render import configure_headless_gl

            configure_headless_gl()  # before anything imports mujoco
        elif tracking is not None and tracking.on() and tracking.video_steps:
            from mjx_emp.viz.render import prefer_headless_gl

            prefer_headless_gl()  # the trackers' video at the end
        command(exp)

    main_guarded(parse_and_run, argv)


if __name__ == "__main__":
    main()
