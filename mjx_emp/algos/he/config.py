"""Hierarchical Empowerment's phase-1 configs: HEConfig, and GcrlConfig (its fixed-box baseline).

Plain Python (no JAX import), so the CLI can reject bad input before compiling anything.
"""

from __future__ import annotations

import dataclasses
import math

from mjx_emp.checks import (
    check_bounds,
    check_capacity,
    check_counts,
    check_finite,
    check_learning,
    check_levels,
    check_shards,
)
from mjx_emp.envs.registry import DOMAINS, check_physics, tiltable
from mjx_emp.errors import ConfigError

RESET_OUTCOMES = ("last", "start")
"""Where the goal spaces may score an episode a reset cut short (``HEConfig.reset_outcome``)."""


@dataclasses.dataclass(frozen=True)
class Physics:
    """The domain and how it is simulated."""

    env: str = "point_mass"
    """Domain: point_mass, ant_field, ant_cage, half_cheetah_field or half_cheetah_cage."""
    heading_frame: bool = False
    """Networks see the state and goal offset in the torso's heading frame (Ant domains
    only; see Env.heading_frame). False is the paper's world-frame input, and what every
    preset uses: on the Ant's CPU learner under the model's physics (ant-field-k1-cpu with one
    solver iteration and a plain critic), heading-frame inputs learnt a smaller box at a lower
    success."""
    solver_iterations: int = 0
    """Constraint-solver iterations of the physics; 0 keeps the model file's (the robots': 1,
    the paper's Brax settings)."""
    integrator: str = "model"
    """Integrator of the physics: model (the file's; Euler for every domain), euler,
    implicitfast or rk4."""
    impl: str = "jax"
    """MJX backend: jax (MJX's own, on any device; deterministic) or warp (MuJoCo Warp, CUDA
    GPUs only, needs the mujoco-warp package; not bit-for-bit deterministic)."""


@dataclasses.dataclass(frozen=True)
class Levels:
    """What each level is, bottom level first: its actions per attempt, rewards' widths, goal
    threshold and goal-space box. k is the length of these tuples; names follow the paper."""

    n: tuple[int, ...] = (10,)
    """Maximum number of actions per level (the paper's n), bottom level first."""
    sigma_gc: tuple[float, ...] = (0.2,)
    """Std of the goal-conditioned reward's Gaussian, log N(h(s0)+z; h(s_t+1), sigma_gc)."""
    sigma_gs: tuple[float, ...] = (0.8,)
    """Std of the goal-space reward's Gaussian, log N(h(s0)+z; h(s_n), sigma_gs)."""
    eps: tuple[float, ...] = (0.3,)
    """Goal threshold per level: a goal counts as reached within this distance."""
    init_half_width: tuple[float, ...] = (0.1,)
    """Half-width of every level's goal-space box before training."""
    max_half_width: tuple[float, ...] = (5.0,)
    """Soft upper bound on each level's goal-space half-width and |shift| (a safety rail
    far above what the level can reach; see networks.GoalSpaceActor)."""
    @property
    def k(self) -> int:
        return len(self.n)


@dataclasses.dataclass(frozen=True)
class Schedule:
    """How an epoch spends its environment steps and gradient steps, and how many epochs run."""

    epochs: int = 20
    """Curriculum epochs (the paper trains 980-1900; see the presets)."""
    max_env_steps: int | None = None
    """Stop at the end of the first epoch whose total environment steps reach this many (with
    ``--seeds``, once every seed has): one budget for methods whose epochs hold different
    numbers of steps. None: train all ``epochs``."""
    num_envs: int = 128
    """Environments simulated in parallel during data collection."""
    chunk_steps: int = 10
    """Primitive steps per rollout call inside a collection loop."""
    gc_iterations: int = 10
    """Goal-conditioned iterations (collect, then gradient steps) per level per epoch."""
    gc_grad_steps: int = 50
    """Gradient steps per goal-conditioned iteration (the paper's S=50)."""
    gs_iterations: int = 1
    """Goal-space iterations per level per epoch."""
    gs_grad_steps: int = 10
    """Gradient steps per goal-space iteration (the paper's S=10)."""
    eval_iterations: int = 1
    """Greedy evaluation collections per level per epoch (metrics only; 0 turns them off)."""
    level_repeats: tuple[int, ...] = ()
    """How many times each level's iterations (goal-conditioned, goal-space, evaluation) run
    per epoch, bottom level first. () runs each level once, as the paper's Algorithm 1 does.
    Each level learns only from the episodes it roots, so in a k-level agent under a fixed
    env-step budget the upper levels' longer episodes take most of the steps and level 0
    gets fewer iterations than a one-level agent's; repeating it gives some back."""
    batch_size: int = 256
    """Minibatch size of every gradient step."""
    start_chain: int = 10
    """Top-level skills executed in a row from the initial state when filling start buffers."""
    start_chunks: int = 2
    """Rollout calls per epoch spent on the start-state chain."""


