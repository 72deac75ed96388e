"""Phase 2's config: the downstream task (Table 2) and the policy that learns it over frozen skills.

Plain Python (no JAX import), so the CLI can reject bad input before compiling anything.
"""

from __future__ import annotations

import dataclasses

from mjx_emp.checks import (
    check_bounds,
    check_capacity,
    check_counts,
    check_finite,
    check_learning,
)
from mjx_emp.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class Phase2Config:
    """Phase 2: a goal-conditioned policy over a trained agent's frozen top-level skills.

    The added level k has no goal-space policy: its actions are subgoals for level k-1,
    squashed into the top level's learned goal space at the current state. Each episode
    starts at the task's initial state with a goal drawn uniformly from a fixed region
    around h(s0) (the paper's Table 2); the policy has ``n`` attempts (top-level skills)
    to come within ``eps`` of it.
    """

    n: int = 10
    """Maximum number of attempts (top-level skills) per episode (Table 2's n)."""
    eps: float = 0.6
    """Goal threshold: an episode succeeds once h(s) is within eps of its goal."""
    region: tuple[float, ...] = (3.0, 3.0)
    """Length of the goal region along each goal dimension (Table 2's last column)."""
    region_offset: tuple[float, ...] = (0.0, 0.0)
    """Centre of the goal region relative to h(s0) (Half Cheetah's regions lie ahead)."""
    sigma: float = 0.6
    """Std of the reward's Gaussian, log N(goal; h(s_t+1), sigma): phase 1's goal-conditioned
    reward, with its own width (the paper leaves phase 2's reward open)."""
    epochs: int = 30
    """Training epochs (each: ``iterations`` x (collect, update), then a greedy evaluation)."""
    max_env_steps: int | None = None
    """Stop at the end of the first epoch whose total phase-2 environment steps reach this many
    (a two-level agent's attempts hold more primitive steps than a one-level agent's). None:
    train all ``epochs``."""
    num_envs: int = 64
    """Environments simulated in parallel."""
    iterations: int = 10
    """Collect-then-update iterations per epoch."""
    grad_steps: int = 50
    """Gradient steps per iteration."""
    batch_size: int = 128
    """Minibatch size of every gradient step."""
    replay_capacity: int = 100_000
    """Phase-2 transitions (one per attempt) kept."""
    eval_rounds: int = 2
    """Greedy evaluation rounds per epoch (num_envs episodes each), for the metrics."""
    hidden: tuple[int, ...] = (128, 128)
    """Hidden layer widths of the phase-2 actor and critic."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 3e-4
    """Adam learning rate of the critic."""
    gamma: float = 0.95
    """Discount per attempt (0 once the goal is reached)."""
    tau: float = 0.01
    """Polyak rate of the target networks."""
    action_noise: float = 0.2
    """Exploration std of the subgoals, in units of the top goal space's half-width."""
    learn_from_resets: bool = False
    """Keep the attempts that a reset (a flipped Ant) ended, as terminal rows scored as if the
    robot stayed where it fell (``learners.ddpg.cut_backup``), so the policy learns what a
    flip costs. Off: those attempts are dropped, as every transition a reset cuts is in phase 1,
    and the policy never sees one."""
    flip_cost: float = 0.0
    """A flipped attempt as an absorbing failure: with a cost > 0 the attempts a reset ended
    are kept (as with ``learn_from_resets``) and worth (r - flip_cost) / (1 - gamma), the robot
    paying the cost every step after (``learners.ddpg.cut_backup``), so the policy learns to
    ask for subgoals whose skills keep it on its feet. An attempt that leaves the torso upside
    down with no reset (a Half Cheetah on its back) is scored the same way. In units of the reward,
    log N(goal; h(s'), sigma). 0: a flip costs only the reach it lost."""
    reflex_tilt: float = 0.0
    """A reflex (0: none): a skill hands control back to the policy on top, ending its attempt
    early with no reset, once the torso's tilt (1 - z of its up axis: 0 upright, 1 on its side)
    passes this, so the policy chooses its next subgoal before the robot is on its back
    (``rollout.hierarchy.Hierarchy.reflex_tilt``). The attempt counts as one of the n. A
    threshold to start from is the one the flip table's warning reports (`mjx-emp eval`)."""
    subgoal_reach: float = 1.0
    """The share of the top level's box, in half-widths about its centre, that the learned
    policy's subgoals are squashed into (1: the whole box, the paper's). Below 1 the skills
    are asked for shorter moves, which they make at a slower pace: the goals near a box's edge
    are where skills flip most per metre gained (the flip table's goal places). The scripted
    diagnostics keep the whole box."""
    aim_prior: bool = False
    """Start the policy as the scripted aimed one (each subgoal straight at the goal, within the
    top goal space) and learn a correction to it: the actor's output is added before the tanh to
    the aimed subgoal's, from an output layer that starts near zero. Beyond the paper (off in its
    presets); for skills addressed by goal-space subgoals (HE, GCRL), not latent skills."""
    aim_weight: float = 0.0
    """With ``aim_prior``, what the actor pays for leaving the prior: its loss becomes
    -Q / mean|Q| + aim_weight * mean(f^2), f the correction added before the tanh (the critic's
    gain normalised as in TD3+BC, Fujimoto and Gu 2021), so the policy moves off the aimed
    subgoal only where the critic's gain outweighs the cost. 0: plain DDPG over the prior."""
    phase1_epoch: int = -1
    """Phase-1 checkpoint to build on; -1 means the newest one of the run."""
    seed: int = 0
    """Seed of phase 2's randomness."""


