"""Phase 2 on a tiny agent: the added level's actions, goals, learning and failure handling."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny import TINY, TINY_PHASE2, tiny_after_two_epochs

from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.algos.registry import all_presets
from mjx_emp.envs.parts import Torso
from mjx_emp.envs.registry import DOMAINS
from mjx_emp.errors import ConfigError
from mjx_emp.nets import AIM_EDGE, LevelParams
from mjx_emp.phase2.config import Phase2Config, check_phase2_config
from mjx_emp.phase2.goal_spaces import TRAIN_EPOCH_TRACE, Phase2Trainer
from mjx_emp.phase2.presets import PHASE2_PRESETS, phase2_preset_for
from mjx_emp.tracing import traces


@pytest.fixture(scope="module")
def tiny_phase2():
    skills, _, skills_state, _, _ = tiny_after_two_epochs()
    trainer = Phase2Trainer(skills, TINY_PHASE2)
    return trainer, skills_state, trainer.init(skills_state)


def test_the_added_level_sits_on_top_with_phase_2_n_and_eps(tiny_phase2):
    trainer, _, _ = tiny_phase2
    assert trainer.level == TINY.k
    assert trainer.hierarchy.n == TINY.n + (TINY_PHASE2.n,)
    assert trainer.hierarchy.eps == TINY.eps + (TINY_PHASE2.eps,)


def test_episodes_start_at_the_initial_state_with_goals_uniform_in_the_region(tiny_phase2):
    trainer, _, _ = tiny_phase2
    states, goals, _ = jax.vmap(trainer.start, (None, 0))(None, jax.random.split(jax.random.key(0), 2000))
    low, high = trainer.region()
    goals = np.asarray(goals)
    assert ((goals >= low) & (goals <= high)).all()
    # Uniform: each quarter of the region along x gets about a quarter of the goals.
    quarters = np.histogram(goals[:, 0], bins=4, range=(low[0], high[0]))[0]
    assert (np.abs(quarters - 500) < 80).all()
    np.testing.assert_allclose(np.asarray(jax.vmap(trainer.env.observe)(states)),
                               np.broadcast_to(trainer.phase1.initial_obs, (2000, trainer.phase1.initial_obs.size)),
                               atol=1e-6)


def test_region_is_centred_on_h_s0_plus_the_offset(tiny_phase2):
    trainer, _, _ = tiny_phase2
    shifted = Phase2Trainer(trainer.phase1, dataclasses.replace(TINY_PHASE2, region=(4.0, 2.0), region_offset=(1.0, 0.0)))
    start = trainer.env.goal_of_obs(trainer.phase1.initial_obs)
    low, high = shifted.region()
    np.testing.assert_allclose(low, start + [-1.0, -1.0])
    np.testing.assert_allclose(high, start + [3.0, 1.0])


@pytest.mark.parametrize("reach", [1.0, 0.4])
def test_subgoals_stay_inside_the_top_goal_space_even_with_exploration_noise(tiny_phase2, reach):
    """... and with ``subgoal_reach`` inside its central share, whose edge the noise reaches."""
    trainer, _, state = tiny_phase2
    trainer = dataclasses.replace(trainer, cfg=dataclasses.replace(trainer.cfg, subgoal_reach=reach))
    k, env = trainer.level, trainer.env
    obs = jnp.asarray(trainer.phase1.initial_obs) + 0.5 * jax.random.normal(jax.random.key(1), (256, env.obs_size))
    goals = 3.0 * jax.random.normal(jax.random.key(2), (256, env.goal_size))
    params = LevelParams(actor=state.learner.actor, box=state.goal_space_actors[k - 1], noise=jnp.asarray(2.0))
    keys = jax.random.split(jax.random.key(3), 256)
    subgoals = jax.vmap(trainer.hierarchy.policies[k], (None, 0, 0, 0))(params, obs, goals, keys)
    shift, half_width = jax.vmap(trainer.phase1.nets.learned_box(k - 1), (None, 0))(state.goal_space_actors[k - 1], obs)
    assert (np.abs(np.asarray(subgoals - shift)) <= reach * np.asarray(half_width) + 1e-5).all()
    assert np.asarray(jnp.abs(subgoals - shift) > 0.9 * reach * half_width).any()  # the noise reaches the edge


def test_two_epochs_train_the_added_level_only_and_do_not_recompile(tiny_phase2):
    trainer, skills_state, state = tiny_phase2
    before = jax.tree.map(np.asarray, state.learner.actor)
    state, first = trainer.train_epoch(jax.tree.map(jnp.copy, state))
    compiled = traces(TRAIN_EPOCH_TRACE)
    state, second = trainer.train_epoch(state)
    assert traces(TRAIN_EPOCH_TRACE) == compiled, "epoch 2 recompiled"
    assert int(state.epoch) == 2 and state.env_steps.value() > 0
    # The phase-1 skills and goal spaces are frozen.
    for frozen, source in ((state.skill_actors, tuple(g.actor for g in skills_state.policies)),
                           (state.goal_space_actors, tuple(g.actor for g in skills_state.goal_spaces))):
        for a, b in zip(jax.tree.leaves(frozen), jax.tree.leaves(source)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert not all(np.array_equal(a, np.asarray(b)) for a, b in zip(jax.tree.leaves(before),
                                                                      jax.tree.leaves(state.learner.actor)))
    # One stored transition per attempt, with goals from the region.
    size = int(state.replay.size)
    assert size == int(np.asarray(first.transitions).sum() + np.asarray(second.transitions).sum()) > 0
    low, high = trainer.region()
    goals = np.asarray(state.replay.data.goal[:size])
    assert ((goals >= low - 1e-6) & (goals <= high + 1e-6)).all()
    metrics = trainer.metrics(state, second, 1.0)
    assert 0.0 <= metrics["success"] <= 1.0 and 0.0 <= metrics["min_distance"] < 10.0
    assert np.isfinite([metrics["critic_loss"], metrics["actor_loss"]]).all()
    assert trainer.divergence(state, second) is None


def test_divergence_names_the_phase_2_loss(tiny_phase2):
    trainer, _, state = tiny_phase2
    poisoned = state.replace(learner=state.learner.replace(
        critic=jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), state.learner.critic)))
    poisoned, stats = trainer.train_epoch(jax.tree.map(jnp.copy, poisoned))
    assert "phase-2 critic loss is nan" in trainer.divergence(poisoned, stats)


def test_evaluation_counts_whole_rounds_of_greedy_episodes(tiny_phase2):
    trainer, _, state = tiny_phase2
    figures = trainer.evaluate(state, jax.random.key(0), episodes=10)
    assert figures["episodes"] == 2 * TINY_PHASE2.num_envs  # 10 episodes round up to two rounds of 8
    assert 0.0 <= figures["success"] <= 1.0 and np.isfinite(figures["min_distance"])
    assert figures["cut_short"] == 0.0  # a point mass under sane skills never resets
    assert figures["uncut_min_distance"] == pytest.approx(figures["min_distance"], rel=1e-6)


def test_evaluation_counts_episodes_a_reset_cut_short(tiny_phase2):
    """Skills that break the physics (NaN actions) reset every environment at its first step:
    every episode is cut short, none succeeds."""
    trainer, _, state = tiny_phase2
    broken = state.replace(skill_actors=jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), state.skill_actors))
    figures = trainer.evaluate(broken, jax.random.key(0), episodes=8)
    assert figures["cut_short"] == 1.0 and figures["success"] == 0.0
    assert np.isnan(figures["uncut_min_distance"])  # no episode left to average


def test_attempts_a_reset_ended_are_kept_as_terminal_rows_only_when_asked(tiny_phase2):
    """With ``learn_from_resets`` the attempt a reset ended is stored at its last state before the
    reset, not reached and marked cut, and it trains; without it no such attempt is stored."""
    trainer, skills_state, _ = tiny_phase2
    for learn, cost in ((False, 0.0), (True, 0.0), (False, 5.0)):  # a flip cost keeps them too
        keeping = Phase2Trainer(trainer.phase1, dataclasses.replace(TINY_PHASE2, learn_from_resets=learn,
                                                                    flip_cost=cost))
        state = keeping.init(skills_state)
        broken = state.replace(skill_actors=jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), state.skill_actors))
        new, totals = jax.jit(keeping._collect)(broken, jnp.float32(0.0), jnp.bool_(True), jax.random.key(1))
        size = int(new.replay.size)
        assert int(totals.cut_short) == TINY_PHASE2.num_envs
        if not learn and not cost:
            assert size == 0 and new.replay.data.cut is None
            continue
        assert size >= TINY_PHASE2.num_envs
        rows = jax.tree.map(lambda x: np.asarray(x[:size]), new.replay.data)
        assert rows.cut.all() and not rows.reached.any()
        initial = np.broadcast_to(keeping.phase1.initial_obs, rows.next_obs.shape)
        np.testing.assert_allclose(rows.next_obs, initial, atol=1e-6)  # the state before each reset: a fresh start
        _, losses = jax.jit(keeping.update)(new.replace(skill_actors=state.skill_actors), jax.random.key(2))
        assert np.isfinite(np.asarray(losses)).all()


def test_a_reflex_needs_skills_of_a_robot_with_a_torso(tiny_phase2):
    trainer, _, _ = tiny_phase2
    with pytest.raises(ConfigError, match="reflex_tilt: 'point_mass' has no torso to tilt"):
        Phase2Trainer(trainer.phase1, dataclasses.replace(TINY_PHASE2, reflex_tilt=0.5))


def test_a_cut_backup_scores_the_fall_for_ever_and_bootstraps_nothing():
    from mjx_emp.learners.ddpg import Backup, cut_backup

    backup = Backup(reward=jnp.array([-2.0, -2.0]), discount=jnp.array([0.95, 0.0]), next_obs=jnp.zeros((2, 3)))
    cut = cut_backup(backup, jnp.array([True, False]), 0.95)
    np.testing.assert_allclose(np.asarray(cut.reward), [-40.0, -2.0], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(cut.discount), [0.0, 0.0])
    absorbing = cut_backup(backup, jnp.array([True, False]), 0.95, flip_cost=3.0)  # -5 every step after the flip
    np.testing.assert_allclose(np.asarray(absorbing.reward), [-100.0, -2.0], rtol=1e-6)


@pytest.mark.parametrize("field, value, message", [
    ("region", (2.0,), "region: the domain's goal space has 2"),
    ("region", (2.0, -1.0), "region: give one length > 0"),
    ("region_offset", (0.0,), "region_offset: the domain's goal space has 2"),
    ("n", 0, "n: must be >= 1"),
    ("eps", 0.0, "eps: must be > 0"),
    ("gamma", 1.0, "gamma: must be in [0, 1)"),
    ("phase1_epoch", -2, "phase1_epoch"),
    ("aim_weight", 1.0, "aim_weight: a cost of leaving the aim prior needs aim_prior True"),
    ("aim_weight", -1.0, "aim_weight: must be >= 0"),
    ("flip_cost", -1.0, "flip_cost: must be >= 0"),
    ("reflex_tilt", 2.5, "reflex_tilt: a tilt in [0, 2)"),
    ("subgoal_reach", 0.0, "subgoal_reach: a share of the top box's half-widths in (0, 1]"),
    ("subgoal_reach", 1.5, "subgoal_reach: a share of the top box's half-widths in (0, 1]"),
])
def test_bad_phase2_values_name_the_field(field, value, message):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")):
        check_phase2_config(dataclasses.replace(Phase2Config(), **{field: value}), goal_size=2)


def test_every_table_2_preset_builds_on_a_phase_1_preset_of_the_same_domain():
    for name, (_, phase1, cfg) in PHASE2_PRESETS.items():
        skills = PRESETS[phase1][1]
        check_phase2_config(cfg, goal_size=len(DOMAINS[skills.env].goal_qpos))
        if "-paper" in name:
            assert name == f"reach-{phase1}"
        assert not cfg.aim_prior and not cfg.learn_from_resets and not cfg.flip_cost, name  # beyond the paper: off
    assert phase2_preset_for(PRESETS["ant-field-k3-paper-xl"][1]) == "reach-ant-field-k3-paper-xl"
    # Two presets share Ant Field's n = (20,): each run gets the task sized for its own preset.
    assert phase2_preset_for(PRESETS["ant-field-k1-paper-small"][1]) == "reach-ant-field-k1-paper-small"
    assert phase2_preset_for(dataclasses.replace(PRESETS["ant-field-k1-cpu"][1], seed=3)) == "reach-ant-field-cpu"
    assert phase2_preset_for(PRESETS["point-mass-k2"][1]) == "reach-point-mass-wide"
    # A run without a task of its own preset gets the task of its domain, scale and depth, else of its domain and
    # scale: every depth of a CPU recipe shares the domain's CPU task.
    assert phase2_preset_for(PRESETS["half-cheetah-field-k2-cpu"][1]) == "reach-half-cheetah-field-cpu"
    assert phase2_preset_for(PRESETS["ant-field-k2-cpu"][1]) == "reach-ant-field-cpu"
    assert phase2_preset_for(dataclasses.replace(PRESETS["point-mass-k2"][1], n=(7, 7))) == "reach-point-mass-wide"
    assert phase2_preset_for(dataclasses.replace(PRESETS["point-mass-k2"][1], env="moon")) is None
    # Baselines get their domain's one-level task at their own scale (CPU or GPU).
    baselines = all_presets()
    for algo in ("metra", "dads"):
        assert phase2_preset_for(baselines[f"{algo}-ant-field-cpu"][1]) == "reach-ant-field-cpu"
        assert phase2_preset_for(baselines[f"{algo}-ant-field-gpu"][1]) == "reach-ant-field-k1-paper-small"
        assert phase2_preset_for(baselines[f"{algo}-half-cheetah-field-gpu"][1]) == \
            "reach-half-cheetah-field-k1-paper-small"
    assert phase2_preset_for(baselines["gcrl-ant-field-k1-cpu"][1]) == "reach-ant-field-cpu"
    assert phase2_preset_for(baselines["gcrl-ant-field-k1-gpu"][1]) == "reach-ant-field-k1-paper-small"
    cheetah = PHASE2_PRESETS["reach-half-cheetah-field-k2-paper-big"][2]
    assert cheetah.region == (450.0,) and cheetah.region_offset[0] > 0  # lies ahead of the start


@pytest.mark.parametrize("reached", [False, True])
def test_phase_2_critic_learns_its_own_reward_sigma_and_discount(tiny_phase2, reached):
    """The phase-2 critic's loss is (Q - target)^2 with target = log N(goal; h(s'), sigma) +
    gamma * Q_target(s', pi_target(s')) for phase 2's own sigma and gamma (not phase 1's),
    the bootstrap dropped where the goal was reached."""
    from mjx_emp import gce
    from mjx_emp.learners.ddpg import GoalTransition, reward_cap
    from mjx_emp.replay import replay_insert

    base, skills_state, _ = tiny_phase2
    cfg = dataclasses.replace(TINY_PHASE2, sigma=1.3, gamma=0.7, grad_steps=1)
    assert (cfg.sigma, cfg.gamma) != (TINY.sigma_gc[-1], TINY.gamma)
    trainer = Phase2Trainer(base.phase1, cfg)
    state = trainer.init(skills_state)
    learner = state.learner.replace(target_critic=jax.tree.map(lambda x: x - 1.0, state.learner.target_critic),
                                    target_actor=jax.tree.map(lambda x: x + 0.3, state.learner.target_actor))
    obs = jnp.asarray(trainer.phase1.initial_obs)
    next_obs = obs.at[:2].add(jnp.array([0.4, -0.2]))
    goal = trainer.env.goal_of_obs(obs) + jnp.array([1.0, 0.5])
    row = GoalTransition(obs, goal, jnp.array([0.2, -0.1]), next_obs, jnp.asarray(reached))
    rows = jax.tree.map(lambda x: jnp.broadcast_to(x, (cfg.batch_size,) + x.shape), row)
    replay = replay_insert(state.replay, rows, jnp.ones(cfg.batch_size, bool))
    _, losses = trainer.update(state.replace(learner=learner, replay=replay), jax.random.key(1))

    def expected(sigma: float, gamma: float) -> float:
        reward = gce.goal_conditioned_reward(goal[None], trainer.env.goal_of_obs(next_obs)[None], sigma)
        next_action = trainer.greedy_actions(state)(learner.target_actor, next_obs[None], goal[None])
        bootstrap = jnp.minimum(trainer.q_value(learner.target_critic, next_obs[None], goal[None], next_action),
                                reward_cap(trainer.env.goal_size, sigma, gamma))
        target = reward + (0.0 if reached else gamma) * bootstrap
        q = trainer.q_value(learner.critic, obs[None], goal[None], row.action[None])
        return float(jnp.mean(jnp.square(q - target)))

    actual = float(losses[0])
    assert actual == pytest.approx(expected(cfg.sigma, cfg.gamma), rel=1e-5)
    wrong = [expected(TINY.sigma_gc[-1], cfg.gamma)]  # phase 1's top-level sigma
    if not reached:
        wrong.append(expected(cfg.sigma, TINY.gamma))  # phase 1's discount
    for value in wrong:
        assert abs(value - actual) > 1e-3 * abs(actual), (value, actual)


def test_the_aimed_policy_asks_for_the_goal_itself_inside_the_top_box_and_its_edge_outside(tiny_phase2):
    trainer, skills_state, state = tiny_phase2
    aimed = dataclasses.replace(trainer, top="aimed")
    assert aimed != trainer and aimed.identity == trainer.identity  # its own compiled programs
    policy = aimed.hierarchy.policies[aimed.level]
    box = state.goal_space_actors[aimed.level - 1]
    params = LevelParams(actor=None, box=box, noise=jnp.zeros(()))
    obs = jnp.asarray(aimed.phase1.initial_obs)
    shift, half_width = aimed.phase1.nets.learned_box(aimed.level - 1)(box, obs)
    here = aimed.env.goal_of_obs(obs)
    inside = here + shift + 0.5 * half_width
    np.testing.assert_allclose(policy(params, obs, inside, jax.random.key(0)), inside - here, rtol=1e-5, atol=1e-6)
    far = here + shift + 10.0 * half_width  # out of reach: the box's corner towards it
    np.testing.assert_allclose(policy(params, obs, far, jax.random.key(0)), shift + half_width, rtol=1e-5, atol=1e-6)
    short = dataclasses.replace(trainer, top="aimed_half").hierarchy.policies[aimed.level]
    np.testing.assert_allclose(short(params, obs, far, jax.random.key(0)), shift + 0.5 * half_width, rtol=1e-5,
                               atol=1e-6)  # the corner of the box's central half
    near = here + shift + 0.25 * half_width
    np.testing.assert_allclose(short(params, obs, near, jax.random.key(0)), near - here, rtol=1e-5, atol=1e-6)
    randomly = dataclasses.replace(trainer, top="random").hierarchy.policies[aimed.level]
    draws = jax.vmap(lambda k: randomly(params, obs, far, k))(jax.random.split(jax.random.key(1), 256))
    assert bool(jnp.all(jnp.abs(draws - shift) <= half_width + 1e-6))  # uniform in the box, whatever the goal
    assert float(jnp.std(draws)) > 0.2 * float(jnp.min(half_width))
    with pytest.raises(ConfigError, match="top: 'greedy' is unknown"):
        dataclasses.replace(trainer, top="greedy")


def test_the_scripted_diagnostics_share_one_program_and_give_what_each_gives_alone(tiny_phase2):
    """Each scripted policy through the ``scripted`` top (one compiled rollout, the policy picked
    by its index at run time) gives the figures it gives as the top on its own, on the same goals."""
    from mjx_emp.metrics import PHASE2_DIAGNOSTICS

    trainer, _, state = tiny_phase2
    key = jax.random.key(4)
    together = trainer.diagnostic_figures(state, key, episodes=16)
    assert list(together) == list(PHASE2_DIAGNOSTICS)
    for name in PHASE2_DIAGNOSTICS:
        alone = dataclasses.replace(trainer, top=name).evaluate(state, key, episodes=16)
        assert together[name].keys() == alone.keys()
        for figure, value in alone.items():
            assert together[name][figure] == pytest.approx(value, rel=1e-5, nan_ok=True), (name, figure)
    assert together["aimed"] != together["random"]


def test_an_aim_prior_starts_as_the_aimed_policy_and_training_moves_it_away(tiny_phase2):
    trainer, skills_state, plain_state = tiny_phase2
    primed = Phase2Trainer(trainer.phase1, dataclasses.replace(TINY_PHASE2, aim_prior=True))
    assert primed != trainer  # its own compiled programs
    state = primed.init(skills_state)
    k, env = primed.level, primed.env
    box = state.goal_space_actors[k - 1]
    obs = jnp.asarray(primed.phase1.initial_obs)
    shift, half_width = primed.phase1.nets.learned_box(k - 1)(box, obs)
    here = env.goal_of_obs(obs)
    goals = jnp.stack([here + shift + 0.5 * half_width, here + shift - 0.3 * half_width,
                       here + shift + 10.0 * half_width])  # two inside the top box, one far beyond its corner
    wanted = jnp.stack([shift + 0.5 * half_width, shift - 0.3 * half_width, shift + AIM_EDGE * half_width])
    obs_batch = jnp.broadcast_to(obs, (3, obs.size))

    def greedy(trainer, state):
        return trainer.greedy_actions(state)(state.learner.actor, obs_batch, goals)

    np.testing.assert_allclose(greedy(primed, state), wanted, atol=0.02 * float(jnp.min(half_width)))
    plain = np.asarray(greedy(trainer, plain_state))  # without the prior a fresh actor asks for something else
    assert np.abs(plain - np.asarray(wanted)).max() > 0.05 * float(jnp.min(half_width))
    trained, _ = primed.train_epoch(jax.tree.map(jnp.copy, state))
    moved = np.asarray(greedy(primed, trained))
    assert np.abs(moved - np.asarray(greedy(primed, state))).max() > 1e-4  # the correction is learned
    assert (np.abs(moved - np.asarray(shift)) <= np.asarray(half_width) + 1e-5).all()


def test_a_cost_of_leaving_the_aim_prior_keeps_the_policy_near_the_aimed_subgoals(tiny_phase2):
    trainer, skills_state, _ = tiny_phase2
    eager = dataclasses.replace(TINY_PHASE2, aim_prior=True, grad_steps=40, actor_lr=1e-2)  # drifts within an epoch
    obs = jnp.broadcast_to(jnp.asarray(trainer.phase1.initial_obs), (64, trainer.env.obs_size))
    goals = jax.random.uniform(jax.random.key(4), (64, trainer.env.goal_size), minval=-1.5, maxval=1.5)

    def drift(weight: float) -> float:
        """How far (in goal units) one epoch moves the greedy subgoals from where the prior starts them."""
        primed = Phase2Trainer(trainer.phase1, dataclasses.replace(eager, aim_weight=weight))
        state = primed.init(skills_state)
        before = primed.greedy_actions(state)(state.learner.actor, obs, goals)
        state, _ = primed.train_epoch(state)
        return float(jnp.abs(primed.greedy_actions(state)(state.learner.actor, obs, goals) - before).mean())

    free, held = drift(0.0), drift(100.0)
    assert held < 0.5 * free, (held, free)


@dataclasses.dataclass(frozen=True)
class PlanarEnv:
    """What :func:`attempt_rows` reads of an environment: h(s) is obs[0], the torso pitch obs[1]."""

    torso: Torso = Torso(nq=2, pitch=1)

    def goal_of_obs(self, obs):
        return obs[..., :1]


def test_attempt_rows_follow_each_first_episode_attempt_by_attempt():
    """Rows [T=5, B=2]: environment 0 ends attempts at steps 1 and 3 (its first episode ends at 3,
    so step 4's row belongs to its second); environment 1's first attempt is cut short at step 0
    after moving away from the goal, its second ends at step 2 on its back."""
    from mjx_emp.rollout.structures import Transition
    from mjx_emp.run.flips import attempt_rows

    obs, next_obs = np.zeros((5, 2, 2)), np.zeros((5, 2, 2))
    obs[1, 0, 0], next_obs[1, 0, 0] = 0.0, 1.0
    obs[3, 0, 0], next_obs[3, 0, 0] = 1.0, 3.0
    obs[4, 0, 0], next_obs[4, 0, 0] = 0.0, 4.0
    obs[0, 1, 0], next_obs[0, 1, 0] = 0.0, -1.0
    obs[2, 1, 0], next_obs[2, 1, :] = 0.0, (2.0, np.pi)
    valid, cut = np.zeros((5, 2), bool), np.zeros((5, 2), bool)
    valid[[1, 3, 4], 0] = True
    valid[2, 1], cut[0, 1] = True, True
    top = Transition(obs=obs, goal=np.full((5, 2, 1), 4.0), action=np.zeros((5, 2, 1)), next_obs=next_obs,
                     reached=np.zeros((5, 2), bool), final=valid | cut, valid=valid, cut=cut)
    rows = attempt_rows(PlanarEnv(), top, first_end=np.array([3, 2]), attempts=10)
    assert [r["attempt"] for r in rows] == [0, 1] and [r["episodes"] for r in rows] == [2, 2]
    np.testing.assert_allclose([r["progress"] for r in rows], [(1.0 - 1.0) / 2, (2.0 + 2.0) / 2])
    np.testing.assert_allclose([r["distance_after"] for r in rows], [(3.0 + 5.0) / 2, (1.0 + 2.0) / 2])
    assert [r["cut_short"] for r in rows] == [0.5, 0.0]
    assert [r["upside_down_before"] for r in rows] == [0.0, 0.0]
    assert [r["upside_down_after"] for r in rows] == [0.0, 0.5]
    assert [r["flipped"] for r in rows] == [0.5, 0.5]  # env 1: cut short, then turned onto its back


def test_attempts_of_the_aimed_policy_start_with_every_episode(tiny_phase2):
    from mjx_emp.run.flips import phase2_flips

    trainer, _, state = tiny_phase2
    rows = phase2_flips(dataclasses.replace(trainer, top="aimed"), state, jax.random.key(0), envs=8)["by_attempt"]
    assert rows[0]["attempt"] == 0 and rows[0]["episodes"] == 8
    counts = [r["episodes"] for r in rows]
    assert counts == sorted(counts, reverse=True) and len(rows) <= trainer.cfg.n
    assert all(r["upside_down_after"] == 0.0 and r["cut_short"] == 0.0 for r in rows)  # a point mass never tips


def test_collect_totals_split_the_distance_between_cut_and_uncut_episodes():
    """Over first episodes only: the uncut mean leaves out the episodes a reset ended (and the
    rows that are not first episodes), and is NaN once every counted episode was cut."""
    from mjx_emp.rollout.collect import CollectTotals
    from mjx_emp.rollout.structures import RolloutStats

    zero = jnp.int32(0)
    stats = RolloutStats(primitive_steps=jnp.int32(4), useful_steps=zero, episodes_finished=zero, nan_resets=zero,
                         flip_resets=zero, decisions=())
    first = jnp.array([True, True, True, False])
    distance = jnp.array([1.0, 3.0, 8.0, 100.0])
    cut = jnp.array([False, False, True, True])
    totals = CollectTotals.zero().add(stats, first, first, jnp.zeros(4, bool), distance, cut)
    assert float(totals.mean_distance()) == pytest.approx(4.0)
    assert float(totals.cut_fraction()) == pytest.approx(1 / 3)
    assert float(totals.uncut_mean_distance()) == pytest.approx(2.0)
    all_cut = CollectTotals.zero().add(stats, first, first, jnp.zeros(4, bool), distance, jnp.ones(4, bool))
    assert np.isnan(float(all_cut.uncut_mean_distance()))
