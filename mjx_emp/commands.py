"""The commands a user can give, as typed dataclasses: the CLI's vocabulary.

Plain data (tyro annotations, no JAX import): the CLI parses them, and the run layer and
experiment scripts take them as requests. Domain names come from the registry, so the
rollout command offers exactly the domains that exist.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated, Generic, Literal, TypeVar

import tyro

from mjx_emp.checks import check_levels, check_seed
from mjx_emp.envs.registry import DOMAIN_NAMES
from mjx_emp.errors import ConfigError
from mjx_emp.phase2.config import Phase2Config

ConfigT = TypeVar("ConfigT")


@dataclasses.dataclass(frozen=True)
class Tracking:
    """Where else the metrics go, beside metrics.jsonl (:mod:`mjx_emp.run.tracking`; needs
    ``pip install "mjx-emp[tracking]"``)."""

    tensorboard: bool = False
    """Also write TensorBoard event files to RUN_DIR/tensorboard (x axis: env steps)."""
    wandb: bool = False
    """Also log to a Weights & Biases run (offline into RUN_DIR/wandb unless WANDB_API_KEY is set)."""
    wandb_project: str = "mjx-emp"
    """W&B project."""
    wandb_group: str = ""
    """W&B group, e.g. one per preset to compare seeds; empty: none."""
    wandb_name: str = ""
    """W&B run name; empty: the run directory's name."""
    wandb_mode: Literal["auto", "online", "offline"] = "auto"
    """auto: online with WANDB_API_KEY set, offline otherwise."""
    video_steps: int = 200
    """When training ends, film this many steps of the trained run (640x480, as `mjx-emp render`
    does, into RUN_DIR) and log the video to the trackers; 0: no video. Without offscreen GL
    (EGL or OSMesa) the run ends with a note instead of the video."""

    def on(self) -> bool:
        """Whether any tracker is asked for."""
        return self.tensorboard or self.wandb


@dataclasses.dataclass(frozen=True)
class TrainExperiment(Generic[ConfigT]):
    """Training of any registered algorithm (Hierarchical Empowerment's phase 1, or a baseline).

    RUN_DIR receives config.json, metrics.jsonl (one line per epoch) and checkpoints/ (an
    orbax checkpoint after every epoch; continue with `mjx-emp resume RUN_DIR`).
    """

    config: Annotated[ConfigT, tyro.conf.OmitArgPrefixes]
    run_dir: str = ""
    """Run directory; empty picks runs/<env>-k<k>-<date>-<time>. Must not hold a run already."""
    keep_checkpoints: int = 3
    """How many of the newest epoch checkpoints to keep."""
    num_devices: int = 0
    """Local devices to train on. An unsplit config is split into one shard per device (its
    environments, minibatch and buffers divided among them, gradients averaged; see
    ``--shards``); 0: every local device (one on a machine with one GPU or a CPU)."""
    coordinator_address: str = ""
    """Several hosts: host:port of process 0's coordinator (or JAX_COORDINATOR_ADDRESS); every
    process runs the same command with its --process-id and the same --run-dir."""
    num_processes: int = 0
    """Several hosts: how many processes (or JAX_NUM_PROCESSES)."""
    process_id: int = -1
    """Several hosts: this process's index, 0 the lead (or JAX_PROCESS_ID)."""
    join_timeout: int = 300
    """Several hosts: seconds to wait for every process to join the coordinator before giving up."""
    seeds: tuple[int, ...] = ()
    """Train these seeds of the config together, as one vmapped program (the config's own seed
    is then unused); each seed gets its own run directory RUN_DIR-s<seed>, resumable and
    evaluable on its own. Empty: one run of the config's seed."""
    tracking: Annotated[Tracking, tyro.conf.OmitArgPrefixes] = Tracking()
    """TensorBoard and W&B beside metrics.jsonl."""


