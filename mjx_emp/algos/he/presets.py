"""Hierarchical Empowerment's phase-1 presets and the fixed-box GCRL baseline on each.

Names follow :mod:`mjx_emp.algos.names` (``[ALGO-]DOMAIN[-kK][-SIZE]``). The recommended
recipes are one per domain and depth at two sizes: ``cpu`` (16 environments, for a 2-core
CPU) and ``gpu`` (the same recipe at the paper's 4096 environments and minibatches of 1024).
The point mass has one size and keeps the CI default's name, ``point-mass-k1``. Beside them
stand the paper's Table-1 rows (``-paper-small``, ``-paper-big``, ``-paper-xl``, ``-paper``),
value for value.

Values the paper gives (k, n, sigma_gc, sigma_gs, eps, epochs, the 10 x S=50 / 1 x S=10
epoch structure) are its Table 1's and appendix's; the comments below say why every other
value is what it is, docs/algorithm.md#differences-from-the-papers-algorithms-1-3 why each
option beyond the paper exists, and docs/results.md what the recipes measured. The variants
single experiments trained left the catalogue; :mod:`mjx_emp.algos.retired` gives each one's
command.
"""

from __future__ import annotations

import dataclasses

from mjx_emp.algos.he.config import GcrlConfig, HEConfig

_PAPER = dict(
    num_envs=4096, batch_size=1024, hidden=(256, 256), replay_capacity=500_000,
    gs_replay_capacity=65_536, start_capacity=65_536, actor_lr=3e-4, critic_lr=3e-4,
    gs_actor_lr=1e-4, gs_critic_lr=1e-3,
)


def _paper(env: str, n, sigma_gc, sigma_gs, eps, epochs: int, max_half_width) -> HEConfig:
    return HEConfig(
        env=env, n=tuple(n), sigma_gc=tuple(sigma_gc), sigma_gs=tuple(sigma_gs), eps=tuple(eps),
        init_half_width=tuple(e / 2 for e in eps), max_half_width=tuple(max_half_width),
        epochs=epochs, chunk_steps=n[0], **_PAPER,
    )


_ANT_K2 = dict(sigma_gc=(0.4, 0.8), sigma_gs=(1.75, 3.5), eps=(0.6, 1.2))
_CHEETAH_K2 = dict(sigma_gc=(0.3, 3.0), sigma_gs=(2.0, 10.0), eps=(1.0, 2.0))

POINT_MASS_K1 = HEConfig(
    env="point_mass", n=(10,), sigma_gc=(0.4,), sigma_gs=(0.2,), eps=(0.3,),
    init_half_width=(0.2,), max_half_width=(3.0,), epochs=150, num_envs=64, chunk_steps=10,
    batch_size=128, hidden=(128, 128), replay_capacity=100_000, gs_replay_capacity=4_096,
    start_capacity=8_192, actor_lr=3e-4, critic_lr=3e-4, gs_actor_lr=2e-4, gs_critic_lr=1e-3,
)
POINT_MASS_K2 = dataclasses.replace(
    POINT_MASS_K1, n=(10, 5), sigma_gc=(0.4, 0.8), sigma_gs=(0.2, 0.4), eps=(0.3, 0.6),
    init_half_width=(0.2, 0.4), max_half_width=(3.0, 15.0), action_noise=0.1, gs_iterations=8,
)

# ---- the paper's robots on a 2-core CPU ----------------------------------------------------
# The learner that walks the Ant to goals, under the model file's physics (one solver
# iteration) and a plain critic; the recipes below build on it. Against the Table-1 presets':
# sigma_gc 1.0 (a flatter reward, so errors on far goals do not swamp the critic), critic rate
# 1e-4 and tau 0.005, half of every minibatch relabelled with another row's goal, 16
# environments and 100 gradient steps per iteration (gradient steps are cheap on a CPU beside
# its physics), action noise 0.3, 8 goal-space iterations per epoch (one is 16 episodes here)
# and sigma_gs 0.5, which settles the box just beyond the policy's reach
# (docs/algorithm.md#differences-from-the-papers-algorithms-1-3; under this physics:
# docs/results.md#the-ant-with-the-model-files-physics).
_ROBOT_CPU = dict(
    n=(20,), sigma_gs=(0.5,), sigma_gc=(1.0,), epochs=300, num_envs=16, chunk_steps=20, gc_grad_steps=100,
    gs_iterations=8, batch_size=256, hidden=(256, 256), replay_capacity=200_000, gs_replay_capacity=65_536,
    start_capacity=65_536, actor_lr=3e-4, critic_lr=1e-4, gs_actor_lr=2e-4, gs_critic_lr=1e-3, tau=0.005,
    action_noise=0.3, relabel=0.5,
)
_ANT_FIELD_MODEL_K1 = HEConfig(env="ant_field", eps=(0.6,), init_half_width=(0.3,), max_half_width=(10.0,),
                               **_ROBOT_CPU)
