"""``mjx-emp`` command line (tyro).

Bad input exits with code 2 and a message naming the field and what it allows.
"""

from __future__ import annotations

import difflib
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Union

import tyro

from mjx_emp.algos.registry import LATENT_SKILLS, algorithm_of, all_presets
from mjx_emp.checks import check_levels
from mjx_emp.commands import (
    EvalExperiment,
    Phase2Experiment,
    PlotExperiment,
    PresetsExperiment,
    RenderExperiment,
    ResumeExperiment,
    RolloutExperiment,
    TrainExperiment,
)
from mjx_emp.errors import (
    CheckpointError,
    CheckpointWriteError,
    ConfigError,
    Interrupted,
    RenderError,
    TrainingDiverged,
)
from mjx_emp.phase2.presets import PHASE2_PRESETS, phase2_preset_for
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
    from mjx_emp.rollout.hierarchy import Hierarchy, default_start, jit_init_rollout, jit_rollout

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
    """Draw a run's pictures into RUN_DIR/plots/ and print their paths."""
    from mjx_emp.viz.plots import plot_any_run

    run_dir = Path(exp.run_dir)
    if not (run_dir / store.METRICS_FILE).exists():
        raise ConfigError(f"run_dir: {str(run_dir)!r} has no {store.METRICS_FILE}; is it a run directory?")
    for path in plot_any_run(run_dir):
        print(path)


def render(exp: RenderExperiment) -> None:
    """Write a GIF of a run's greedy top-level skill chain (or phase-2 policy), every level's goal drawn;
    for a flat skill learner, its greedy skills from the prior one after another."""
    for name in ("steps", "width", "height"):
        if getattr(exp, name) < 1:
            raise ConfigError(f"{name}: must be >= 1; got {getattr(exp, name)}")
    if not exp.fps > 0:
        raise ConfigError(f"fps: must be > 0; got {exp.fps}")
    import jax

    from mjx_emp.viz.render import record_rollout, render_frames, skill_recording, write_gif

    if exp.phase2:
        phase2_dir = Path(exp.run_dir) / store.PHASE2_SUBDIR
        if not (phase2_dir / store.CONFIG_FILE).exists():
            raise ConfigError(f"phase2: {str(phase2_dir)!r} holds no phase-2 run; train one with "
                              f"`mjx-emp phase2 {exp.run_dir}`")
        trainer, epoch, state = jobs.load_phase2(phase2_dir)
        recording = record_rollout(trainer.greedy_episodes(state), jax.random.key(exp.seed), exp.steps)
    else:
        trainer, epoch, state = jobs.load_run(Path(exp.run_dir))
        recording = skill_recording(trainer, state, jax.random.key(exp.seed), exp.steps)
    frames = render_frames(trainer.env, recording, exp.width, exp.height, exp.distance)
    default_name = "phase2.gif" if exp.phase2 else "skills.gif"
    out = write_gif(frames, Path(exp.out or Path(exp.run_dir) / default_name), exp.fps)
    print(f"{out}: {len(frames)} frames of {exp.width}x{exp.height} (epoch {epoch})")


def evaluate(exp: EvalExperiment) -> dict:
    """Evaluate each run's newest checkpoints, aggregate over runs, print tables, write JSON.

    Phase-1 figures always; the paper's phase-2 figure (mean minimum distance to goal) for
    runs that have a phase-2 directory (RUN_DIR/phase2).
    """
    if exp.episodes < 1:
        raise ConfigError(f"episodes: must be >= 1; got {exp.episodes}")
    import jax

    from mjx_emp.metrics import LEVEL_FIGURES, aggregate_agent, aggregate_phase2, aggregate_runs
    from mjx_emp.run.evaluate import COVERAGE_SKILLS, phase1_figures, phase2_figures, skill_figures

    algorithms = {algorithm.name: algorithm
                  for algorithm in (algorithm_of(store.read_run_config(Path(d), "run_dirs")) for d in exp.run_dirs)}
    if len(algorithms) > 1:
        raise ConfigError(f"run_dirs: runs of one algorithm at a time (they are aggregated); got {sorted(algorithms)}")
    if next(iter(algorithms.values())).skills == LATENT_SKILLS:  # no goal spaces to report
        return evaluate_skills(exp, skill_figures)
    runs = []
    for run_dir in exp.run_dirs:
        trainer, _, state = jobs.load_run(Path(run_dir))
        report = {"run_dir": run_dir, **phase1_figures(trainer, state, jax.random.key(exp.seed), exp.episodes)}
        phase2_dir = Path(run_dir) / store.PHASE2_SUBDIR
        if (phase2_dir / store.CONFIG_FILE).exists():
            report["phase2"] = phase2_figures(*jobs.load_phase2(phase2_dir), jax.random.key(exp.seed), exp.episodes)
        runs.append(report)
    report = {"runs": runs, "levels": aggregate_runs(runs), **aggregate_agent(runs)}
    with_phase2 = [r["phase2"] for r in runs if "phase2" in r]
    if with_phase2:
        report["phase2"] = aggregate_phase2(with_phase2)
    out = Path(exp.out or Path(exp.run_dirs[0]) / "eval.json")
    out.write_text(json.dumps(report, indent=1))
    print(f"{len(runs)} run(s); mean ± standard error over runs")
    print("| level | goal-space volume | greedy success | final distance | success from s0 | success from "
          "chained starts | cut short (flipped) |")
    print("|---|---|---|---|---|---|---|")
    for row in report["levels"]:
        cells = [f"{row[name]['mean']:.3g} ± {row[name]['stderr']:.2g}" for name in LEVEL_FIGURES]
        print(f"| {row['level']} | " + " | ".join(cells) + " |")
    cover, area = report["coverage_cells"], report["volume_x_success"]
    print(f"coverage ({COVERAGE_SKILLS} greedy top-level skills from the initial state, 1 m cells of goal space): "
          f"{cover['mean']:.3g} ± {cover['stderr']:.2g} cells; top volume x greedy success "
          f"{area['mean']:.3g} ± {area['stderr']:.2g}")
    if with_phase2:
        p2 = report["phase2"]
        first = with_phase2[0]
        print(f"phase 2 ({len(with_phase2)} run(s), {first['episodes']} episodes each, region {first['region']}, "
              f"eps {first['eps']}): mean min distance to goal {p2['min_distance']['mean']:.3g} ± "
              f"{p2['min_distance']['stderr']:.2g}, success {p2['success']['mean']:.3g} ± {p2['success']['stderr']:.2g}")
    else:
        print("phase 2: no run has a phase-2 directory (train one with `mjx-emp phase2 RUN_DIR`)")
    print(f"wrote {out}")
    return report


