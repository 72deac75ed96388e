"""What the commands do with a run directory: train a new run, resume one, train phase 2 on a
run's skills, and load a run's agent and newest good checkpoint. Each command checks its
request once, where it starts.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

import jax

from mjx_emp.algos.registry import (
    algorithm_of,
    make_agent,
)
from mjx_emp.commands import (
    ExportExperiment,
    Phase2Experiment,
    ResumeExperiment,
    Tracking,
    TrainExperiment,
    check_export,
    check_phase2,
    check_resume,
    check_train,
    resumed_stops,
)
from mjx_emp.errors import ConfigError, RenderError
from mjx_emp.phase2.build import make_phase2_trainer
from mjx_emp.phase2.config import Phase2Config
from mjx_emp.phase2.presets import OWN_TASK, PHASE2_PRESETS, phase2_preset_for
from mjx_emp.run import loop
from mjx_emp.run.checkpoint import Checkpoints
from mjx_emp.run.devices import ShardedAgent, choose_devices, shard_slice
from mjx_emp.run.hosts import is_lead, join_hosts, wait_for_all
from mjx_emp.run.loop import Member, env_steps_of, epoch_of, progress_reporter
from mjx_emp.run.preflight import preflight
from mjx_emp.run.provenance import EXPORT_OF
from mjx_emp.run.seeds import resume_seeds, seed_group_of, train_seeds
from mjx_emp.run.store import (
    CONFIG_FILE,
    METRICS_FILE,
    PHASE2_SUBDIR,
    SKILLS_FILE,
    config_json,
    default_run_dir,
    fresh_run_dir,
    keep_metrics_through,
    newest_checkpoint_on_disk,
    own_phase2,
    read_run_config,
    read_run_record,
    run_lock,
    write_atomically,
    write_config,
    write_run_record,
)
from mjx_emp.run.tracking import Film, Trackers, open_trackers


def _train_run(program, state, run_dir: Path, keep_checkpoints: int, tracking: Tracking,
               on_epoch: Callable[[dict], None] | None = None, film: Film | None = None):
    """One run through the training loop (:func:`mjx_emp.run.loop.train`), which owns its
    checkpoints, after the run's config.json is written (by the lead, with several hosts): each
    epoch's metrics go to the progress display, to the trackers ``tracking`` asks for and to
    ``on_epoch``; at the end the trackers get ``film``'s video."""
    if is_lead():
        write_config(run_dir, program.cfg)
    with open_trackers(tracking, run_dir, config_json(program.cfg)) as trackers:
        with progress_reporter(program.cfg.epochs, epoch_of(state), program.describe) as show:
            state = loop.train(program, state, [Member(program, run_dir)], keep_checkpoints,
                               (show, trackers and trackers.log, on_epoch))
        if trackers is not None and film is not None and tracking.video_steps:
            _film_for_trackers(trackers, film, program, state, run_dir, tracking.video_steps)
        return state


def _film_for_trackers(trackers: Trackers, film: Film, trainer, state, run_dir: Path, steps: int) -> None:
    """Hand the trackers a video of the trained run (the lead process films); without offscreen
    GL the run still ends as trained, with a note on stderr."""
    if not is_lead():
        return
    print(f"filming {steps} steps of the trained run for the trackers ...", flush=True)
    try:
        video = film(trainer, state, run_dir, steps)
    except RenderError as err:
        print(f"mjx-emp: no video for the trackers: {err}", file=sys.stderr, flush=True)
        return
    trackers.log_video(video)
    print(f"{video.path}: logged to the trackers", flush=True)


def training_program(cfg, num_devices: int = 0):
    """What trains a run of ``cfg``: its agent, or for a run split into shards a
    :class:`~mjx_emp.run.devices.ShardedAgent` over ``num_devices`` local devices (0: as
    many as divide the shards)."""
    if cfg.shards == 1 and num_devices <= 1:
        return make_agent(cfg)
    return ShardedAgent(cfg, choose_devices(cfg.shards, num_devices))