_P2_POSITIVE = ("n", "epochs", "max_env_steps", "num_envs", "iterations", "grad_steps", "batch_size",
                "replay_capacity", "eval_rounds")


def keeps_cut_attempts(cfg: Phase2Config) -> bool:
    """Whether phase 2's replay keeps the attempts a reset cut short (``learn_from_resets`` or a
    ``flip_cost``)."""
    return cfg.learn_from_resets or cfg.flip_cost > 0.0


def check_phase2_config(cfg: Phase2Config, goal_size: int | None = None) -> None:
    """Raise ConfigError naming the first invalid field of ``cfg`` (``goal_size``: the domain's)."""
    check_counts(cfg, _P2_POSITIVE)
    for name in ("eps", "sigma"):
        if not getattr(cfg, name) > 0:
            raise ConfigError(f"{name}: must be > 0; got {getattr(cfg, name)}")
    if not cfg.region or any(not v > 0 for v in cfg.region):
        raise ConfigError(f"region: give one length > 0 per goal dimension; got {cfg.region}")
    if goal_size is not None:
        for name in ("region", "region_offset"):
            if len(getattr(cfg, name)) != goal_size:
                raise ConfigError(f"{name}: the domain's goal space has {goal_size} dimension(s); "
                                  f"got {getattr(cfg, name)}")
    check_learning(cfg, ("actor_lr", "critic_lr"), ("action_noise",))
    if not cfg.aim_weight >= 0:
        raise ConfigError(f"aim_weight: must be >= 0; got {cfg.aim_weight}")
    if not cfg.flip_cost >= 0:
        raise ConfigError(f"flip_cost: must be >= 0; got {cfg.flip_cost}")
    if not 0 < cfg.subgoal_reach <= 1:
        raise ConfigError(f"subgoal_reach: a share of the top box's half-widths in (0, 1] (1: the whole box); "
                          f"got {cfg.subgoal_reach}")
    if not 0 <= cfg.reflex_tilt < 2:
        raise ConfigError(f"reflex_tilt: a tilt in [0, 2) (0: no reflex; 1 is on its side); got {cfg.reflex_tilt}")
    if cfg.aim_weight > 0 and not cfg.aim_prior:
        raise ConfigError(f"aim_weight: a cost of leaving the aim prior needs aim_prior True; got {cfg.aim_weight} "
                          "with aim_prior False")
    if cfg.phase1_epoch < -1:
        raise ConfigError(f"phase1_epoch: an epoch >= 0, or -1 for the newest; got {cfg.phase1_epoch}")
    check_finite(cfg)
    check_bounds(cfg)
    check_capacity(cfg, "replay_capacity", {"a minibatch (batch_size)": cfg.batch_size,
                                            "one episode of attempts per environment (num_envs x n)": cfg.num_envs * cfg.n})