def evaluate_skills(exp: EvalExperiment, skill_figures) -> dict:
    """``mjx-emp eval`` for flat skill learners: coverage and posterior std per run, and the
    phase-2 figure where RUN_DIR/phase2 exists, aggregated."""
    import jax

    from mjx_emp.metrics import aggregate_phase2, mean_and_stderr
    from mjx_emp.run.evaluate import COVERAGE_SKILLS, phase2_figures

    runs = []
    for run_dir in exp.run_dirs:
        agent, _, state = jobs.load_run(Path(run_dir))
        report = {"run_dir": run_dir, **skill_figures(agent, state, jax.random.key(exp.seed))}
        phase2_dir = Path(run_dir) / store.PHASE2_SUBDIR
        if (phase2_dir / store.CONFIG_FILE).exists():
            report["phase2"] = phase2_figures(*jobs.load_phase2(phase2_dir), jax.random.key(exp.seed), exp.episodes)
        runs.append(report)
    report = {"runs": runs, "coverage_cells": mean_and_stderr([r["coverage_cells"] for r in runs])}
    with_phase2 = [r["phase2"] for r in runs if "phase2" in r]
    if with_phase2:
        report["phase2"] = aggregate_phase2(with_phase2)
    stds = [r["posterior_std"] for r in runs if r["posterior_std"] is not None]
    if stds:
        report["posterior_std"] = mean_and_stderr(stds)
    out = Path(exp.out or Path(exp.run_dirs[0]) / "eval.json")
    out.write_text(json.dumps(report, indent=1))
    cover = report["coverage_cells"]
    print(f"{len(runs)} {runs[0]['algorithm']} run(s); coverage ({COVERAGE_SKILLS} greedy skills from the initial "
          f"state, 1 m cells of goal space): {cover['mean']:.3g} ± {cover['stderr']:.2g} cells")
    if stds:
        print(f"posterior mean std: {report['posterior_std']['mean']:.3g} ± {report['posterior_std']['stderr']:.2g}")
    if with_phase2:
        p2 = report["phase2"]
        print(f"phase 2 ({len(with_phase2)} run(s), {with_phase2[0]['episodes']} episodes each): mean min distance "
              f"to goal {p2['min_distance']['mean']:.3g} ± {p2['min_distance']['stderr']:.2g}, success "
              f"{p2['success']['mean']:.3g} ± {p2['success']['stderr']:.2g}")
    print(f"wrote {out}")
    return report


def with_phase2_preset(args: list[str]) -> list[str]:
    """``phase2`` arguments with a preset first: given ``RUN_DIR ...``, the run's own preset.

    The preset is the Table-2 row whose phase-1 preset has the run's domain and n.
    """
    if not args or args[0] in PHASE2_PRESETS or args[0].startswith("-"):
        return args
    if not Path(args[0]).exists() and close_names(args[0], PHASE2_PRESETS):
        raise unknown_preset(args[0], PHASE2_PRESETS, "mjx-emp phase2 PRESET RUN_DIR")
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


def unknown_preset(name: str, known, usage: str) -> ConfigError:
    """The error for a preset name that does not exist, suggesting the closest ones."""
    closest = close_names(name, known)
    hint = f"did you mean {', '.join(closest)}? " if closest else ""
    return ConfigError(f"preset: {name!r} is unknown ({usage}); {hint}`mjx-emp presets` lists all {len(known)}")