def split_for_devices(cfg, num_devices: int):
    """A new run's config with its shards set from ``--num-devices``: an unsplit config
    becomes one shard per device (``num_devices`` 0: every local device); a config that
    sets its shards keeps them."""
    if cfg.shards > 1:
        return cfg
    if num_devices == 0:
        num_devices = jax.device_count()  # every device of every process
    return dataclasses.replace(cfg, shards=num_devices) if num_devices > 1 else cfg


def train(exp: TrainExperiment, on_epoch: Callable[[dict], None] | None = None, film: Film | None = None,
          record: dict | None = None):
    """Train a new run of the config's algorithm (with ``exp.seeds``, one run per seed under one
    vmap: :mod:`mjx_emp.run.seeds`; split over devices per ``exp.num_devices``: :mod:`mjx_emp.run.devices`);
    returns the final state. ``on_epoch`` (one run, not a seed group) sees each epoch's metrics;
    ``film`` makes the video the trackers get at the end (no video without it); ``record`` (how the
    run was asked for, :func:`mjx_emp.run.provenance.run_record`) is kept in each run directory."""
    check_train(exp)
    several = join_hosts(exp.coordinator_address, exp.num_processes, exp.process_id, exp.join_timeout)
    if exp.seeds:
        if several:
            raise ConfigError("seeds: a seed group trains in one process; drop --seeds or the coordinator")
        if on_epoch is not None:
            raise ConfigError("seeds: a progress callback follows one run; train the seeds one by one")
        return train_seeds(exp, record)
    cfg = split_for_devices(exp.config, exp.num_devices)
    if several and not exp.run_dir:
        raise ConfigError("run_dir: several hosts must be given the same --run-dir (on a shared filesystem)")
    trainer = training_program(cfg, exp.num_devices)
    check_memory(trainer)  # before anything is allocated or written
    run_dir = fresh_run_dir(exp.run_dir or default_run_dir(cfg), "run_dir", "a run", "mjx-emp train")
    wait_for_all("mjx-emp: every process checked the run directory")  # before the lead writes into it
    print(f"run directory: {run_dir}", flush=True)
    with run_lock(run_dir, "run_dir"):
        if record is not None and is_lead():
            write_run_record(run_dir, record)
        if cfg.shards > 1:
            print(f"split into {cfg.shards} shards on {trainer.num_devices} device(s)", flush=True)
        return _train_run(trainer, trainer.init(), run_dir, exp.keep_checkpoints, exp.tracking, on_epoch, film)


def check_memory(program) -> None:
    """The memory preflight (:mod:`mjx_emp.run.preflight`) of what trains a run, before it allocates."""
    agent = getattr(program, "alone", program)  # a split run: one shard's agent sees the environment
    preflight(program, program.cfg, agent.env, getattr(program, "num_devices", 1))


def _restore(run_dir: Path, trainer, template, fallback: bool = False, epoch: int | None = None,
             writer: bool = False, epoch_field: str = "phase1_epoch"):
    """``(epoch, state)`` of ``run_dir``'s newest good checkpoint, or of ``epoch``'s, for ``trainer``.

    Only the run's ``writer`` (a resume, holding the run's lock) may change the checkpoint folder
    (set aside unusable newer checkpoints, remove half-written ones); any other caller reads."""
    with Checkpoints(run_dir, read_only=not writer) as checkpoints:
        epochs = checkpoints.epochs()
        left_out = checkpoints.left_out(epochs[-1]) if writer and epochs else []
        if left_out:
            raise ConfigError(f"resume: {run_dir} is a skills export (its checkpoint holds no "
                              f"{', '.join(left_out)}); phase 2, eval, plot and render read it, "
                              "training cannot continue from it")
        if epoch is None:
            return checkpoints.restore_latest(template, trainer.cfg, fallback)
        if epoch not in epochs:
            raise ConfigError(f"{epoch_field}: {run_dir} has checkpoints of epochs {epochs}; got {epoch}")
        return epoch, checkpoints.restore(epoch, template, trainer.cfg)