_HALF_CHEETAH_MODEL_K1 = dataclasses.replace(
    HEConfig(env="half_cheetah_field", eps=(1.0,), init_half_width=(0.5,), max_half_width=(20.0,), **_ROBOT_CPU),
    epochs=320,
)
# Two levels: n = 5 subgoals at level 1 (Table 1's Ant Field Big has 10), which keeps a CPU
# epoch affordable, and twice level 0's sigma_gc and eps, as the paper's Ant rows double them
# per level (docs/results.md#one-level-against-two-on-the-robots-with-the-models-physics).
_ANT_FIELD_MODEL_K2 = dataclasses.replace(
    _ANT_FIELD_MODEL_K1, n=(20, 5), sigma_gc=(1.0, 2.0), sigma_gs=(0.5, 0.5), eps=(0.6, 1.2),
    init_half_width=(0.3, 0.6), max_half_width=(10.0, 50.0), epochs=100,
)
_HALF_CHEETAH_MODEL_K2 = dataclasses.replace(
    _HALF_CHEETAH_MODEL_K1, n=(20, 5), sigma_gc=(1.0, 2.0), sigma_gs=(0.5, 1.0), eps=(1.0, 2.0),
    init_half_width=(0.5, 1.0), max_half_width=(20.0, 100.0), epochs=300,
)

# The Ant: the constraint solver at 4 iterations instead of the model file's 1, with which the
# Ant's skills flip far more often and barely reach, and a LayerNorm goal-conditioned critic,
# which keeps the critic from collapsing over the full 2.0 M steps
# (docs/results.md#the-ant-with-the-model-files-physics). Two levels run level 0's iterations
# four times per epoch, so that in the same env steps level 0 learns about as much as one
# level's (docs/algorithm.md#differences-from-the-papers-algorithms-1-3).
ANT_FIELD_K1_CPU = dataclasses.replace(_ANT_FIELD_MODEL_K1, solver_iterations=4, critic_layer_norm=True)
ANT_FIELD_K2_CPU = dataclasses.replace(_ANT_FIELD_MODEL_K2, solver_iterations=4, critic_layer_norm=True,
                                       level_repeats=(4, 1))
# The Half Cheetah: level 0 pays 4 per step for a vertical torso (8 on its back; tilt_cost, beyond
# the paper), so that its skills keep it off its back, where they no longer move it; two levels
# repeat level 0 as the Ant's (docs/results.md#the-half-cheetah-on-one-budget).
HALF_CHEETAH_FIELD_K1_CPU = dataclasses.replace(_HALF_CHEETAH_MODEL_K1, tilt_cost=4.0)
HALF_CHEETAH_FIELD_K2_CPU = dataclasses.replace(_HALF_CHEETAH_MODEL_K2, level_repeats=(4, 1), tilt_cost=4.0)

# The cages: each robot's field learner in its Table-1 cage, unchanged so that what differs is
# the cage (the Half Cheetah's without the tilt cost: the paper's reward; docs/results.md#the-cages).
# The two-level ones stop after the epoch that passes the one-level recipe's env steps less
# about half a two-level epoch, so both depths end on the same budget within about 1 %.
ANT_CAGE_K1_CPU = dataclasses.replace(ANT_FIELD_K1_CPU, env="ant_cage")
HALF_CHEETAH_CAGE_K1_CPU = dataclasses.replace(_HALF_CHEETAH_MODEL_K1, env="half_cheetah_cage")
ANT_CAGE_K2_CPU = dataclasses.replace(ANT_FIELD_K2_CPU, env="ant_cage", epochs=1000, max_env_steps=1_990_000)
HALF_CHEETAH_CAGE_K2_CPU = dataclasses.replace(_HALF_CHEETAH_MODEL_K2, level_repeats=(4, 1), env="half_cheetah_cage",
                                               epochs=1000, max_env_steps=2_125_000)


def gpu_size(cpu: HEConfig, epochs: int | None = None) -> HEConfig:
    """A CPU recipe at the paper's shape: 4096 environments and minibatches of 1024, the rest
    unchanged. A recipe that stops at a CPU step budget (``max_env_steps``) runs its ``epochs``
    instead, as a GPU epoch collects 256 times the steps."""
    gpu = dataclasses.replace(cpu, num_envs=4096, batch_size=1024)
    if cpu.max_env_steps is None:
        return gpu
    return dataclasses.replace(gpu, max_env_steps=None, epochs=epochs)


