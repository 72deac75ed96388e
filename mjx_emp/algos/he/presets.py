"""Hierarchical Empowerment's phase-1 presets: one per row of the paper's Table 1, CPU presets
for the point mass and the paper's robots, and the fixed-box GCRL baseline on each.

Values the paper gives (k, n, sigma_gc, sigma_gs, eps, epochs, the 10 x S=50 / 1 x S=10
epoch structure) are its Table 1's and appendix's; why every other value is what it is, with
the runs that chose it, is in docs/presets.md.
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
# A learner that walks the Ant to goals (docs/presets.md#the-robots-on-a-cpu).
_ROBOT_CPU = dict(
    n=(20,), sigma_gs=(0.5,), sigma_gc=(1.0,), epochs=300, num_envs=16, chunk_steps=20, gc_grad_steps=100,
    gs_iterations=8, batch_size=256, hidden=(256, 256), replay_capacity=200_000, gs_replay_capacity=65_536,
    start_capacity=65_536, actor_lr=3e-4, critic_lr=1e-4, gs_actor_lr=2e-4, gs_critic_lr=1e-3, tau=0.005,
    action_noise=0.3, relabel=0.5,
)
ANT_FIELD_CPU_K1 = HEConfig(env="ant_field", eps=(0.6,), init_half_width=(0.3,), max_half_width=(10.0,),
                               **_ROBOT_CPU)
HALF_CHEETAH_CPU_K1 = dataclasses.replace(
    HEConfig(env="half_cheetah_field", eps=(1.0,), init_half_width=(0.5,), max_half_width=(20.0,), **_ROBOT_CPU),
    epochs=320,
)

# Two levels: n = 5 subgoals at level 1, twice level 0's sigma_gc and eps (docs/presets.md#two-levels-on-the-robots).
ANT_FIELD_CPU_K2_WIDE = dataclasses.replace(
    ANT_FIELD_CPU_K1, n=(20, 5), sigma_gc=(1.0, 2.0), sigma_gs=(0.5, 1.0), eps=(0.6, 1.2),
    init_half_width=(0.3, 0.6), max_half_width=(10.0, 50.0), epochs=300,
)
ANT_FIELD_CPU_K2 = dataclasses.replace(ANT_FIELD_CPU_K2_WIDE, sigma_gs=(0.5, 0.5), epochs=100)
HALF_CHEETAH_CPU_K2 = dataclasses.replace(
    HALF_CHEETAH_CPU_K1, n=(20, 5), sigma_gc=(1.0, 2.0), sigma_gs=(0.5, 1.0), eps=(1.0, 2.0),
    init_half_width=(0.5, 1.0), max_half_width=(20.0, 100.0), epochs=300,
)

# ant-field-cpu-k1 with hindsight goals and a LayerNorm critic (docs/presets.md#hindsight-goals-and-layernorm).
ANT_FIELD_CPU_K1_HER_LN = dataclasses.replace(ANT_FIELD_CPU_K1, her=0.5, critic_layer_norm=True, epochs=120)

# The CPU Ant presets with the constraint solver at 4 iterations instead of the model file's 1
# (docs/presets.md#the-accurate-physics-presets).
ANT_FIELD_CPU_K1_4ITER = dataclasses.replace(ANT_FIELD_CPU_K1, solver_iterations=4)
ANT_FIELD_CPU_K2_4ITER = dataclasses.replace(ANT_FIELD_CPU_K2, solver_iterations=4)
HALF_CHEETAH_CPU_K1_4ITER = dataclasses.replace(HALF_CHEETAH_CPU_K1, solver_iterations=4)

# The accurate-physics Ant presets with a LayerNorm goal-conditioned critic, which keeps the critic
# from collapsing over the full 2.0 M steps (docs/presets.md#the-accurate-physics-presets).
ANT_FIELD_CPU_K1_4ITER_LN = dataclasses.replace(ANT_FIELD_CPU_K1_4ITER, critic_layer_norm=True)
ANT_FIELD_CPU_K2_4ITER_LN = dataclasses.replace(ANT_FIELD_CPU_K2_4ITER, critic_layer_norm=True)
# The same with half the goal-space posterior's sigma_gs: the box settles about sqrt(2) sigma_gs past the
# skills' reach, so a smaller sigma_gs trades box size for the skills' success (docs/presets.md#a-tighter-box).
ANT_FIELD_CPU_K1_4ITER_LN_GS025 = dataclasses.replace(ANT_FIELD_CPU_K1_4ITER_LN, sigma_gs=(0.25,))
# The same learner trained on what its flips cut short: the goal-conditioned level scores a flip as staying
# where the Ant fell, the goal space scores the episode at its last state (docs/presets.md#learning-from-flips).
ANT_FIELD_CPU_K1_4ITER_LN_RESETS = dataclasses.replace(ANT_FIELD_CPU_K1_4ITER_LN, learn_from_resets=True)
# The same with the goal space scoring a skill that flipped as one that never left its start, so a box
# whose far goals flip the Ant earns no more than a box of skills that stay put (docs/presets.md#learning-from-flips).
ANT_FIELD_CPU_K1_4ITER_LN_RESETS_START = dataclasses.replace(ANT_FIELD_CPU_K1_4ITER_LN_RESETS, reset_outcome="start")
# The same learner with level 0 paying for tilting its torso (1 per step on its side), so the skills
# learn gaits that flip less (docs/presets.md#paying-for-tilt).
ANT_FIELD_CPU_K1_4ITER_LN_TILT = dataclasses.replace(ANT_FIELD_CPU_K1_4ITER_LN, tilt_cost=1.0)
ANT_FIELD_CPU_K2_4ITER_LN_TILT = dataclasses.replace(ANT_FIELD_CPU_K2_4ITER_LN, tilt_cost=1.0)
# The two-level learner with level 0's iterations run four times per epoch: in the same env steps its
# level 0 gets over half the one-level learner's iterations, not a quarter (docs/presets.md#repeating-level-0).
ANT_FIELD_CPU_K2_4ITER_LN_REP4 = dataclasses.replace(ANT_FIELD_CPU_K2_4ITER_LN, level_repeats=(4, 1))
# The same two-level learner with level 0 paying four times the tilt cost, as the Half Cheetah's
# half-cheetah-cpu-k2-rep4-tilt4, and the one-level learner with the same cost to compare it with.
ANT_FIELD_CPU_K2_4ITER_LN_REP4_TILT4 = dataclasses.replace(ANT_FIELD_CPU_K2_4ITER_LN_REP4, tilt_cost=4.0)
ANT_FIELD_CPU_K1_4ITER_LN_TILT4 = dataclasses.replace(ANT_FIELD_CPU_K1_4ITER_LN, tilt_cost=4.0)
HALF_CHEETAH_CPU_K2_REP4 = dataclasses.replace(HALF_CHEETAH_CPU_K2, level_repeats=(4, 1))
# The one-level Half Cheetah with Table 1's sigma_gs (2.0) instead of 0.5: its box is reached on every goal
# but grows too slowly for phase 2's 95 m (docs/presets.md#the-half-cheetahs-box-with-table-1s-sigma_gs).
HALF_CHEETAH_CPU_K1_GS2 = dataclasses.replace(HALF_CHEETAH_CPU_K1, sigma_gs=(2.0,))
# The one-level Half Cheetah and the two-level one with level 0 four times per epoch, with level 0 paying for
# tilting its torso, so its skills keep it off its back, where they no longer move it
# (docs/presets.md#the-half-cheetah-on-its-back).
HALF_CHEETAH_CPU_K1_TILT = dataclasses.replace(HALF_CHEETAH_CPU_K1, tilt_cost=1.0)
HALF_CHEETAH_CPU_K2_REP4_TILT = dataclasses.replace(HALF_CHEETAH_CPU_K2_REP4, tilt_cost=1.0)
# Both changes at once: the tilt cost keeps the cheetah upright for more attempts and Table 1's sigma_gs grows a
# longer box, the two things its phase 2 lacks (docs/presets.md#the-half-cheetah-on-its-back).
HALF_CHEETAH_CPU_K1_TILT_GS2 = dataclasses.replace(HALF_CHEETAH_CPU_K1_TILT, sigma_gs=(2.0,))
# Four times the tilt cost: a torso on its back costs 8 per step, what the goal reward (sigma_gc 1) charges a 4 m miss.
HALF_CHEETAH_CPU_K1_TILT4 = dataclasses.replace(HALF_CHEETAH_CPU_K1, tilt_cost=4.0)
# The same with four times the paper's S=10 goal-space steps per epoch, so the box grows faster while the cost keeps
# the cheetah upright (docs/presets.md#the-half-cheetah-on-its-back).
HALF_CHEETAH_CPU_K1_TILT4_GS40 = dataclasses.replace(HALF_CHEETAH_CPU_K1_TILT4, gs_grad_steps=40)
# The two-level learner with the same cost at level 0, so that a chain of five skills stays upright.
HALF_CHEETAH_CPU_K2_REP4_TILT4 = dataclasses.replace(HALF_CHEETAH_CPU_K2_REP4, tilt_cost=4.0)

# The cages at CPU scale: the best CPU learner of each robot's field, in its Table-1 cage
# (docs/presets.md#the-cages-on-a-cpu).
ANT_CAGE_CPU_K1 = dataclasses.replace(ANT_FIELD_CPU_K1_4ITER_LN, env="ant_cage")
HALF_CHEETAH_CAGE_CPU_K1 = dataclasses.replace(HALF_CHEETAH_CPU_K1, env="half_cheetah_cage")
# Their two-level twins: each field's two-level learner with level 0 four times per epoch, in the same cage,
# stopped after the epoch that passes the one-level preset's env steps less about half a two-level epoch, so
# both depths end on the same budget within about 1 %.
ANT_CAGE_CPU_K2 = dataclasses.replace(ANT_FIELD_CPU_K2_4ITER_LN_REP4, env="ant_cage", epochs=1000,
                                      max_env_steps=1_990_000)
HALF_CHEETAH_CAGE_CPU_K2 = dataclasses.replace(HALF_CHEETAH_CPU_K2_REP4, env="half_cheetah_cage", epochs=1000,
                                               max_env_steps=2_125_000)

PRESETS: dict[str, tuple[str, HEConfig]] = {
    "point-mass-k1": ("CPU default: point mass, one level of n=10 skills", POINT_MASS_K1),
    "point-mass-k2": ("CPU: point mass, two levels n=(10, 5)", POINT_MASS_K2),
    "ant-field-cpu-k1": ("CPU: the paper's Ant, one level of n=20 skills", ANT_FIELD_CPU_K1),
    "half-cheetah-cpu-k1": ("CPU: the paper's Half Cheetah, one level of n=20 skills", HALF_CHEETAH_CPU_K1),
    "ant-field-cpu-k2": ("CPU: the paper's Ant, two levels n=(20, 5)", ANT_FIELD_CPU_K2),
    "ant-field-cpu-k2-wide": ("CPU: ant-field-cpu-k2 with level 1's sigma_gs doubled: larger boxes, "
                              "lower success", ANT_FIELD_CPU_K2_WIDE),
    "half-cheetah-cpu-k2": ("CPU: the paper's Half Cheetah, two levels n=(20, 5)", HALF_CHEETAH_CPU_K2),
    "ant-field-cpu-k1-4iter": ("CPU: ant-field-cpu-k1 with 4 solver iterations (accurate contacts)",
                               ANT_FIELD_CPU_K1_4ITER),
    "ant-field-cpu-k2-4iter": ("CPU: ant-field-cpu-k2 with 4 solver iterations (accurate contacts)",
                               ANT_FIELD_CPU_K2_4ITER),
    "ant-field-cpu-k1-4iter-ln": ("CPU: ant-field-cpu-k1-4iter with a LayerNorm critic (on seed 0 its success holds "
                                  "to 2.0 M steps)",
                                  ANT_FIELD_CPU_K1_4ITER_LN),
    "ant-field-cpu-k2-4iter-ln": ("CPU: ant-field-cpu-k2-4iter with a LayerNorm critic at both levels",
                                  ANT_FIELD_CPU_K2_4ITER_LN),
    "ant-field-cpu-k1-4iter-ln-gs0.25": ("CPU: ant-field-cpu-k1-4iter-ln with sigma_gs 0.25 instead of 0.5: a box "
                                         "that settles nearer the skills' reach", ANT_FIELD_CPU_K1_4ITER_LN_GS025),
    "ant-field-cpu-k1-4iter-ln-resets": ("CPU: ant-field-cpu-k1-4iter-ln learning from what flips cut short "
                                         "(learn_from_resets)", ANT_FIELD_CPU_K1_4ITER_LN_RESETS),
    "ant-field-cpu-k1-4iter-ln-resets-start": ("CPU: ant-field-cpu-k1-4iter-ln-resets with a flipped skill scored "
                                               "in the goal space as one that never moved (reset_outcome start)",
                                               ANT_FIELD_CPU_K1_4ITER_LN_RESETS_START),
    "ant-field-cpu-k1-4iter-ln-tilt1": ("CPU: ant-field-cpu-k1-4iter-ln with level 0 paying 1 per step for a torso "
                                        "on its side (tilt_cost)", ANT_FIELD_CPU_K1_4ITER_LN_TILT),
    "ant-field-cpu-k2-4iter-ln-tilt1": ("CPU: ant-field-cpu-k2-4iter-ln with level 0 paying 1 per step for a torso "
                                        "on its side (tilt_cost)", ANT_FIELD_CPU_K2_4ITER_LN_TILT),
    "ant-field-cpu-k2-4iter-ln-rep4": ("CPU: ant-field-cpu-k2-4iter-ln with level 0's iterations run four times "
                                       "per epoch (level_repeats)", ANT_FIELD_CPU_K2_4ITER_LN_REP4),
    "ant-field-cpu-k2-4iter-ln-rep4-tilt4": ("CPU: ant-field-cpu-k2-4iter-ln-rep4 with level 0 paying 4 per step for "
                                             "a torso on its side (tilt_cost)", ANT_FIELD_CPU_K2_4ITER_LN_REP4_TILT4),
    "ant-field-cpu-k1-4iter-ln-tilt4": ("CPU: ant-field-cpu-k1-4iter-ln with level 0 paying 4 per step for a torso "
                                        "on its side (tilt_cost)", ANT_FIELD_CPU_K1_4ITER_LN_TILT4),
    "half-cheetah-cpu-k2-rep4": ("CPU: half-cheetah-cpu-k2 with level 0's iterations run four times per epoch "
                                 "(level_repeats)", HALF_CHEETAH_CPU_K2_REP4),
    "half-cheetah-cpu-k1-gs2": ("CPU: half-cheetah-cpu-k1 with Table 1's sigma_gs of 2.0 instead of 0.5 "
                                "(a box that grows faster)", HALF_CHEETAH_CPU_K1_GS2),
    "half-cheetah-cpu-k1-tilt1": ("CPU: half-cheetah-cpu-k1 with level 0 paying 1 per step for a vertical torso "
                                  "(tilt_cost), so its skills keep off its back", HALF_CHEETAH_CPU_K1_TILT),
    "half-cheetah-cpu-k1-tilt1-gs2": ("CPU: half-cheetah-cpu-k1-tilt1 with Table 1's sigma_gs of 2.0 (a box that "
                                      "grows faster, skills that keep off its back)", HALF_CHEETAH_CPU_K1_TILT_GS2),
    "half-cheetah-cpu-k1-tilt4": ("CPU: half-cheetah-cpu-k1 with level 0 paying 4 per step for a vertical torso "
                                  "(tilt_cost)", HALF_CHEETAH_CPU_K1_TILT4),
    "half-cheetah-cpu-k1-tilt4-gs40": ("CPU: half-cheetah-cpu-k1-tilt4 with 40 goal-space steps per epoch instead of "
                                       "the paper's 10 (a box that grows faster)", HALF_CHEETAH_CPU_K1_TILT4_GS40),
    "half-cheetah-cpu-k2-rep4-tilt1": ("CPU: half-cheetah-cpu-k2-rep4 with level 0 paying 1 per step for a "
                                       "vertical torso (tilt_cost)", HALF_CHEETAH_CPU_K2_REP4_TILT),
    "half-cheetah-cpu-k2-rep4-tilt4": ("CPU: half-cheetah-cpu-k2-rep4 with level 0 paying 4 per step for a "
                                       "vertical torso (tilt_cost)", HALF_CHEETAH_CPU_K2_REP4_TILT4),
    "half-cheetah-cpu-k1-4iter": ("CPU: half-cheetah-cpu-k1 with 4 solver iterations (accurate contacts)",
                                  HALF_CHEETAH_CPU_K1_4ITER),
    "ant-field-cpu-k1-her-ln": ("CPU: ant-field-cpu-k1 with hindsight goals and a LayerNorm critic, 120 epochs",
                                ANT_FIELD_CPU_K1_HER_LN),
    "ant-cage-cpu-k1": ("CPU: ant-field-cpu-k1-4iter-ln in the Ant Cage (8 x 8 m walls, a button that opens them)",
                        ANT_CAGE_CPU_K1),
    "half-cheetah-cage-cpu-k1": ("CPU: half-cheetah-cpu-k1 in the Half Cheetah Cage (walls 8 m ahead and behind, "
                                 "a button that opens them)", HALF_CHEETAH_CAGE_CPU_K1),
    "ant-cage-cpu-k2": ("CPU: ant-field-cpu-k2-4iter-ln-rep4 in the Ant Cage, on ant-cage-cpu-k1's env steps",
                        ANT_CAGE_CPU_K2),
    "half-cheetah-cage-cpu-k2": ("CPU: half-cheetah-cpu-k2-rep4 in the Half Cheetah Cage, on "
                                 "half-cheetah-cage-cpu-k1's env steps", HALF_CHEETAH_CAGE_CPU_K2),
    "ant-field-small-k1": ("Table 1: Ant Field Small, k=1",
                           _paper("ant_field", (20,), (0.4,), (1.75,), (0.6,), 1220, (10.0,))),
    "ant-field-big-k1": ("Table 1: Ant Field Big, k=1",
                         _paper("ant_field", (80,), (0.4,), (1.75,), (0.6,), 1900, (50.0,))),
    "ant-field-big-k2": ("Table 1: Ant Field Big, k=2",
                         _paper("ant_field", (20, 10), **_ANT_K2, epochs=1900, max_half_width=(10.0, 200.0))),
    "ant-field-xl-k2": ("Table 1: Ant Field XL, k=2",
                        _paper("ant_field", (50, 40), **_ANT_K2, epochs=1450, max_half_width=(25.0, 800.0))),
    "ant-field-xl-k3": ("Table 1: Ant Field XL, k=3",
                        _paper("ant_field", (20, 10, 10), (0.4, 0.8, 1.6), (1.75, 3.5, 7.0), (0.6, 1.2, 2.4),
                               1450, (10.0, 100.0, 800.0))),
    "half-cheetah-small-k1": ("Table 1: Half Cheetah Small, k=1",
                              _paper("half_cheetah_field", (20,), (0.3,), (2.0,), (1.0,), 1000, (20.0,))),
    "half-cheetah-big-k1": ("Table 1: Half Cheetah Big, k=1",
                            _paper("half_cheetah_field", (200,), (0.3,), (2.0,), (1.0,), 1300, (250.0,))),
    "half-cheetah-big-k2": ("Table 1: Half Cheetah Big, k=2",
                            _paper("half_cheetah_field", (20, 10), **_CHEETAH_K2, epochs=1300,
                                   max_half_width=(20.0, 250.0))),
    "ant-cage-k1": ("Table 1: Ant Cage, k=1",
                    _paper("ant_cage", (80,), (0.4,), (1.75,), (0.6,), 1900, (50.0,))),
    "ant-cage-k2": ("Table 1: Ant Cage, k=2",
                    _paper("ant_cage", (20, 10), **_ANT_K2, epochs=1900, max_half_width=(10.0, 100.0))),
    "half-cheetah-cage-k1": ("Table 1: Half Cheetah Cage, k=1",
                             _paper("half_cheetah_cage", (200,), (0.3,), (2.0,), (1.0,), 980, (100.0,))),
    "half-cheetah-cage-k2": ("Table 1: Half Cheetah Cage, k=2",
                             _paper("half_cheetah_cage", (20, 10), **_CHEETAH_K2, epochs=980,
                                    max_half_width=(20.0, 100.0))),
}


def _gcrl(base: HEConfig, goal_half_width: float) -> GcrlConfig:
    return GcrlConfig(**{**dataclasses.asdict(base), "gs_iterations": 0, "goal_half_width": (goal_half_width,)})


# Fixed-goal-space GCRL (Choi et al. 2021): the HE presets' goal-conditioned learner with a
# hand-set box, as a user without HE would pick it: the reach asked of the robots' skills (Ant
# 4 x 4 m, Half Cheetah 8 m long) and, on the point mass, 3 x 3 m (HE's point-mass-k1
# learns about 2.8 x 2.8 m).
GCRL_PRESETS: dict[str, tuple[str, GcrlConfig]] = {
    "gcrl-point-mass": ("GCRL: point-mass-k1's learner, fixed 3 x 3 m goal box", _gcrl(POINT_MASS_K1, 1.5)),
    "gcrl-ant-field-cpu": ("GCRL: ant-field-cpu-k1's learner, fixed 4 x 4 m goal box", _gcrl(ANT_FIELD_CPU_K1, 2.0)),
    "gcrl-ant-field-cpu-4iter-ln": ("GCRL: ant-field-cpu-k1-4iter-ln's learner (4 solver iterations, LayerNorm "
                                    "critic), fixed 4 x 4 m goal box", _gcrl(ANT_FIELD_CPU_K1_4ITER_LN, 2.0)),
    "gcrl-half-cheetah-cpu": ("GCRL: half-cheetah-cpu-k1's learner, fixed 8 m goal box",
                              _gcrl(HALF_CHEETAH_CPU_K1, 4.0)),
    "gcrl-ant-field-small": ("GCRL: ant-field-small-k1's learner, fixed 40 x 40 m goal box (GPU scale)",
                             _gcrl(PRESETS["ant-field-small-k1"][1], 20.0)),
    "gcrl-half-cheetah-small": ("GCRL: half-cheetah-small-k1's learner, fixed 95 m goal box (GPU scale)",
                                _gcrl(PRESETS["half-cheetah-small-k1"][1], 47.5)),
}
"""Name -> (description, config) of the fixed-goal-space baseline."""