def _with_stops(cfg, stops: dict | None):
    """``cfg`` with the loop fields in ``stops`` replaced (the settings a resume may change)."""
    return dataclasses.replace(cfg, **stops) if stops else cfg


def load_run(run_dir: Path, field: str = "run_dir", epoch: int | None = None, epoch_field: str = "phase1_epoch"):
    """A run's agent and its newest good checkpoint (or ``epoch``'s), to read: ``(agent, epoch,
    state)``. ``field`` is the CLI field that errors about ``run_dir`` name."""
    cfg = read_run_config(Path(run_dir), field)
    if cfg.shards > 1:  # a split run: shard 0's state (its networks are every shard's) and agent
        program = ShardedAgent(cfg, 1)
        epoch, state = _restore(Path(run_dir), program, jax.eval_shape(program.init), epoch=epoch,
                                epoch_field=epoch_field)
        return program.alone, epoch, shard_slice(state, 0)
    trainer = make_agent(cfg)
    epoch, state = _restore(Path(run_dir), trainer, jax.eval_shape(trainer.init), epoch=epoch, epoch_field=epoch_field)
    return trainer, epoch, state


def export_skills(exp: ExportExperiment) -> tuple[Path, int]:
    """Write RUN_DIR's skills (see :class:`ExportExperiment`) to OUT; returns OUT and the epoch exported."""
    check_export(exp)
    if (Path(exp.run_dir) / SKILLS_FILE).exists():
        raise ConfigError(f"run_dir: {exp.run_dir} is a phase-2 directory; export the phase-1 run it was trained on")
    agent, epoch, state = load_run(Path(exp.run_dir), epoch=None if exp.epoch < 0 else exp.epoch, epoch_field="epoch")
    out = fresh_run_dir(exp.out, "out", "a skills export", None)
    with run_lock(out, "out"):
        write_config(out, agent.cfg)
        write_run_record(out, {**read_run_record(Path(exp.run_dir)), EXPORT_OF: str(exp.run_dir), "epoch": epoch})
        metrics = Path(exp.run_dir) / METRICS_FILE
        if metrics.exists():
            shutil.copyfile(metrics, out / METRICS_FILE)
            keep_metrics_through(out / METRICS_FILE, epoch)
        with Checkpoints(out, keep=1) as checkpoints:
            checkpoints.save(epoch, state, agent.cfg, leave_out=algorithm_of(agent.cfg).rebuilt_fields)
    return out, epoch


def load_program(run_dir: Path, fallback: bool = False, stops: dict | None = None, field: str = "resume",
                 num_devices: int = 0):
    """What trains a run on (see :func:`training_program`) and its newest good checkpoint,
    placed on the program's devices: ``(program, epoch, state)``. For the run's writer (a resume)."""
    program = training_program(_with_stops(read_run_config(Path(run_dir), field), stops), num_devices)
    epoch, state = _restore(Path(run_dir), program, jax.eval_shape(program.init), fallback, writer=True)
    return program, epoch, (program.place(state) if hasattr(program, "place") else state)


def _resume(exp: ResumeExperiment, load: Callable, start_over: Callable, film: Film | None = None):
    """Continue a run directory from its newest good checkpoint (``load`` restores it); one that
    a kill stopped before its first checkpoint starts over with what ``start_over`` builds."""
    check_resume(exp)
    run_dir = Path(exp.resume)
    if not (run_dir / CONFIG_FILE).exists():  # a directory that is no run is refused before anything is written
        raise ConfigError(f"resume: {str(run_dir)!r} has no {CONFIG_FILE}; is it a run directory?")
    with run_lock(run_dir, "resume"):
        if newest_checkpoint_on_disk(run_dir) is None:
            trainer = start_over(run_dir, exp)
            print(f"{run_dir} was stopped before its first checkpoint; starting it over from its {CONFIG_FILE}",
                  flush=True)
            keep_metrics_through(run_dir / METRICS_FILE, 0)
            return _train_run(trainer, trainer.init(), run_dir, exp.keep_checkpoints, exp.tracking, film=film)
        trainer, epoch, state = load(run_dir, exp.fallback, resumed_stops(exp), field="resume")
        if trainer.cfg.epochs < epoch:  # before anything is rewritten
            raise ConfigError(f"epochs: {run_dir} is at epoch {epoch}; give at least that many; got {trainer.cfg.epochs}")
        steps = env_steps_of(state)
        if exp.max_env_steps and steps >= exp.max_env_steps:  # a budget already spent would train nothing
            raise ConfigError(f"max_env_steps: {run_dir} is at {steps} env steps (epoch {epoch}); give a larger "
                              f"budget, or 0 to lift it; got {exp.max_env_steps}")
        print(f"resuming {run_dir} from epoch {epoch}", flush=True)
        keep_metrics_through(run_dir / METRICS_FILE, epoch)
        return _train_run(trainer, state, run_dir, exp.keep_checkpoints, exp.tracking, film=film)