def canonical_args(argv: list[str]) -> list[str]:
    """The command line in the one form the parser reads: ``train --resume RUN_DIR ...`` and
    ``phase2 --resume DIR ...`` are ``resume RUN_DIR ...``; ``phase2 RUN_DIR ...`` names the
    run's own Table-2 preset (:func:`with_phase2_preset`)."""
    command, rest = argv[:1], argv[1:]
    if command in (["train"], ["phase2"]):
        for i, arg in enumerate(rest):
            if arg == "--resume" and i + 1 < len(rest):
                return ["resume", rest[i + 1], *rest[:i], *rest[i + 2:]]
            if arg.startswith("--resume="):
                return ["resume", arg.split("=", 1)[1], *rest[:i], *rest[i + 1:]]
    if command == ["phase2"]:
        return ["phase2", *with_phase2_preset(rest)]
    if command == ["train"] and rest and not rest[0].startswith("-"):
        presets = all_presets()
        if rest[0] not in presets:
            raise unknown_preset(rest[0], presets, "mjx-emp train PRESET")
    return argv


def list_presets(_: PresetsExperiment) -> None:
    """Print every phase-1 and phase-2 preset with its description."""
    print("phase 1 (mjx-emp train PRESET):")
    for name, (description, _) in all_presets().items():
        print(f"  {name:24s} {description}")
    print("phase 2 (mjx-emp phase2 [PRESET] RUN_DIR):")
    for name, (description, phase1, _) in PHASE2_PRESETS.items():
        print(f"  {name:24s} {description} (on {phase1})")


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


COMMANDS: dict[str, tuple[Any, Any, str]] = {
    "train": (preset_commands, jobs.train, "Train a new run of a preset; every config field is a flag "
              "(`train --resume RUN_DIR` is `resume RUN_DIR`)."),
    "resume": (lambda: ResumeExperiment, jobs.resume, "Continue a run or phase-2 directory from its newest good "
               "checkpoint, bit for bit."),
    "phase2": (phase2_commands, jobs.train_phase2, "Phase 2: reach goals of a region with a run's skills as actions "
               "(`phase2 RUN_DIR` picks the run's own preset)."),
    "presets": (lambda: PresetsExperiment, list_presets, "List every phase-1 and phase-2 preset."),
    "eval": (lambda: EvalExperiment, evaluate, "Figures of runs' newest checkpoints (goal spaces, success, "
             "coverage; phase 2's distance), mean over runs."),
    "plot": (lambda: PlotExperiment, plot, "Draw a run's pictures into RUN_DIR/plots/."),
    "render": (lambda: RenderExperiment, render, "Film a run's greedy skills (or its phase-2 policy)."),
    "rollout": (lambda: RolloutExperiment, rollout, "Roll out a random-init k-level agent and print throughput."),
}
"""Every command: (its type, built on demand; what runs it; its one-line help)."""


def parse(argv: list[str]) -> tuple[Any, Any]:
    """(what runs the command, its parsed experiment) for a canonical command line."""
    choices = Union[tuple(  # noqa: UP007
        Annotated[make_type(), tyro.conf.subcommand(name, description=" ".join(help_text.split()))]
        for name, (make_type, _, help_text) in COMMANDS.items()
    )]
    exp = tyro.cli(choices, args=argv, prog="mjx-emp")  # exits on a missing or unknown command
    return COMMANDS[argv[0]][1], exp


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
    memory 1, no offscreen GL 3, SIGINT/SIGTERM 130/143, each with a reason."""
    failures = (
        (ConfigError, "invalid configuration", 2),
        (CheckpointError, "unusable checkpoint", 2),
        (TrainingDiverged, "training diverged", 1),
        (CheckpointWriteError, "checkpoint write failed", 1),
        (RenderError, "cannot render", 3),
    )
    try:
        command(exp)
    except Interrupted as stop:
        print(f"mjx-emp: {stop}", file=sys.stderr)
        sys.exit(128 + stop.signum)
    except tuple(kind for kind, _, _ in failures) as err:
        what, code = next((what, code) for kind, what, code in failures if isinstance(err, kind))
        print(f"mjx-emp: {what}: {err}", file=sys.stderr)
        sys.exit(code)
    except Exception as err:  # XLA's out-of-memory error is explained; anything else is a bug to report
        explanation = explain_out_of_memory(err)
        if explanation is None:
            raise
        print(f"mjx-emp: {explanation}", file=sys.stderr)
        sys.exit(1)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``mjx-emp`` console script: one parser, every command a subcommand
    (``mjx-emp --help`` lists them, ``mjx-emp COMMAND --help`` shows every flag).

    Compiled programs are cached under ``default_compile_cache()``; ``--no-compile-cache``
    (any command) compiles afresh. Bad input exits 2 naming the field (:func:`main_guarded`).
    """
    argv = use_compile_cache(sys.argv[1:] if argv is None else list(argv))
    if argv[:1] == ["render"]:
        from mjx_emp.viz.render import configure_headless_gl

        configure_headless_gl()  # before anything imports mujoco

    def parse_and_run(args: list[str]) -> None:
        command, exp = parse(canonical_args(args))
        command(exp)

    main_guarded(parse_and_run, argv)


if __name__ == "__main__":
    main()