PRESETS: dict[str, tuple[str, HEConfig]] = {
    "point-mass-k1": ("CPU default: point mass, one level of n=10 skills", POINT_MASS_K1),
    "point-mass-k2": ("CPU: point mass, two levels n=(10, 5)", POINT_MASS_K2),
    "ant-field-k1-cpu": (
        "Ant Field, one level of n=20 skills, 16 environments, 300 epochs (2.0 M env steps): 4 solver iterations "
        "(with the model file's one the Ant's skills flip and barely reach), a LayerNorm critic, relabelled goals; "
        "results: docs/results.md", ANT_FIELD_K1_CPU),
    "ant-field-k1-gpu": ("ant-field-k1-cpu at 4096 environments, batch 1024; results: "
                         "docs/results.md#the-ant-at-gpu-scale", gpu_size(ANT_FIELD_K1_CPU)),
    "ant-field-k2-cpu": (
        "Ant Field, two levels n=(20, 5), 16 environments, 100 epochs: ant-field-k1-cpu's learner at both levels, "
        "level 0's iterations four times per epoch so that it learns about as much as one level's", ANT_FIELD_K2_CPU),
    "ant-field-k2-gpu": ("ant-field-k2-cpu at 4096 environments, batch 1024", gpu_size(ANT_FIELD_K2_CPU)),
    "half-cheetah-field-k1-cpu": (
        "Half Cheetah Field, one level of n=20 skills, 16 environments, 320 epochs: level 0 pays 4 per step for a "
        "vertical torso (tilt_cost, beyond the paper), so that its skills keep it off its back",
        HALF_CHEETAH_FIELD_K1_CPU),
    "half-cheetah-field-k1-gpu": ("half-cheetah-field-k1-cpu at 4096 environments, batch 1024",
                                  gpu_size(HALF_CHEETAH_FIELD_K1_CPU)),
    "half-cheetah-field-k2-cpu": (
        "Half Cheetah Field, two levels n=(20, 5), 16 environments, 300 epochs: level 0 four times per epoch and "
        "paying 4 per step for a vertical torso (tilt_cost, beyond the paper)", HALF_CHEETAH_FIELD_K2_CPU),
    "half-cheetah-field-k2-gpu": ("half-cheetah-field-k2-cpu at 4096 environments, batch 1024",
                                  gpu_size(HALF_CHEETAH_FIELD_K2_CPU)),
    "ant-cage-k1-cpu": ("Ant Cage (8 x 8 m walls, a button that opens them), ant-field-k1-cpu's learner; results: "
                        "docs/results.md#the-cages", ANT_CAGE_K1_CPU),
    "ant-cage-k1-gpu": ("ant-cage-k1-cpu at 4096 environments, batch 1024", gpu_size(ANT_CAGE_K1_CPU)),
    "ant-cage-k2-cpu": ("Ant Cage, ant-field-k2-cpu's learner, stopped at ant-cage-k1-cpu's env steps so that both "
                        "depths end on one budget", ANT_CAGE_K2_CPU),
    "ant-cage-k2-gpu": ("ant-cage-k2-cpu at 4096 environments, batch 1024, for ant-field-k2-cpu's 100 epochs "
                        "instead of a CPU step budget", gpu_size(ANT_CAGE_K2_CPU, epochs=ANT_FIELD_K2_CPU.epochs)),
    "half-cheetah-cage-k1-cpu": (
        "Half Cheetah Cage (walls 8 m ahead and behind, a button that opens them), one level of n=20 skills "
        "without a tilt cost; results: docs/results.md#the-cages", HALF_CHEETAH_CAGE_K1_CPU),
    "half-cheetah-cage-k1-gpu": ("half-cheetah-cage-k1-cpu at 4096 environments, batch 1024",
                                 gpu_size(HALF_CHEETAH_CAGE_K1_CPU)),
    "half-cheetah-cage-k2-cpu": (
        "Half Cheetah Cage, two levels n=(20, 5), level 0 four times per epoch, no tilt cost, stopped at "
        "half-cheetah-cage-k1-cpu's env steps so that both depths end on one budget", HALF_CHEETAH_CAGE_K2_CPU),
    "half-cheetah-cage-k2-gpu": ("half-cheetah-cage-k2-cpu at 4096 environments, batch 1024, for 300 epochs "
                                 "instead of a CPU step budget",
                                 gpu_size(HALF_CHEETAH_CAGE_K2_CPU, epochs=_HALF_CHEETAH_MODEL_K2.epochs)),
    "ant-field-k1-paper-small": ("the paper's Table 1: Ant Field Small, k=1",
                                 _paper("ant_field", (20,), (0.4,), (1.75,), (0.6,), 1220, (10.0,))),
    "ant-field-k1-paper-big": ("the paper's Table 1: Ant Field Big, k=1",
                               _paper("ant_field", (80,), (0.4,), (1.75,), (0.6,), 1900, (50.0,))),
    "ant-field-k2-paper-big": ("the paper's Table 1: Ant Field Big, k=2",
                               _paper("ant_field", (20, 10), **_ANT_K2, epochs=1900, max_half_width=(10.0, 200.0))),
    "ant-field-k2-paper-xl": ("the paper's Table 1: Ant Field XL, k=2",
                              _paper("ant_field", (50, 40), **_ANT_K2, epochs=1450, max_half_width=(25.0, 800.0))),
    "ant-field-k3-paper-xl": ("the paper's Table 1: Ant Field XL, k=3",
                              _paper("ant_field", (20, 10, 10), (0.4, 0.8, 1.6), (1.75, 3.5, 7.0), (0.6, 1.2, 2.4),
                                     1450, (10.0, 100.0, 800.0))),
    "half-cheetah-field-k1-paper-small": ("the paper's Table 1: Half Cheetah Small, k=1",
                                          _paper("half_cheetah_field", (20,), (0.3,), (2.0,), (1.0,), 1000, (20.0,))),
    "half-cheetah-field-k1-paper-big": ("the paper's Table 1: Half Cheetah Big, k=1",
                                        _paper("half_cheetah_field", (200,), (0.3,), (2.0,), (1.0,), 1300, (250.0,))),
    "half-cheetah-field-k2-paper-big": ("the paper's Table 1: Half Cheetah Big, k=2",
                                        _paper("half_cheetah_field", (20, 10), **_CHEETAH_K2, epochs=1300,
                                               max_half_width=(20.0, 250.0))),
    "ant-cage-k1-paper": ("the paper's Table 1: Ant Cage, k=1",
                          _paper("ant_cage", (80,), (0.4,), (1.75,), (0.6,), 1900, (50.0,))),
    "ant-cage-k2-paper": ("the paper's Table 1: Ant Cage, k=2",
                          _paper("ant_cage", (20, 10), **_ANT_K2, epochs=1900, max_half_width=(10.0, 100.0))),
    "half-cheetah-cage-k1-paper": ("the paper's Table 1: Half Cheetah Cage, k=1",
                                   _paper("half_cheetah_cage", (200,), (0.3,), (2.0,), (1.0,), 980, (100.0,))),
    "half-cheetah-cage-k2-paper": ("the paper's Table 1: Half Cheetah Cage, k=2",
                                   _paper("half_cheetah_cage", (20, 10), **_CHEETAH_K2, epochs=980,
                                          max_half_width=(20.0, 100.0))),
}
"""Name -> (description, config): the recommended recipes, then the paper's Table-1 rows."""