@dataclasses.dataclass(frozen=True)
class ResumeExperiment:
    """Continue a run from its latest good checkpoint, bit for bit as if never stopped."""

    resume: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """Run directory written by `mjx-emp train`, or a phase-2 directory written by `mjx-emp phase2`."""
    epochs: int | None = None
    """New total number of epochs (default: the run's own)."""
    max_env_steps: int | None = None
    """New environment-step budget (default: the run's own; 0 lifts it). With ``epochs``, the
    only settings a resume may change: neither alters what an epoch computes."""
    fallback: bool = False
    """If the newest checkpoint is unusable, resume from the newest one that restores."""
    group: bool = False
    """Continue every run of RUN_DIR's seed group (seeds trained in one program, `train --seeds`)
    as one program again, so that each ends where the uninterrupted group would; resumed alone,
    a seed of a group runs a program of another batch shape and drifts from it in the last bits."""
    phase2: bool = False
    """Continue the run's phase 2 (RUN_DIR/phase2, or RUN_DIR itself if it is a phase-2 directory);
    a run without one is refused (`mjx-emp phase2 --resume RUN_DIR` means this)."""
    keep_checkpoints: int = 3
    """How many of the newest epoch checkpoints to keep."""
    num_devices: int = 0
    """Local devices a run split into shards trains on (any count that divides its shards;
    0: as many as divide them)."""
    tracking: Annotated[Tracking, tyro.conf.OmitArgPrefixes] = Tracking()
    """TensorBoard and W&B beside metrics.jsonl."""


@dataclasses.dataclass(frozen=True)
class ExportExperiment:
    """Copy a phase-1 run's skills into a new, small run directory: its config, metrics and one
    checkpoint without what training refills as it goes (replays, environments mid-episode;
    the algorithm's ``rebuilt_fields``). Phase 2, eval, plot and render read the export as they
    read the run; resume refuses it. A checkpoint of a large run is mostly replay: the export
    is what to move between machines."""

    run_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """Phase-1 run directory written by `mjx-emp train`."""
    out: Annotated[str, tyro.conf.arg(metavar="OUT")]
    """The export's directory; must not hold a run already."""
    epoch: int = -1
    """The checkpoint to export; -1: the newest."""


@dataclasses.dataclass(frozen=True)
class PresetsExperiment:
    """List every preset: phase 1 (`mjx-emp train PRESET`) and phase 2 (`mjx-emp phase2 PRESET RUN_DIR`)."""


@dataclasses.dataclass(frozen=True)
class Phase2Experiment:
    """Phase 2 of Hierarchical Empowerment: learn to reach goals drawn uniformly from a fixed
    region, with the phase-1 run's top-level skills as actions (for a flat skill learner's
    run: its skills z, each run for the skill's length).

    Writes to OUT (default RUN_DIR/phase2): config.json, skills.json (the phase-1 config),
    metrics.jsonl and checkpoints/ (one per epoch; continue with
    `mjx-emp resume OUT`).
    """

    run_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """Phase-1 run directory written by `mjx-emp train`."""
    config: Annotated[Phase2Config, tyro.conf.OmitArgPrefixes]
    out: str = ""
    """Phase-2 directory; empty means RUN_DIR/phase2. Must not hold a phase-2 run already."""
    keep_checkpoints: int = 3
    """How many of the newest epoch checkpoints to keep."""
    tracking: Annotated[Tracking, tyro.conf.OmitArgPrefixes] = Tracking()
    """TensorBoard and W&B beside metrics.jsonl."""
    own_task: Annotated[tuple[str, ...] | None, tyro.conf.Suppress] = None
    """Set (by `mjx-emp phase2 RUN_DIR`, the ``own`` task): train the run's own task, its fields
    replaced only where named here (the others of ``config`` are defaults, not choices)."""