@dataclasses.dataclass(frozen=True)
class Buffers:
    """What each level keeps to learn from."""

    replay_capacity: int = 100_000
    """Goal-conditioned transitions kept per level."""
    gs_replay_capacity: int = 4_096
    """Goal-space (s0, noise, a, r) tuples kept per level."""
    start_capacity: int = 8_192
    """Start states kept per level."""
    fresh_replay: bool = False
    """The paper's Algorithms 2 and 3 literally: each goal-conditioned or goal-space
    iteration starts from an empty buffer D and learns from its own collection only.
    False keeps persistent ring buffers of the capacities above (the default;
    docs/algorithm.md#differences-from-the-papers-algorithms-1-3)."""


@dataclasses.dataclass(frozen=True)
class Learner:
    """The networks and their updates: DDPG's goal-conditioned actors and critics and the
    goal-space actor-critics, with the options beyond the paper each off by default."""

    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer widths of every actor and critic."""
    actor_lr: float = 3e-4
    """Adam learning rate of the goal-conditioned actors."""
    critic_lr: float = 3e-4
    """Adam learning rate of the goal-conditioned critics."""
    gs_actor_lr: float = 3e-4
    """Adam learning rate of the goal-space actors."""
    gs_critic_lr: float = 3e-4
    """Adam learning rate of the goal-space critics."""
    gamma: float = 0.95
    """Discount of the goal-conditioned critics (0 once the goal is reached)."""
    relabel: float = 0.0
    """Fraction of every goal-conditioned minibatch whose goal offset is swapped for another
    row's (goal = h(s) + that row's goal - h(s)), with reached recomputed. The reward
    depends only on h(s') and the goal, so any goal makes a valid transition; 0 is the
    paper's Algorithm 2."""
    her: float = 0.0
    """Fraction of every goal-conditioned minibatch whose goal is replaced by one its own
    episode achieved later (HER's "future" strategy, Andrychowicz et al. 2017), with
    reached recomputed; applied before ``relabel``. 0 is the paper's Algorithm 2."""
    n_step: int = 1
    """Transitions of a row's episode summed into each critic target before bootstrapping
    (an uncorrected n-step return; it stops where the goal is reached). 1 is the paper's
    one-step DDPG target."""
    critic_layer_norm: bool = False
    """LayerNorm before every hidden ReLU of the goal-conditioned critics (Ball et al. 2023).
    False is the paper's plain MLP."""
    actor_layer_norm: bool = False
    """LayerNorm before every hidden ReLU of the goal-conditioned actors."""
    critics: int = 1
    """Goal-conditioned critics per level. 1 is the paper's DDPG; 2 is TD3's clipped
    double-Q (Fujimoto et al. 2018): two critics, bootstrapped targets from the smaller
    of the two target critics, the actor ascending their mean."""
    tau: float = 0.01
    """Polyak rate of the goal-conditioned target networks."""
    action_noise: float = 0.2
    """Exploration std of the trained level's actions, in units of its box half-width."""
    goal_noise: float = 0.2
    """Std of the noise on the goal-space action when sampling training goals (shift in
    half-widths, log half-width in nats), so goals come from within and near the box."""
    gs_noise: float = 0.2
    """Std of the noise on the goal-space action in goal-space iterations (same units)."""


@dataclasses.dataclass(frozen=True)
class Flips:
    """What a flip (an Ant reset upside down, a Half Cheetah on its back) teaches the levels.
    Every option is off by default, as in the paper, which does not say what its robots did
    on their backs."""

    learn_from_resets: bool = False
    """Keep what a reset (a flipped Ant) ended: the goal-conditioned levels store the actions it
    cut short as final rows scored as if the robot stayed where it fell (r / (1 - gamma),
    ``learners.ddpg.cut_backup``), and the goal spaces learn from the episodes it cut short,
    scored where ``reset_outcome`` says (by default their last state before the reset). False
    drops both, as no transition of the task ends in a reset (the paper does not say what its
    Brax Ant did on its back)."""
    flip_cost: float = 0.0
    """A flip as an absorbing failure the goal-conditioned levels learn: with a cost > 0 every
    level keeps the actions a reset (a flipped Ant) cut short, as terminal rows worth
    (r - flip_cost) / (1 - gamma), r being the reward at the last state before the reset: the
    robot stays there and pays the cost every step after (``learners.ddpg.cut_backup``). An
    action that leaves the torso upside down without a reset (a Half Cheetah on its back) is
    scored the same way, at the state it reached. In
    units of the reward, log N(goal; h(s'), sigma_gc): a cost of c is the reward lost by
    ending sqrt(2 c) sigma_gc from the goal instead of on it. 0 drops those rows (the paper's setting;
    with ``learn_from_resets`` they are kept at no cost). With ``learn_from_resets`` the goal
    spaces also learn from the episodes a reset ended, each scored (where ``reset_outcome``
    says) less this cost, so that a box whose goals make its skills flip earns less."""
    reset_outcome: str = "last"
    """With ``learn_from_resets``, where the goal spaces score an episode a reset cut short:
    "last" at its last state before the reset; "start" as if the skill never left its start
    state, so a box whose skills fall over earns what a box of skills that never move earns."""
    tilt_cost: float = 0.0
    """Subtracted from level 0's per-step reward times the torso's tilt after the action
    (1 - z of its up axis: 0 upright, 1 on its side, 2 upside down), so the level that moves
    the joints learns to keep the robot upright; robots with a torso that tilts only (the Ant,
    the Half Cheetah). 0 is the paper's reward, log N(goal; h(s'), sigma) alone."""
    tilted_starts: float = 0.0
    """The share of level 0's training episodes begun from their start state turned by an angle
    drawn uniformly up to ``tilted_start_angle`` about a random horizontal axis
    (``Torso.turned``): the level that moves the joints then learns to reach its goals from a
    torso already tilting, where the flip table sees flips coming two or three steps ahead and
    where a skill trained only from upright starts has never acted. Evaluation and the levels
    above start as before. 0 is the paper's starts."""
    tilted_start_angle: float = 1.0
    """The largest turn of a tilted start, in radians, in (0, pi/2]: 1.0 tilts the torso by up to
    0.46 (1 - cos), past the 0.32-0.36 that the recipe's upright steps stay below 99 % of the time."""


@dataclasses.dataclass(frozen=True)
class HEConfig(Flips, Learner, Buffers, Schedule, Levels, Physics):
    """Phase-1 Hierarchical Empowerment training of a k-level agent.

    The fields of Physics, Levels, Schedule, Buffers, Learner and Flips, and the run's seed and
    shards, as one flat set: the names that flags, config.json, presets and sweep overrides use.
    (Dataclass fields come from the last base class first, so the flags list physics first.)
    Names follow the paper; values the paper leaves open are ours, stated in the presets.
    """

    seed: int = 0
    """Seed of all randomness."""
    shards: int = 1
    """Equal parts the environment batch, minibatch, replay and start buffers are split into
    (data parallelism: each part on its own device where there are enough, gradients
    averaged over them). Fixed for a run; `--num-devices` places the parts."""


_PER_LEVEL = ("n", "sigma_gc", "sigma_gs", "eps", "init_half_width", "max_half_width")
_POSITIVE = ("epochs", "max_env_steps", "num_envs", "chunk_steps", "gc_iterations", "gc_grad_steps", "critics",
             "n_step", "gs_iterations", "gs_grad_steps", "batch_size", "replay_capacity",
             "gs_replay_capacity", "start_capacity", "start_chain", "start_chunks")


SHARD_SPLIT = ("num_envs", "batch_size", "replay_capacity", "gs_replay_capacity", "start_capacity")
"""The fields a shard of a split run takes its part of (see ``HEConfig.shards``)."""


def check_train_config(cfg: HEConfig, positive: tuple[str, ...] = _POSITIVE) -> None:
    """Raise ConfigError naming the first invalid field of ``cfg`` and what it allows
    (``positive``: the count fields that must be >= 1), group by group."""
    check_physics_fields(cfg)
    check_level_fields(cfg)
    check_flip_fields(cfg)
    check_shards(cfg, SHARD_SPLIT)
    check_counts(cfg, positive)
    check_schedule_fields(cfg)
    check_learner_fields(cfg)
    check_finite(cfg)
    check_bounds(cfg)
    check_buffer_fields(cfg)


def check_physics_fields(cfg: HEConfig) -> None:
    """The domain exists and the physics' overrides are allowed; heading frames and tilt costs only
    where the robot has the torso they read."""
    if cfg.env not in DOMAINS:
        raise ConfigError(f"env: {cfg.env!r} is unknown; allowed values: {sorted(DOMAINS)}")
    if cfg.heading_frame and DOMAINS[cfg.env].torso_quat is None:
        allowed = sorted(name for name, spec in DOMAINS.items() if spec.torso_quat is not None)
        raise ConfigError(f"heading_frame: {cfg.env!r} has no free torso; allowed only with env in {allowed}")
    check_physics(cfg.solver_iterations, cfg.integrator, cfg.impl)


def check_level_fields(cfg: HEConfig) -> None:
    """One positive entry per level in every per-level tuple, each box starting below its bound."""
    check_levels(cfg.n, cfg.eps)
    for name in _PER_LEVEL:
        value = getattr(cfg, name)
        if len(value) != cfg.k:
            raise ConfigError(f"{name}: need one entry per level (k={cfg.k} from n); got {value}")
        if any(not v > 0 for v in value):
            raise ConfigError(f"{name}: every entry must be > 0; got {value}")
    for level, (start, bound) in enumerate(zip(cfg.init_half_width, cfg.max_half_width)):
        if not start < bound:
            raise ConfigError(
                f"init_half_width: level {level} starts at {start}, which must be below "
                f"max_half_width {bound}"
            )


def check_schedule_fields(cfg: HEConfig) -> None:
    """Level repeats, one per level, and evaluation collections that are not negative (the counts
    that must be >= 1 are checked with the others by ``check_counts``)."""
    if cfg.level_repeats and (len(cfg.level_repeats) != cfg.k or any(r < 1 for r in cfg.level_repeats)):
        raise ConfigError(f"level_repeats: empty (each level once) or one entry >= 1 per level (k={cfg.k} from n); "
                          f"got {cfg.level_repeats}")
    if cfg.eval_iterations < 0:
        raise ConfigError(f"eval_iterations: must be >= 0; got {cfg.eval_iterations}")


def check_learner_fields(cfg: HEConfig) -> None:
    """Learning rates and noises in range, relabelling fractions in [0, 1]."""
    check_learning(cfg, ("actor_lr", "critic_lr", "gs_actor_lr", "gs_critic_lr"),
                    ("action_noise", "goal_noise", "gs_noise"))
    if not 0 <= cfg.relabel <= 1:
        raise ConfigError(f"relabel: a fraction in [0, 1]; got {cfg.relabel}")
    if not 0 <= cfg.her <= 1:
        raise ConfigError(f"her: a fraction in [0, 1]; got {cfg.her}")


def check_flip_fields(cfg: HEConfig) -> None:
    """Costs that are not negative, a tilt cost and tilted starts only on a robot that tilts, and a reset outcome only
    where the episodes a reset cut short are learnt from."""
    if not cfg.flip_cost >= 0.0:
        raise ConfigError(f"flip_cost: must be >= 0; got {cfg.flip_cost}")
    if not cfg.tilt_cost >= 0.0:
        raise ConfigError(f"tilt_cost: must be >= 0; got {cfg.tilt_cost}")
    if not 0.0 <= cfg.tilted_starts <= 1.0:
        raise ConfigError(f"tilted_starts: a share in [0, 1]; got {cfg.tilted_starts}")
    if not 0.0 < cfg.tilted_start_angle <= math.pi / 2:
        raise ConfigError(f"tilted_start_angle: radians in (0, pi/2]; got {cfg.tilted_start_angle}")
    for field in ("tilt_cost", "tilted_starts"):  # what reads the torso's tilt
        if getattr(cfg, field) > 0.0 and not tiltable(DOMAINS[cfg.env]):
            allowed = sorted(name for name, spec in DOMAINS.items() if tiltable(spec))
            raise ConfigError(f"{field}: {cfg.env!r} has no torso to tilt; allowed only with env in {allowed}")
    if cfg.reset_outcome not in RESET_OUTCOMES:
        raise ConfigError(f"reset_outcome: {cfg.reset_outcome!r} is unknown; allowed values: {list(RESET_OUTCOMES)}")
    if cfg.reset_outcome != "last" and not cfg.learn_from_resets:
        raise ConfigError(f"reset_outcome: {cfg.reset_outcome!r} needs learn_from_resets=True (without it the "
                          "episodes a reset cut short are not scored)")


def check_buffer_fields(cfg: HEConfig) -> None:
    """Every buffer holds at least a minibatch and one step or episode of every environment (a
    collection chunk larger than the ring keeps its newest rows)."""
    check_capacity(cfg, "replay_capacity", {"a minibatch (batch_size)": cfg.batch_size,
                                            "one step of every environment (num_envs)": cfg.num_envs})
    check_capacity(cfg, "gs_replay_capacity", {"a minibatch (batch_size)": cfg.batch_size,
                                               "one episode per environment (num_envs)": cfg.num_envs})
    check_capacity(cfg, "start_capacity", {"one start state per environment (num_envs)": cfg.num_envs})


def keeps_cut_rows(cfg: HEConfig) -> bool:
    """Whether the goal-conditioned replays keep the actions a reset cut short (``learn_from_resets``
    or a ``flip_cost``)."""
    return cfg.learn_from_resets or cfg.flip_cost > 0.0


@dataclasses.dataclass(frozen=True)
class GcrlConfig(HEConfig):
    """Goal-conditioned RL with a hand-set goal space (Choi et al. 2021, as Levy et al. compare
    against it): Hierarchical Empowerment's goal-conditioned levels, but every level's goal
    space is a fixed box of ``goal_half_width`` around h(s), never learnt (no goal-space
    iterations)."""

    goal_half_width: tuple[float, ...] = (1.0,)
    """Half-width of each level's fixed goal box (one entry per level)."""
    gs_iterations: int = 0
    """Always 0: nothing learns the goal space."""


def check_gcrl_config(cfg: GcrlConfig) -> None:
    """HE's checks, plus one finite goal half-width > 0 per level and no goal-space iterations."""
    if cfg.gs_iterations != 0:
        raise ConfigError(f"gs_iterations: GCRL learns no goal space; must be 0, got {cfg.gs_iterations}")
    if len(cfg.goal_half_width) != cfg.k or any(not 0 < w < float("inf") for w in cfg.goal_half_width):
        raise ConfigError(f"goal_half_width: one finite entry > 0 per level (k={cfg.k}); got {cfg.goal_half_width}")
    check_train_config(cfg, tuple(name for name in _POSITIVE if name != "gs_iterations"))
