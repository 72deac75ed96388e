"""Training presets: phase 1 per row of the paper's Table 1, phase 2 per row of its Table 2,
plus CPU presets (point mass, and the paper's robots with the learner described above
``_ROBOT_CPU``).

Values the paper gives (k, n, sigma_gc, sigma_gs, eps, epochs, and the 10 x S=50 /
1 x S=10 epoch structure) are copied from its Table 1 and appendix. It leaves the rest
open; our choices, used by every paper preset:

- networks 256x256 ReLU MLPs, Adam 3e-4 for the goal-conditioned actor and critic,
  1e-4 for the goal-space actor and 1e-3 for the goal-space critic (the goal-space actor
  must move slower than the goal-conditioned policy can follow; faster rates made the
  boxes overrun the policy's reach on point mass), gamma 0.95, tau 0.01;
- 4096 environments per collection and minibatches of 1024 (GPU scale);
- every level's box starts at half-width eps/2; the soft bound ``max_half_width`` is a
  safety rail well above the phase-2 goal region (Table 2), not a target.

The point-mass presets are sized for a 2-core CPU (the k=1 default learns in under two
minutes there). Their sigma_gc = 0.4 keeps the 2-D reward peak log N(0; 0, 0.4) at about
0 (as in the Ant rows): with a smaller sigma the reward near the goal is positive, and
hovering just outside eps pays more than reaching. sigma_gs sets how far past the
policy's reach a box settles: where goals at the box edge are missed by m, growing the
box further costs about m^2 / (2 sigma_gs^2) per unit of log half-width against the
entropy's 1, so the edge settles about sqrt(2) sigma_gs beyond reach. With sigma_gs = 0.4
(0.57 beyond a 2 m reach) the greedy success within the box ended at 0.65-0.82 over three
seeds; with 0.2 it ended at 0.98-0.99 (two seeds). The two-level preset explores with
action noise 0.1 instead of 0.2: with 0.2 its level-1 policy ran away early (final
distances of metres to goals 0.4 m away) and the level-1 box collapsed; with 0.1 it grew. The goal-space actor's 2e-4 is twice
the paper presets' rate to fit CPU time, which makes the early epochs noisier.

The two-level preset also runs 8 goal-space iterations per level per epoch instead of 1.
With 64 environments one iteration is 64 episodes (the paper's 4096 environments give
4096), too few for the goal-space critic at moving start states: there level 0's box
swung out to |shift| ~2.5 by epoch 9 (a 1-2 m reach), level 1's subgoals fell out of
reach, its critic diverged and the agent ran away (README, "Why level 1 of point-mass-k2
broke down"). With 8, level 0's mean |shift| at moving states was 0.3-0.6 at epochs 9-15.
"""

from __future__ import annotations

import dataclasses

from mjx_emp.algos.he.config import GcrlConfig, Phase2Config, TrainConfig

_PAPER = dict(
    num_envs=4096, batch_size=1024, hidden=(256, 256), replay_capacity=500_000,
    gs_replay_capacity=65_536, start_capacity=65_536, actor_lr=3e-4, critic_lr=3e-4,
    gs_actor_lr=1e-4, gs_critic_lr=1e-3,
)


def _paper(env: str, n, sigma_gc, sigma_gs, eps, epochs: int, max_half_width) -> TrainConfig:
    return TrainConfig(
        env=env, n=tuple(n), sigma_gc=tuple(sigma_gc), sigma_gs=tuple(sigma_gs), eps=tuple(eps),
        init_half_width=tuple(e / 2 for e in eps), max_half_width=tuple(max_half_width),
        epochs=epochs, chunk_steps=n[0], **_PAPER,
    )


_ANT_K2 = dict(sigma_gc=(0.4, 0.8), sigma_gs=(1.75, 3.5), eps=(0.6, 1.2))
_CHEETAH_K2 = dict(sigma_gc=(0.3, 3.0), sigma_gs=(2.0, 10.0), eps=(1.0, 2.0))

