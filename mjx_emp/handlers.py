"""What each command does with its parsed request: ``mjx-emp COMMAND`` is ``HANDLERS[COMMAND](request)``.

:mod:`mjx_emp.cli` parses the command line into a request (:mod:`mjx_emp.commands`), imports
this module (JAX, MuJoCo and the rest load here, not for ``--help``), and calls the handler;
the handlers check what only they can, do the work through the library and print what it
gives. Training, resuming and phase 2 are :mod:`mjx_emp.run.jobs`' own, with the video the
trackers get at the end.
"""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

from mjx_emp import commands
from mjx_emp.errors import ConfigError
from mjx_emp.run import jobs, specs, store, sweep
from mjx_emp.run.evaluate import evaluate_runs, evaluation_text
from mjx_emp.run.provenance import command_line
from mjx_emp.run.throughput import random_rollout
from mjx_emp.viz.flips import plot_flips
from mjx_emp.viz.plots import plot_any_run, plot_runs
from mjx_emp.viz.render import (
    check_video,
    film_for_trackers,
    record_trained,
    render_frames,
    video_name,
    write_video,
)


def rollout(exp: commands.RolloutExperiment) -> None:
    """Roll out a random-init k-level agent and print its statistics as JSON."""
    commands.check_rollout(exp)
    print(json.dumps(random_rollout(exp), indent=1))


def plot(exp: commands.PlotExperiment) -> None:
    """Draw one run's pictures into RUN_DIR/plots/, or compare several runs in ``--out``; print the paths."""
    commands.check_distinct_runs(exp.run_dirs, "plot")
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


def render(exp: commands.RenderExperiment) -> None:
    """Write a video of a run's greedy top-level skill chain (or phase-2 policy), every level's goal
    drawn; for a flat skill learner, its greedy skills from the prior one after another."""
    commands.check_render(exp)
    out = Path(exp.out or Path(exp.run_dir) / video_name(exp.phase2))
    check_video(out, exp.width, exp.height)  # before the run is loaded
    if exp.out:
        store.output_target(out, "out")
    if exp.phase2:
        phase2_dir = store.own_phase2(exp.run_dir)
        if phase2_dir is None:
            raise ConfigError(f"phase2: {str(Path(exp.run_dir) / store.PHASE2_SUBDIR)!r} holds no phase-2 run; train one with "
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


def run_sweep(exp: commands.SweepExperiment) -> None:
    """Check the spec, say what it holds, then run what is not done."""
    spec = specs.load_spec(exp.spec)  # a bad spec exits 2 here, before anything trains
    for line in specs.describe_plan(spec):
        print(line)
    written = sweep.sweep(exp.spec, exp.runs, exp.results, exp.workers, exp.executor, exp.dry_run)
    if not exp.dry_run:
        print(f"sweep {spec.name}: {len(written)} row(s) written this call")


def evaluate(exp: commands.EvalExperiment) -> dict:
    """Each run's evaluation row (:func:`mjx_emp.run.evaluate.evaluate_runs`, the evaluation
    `mjx-emp sweep` writes its rows with), aggregated over runs, printed and written as JSON
    (``runs`` holds the rows), with the flip figure beside it where there is a flip table."""
    commands.check_eval(exp)
    if exp.out:
        store.output_target(Path(exp.out), "out")  # a place it cannot write is refused before the evaluation runs
    if exp.flip_figure:
        store.output_target(Path(exp.flip_figure), "flip_figure")
    out = Path(exp.out or Path(exp.run_dirs[0]) / "eval.json")
    report = evaluate_runs([Path(d) for d in exp.run_dirs], exp.seed, exp.episodes,
                           command_line(["mjx-emp", *sys.argv[1:]]), exp.coverage_draws)
    store.write_atomically(out, json.dumps(report, indent=1), chosen=bool(exp.out))
    print(evaluation_text(report))
    print(f"wrote {out}")
    if report.get("flip_table") is not None:
        figure = Path(exp.flip_figure or out.with_name("flips.png"))
        print(f"wrote {plot_flips(report['flip_table']['levels'], report['flip_table']['phase2'], figure)}")
    return report


def export(exp: commands.ExportExperiment) -> None:
    """Write the skills export and say how big it is beside the run's checkpoints."""
    out, epoch = jobs.export_skills(exp)
    whole = store.directory_megabytes(Path(exp.run_dir) / store.CHECKPOINT_SUBDIR / str(epoch))
    print(f"exported the skills of {exp.run_dir} (epoch {epoch}) to {out}: {store.directory_megabytes(out):.1f} MB, "
          f"against {whole:.1f} MB for the run's checkpoint", flush=True)


HANDLERS: dict[str, Callable[[Any], Any]] = {
    "train": functools.partial(jobs.train, film=film_for_trackers),
    "resume": functools.partial(jobs.resume, film=film_for_trackers),
    "phase2": functools.partial(jobs.train_phase2, film=film_for_trackers),
    "export": export,
    "eval": evaluate,
    "plot": plot,
    "render": render,
    "rollout": rollout,
    "sweep": run_sweep,
}
"""Each command's handler, by the command's name; ``presets`` and ``report``, which need no JAX,
are the command line's own (:func:`mjx_emp.cli.run_command`)."""