def _gcrl(base: HEConfig, goal_half_width: float) -> GcrlConfig:
    return GcrlConfig(**{**dataclasses.asdict(base), "gs_iterations": 0, "goal_half_width": (goal_half_width,)})


# Fixed-goal-space GCRL (Choi et al. 2021): an HE preset's goal-conditioned learner with a
# hand-set box, as a user without HE would pick it: the reach asked of the robots' skills (Ant
# 4 x 4 m, Half Cheetah 8 m long), on the point mass 3 x 3 m (about the box HE's point-mass-k1
# learns), and at GPU size the region of Table 2's Small tasks (40 x 40 m, 95 m). The Half
# Cheetah's CPU row keeps the paper's reward, without the tilt cost, as the flat learners it is
# compared with have none (docs/results.md#the-half-cheetah-on-one-budget).
GCRL_PRESETS: dict[str, tuple[str, GcrlConfig]] = {
    "gcrl-point-mass-k1": ("GCRL: point-mass-k1's learner, fixed 3 x 3 m goal box", _gcrl(POINT_MASS_K1, 1.5)),
    "gcrl-ant-field-k1-cpu": ("GCRL: ant-field-k1-cpu's learner (4 solver iterations, LayerNorm critic), fixed "
                              "4 x 4 m goal box", _gcrl(ANT_FIELD_K1_CPU, 2.0)),
    "gcrl-half-cheetah-field-k1-cpu": ("GCRL: half-cheetah-field-k1-cpu's learner without its tilt cost, fixed "
                                       "8 m goal box", _gcrl(_HALF_CHEETAH_MODEL_K1, 4.0)),
    "gcrl-ant-field-k1-gpu": ("GCRL: ant-field-k1-paper-small's learner, fixed 40 x 40 m goal box (GPU scale)",
                              _gcrl(PRESETS["ant-field-k1-paper-small"][1], 20.0)),
    "gcrl-half-cheetah-field-k1-gpu": ("GCRL: half-cheetah-field-k1-paper-small's learner, fixed 95 m goal box "
                                       "(GPU scale)", _gcrl(PRESETS["half-cheetah-field-k1-paper-small"][1], 47.5)),
}
"""Name -> (description, config) of the fixed-goal-space baseline."""