POINT_MASS_K1 = TrainConfig(
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
# Found on Ant Field with a fixed goal box of +-1.5 m (goal-space learning off) before the
# curriculum runs; each figure is from a run of 24-115 epochs (README, "Learning on the
# robots"; benchmarks/results/ant_learner_diagnostics_cpu.json). The Table-1 learner (DDPG, sigma_gc 0.4, critic rate 3e-4, tau 0.01) did not
# learn to walk to goals: final distance stayed ~1.0-1.2 m, the greedy policy moved 0.06 m
# per action (random actions: 0.18) and the critic loss grew without bound (4 -> 1.2e3 in
# 15 epochs; with TD3's twin critics to 2.7e5). What made a critic that tracks the
# policy's returns (Q -28 against a rollout's -28 at 1-1.5 m) and a box that grows:
# - sigma_gc = 1.0 instead of 0.4: the reward's quadratic term is 6x flatter, so errors
#   on far goals no longer swamp the critic (loss ~30 instead of ~300 with the rest equal);
# - critic rate 1e-4 and tau 0.005 (with 3e-4 / 0.01 the loss kept growing);
# - half of every minibatch relabelled with another row's goal offset (``relabel``);
# - 16 environments and 100 gradient steps per iteration: ~50 sampled rows per collected
#   transition instead of ~5, as the CPU's gradient steps are cheap beside its physics;
# - action noise 0.3 and 8 goal-space iterations per epoch (16 episodes per iteration);
# - sigma_gs = 0.5, which settles the box about 0.7 m beyond the policy's reach.
# Ant: 300 epochs (2.0 M environment steps), Half Cheetah 320: by then the Ant's box had
# stopped growing (about 10-12 m^2 from epoch 80 on) and the cheetah's length wavered
# around 6-8 m. The seed-0 runs were started for 600 epochs and evaluated at these
# checkpoints, which are bitwise what a run of this length ends with.
_ROBOT_CPU = dict(
    n=(20,), sigma_gs=(0.5,), sigma_gc=(1.0,), epochs=300, num_envs=16, chunk_steps=20, gc_grad_steps=100,
    gs_iterations=8, batch_size=256, hidden=(256, 256), replay_capacity=200_000, gs_replay_capacity=65_536,
    start_capacity=65_536, actor_lr=3e-4, critic_lr=1e-4, gs_actor_lr=2e-4, gs_critic_lr=1e-3, tau=0.005,
    action_noise=0.3, relabel=0.5,
)
ANT_FIELD_CPU_K1 = TrainConfig(env="ant_field", eps=(0.6,), init_half_width=(0.3,), max_half_width=(10.0,),
                               **_ROBOT_CPU)
HALF_CHEETAH_CPU_K1 = dataclasses.replace(
    TrainConfig(env="half_cheetah_field", eps=(1.0,), init_half_width=(0.5,), max_half_width=(20.0,), **_ROBOT_CPU),
    epochs=320,
)

# Two levels: level 0 as above; level 1 gets n = 5 subgoals (the paper's Ant Field Big
# uses 10) to keep a CPU epoch affordable (each level-1 iteration runs until all 16
# environments finished an episode of up to 100 actions), and twice level 0's sigma_gc and
# eps, as the paper's Ant rows double them per level. 300 epochs: a k=2 epoch simulates
# several times a k=1 epoch's steps.
# ``ant-field-cpu-k2-wide`` also doubles sigma_gs (1.0 at level 1), which settles the top
# box about 1.4 m beyond level 1's reach: on seeds 0 and 1 it grew to 37 and 56 m^2 by epoch
# 300 while greedy success fell to 0.60 and 0.45 (at k=1's 2.0 M steps: 28.5 and 34.5 m^2
# at 0.69 and 0.51). ``ant-field-cpu-k2`` keeps level 1's sigma_gs at 0.5: on seed 0 the top
# box settled at 12-17 m^2 from epoch 60 on with per-epoch success 0.6-1.0 (at 2.0 M steps
# 14.1 m^2 at 0.88, mean of 11 epochs); 100 epochs (about 2.9 M steps) cover k=1's budget.
ANT_FIELD_CPU_K2_WIDE = dataclasses.replace(
    ANT_FIELD_CPU_K1, n=(20, 5), sigma_gc=(1.0, 2.0), sigma_gs=(0.5, 1.0), eps=(0.6, 1.2),
    init_half_width=(0.3, 0.6), max_half_width=(10.0, 50.0), epochs=300,
)
ANT_FIELD_CPU_K2 = dataclasses.replace(ANT_FIELD_CPU_K2_WIDE, sigma_gs=(0.5, 0.5), epochs=100)
HALF_CHEETAH_CPU_K2 = dataclasses.replace(
    HALF_CHEETAH_CPU_K1, n=(20, 5), sigma_gc=(1.0, 2.0), sigma_gs=(0.5, 1.0), eps=(1.0, 2.0),
    init_half_width=(0.5, 1.0), max_half_width=(20.0, 100.0), epochs=300,
)

# The goal-conditioned learner with the two options that helped the learner alone on the Ant
# (docs/learner.md, fixed-box screen): half of every minibatch relabelled with a goal its
# episode reached later (her, before the offset swap of ``relabel``) and LayerNorm in the
# goal-conditioned critic. Everything else is ant-field-cpu-k1's. On the curriculum its four
# seeds were measured at epoch 75 (0.50 M steps) of the 120 set here; there it did not beat
# ant-field-cpu-k1 (smaller boxes at slightly higher success, and far more flips), so no
# other robot preset takes this learner.
ANT_FIELD_CPU_K1_HER_LN = dataclasses.replace(ANT_FIELD_CPU_K1, her=0.5, critic_layer_norm=True, epochs=120)

PRESETS: dict[str, tuple[str, TrainConfig]] = {
    "point-mass-k1": ("CPU default: point mass, one level of n=10 skills", POINT_MASS_K1),
    "point-mass-k2": ("CPU: point mass, two levels n=(10, 5)", POINT_MASS_K2),
    "ant-field-cpu-k1": ("CPU: the paper's Ant, one level of n=20 skills", ANT_FIELD_CPU_K1),
    "half-cheetah-cpu-k1": ("CPU: the paper's Half Cheetah, one level of n=20 skills", HALF_CHEETAH_CPU_K1),
    "ant-field-cpu-k2": ("CPU: the paper's Ant, two levels n=(20, 5)", ANT_FIELD_CPU_K2),
    "ant-field-cpu-k2-wide": ("CPU: ant-field-cpu-k2 with level 1's sigma_gs doubled: larger boxes, "
                              "lower success", ANT_FIELD_CPU_K2_WIDE),
    "half-cheetah-cpu-k2": ("CPU: the paper's Half Cheetah, two levels n=(20, 5)", HALF_CHEETAH_CPU_K2),
    "ant-field-cpu-k1-her-ln": ("CPU: ant-field-cpu-k1 with hindsight goals and a LayerNorm critic, 120 epochs",
                                ANT_FIELD_CPU_K1_HER_LN),
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


# ---- phase 2 -------------------------------------------------------------------------
# Table 2 gives n (attempts), eps and the region's length per dimension. The rest is ours:
# the reward's sigma equals eps (phase 1's goal-conditioned reward, as wide as the goal
# threshold); Half Cheetah's regions lie ahead of the start by a tenth of their length
# (the paper shifts them "slightly" forward without a number); the GPU-scale learning
# settings below; 100 epochs.
_PHASE2_PAPER = dict(
    num_envs=1024, batch_size=1024, hidden=(256, 256), replay_capacity=500_000, epochs=100,
)



def _gcrl(base: TrainConfig, goal_half_width: float) -> GcrlConfig:
    return GcrlConfig(**{**dataclasses.asdict(base), "gs_iterations": 0, "goal_half_width": (goal_half_width,)})


# Fixed-goal-space GCRL (Choi et al. 2021): the HE presets' goal-conditioned learner with a
# hand-set box, as a user without HE would pick it: the targets of the robots issue (Ant
# 4 x 4 m, Half Cheetah 8 m long) and, on the point mass, 3 x 3 m (HE's point-mass-k1
# learns about 2.8 x 2.8 m).
GCRL_PRESETS: dict[str, tuple[str, GcrlConfig]] = {
    "gcrl-point-mass": ("GCRL: point-mass-k1's learner, fixed 3 x 3 m goal box", _gcrl(POINT_MASS_K1, 1.5)),
    "gcrl-ant-field-cpu": ("GCRL: ant-field-cpu-k1's learner, fixed 4 x 4 m goal box", _gcrl(ANT_FIELD_CPU_K1, 2.0)),
    "gcrl-half-cheetah-cpu": ("GCRL: half-cheetah-cpu-k1's learner, fixed 8 m goal box",
                              _gcrl(HALF_CHEETAH_CPU_K1, 4.0)),
    "gcrl-ant-field-small": ("GCRL: ant-field-small-k1's learner, fixed 40 x 40 m goal box (GPU scale)",
                             _gcrl(PRESETS["ant-field-small-k1"][1], 20.0)),
    "gcrl-half-cheetah-small": ("GCRL: half-cheetah-small-k1's learner, fixed 95 m goal box (GPU scale)",
                                _gcrl(PRESETS["half-cheetah-small-k1"][1], 47.5)),
}
"""Name -> (description, config) of the fixed-goal-space baseline."""

def _phase2(n: int, eps: float, length: float, dims: int, ahead: float = 0.0) -> Phase2Config:
    return Phase2Config(n=n, eps=eps, sigma=eps, region=(length,) * dims,
                        region_offset=(ahead * length,) + (0.0,) * (dims - 1), **_PHASE2_PAPER)


def _robot_phase2(n: int, eps: float, length: float, dims: int, ahead: float = 0.0) -> Phase2Config:
    """A Table-2 task sized for the CPU: 16 environments, 30 epochs."""
    return dataclasses.replace(_phase2(n, eps, length, dims, ahead), num_envs=16, batch_size=256, epochs=30,
                               replay_capacity=100_000)


_ANT_SMALL_TASK = _robot_phase2(10, 1.8, 40, 2)
_CHEETAH_SMALL_TASK = _robot_phase2(10, 3.0, 95, 1, ahead=0.1)

_POINT_MASS_PHASE2 = Phase2Config(n=3, eps=0.6, sigma=0.6, region=(2.4, 2.4), region_offset=(0.0, 0.0), epochs=30)

PHASE2_PRESETS: dict[str, tuple[str, str, Phase2Config]] = {
    # name: (description, the phase-1 preset it builds on, config). A run without a named
    # preset gets the first one whose phase-1 preset has its domain and n.
    "point-mass-k1": ("CPU default: goals in a 2.4 x 2.4 square, inside the k=1 agent's learned "
                      "goal space; 3 attempts", "point-mass-k1", _POINT_MASS_PHASE2),
    "point-mass-wide-k2": ("CPU: goals in an 8 x 8 square, beyond the k=1 goal space; 3 attempts",
                           "point-mass-k2", dataclasses.replace(_POINT_MASS_PHASE2, region=(8.0, 8.0))),
    "point-mass-wide-k1": ("CPU: point-mass-wide-k2's task for the k=1 agent", "point-mass-k1",
                           dataclasses.replace(_POINT_MASS_PHASE2, region=(8.0, 8.0))),
    "point-mass-wider-k2": ("CPU: goals in a 16 x 16 square, beyond 3 of the k=1 agent's skills; 3 attempts",
                            "point-mass-k2", dataclasses.replace(_POINT_MASS_PHASE2, region=(16.0, 16.0))),
    "point-mass-wider-k1": ("CPU: point-mass-wider-k2's task for the k=1 agent", "point-mass-k1",
                            dataclasses.replace(_POINT_MASS_PHASE2, region=(16.0, 16.0))),
    "ant-field-cpu-k1": ("CPU: Table 2's Ant Field Small task (40 x 40, 10 attempts, eps 1.8)",
                         "ant-field-cpu-k1", _ANT_SMALL_TASK),
    "ant-field-cpu-k2": ("CPU: Table 2's Ant Field Small task for the two-level agent", "ant-field-cpu-k2",
                         _ANT_SMALL_TASK),
    "ant-field-cpu-k2-wide": ("CPU: Table 2's Ant Field Small task for ant-field-cpu-k2-wide",
                              "ant-field-cpu-k2-wide", _ANT_SMALL_TASK),
    "half-cheetah-cpu-k1": ("CPU: Table 2's Half Cheetah Small task (95 m, 10 attempts, eps 3.0)",
                            "half-cheetah-cpu-k1", _CHEETAH_SMALL_TASK),
    "half-cheetah-cpu-k2": ("CPU: Table 2's Half Cheetah Small task for the two-level agent",
                            "half-cheetah-cpu-k2", _CHEETAH_SMALL_TASK),
    "ant-field-small-k1": ("Table 2: Ant Field Small, k=1", "ant-field-small-k1", _phase2(10, 1.8, 40, 2)),
    "ant-field-big-k1": ("Table 2: Ant Field Big, k=1", "ant-field-big-k1", _phase2(25, 2.4, 200, 2)),
    "ant-field-big-k2": ("Table 2: Ant Field Big, k=2", "ant-field-big-k2", _phase2(10, 2.4, 200, 2)),
    "ant-field-xl-k2": ("Table 2: Ant Field XL, k=2", "ant-field-xl-k2", _phase2(10, 9.6, 800, 2)),
    "ant-field-xl-k3": ("Table 2: Ant Field XL, k=3", "ant-field-xl-k3", _phase2(10, 9.6, 800, 2)),
    "half-cheetah-small-k1": ("Table 2: Half Cheetah Small, k=1", "half-cheetah-small-k1",
                              _phase2(10, 3.0, 95, 1, ahead=0.1)),
    "half-cheetah-big-k1": ("Table 2: Half Cheetah Big, k=1", "half-cheetah-big-k1",
                            _phase2(10, 10.0, 450, 1, ahead=0.1)),
    "half-cheetah-big-k2": ("Table 2: Half Cheetah Big, k=2", "half-cheetah-big-k2",
                            _phase2(10, 10.0, 450, 1, ahead=0.1)),
    "ant-cage-k1": ("Table 2: Ant Cage, k=1", "ant-cage-k1", _phase2(25, 2.4, 100, 2)),
    "ant-cage-k2": ("Table 2: Ant Cage, k=2", "ant-cage-k2", _phase2(10, 2.4, 100, 2)),
    "half-cheetah-cage-k1": ("Table 2: Half Cheetah Cage, k=1", "half-cheetah-cage-k1",
                             _phase2(10, 10.0, 150, 1, ahead=0.1)),
    "half-cheetah-cage-k2": ("Table 2: Half Cheetah Cage, k=2", "half-cheetah-cage-k2",
                             _phase2(10, 10.0, 150, 1, ahead=0.1)),
}


def phase2_preset_for(skills) -> str | None:
    """The phase-2 preset for a run trained with ``skills``: the one built on the phase-1
    preset it was trained with (seed and epochs aside), else the first one built on a
    preset with its domain, n and number of environments (GPU or CPU scale), else the first
    with its domain and n, else None. A flat skill learner's run gets its domain's one-level
    task at its scale (the skills there are as long as HE's k=1 skills)."""
    def same_preset(base: TrainConfig) -> bool:
        return dataclasses.replace(base, seed=skills.seed, epochs=skills.epochs) == skills

    candidates = [(name, PRESETS[phase1][1]) for name, (_, phase1, _) in PHASE2_PRESETS.items()]
    if not isinstance(skills, TrainConfig):  # a flat skill learner: the one-level task of its domain and scale
        gpu = skills.num_envs >= PRESETS["ant-field-small-k1"][1].num_envs
        one_level = {"point_mass": ("point-mass-k1",) * 2, "ant_field": ("ant-field-cpu-k1", "ant-field-small-k1"),
                     "half_cheetah_field": ("half-cheetah-cpu-k1", "half-cheetah-small-k1")}
        return one_level[skills.env][gpu] if skills.env in one_level else None
    for name, base in candidates:
        if same_preset(base):
            return name
    for same_scale in (True, False):
        for name, base in candidates:
            if (base.env, tuple(base.n)) == (skills.env, tuple(skills.n)) and (
                    not same_scale or base.num_envs == skills.num_envs):
                return name
    return None