def resume(exp: ResumeExperiment, film: Film | None = None):
    """Continue a run directory from its newest good checkpoint: a phase-2 directory (it holds
    skills.json) as :func:`resume_phase2` does, a phase-1 run on ``exp.num_devices`` devices
    otherwise; returns the final state."""
    if exp.phase2 and not (Path(exp.resume) / SKILLS_FILE).exists():
        phase2_dir = own_phase2(exp.resume)
        if phase2_dir is None:
            raise ConfigError(f"resume: {exp.resume} holds no phase 2 to continue; start one with "
                              f"`mjx-emp phase2 {exp.resume}`")
        exp = dataclasses.replace(exp, resume=str(phase2_dir))
    if (Path(exp.resume) / SKILLS_FILE).exists():
        return resume_phase2(exp, film)
    group = seed_group_of(Path(exp.resume))
    if exp.group:
        return _resume_group(exp, group)
    if len(group) > 1:
        print(f"note: {exp.resume} trained in one program with {len(group) - 1} other seed(s); resumed alone it "
              f"drifts from the group in the last bits (a program of another batch shape); `mjx-emp resume "
              f"{exp.resume} --group` continues the group as one", file=sys.stderr, flush=True)
    return _resume(exp, functools.partial(load_program, num_devices=exp.num_devices), _program_from_config, film)


def _resume_group(exp: ResumeExperiment, group: list[Path]):
    """``exp`` for every run of a seed group, as one program (:func:`mjx_emp.run.seeds.resume_seeds`)."""
    check_resume(exp)
    if len(group) < 2:
        raise ConfigError(f"group: {exp.resume} was trained alone, not in a seed group; resume it without --group")
    if exp.tracking.on() or exp.num_devices > 1 or exp.fallback:
        raise ConfigError("group: a seed group resumes on one device, untracked, from checkpoints every seed has; "
                          "drop --tensorboard/--wandb, --num-devices and --fallback")
    missing = [str(d) for d in group if newest_checkpoint_on_disk(d) is None]
    if missing:
        raise ConfigError(f"group: {', '.join(missing)} hold no checkpoint; resume the others alone")
    configs = [_with_stops(read_run_config(d, "resume"), resumed_stops(exp)) for d in group]
    return resume_seeds(group, configs, exp.keep_checkpoints)


def _program_from_config(run_dir: Path, exp: ResumeExperiment):
    """What trains RUN_DIR afresh from its config.json (a run stopped before its first checkpoint)."""
    return training_program(_with_stops(read_run_config(run_dir, "resume"), resumed_stops(exp)), exp.num_devices)


def _phase2_without_checkpoint(run_dir: Path, exp: ResumeExperiment):
    """A phase-2 directory stopped before its first checkpoint holds no frozen skills to go on
    from: say how to start it again (``mjx-emp phase2`` reuses such a directory)."""
    raise ConfigError(f"resume: {run_dir} was stopped before its first checkpoint and holds no skills to go on "
                      f"from; start it again with `mjx-emp phase2 PHASE1_RUN_DIR --out {run_dir}`")


