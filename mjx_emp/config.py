"""Configuration checks shared by the library and the CLI.

Plain Python (no JAX import), so the CLI can reject bad input before compiling anything.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the field and what it allows."""


def check_levels(n: Sequence[int], eps: Sequence[float], k: int | None = None) -> None:
    """Validate per-level n and eps for a k-level agent (k defaults to len(n))."""
    k = len(n) if k is None else k
    if k < 1:
        raise ConfigError("n: give at least one level (k >= 1), e.g. --n 20 10")
    if len(n) != k or len(eps) != k:
        raise ConfigError(
            f"n and eps: need one entry per level (k={k}); got n={tuple(n)}, eps={tuple(eps)}"
        )
    if any(int(v) != v or v < 1 for v in n):
        raise ConfigError(f"n: every entry must be an integer >= 1; got {tuple(n)}")
    if any(not v > 0 for v in eps):
        raise ConfigError(f"eps: every entry must be > 0; got {tuple(eps)}")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Phase-1 Hierarchical Empowerment training of a k-level agent.

    Per-level tuples (n, sigma_gc, sigma_gs, eps, init_half_width, max_half_width) are
    indexed from the bottom level up; k is their length. Names follow the paper; values the paper leaves
    open are ours, stated in the presets' docstrings.
    """

    env: str = "point_mass"
    """Domain: point_mass, ant_field, ant_cage, half_cheetah_field or half_cheetah_cage."""
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
    epochs: int = 20
    """Curriculum epochs (the paper trains 980-1900; see the presets)."""
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
    batch_size: int = 256
    """Minibatch size of every gradient step."""
    replay_capacity: int = 100_000
    """Goal-conditioned transitions kept per level."""
    gs_replay_capacity: int = 4_096
    """Goal-space (s0, noise, a, r) tuples kept per level."""
    start_capacity: int = 8_192
    """Start states kept per level."""
    start_chain: int = 10
    """Top-level skills executed in a row from the initial state when filling start buffers."""
    start_chunks: int = 2
    """Rollout calls per epoch spent on the start-state chain."""
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
    tau: float = 0.01
    """Polyak rate of the goal-conditioned target networks."""
    action_noise: float = 0.2
    """Exploration std of the trained level's actions, in units of its box half-width."""
    goal_noise: float = 0.2
    """Std of the noise on the goal-space action when sampling training goals (shift in
    half-widths, log half-width in nats), so goals come from within and near the box."""
    gs_noise: float = 0.2
    """Std of the noise on the goal-space action in goal-space iterations (same units)."""
    seed: int = 0
    """Seed of all randomness."""

    @property
    def k(self) -> int:
        return len(self.n)


_PER_LEVEL = ("n", "sigma_gc", "sigma_gs", "eps", "init_half_width", "max_half_width")
_POSITIVE = ("epochs", "num_envs", "chunk_steps", "gc_iterations", "gc_grad_steps",
             "gs_iterations", "gs_grad_steps", "batch_size", "replay_capacity",
             "gs_replay_capacity", "start_capacity", "start_chain", "start_chunks")


def check_train_config(cfg: TrainConfig) -> None:
    """Raise ConfigError naming the first invalid field of ``cfg`` and what it allows."""
    from mjx_emp.envs import DOMAINS  # imports JAX; kept out of the module's import

    if cfg.env not in DOMAINS:
        raise ConfigError(f"env: {cfg.env!r} is unknown; allowed values: {sorted(DOMAINS)}")
    check_levels(cfg.n, cfg.eps)
    for name in _PER_LEVEL:
        value = getattr(cfg, name)
        if len(value) != cfg.k:
            raise ConfigError(f"{name}: need one entry per level (k={cfg.k} from n); got {value}")
        if any(not v > 0 for v in value):
            raise ConfigError(f"{name}: every entry must be > 0; got {value}")
    for name in _POSITIVE:
        if getattr(cfg, name) < 1:
            raise ConfigError(f"{name}: must be >= 1; got {getattr(cfg, name)}")
    for level, (start, bound) in enumerate(zip(cfg.init_half_width, cfg.max_half_width)):
        if not start < bound:
            raise ConfigError(
                f"init_half_width: level {level} starts at {start}, which must be below "
                f"max_half_width {bound}"
            )
    if cfg.eval_iterations < 0:
        raise ConfigError(f"eval_iterations: must be >= 0; got {cfg.eval_iterations}")
    if not cfg.hidden or any(w < 1 for w in cfg.hidden):
        raise ConfigError(f"hidden: give one or more widths >= 1; got {cfg.hidden}")
    for name in ("actor_lr", "critic_lr", "gs_actor_lr", "gs_critic_lr", "tau"):
        if not 0 < getattr(cfg, name) <= 1:
            raise ConfigError(f"{name}: must be in (0, 1]; got {getattr(cfg, name)}")
    if not 0 <= cfg.gamma < 1:
        raise ConfigError(f"gamma: must be in [0, 1); got {cfg.gamma}")
    for name in ("action_noise", "goal_noise", "gs_noise"):
        if getattr(cfg, name) < 0:
            raise ConfigError(f"{name}: must be >= 0; got {getattr(cfg, name)}")


def config_from_dict(values: dict) -> TrainConfig:
    """Rebuild a TrainConfig from its JSON form (lists back to tuples); unknown fields are an error."""
    fields = {f.name: f for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ConfigError(f"{unknown[0]}: not a TrainConfig field; allowed: {sorted(fields)}")
    return TrainConfig(**{name: tuple(v) if isinstance(v, list) else v for name, v in values.items()})
