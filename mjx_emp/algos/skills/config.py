"""Configs of the flat skill learners (DIAYN, HIDIO, DADS, METRA), plain Python (no JAX).

They share :class:`SkillConfig`: every environment runs one skill z for ``n`` actions from
the initial state, a SAC policy pi(a | y(s), z) is trained on the method's intrinsic
reward, and the method's own model (posterior, skill dynamics or phi) is trained on the
same minibatches. Defaults follow METRA's published code (seohongpark/METRA,
tests/main.py): learning rates 1e-4, initial alpha 0.01, target entropy -|A|/2, tau
5e-3, discount 0.99, minibatch 256, two hidden layers (1024 wide there; 256 here on CPU).
"""

from __future__ import annotations

import dataclasses

from mjx_emp.checks import (
    check_bounds,
    check_capacity,
    check_counts,
    check_finite,
    check_learning,
    check_shards,
)
from mjx_emp.envs.registry import DOMAINS, check_physics
from mjx_emp.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class SkillConfig:
    """What every flat skill learner shares: environment, skills, collection, SAC."""

    env: str = "point_mass"
    """Domain: point_mass, ant_field, ant_cage, half_cheetah_field or half_cheetah_cage."""
    impl: str = "jax"
    """MJX backend: jax (any device; deterministic) or warp (MuJoCo Warp, CUDA GPUs only)."""
    solver_iterations: int = 0
    """Constraint-solver iterations of the physics; 0 keeps the model file's (the robots': 1).
    The same field as HEConfig's, so a comparison can give every method the same physics."""
    integrator: str = "model"
    """Integrator of the physics: model (the file's; Euler for every domain), euler,
    implicitfast or rk4."""
    skill_dim: int = 2
    """Dimension d of the skill z."""
    n: int = 10
    """Actions per skill: an episode runs one skill for n actions from the initial state."""
    epochs: int = 100
    """Epochs (each ``iterations`` collect-then-learn rounds)."""
    max_env_steps: int | None = None
    """Stop at the end of the first epoch whose total environment steps reach this many (with
    ``--seeds``, once every seed has): one budget for methods whose epochs hold different
    numbers of steps. None: train all ``epochs``."""
    num_envs: int = 16
    """Environments simulated in parallel."""
    collect_steps: int = 10
    """Primitive steps every environment takes per iteration."""
    iterations: int = 10
    """Collect-then-learn rounds per epoch."""
    grad_steps: int = 50
    """Gradient steps (model, then SAC) per iteration."""
    batch_size: int = 256
    """Minibatch size of every gradient step."""
    replay_capacity: int = 100_000
    """Transitions kept."""
    min_replay: int = 1_000
    """No gradient steps before the replay holds this many transitions."""
    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer widths of every network."""
    actor_lr: float = 1e-4
    critic_lr: float = 1e-4
    alpha_lr: float = 1e-4
    model_lr: float = 1e-4
    """Adam rate of the method's own model (posterior, skill dynamics or phi)."""
    init_alpha: float = 0.01
    """SAC's initial temperature."""
    target_entropy_scale: float = 0.5
    """SAC's target entropy is -scale x the action size (METRA: 1/2)."""
    gamma: float = 0.99
    tau: float = 5e-3
    seed: int = 0
    shards: int = 1
    """Equal parts the environment batch, minibatch and replay are split into (data
    parallelism; see HEConfig.shards). Fixed for a run."""

    @property
    def k(self) -> int:
        """Levels of skills: one (a flat learner)."""
        return 1


@dataclasses.dataclass(frozen=True)
class DiaynConfig(SkillConfig):
    """DIAYN as Levy et al. ran it: continuous z ~ U[-1, 1]^d held for the skill's n actions,
    a diagonal-Gaussian posterior q(z | s0, s_t), reward log q - log p(z) at every step."""


@dataclasses.dataclass(frozen=True)
class HidioConfig(SkillConfig):
    """HIDIO with the posterior q(z | s0, a_{t-1}, s_t), the variant Levy et al. used."""


@dataclasses.dataclass(frozen=True)
class DadsConfig(SkillConfig):
    """DADS: skill dynamics q(s' | s, z) and its contrastive reward over L prior skills."""

    prior_samples: int = 100
    """L, the prior skills in the reward's denominator (METRA's code: 100)."""


@dataclasses.dataclass(frozen=True)
class MetraConfig(SkillConfig):
    """METRA: phi under the temporal-distance constraint, skills on the unit sphere."""

    dual_lam: float = 30.0
    """Initial lambda of the constraint (METRA's code: 30)."""
    dual_slack: float = 1e-3
    """The constraint term is min(slack, 1 - ||phi(s') - phi(s)||^2) (METRA's code: 1e-3)."""


_POSITIVE = ("skill_dim", "n", "epochs", "max_env_steps", "num_envs", "collect_steps", "iterations", "grad_steps",
             "batch_size", "replay_capacity", "min_replay")
_RATES = ("actor_lr", "critic_lr", "alpha_lr", "model_lr")


SHARD_SPLIT = ("num_envs", "batch_size", "replay_capacity", "min_replay")
"""The fields a shard of a split run takes its part of (see ``SkillConfig.shards``)."""


def check_skill_config(cfg: SkillConfig) -> None:
    """Raise ConfigError naming the first invalid field of ``cfg`` and what it allows."""
    if cfg.env not in DOMAINS:
        raise ConfigError(f"env: {cfg.env!r} is unknown; allowed values: {sorted(DOMAINS)}")
    check_physics(cfg.solver_iterations, cfg.integrator, cfg.impl)
    check_counts(cfg, _POSITIVE)
    check_shards(cfg, SHARD_SPLIT)
    check_learning(cfg, _RATES, ())
    for name in ("init_alpha", "target_entropy_scale"):
        value = getattr(cfg, name)
        if not 0 < value < float("inf"):
            raise ConfigError(f"{name}: must be a finite number > 0; got {value}")
    check_capacity(cfg, "replay_capacity", {"a minibatch (batch_size)": cfg.batch_size,
                                            "one collection (num_envs x collect_steps)": cfg.num_envs * cfg.collect_steps})
    if cfg.min_replay > cfg.replay_capacity:
        raise ConfigError(f"min_replay: must be <= replay_capacity ({cfg.replay_capacity}); got {cfg.min_replay}")
    if isinstance(cfg, DadsConfig) and cfg.prior_samples < 1:
        raise ConfigError(f"prior_samples: must be >= 1; got {cfg.prior_samples}")
    if isinstance(cfg, MetraConfig):
        for name in ("dual_lam", "dual_slack"):
            if not 0 < getattr(cfg, name) < float("inf"):
                raise ConfigError(f"{name}: must be a finite number > 0; got {getattr(cfg, name)}")
    check_finite(cfg)
    check_bounds(cfg)