def train_phase2(exp: Phase2Experiment, film: Film | None = None, record: dict | None = None):
    """Train phase 2 on a phase-1 run's skills in a new phase-2 directory; returns the final state.
    ``record`` (how it was asked for) is kept in the directory, as :func:`train` keeps it."""
    check_phase2(exp)
    requested = None if exp.config.phase1_epoch < 0 else exp.config.phase1_epoch
    skills, epoch, skills_state = load_run(Path(exp.run_dir), field="run_dir", epoch=requested)
    if exp.own_task is not None:
        exp, record = own_task(exp, skills.cfg, record)
    cfg = dataclasses.replace(exp.config, phase1_epoch=epoch)
    trainer = make_phase2_trainer(skills, cfg)
    out = fresh_run_dir(exp.out or str(Path(exp.run_dir) / PHASE2_SUBDIR), "out", "a phase-2 run", "mjx-emp phase2")
    with run_lock(out, "out"):
        print(f"phase 2 on the skills of {exp.run_dir} (epoch {epoch}), writing to {out}", flush=True)
        write_atomically(out / SKILLS_FILE, json.dumps(config_json(skills.cfg), indent=1))
        if record is not None:
            write_run_record(out, record)
        return _train_run(trainer, trainer.init(skills_state), out, exp.keep_checkpoints, exp.tracking, film=film)


def own_task(exp: Phase2Experiment, skills_cfg, record: dict | None) -> tuple[Phase2Experiment, dict | None]:
    """``exp`` as the run's own phase-2 task (:func:`mjx_emp.phase2.presets.phase2_preset_for`)
    with the fields ``exp.own_task`` names taken from ``exp.config``; ``record`` names that task,
    and its command names it in place of ``own``."""
    preset = phase2_preset_for(skills_cfg)
    if preset is None:
        raise ConfigError(f"run_dir: no phase-2 preset is built on env={skills_cfg.env} n={tuple(skills_cfg.n)}; "
                          f"name one before the run directory (mjx-emp phase2 PRESET RUN_DIR); presets: "
                          f"{sorted(PHASE2_PRESETS)}")
    given = {name: getattr(exp.config, name) for name in exp.own_task}
    cfg = dataclasses.replace(PHASE2_PRESETS[preset][2], **given)
    print(f"phase 2 task: {preset} (the run's own){' with ' + ', '.join(exp.own_task) if given else ''}", flush=True)
    if record is not None:  # the task picked, and the command that names it
        command = record.get("command")
        record = {**record, "preset": preset, "command": command.replace(f" phase2 {OWN_TASK} ", f" phase2 {preset} ", 1)
                  if isinstance(command, str) else command}
    return dataclasses.replace(exp, config=cfg, own_task=None), record


def load_phase2(phase2_dir: Path, fallback: bool = False, stops: dict | None = None, field: str = "run_dir",
                writer: bool = False):
    """A phase-2 directory's trainer and newest good checkpoint: ``(trainer, epoch, state)``.

    The directory stands on its own: it holds the phase-1 config and the frozen skills.
    ``writer``: the caller holds the directory's lock to continue it (see :func:`_restore`).
    """
    phase2_dir = Path(phase2_dir)
    cfg = _with_stops(read_run_config(phase2_dir, field, Phase2Config), stops)
    trainer = make_phase2_trainer(make_agent(read_run_config(phase2_dir, field, file=SKILLS_FILE)), cfg)
    template = jax.eval_shape(trainer.init, jax.eval_shape(trainer.phase1.init))
    epoch, state = _restore(phase2_dir, trainer, template, fallback, writer=writer)
    return trainer, epoch, state


def load_run_phase2(run_dir: Path) -> tuple | None:
    """A phase-1 run's own phase 2 (RUN_DIR/phase2) as :func:`load_phase2` gives it, or None
    where the run has none, for evaluations that report phase 2 beside phase 1."""
    phase2_dir = own_phase2(run_dir)
    return None if phase2_dir is None else load_phase2(phase2_dir)


def resume_phase2(exp: ResumeExperiment, film: Film | None = None):
    """Continue a phase-2 directory from its newest good checkpoint; returns the final state."""
    return _resume(exp, functools.partial(load_phase2, writer=True), _phase2_without_checkpoint, film)