@dataclasses.dataclass(frozen=True)
class EvalExperiment:
    """Phase-1 figures of each run's newest checkpoint (goal-space extent per level and greedy
    goal-conditioned success on goals from its own goal space) and, where RUN_DIR/phase2
    exists, the paper's phase-2 figure: the mean over episodes of the minimum distance to
    goal. Several runs (seeds) are aggregated to mean and standard error."""

    run_dirs: Annotated[tuple[str, ...], tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """Run directories written by `mjx-emp train` (one per seed)."""
    episodes: int = 400
    """Evaluation episodes per level and run, and phase-2 episodes per run (each rounded up
    to whole batches of num_envs)."""
    seed: int = 0
    """Seed of the evaluation goals and start states."""
    coverage_draws: int = 1
    """Draws of 48 skills that coverage is averaged over (its spread over draws is reported
    beside it when more than one)."""
    out: str = ""
    """JSON output; empty means eval.json in the first run directory."""
    flip_figure: str = ""
    """PNG of where the skills flip the robot (goal-space algorithms); empty means flips.png
    beside the JSON output."""


@dataclasses.dataclass(frozen=True)
class PlotExperiment:
    """Draw a run's pictures into RUN_DIR/plots/ (goal-space growth or skill learning curves, the
    skills at epoch 0 and now on shared axes, phase 2's curves); or, given several runs (seeds,
    methods), compare them: each method's mean over seeds with a one-std band against env steps."""

    run_dirs: Annotated[tuple[str, ...], tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """Run directories written by `mjx-emp train`: one for its pictures, several to compare."""
    out: str = ""
    """Folder of the comparison charts (several runs); empty means ./plots."""


@dataclasses.dataclass(frozen=True)
class RenderExperiment:
    """Film the greedy chain of top-level skills from RUN_DIR's newest checkpoint (or, with
    --phase2, the phase-2 policy reaching goals from its region) as an MP4 or a GIF: every
    level's subgoal in its own colour, a fading trail of h(s), the top goal-space box on the floor."""

    run_dir: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN_DIR")]
    """Run directory written by `mjx-emp train`."""
    steps: int = 200
    """Primitive steps (frames) to record."""
    width: int = 640
    """Frame width in pixels (even, for an MP4)."""
    height: int = 480
    """Frame height in pixels (even, for an MP4)."""
    fps: float = 10.0
    """Frames per second of the video (one frame is one control step)."""
    camera: Literal["fixed", "follow"] = "fixed"
    """fixed: one view that holds every position, goal and the top box of the recording;
    follow: track the torso from --distance."""
    distance: float = 6.0
    """Camera distance from the torso with --camera follow."""
    seed: int = 0
    """Seed of the skills drawn from the top goal space (or of the phase-2 goals)."""
    phase2: bool = False
    """Film the phase-2 policy of RUN_DIR/phase2 instead of the skill chain."""
    out: str = ""
    """Output video, .mp4 or .gif; empty means RUN_DIR/skills.mp4 (RUN_DIR/phase2.mp4 with --phase2)."""


@dataclasses.dataclass(frozen=True)
class SweepExperiment:
    """Train, resume and evaluate every run of a spec (a TOML file of rows: preset, overrides,
    seeds, budget, phase 2, evaluation; :mod:`mjx_emp.run.sweep`). A second call trains nothing
    that is finished and evaluates nothing whose row is stored; an interrupted one resumes."""

    spec: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SPEC")]
    """The spec file, e.g. experiments/smoke-point-mass.toml."""
    runs: str = ""
    """Runs root: each run is RUNS/<spec name>/<row>-s<seed>; empty: the spec's ``runs`` (default runs/sweeps)."""
    results: str = ""
    """The rows file; empty: results/<spec name>.jsonl."""
    workers: int = 1
    """Local worker processes, one row's job each at a time."""
    executor: Literal["local", "submitit-local", "slurm"] = "local"
    """local: worker processes on this machine; slurm: one Slurm job per row through submitit (the
    spec's [slurm] table holds its parameters); submitit-local: submitit's local executor."""
    dry_run: bool = False
    """Check the spec and say what a call would do; train nothing."""


@dataclasses.dataclass(frozen=True)
class ReportExperiment:
    """Tables and seed-band figures of a spec's rows: per row n, mean ± std (se) and the IQM with
    its 95 % stratified-bootstrap interval; with --baseline, the probability of improvement."""

    spec: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SPEC")]
    """The spec file whose rows are reported (its rows' order and names)."""
    results: str = ""
    """The rows file; empty: results/<spec name>.jsonl."""
    metrics: tuple[str, ...] = ()
    """Metrics to report (`mjx-emp report SPEC --metrics phase2_min_distance coverage_cells`); empty: the
    spec's own, else every metric the rows hold."""
    baseline: str = ""
    """A row name: also give each other row's probability of improvement over it."""
    figure: str = ""
    """Also draw a seed-band figure of a curve (``--curve``) to this PNG."""
    curve: str = "top_volume"
    """The curve the figure shows: top_volume, top_success or phase2_min_distance."""
    into: str = ""
    """A Markdown file whose block ``--block`` (between <!-- report:NAME --> and <!-- /report:NAME -->) gets the table."""
    block: str = ""
    """The block's name; empty: the spec's name."""
    reps: int = 2000
    """Bootstrap resamples per interval."""
    flip_table: str = ""
    """A row name: instead of the table of metrics, that row's flip table pooled over its runs,
    as `mjx-emp eval` prints it (goal-space algorithms' rows)."""


EnvName = Literal[DOMAIN_NAMES]


@dataclasses.dataclass(frozen=True)
class RolloutExperiment:
    """Hierarchical rollout of a k-level agent with random-init MLP policies."""

    env: EnvName = "point_mass"
    """Domain to simulate."""
    n: tuple[int, ...] = (20, 10)
    """Max actions per level, bottom first; its length is k."""
    eps: tuple[float, ...] = (0.6, 1.2)
    """Goal threshold per level (distance in goal space), bottom first."""
    subgoal_half_width: tuple[float, ...] = (2.0,)
    """Half-width of the subgoal box each level above 0 outputs (one per upper level)."""
    root_goal_half_width: float = 4.0
    """Root goals are drawn uniformly within this distance of the start position."""
    batch_size: int = 256
    """Environments simulated in parallel."""
    steps: int = 400
    """Primitive actions per environment per call."""
    calls: int = 3
    """Timed calls after the compiling one."""
    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer widths of every policy MLP."""
    seed: int = 0


def _check_keep(keep_checkpoints: int) -> None:
    if keep_checkpoints < 1:
        raise ConfigError(f"keep_checkpoints: must be >= 1; got {keep_checkpoints}")


def _check_devices(num_devices: int) -> None:
    if num_devices < 0:
        raise ConfigError(f"num_devices: must be >= 0 (0: every local device); got {num_devices}")


MAX_FRAMES = 100_000
"""The longest video a command films (about 2.8 hours at 10 frames per second)."""
MAX_FRAME_SIDE = 8192
"""The widest and tallest frame (OpenGL's offscreen buffers stop at 8192-16384 pixels)."""
MAX_EPISODES = 10**7
"""The most evaluation episodes per level that `mjx-emp eval` rolls out."""
MAX_COVERAGE_DRAWS = 1000
"""The most draws of coverage skills an evaluation averages over."""


def _check_tracking(tracking: Tracking) -> None:
    if not 0 <= tracking.video_steps <= MAX_FRAMES:
        raise ConfigError(f"video_steps: must be in [0, {MAX_FRAMES}] (0: no video); got {tracking.video_steps}")


def check_train(exp: TrainExperiment) -> None:
    """Refuse a training request's own fields before anything is built or written:
    ``keep_checkpoints``, ``num_devices``, tracking and ``seeds`` (the config itself is checked
    where its agent is built, :func:`mjx_emp.algos.registry.make_agent`)."""
    _check_keep(exp.keep_checkpoints)
    _check_devices(exp.num_devices)
    _check_tracking(exp.tracking)
    if not exp.seeds:
        return
    if len(set(exp.seeds)) != len(exp.seeds) or any(seed < 0 for seed in exp.seeds):
        raise ConfigError(f"seeds: must be distinct integers >= 0; got {list(exp.seeds)}")
    if exp.config.shards > 1 or exp.num_devices > 1:
        raise ConfigError(f"seeds: a seed group trains on one device, unsplit; got shards={exp.config.shards}, "
                          f"num_devices={exp.num_devices}")
    if exp.tracking.on():
        raise ConfigError("seeds: tracking follows one run; train the seeds one by one with --tensorboard or --wandb")


def check_resume(exp: ResumeExperiment) -> None:
    """Refuse a resume request's own fields before the run is opened (what depends on the run,
    such as an ``epochs`` below its newest checkpoint, is checked once it is read)."""
    _check_keep(exp.keep_checkpoints)
    _check_devices(exp.num_devices)
    _check_tracking(exp.tracking)
    if exp.epochs is not None and exp.epochs < 1:
        raise ConfigError(f"epochs: must be >= 1; got {exp.epochs}")
    if exp.max_env_steps is not None and exp.max_env_steps < 0:
        raise ConfigError(f"max_env_steps: must be >= 1, or 0 to lift the run's budget; got {exp.max_env_steps}")


def resumed_stops(exp: ResumeExperiment) -> dict:
    """The loop fields (``epochs``, ``max_env_steps``) a resume replaces in the run's config."""
    stops = {} if exp.epochs is None else {"epochs": exp.epochs}
    if exp.max_env_steps is not None:
        stops["max_env_steps"] = exp.max_env_steps or None
    return stops


def check_export(exp: ExportExperiment) -> None:
    """Refuse an export request whose fields cannot work, before anything is read."""
    if not exp.out:
        raise ConfigError("out: give the export's directory (--out DIR)")
    if exp.epoch < -1:
        raise ConfigError(f"epoch: must be -1 (the newest) or a checkpointed epoch >= 0; got {exp.epoch}")


def check_phase2(exp: Phase2Experiment) -> None:
    """Refuse a phase-2 request's own fields before the phase-1 run is read: ``keep_checkpoints``
    and a missing ``run_dir`` (the config is checked where the phase-2 trainer is built)."""
    _check_keep(exp.keep_checkpoints)
    _check_tracking(exp.tracking)
    if not exp.run_dir:
        raise ConfigError("run_dir: give the phase-1 run directory, e.g. `mjx-emp phase2 runs/pm1`")


def check_rollout(exp: RolloutExperiment) -> None:
    """Refuse a rollout request that cannot describe a k-level agent."""
    check_levels(exp.n, exp.eps)
    k = len(exp.n)
    if len(exp.subgoal_half_width) < k - 1 or any(not v > 0 for v in exp.subgoal_half_width):
        raise ConfigError(f"subgoal_half_width: needs k-1={k - 1} positive entries; got {exp.subgoal_half_width}")
    for name in ("batch_size", "steps", "calls"):
        if getattr(exp, name) < 1:
            raise ConfigError(f"{name}: must be >= 1; got {getattr(exp, name)}")
    if not exp.root_goal_half_width > 0:
        raise ConfigError(f"root_goal_half_width: must be > 0; got {exp.root_goal_half_width}")


def check_distinct_runs(run_dirs: tuple[str, ...], command: str) -> None:
    """At least one run directory, and none given twice: runs are aggregated as seeds, and the
    same run twice would count as two (``command`` names the CLI command in the message)."""
    if not run_dirs:
        raise ConfigError(f"run_dirs: give at least one run directory, e.g. `mjx-emp {command} runs/pm1`")
    resolved = [Path(d).resolve() for d in run_dirs]
    twice = sorted({d for d, r in zip(run_dirs, resolved) if resolved.count(r) > 1})
    if twice:
        raise ConfigError(f"run_dirs: each run counts once (they are aggregated as seeds); given twice: {twice}")


def check_render(exp: RenderExperiment) -> None:
    """Refuse a render request's numbers before anything loads: frames, frame size, seed, fps, distance."""
    for name, most in (("steps", MAX_FRAMES), ("width", MAX_FRAME_SIDE), ("height", MAX_FRAME_SIDE)):
        if not 1 <= getattr(exp, name) <= most:
            raise ConfigError(f"{name}: must be in [1, {most}]; got {getattr(exp, name)}")
    check_seed(exp.seed)
    for name in ("fps", "distance"):
        if not (math.isfinite(getattr(exp, name)) and getattr(exp, name) > 0):
            raise ConfigError(f"{name}: must be a finite number > 0; got {getattr(exp, name)}")


def check_eval(exp: EvalExperiment) -> None:
    """Refuse an eval request before anything loads: episodes, seed, coverage draws, and a run
    given twice (it would count as two seeds)."""
    if not 1 <= exp.episodes <= MAX_EPISODES:
        raise ConfigError(f"episodes: must be in [1, {MAX_EPISODES}]; got {exp.episodes}")
    check_seed(exp.seed)
    if not 1 <= exp.coverage_draws <= MAX_COVERAGE_DRAWS:
        raise ConfigError(f"coverage_draws: must be in [1, {MAX_COVERAGE_DRAWS}]; got {exp.coverage_draws}")
    check_distinct_runs(exp.run_dirs, "eval")
