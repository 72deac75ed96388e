"""Phase-1 trainer: update rules, buffers it fills, and one-epoch mechanics on a tiny agent."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny import TINY, TINY1, tiny_after_two_epochs, tiny_trainer

from mjx_emp import gce
from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.he.config import HEConfig
from mjx_emp.algos.he.state import (
    MODE_EVAL,
    MODE_GC,
    MODE_GS,
    MODE_STARTS,
    TRAIN_EPOCH_TRACE,
    EpisodeInfo,
    epoch_schedule,
    start_subset,
)
from mjx_emp.algos.registry import make_agent
from mjx_emp.envs.env import make_env
from mjx_emp.errors import ConfigError
from mjx_emp.learners.ddpg import (
    DDPGLearner,
    GoalTransition,
    ddpg_losses,
    hindsight_goals,
    n_step_backup,
    one_step_backup,
    relabel_goals,
    reward_cap,
)
from mjx_emp.learners.goal_space import GoalSpaceSample
from mjx_emp.nets import greedy_batch
from mjx_emp.replay import replay_init, replay_insert
from mjx_emp.rollout.structures import EpisodeEnd
from mjx_emp.tracing import traces


def test_schedule_follows_the_appendix_per_level():
    schedule = epoch_schedule(HEConfig(n=(20, 10), sigma_gc=(0.4, 0.8), sigma_gs=(1.75, 3.5),
                                          eps=(0.6, 1.2), init_half_width=(0.5, 1.0), max_half_width=(10, 100)))
    assert tuple(schedule[0]) == (2, MODE_STARTS)
    for level in range(2):
        modes = schedule[schedule[:, 0] == level, 1]
        assert list(modes) == [MODE_GC] * 10 + [MODE_GS] + [MODE_EVAL]


def test_level_repeats_run_a_levels_whole_block_that_many_times_per_epoch():
    two_levels = dict(n=(20, 10), sigma_gc=(0.4, 0.8), sigma_gs=(1.75, 3.5), eps=(0.6, 1.2),
                      init_half_width=(0.5, 1.0), max_half_width=(10, 100), gc_iterations=2, gs_iterations=1)
    schedule = epoch_schedule(HEConfig(**two_levels, level_repeats=(3, 1)))
    block = [MODE_GC] * 2 + [MODE_GS] + [MODE_EVAL]
    assert list(schedule[schedule[:, 0] == 0, 1]) == block * 3
    assert list(schedule[schedule[:, 0] == 1, 1]) == block
    assert list(schedule[1:, 0]) == [0] * 12 + [1] * 4  # level 0's blocks all come before level 1's
    np.testing.assert_array_equal(epoch_schedule(HEConfig(**two_levels, level_repeats=(1, 1))),
                                  epoch_schedule(HEConfig(**two_levels)))


def test_reward_cap_is_the_reward_peak_summed_over_an_endless_episode():
    peak = float(gce.goal_conditioned_reward(jnp.zeros(2), jnp.zeros(2), 0.4))
    assert reward_cap(2, 0.4, TINY.gamma) == pytest.approx(max(peak, peak / (1 - TINY.gamma)), rel=1e-5)
    assert math.isclose(peak, -2 * (math.log(0.4) + 0.5 * math.log(2 * math.pi)), rel_tol=1e-5)


def test_goal_space_actor_starts_at_the_initial_box_and_respects_its_bound():
    trainer = tiny_trainer()
    state = trainer.init()
    for level, box in enumerate(trainer.goal_spaces(state)):
        np.testing.assert_allclose(box["half_width"], TINY.init_half_width[level], rtol=1e-2)
        np.testing.assert_allclose(box["shift"], 0.0, atol=1e-2)
    net = trainer.nets.gs_actor_net(0)
    params = jax.tree.map(lambda x: x * 1e4, state.goal_spaces[0].actor)  # an absurd network
    action = net.apply(params, jnp.ones(make_env("point_mass").feature_size) * 50)
    shift, log_half_width = gce.split_goal_space_action(action)
    assert np.all(np.abs(shift) <= TINY.max_half_width[0] + 1e-5)
    assert np.all(np.exp(log_half_width) <= TINY.max_half_width[0] * (1 + 1e-5))


def test_gc_update_moves_targets_by_tau_and_only_its_level():
    cfg = TINY
    trainer_one_step = HEAgent(HEConfig(**{**cfg.__dict__, "gc_grad_steps": 1}))
    state = trainer_one_step.init()
    state, _ = trainer_one_step.train_epoch(state)  # fills the replay buffers
    before = state.policies
    (gcs, gss), losses = trainer_one_step.gc_update(1)((state.policies, state.goal_spaces), state.replay, state.goal_space_replay,
                                                         jax.random.key(0))
    assert np.all(np.isfinite(np.asarray(losses)))
    for new, old, target in zip(jax.tree.leaves(gcs[1].critic), jax.tree.leaves(before[1].target_critic),
                                jax.tree.leaves(gcs[1].target_critic)):
        np.testing.assert_allclose(target, cfg.tau * new + (1 - cfg.tau) * old, rtol=1e-5, atol=1e-7)
    for new, old, target in zip(jax.tree.leaves(gcs[1].actor), jax.tree.leaves(before[1].target_actor),
                                jax.tree.leaves(gcs[1].target_actor)):
        np.testing.assert_allclose(target, cfg.tau * new + (1 - cfg.tau) * old, rtol=1e-5, atol=1e-7)
    for a, b in zip(jax.tree.leaves(gcs[0]), jax.tree.leaves(before[0])):
        np.testing.assert_array_equal(a, b)
    assert not np.allclose(jax.tree.leaves(gcs[1].critic)[0], jax.tree.leaves(before[1].critic)[0])


def test_gc_critic_target_masks_bootstrap_where_reached():
    trainer = tiny_trainer()
    state = trainer.init()
    obs = jnp.zeros((2, make_env("point_mass").obs_size))
    batch = GoalTransition(obs=obs, goal=jnp.ones((2, 2)), action=jnp.zeros((2, 2)), next_obs=obs,
                  reached=jnp.array([True, False]))
    learner = state.policies[0]
    critic_loss, _ = trainer.gc_losses(0, learner, None, batch)
    q = trainer.nets.q_value(learner.critic, obs, batch.goal, batch.action)
    reward = gce.goal_conditioned_reward(batch.goal, jnp.zeros((2, 2)), TINY.sigma_gc[0])
    next_action = greedy_batch(trainer.hierarchy.policies[0], learner.target_actor, None)(obs, batch.goal)
    cap = reward_cap(2, TINY.sigma_gc[0], TINY.gamma)
    next_q = jnp.minimum(trainer.nets.q_value(learner.target_critic, obs, batch.goal, next_action), cap)
    target = reward + jnp.array([0.0, TINY.gamma]) * next_q
    np.testing.assert_allclose(critic_loss(learner.critic), jnp.mean(jnp.square(q - target)), rtol=1e-5)


def test_twin_critics_bootstrap_from_the_smaller_target_critic():
    # Stand-in networks: a "critic" is its table of Q values per (critic, row); the policy is zero.
    env = make_env("point_mass")
    obs = jnp.zeros((2, env.obs_size))
    batch = GoalTransition(obs=obs, goal=jnp.ones((2, 2)), action=jnp.zeros((2, 2)), next_obs=obs,
                  reached=jnp.array([False, True]))
    target_q = jnp.array([[-3.0, -1.0], [-5.0, -2.0]])  # two target critics, two rows
    learner = DDPGLearner(actor=None, critic=None, target_actor=None, target_critic=target_q,
                        actor_opt=None, critic_opt=None)
    critic_loss, actor_loss = ddpg_losses(lambda actor, o, g: jnp.zeros((2, 2)), lambda params, o, g, a: params,
                                          learner, batch, env, 0.4, 0.9)
    reward = gce.goal_conditioned_reward(batch.goal, jnp.zeros((2, 2)), 0.4)
    expected = reward + jnp.array([0.9 * -5.0, 0.0])  # row 0 bootstraps min(-3, -5); row 1 reached
    assert float(critic_loss(jnp.stack([expected, expected]))) == pytest.approx(0.0, abs=1e-9)
    assert float(critic_loss(jnp.stack([expected, expected + 1.0]))) == pytest.approx(0.5)
    assert float(actor_loss(None, target_q)) == pytest.approx(2.75)  # ascends the critics' mean


def test_two_critics_are_initialised_apart_and_evaluated_together():
    trainer = HEAgent(dataclasses.replace(TINY, critics=2))
    state = trainer.init()
    leaves = jax.tree.leaves(state.policies[0].critic)
    assert all(leaf.shape[0] == 2 for leaf in leaves)
    assert any(not np.allclose(leaf[0], leaf[1]) for leaf in leaves)  # two different initialisations
    obs = jnp.zeros((3, trainer.env.obs_size))
    assert trainer.nets.q_value(state.policies[0].critic, obs, jnp.ones((3, 2)), jnp.zeros((3, 2))).shape == (2, 3)


def test_relabelled_goals_take_other_rows_offsets_and_recompute_reached():
    env = make_env("point_mass")
    positions = jnp.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [5.0, 5.0]])
    obs = jnp.zeros((4, env.obs_size)).at[:, :2].set(positions)
    next_obs = obs.at[:, 0].add(1.0)  # every row moved 1 along x
    offsets = jnp.array([[1.0, 0.0], [0.0, 3.0], [-2.0, 0.0], [0.0, -1.0]])
    batch = GoalTransition(obs=obs, goal=positions + offsets, action=jnp.zeros((4, 2)), next_obs=next_obs,
                  reached=jnp.array([True, False, False, False]))
    unchanged = relabel_goals(batch, jax.random.key(0), 0.0, env, 0.3)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(unchanged), jax.tree.leaves(batch)))
    relabelled = relabel_goals(batch, jax.random.key(0), 1.0, env, 0.3)
    new_offsets = np.asarray(relabelled.goal - positions)
    assert all(any(np.allclose(row, o) for o in np.asarray(offsets)) for row in new_offsets)
    np.testing.assert_array_equal(relabelled.reached, np.linalg.norm(new_offsets - [1.0, 0.0], axis=-1) < 0.3)
    np.testing.assert_array_equal(relabelled.obs, obs)


def test_two_epochs_fill_buffers_learn_and_do_not_recompile():
    trainer, initial, state, first, second = tiny_after_two_epochs()
    assert int(state.epoch) == 2
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves((state.policies, state.goal_spaces)))
    # Every level collected and stored its own transitions and goal-space samples.
    for level in range(TINY.k):
        assert int(state.replay[level].size) > 0
        assert int(state.goal_space_replay[level].size) > 0
        assert int(state.starts[level].size) > 1, "the greedy chain added start states"
    # Level-1 transitions act in level 0's goal space: subgoals stay inside its bound.
    rows = np.asarray(state.replay[1].data.action[: int(state.replay[1].size)])
    assert np.all(np.abs(rows) <= 2 * TINY.max_half_width[0] + 1e-4)
    # The goal-space actor was trained.
    assert not np.allclose(jax.tree.leaves(initial)[0], jax.tree.leaves(state.goal_spaces[0].actor)[0])
    # Every GC/GS/eval item ran until each environment finished an episode.
    s = jax.tree.map(np.asarray, second)
    assert np.all(s.episodes[s.mode != MODE_STARTS] >= TINY.num_envs)
    assert np.all(s.env_steps > 0)
    assert state.env_steps.value() == int(np.sum(first.env_steps) + np.sum(s.env_steps))


def test_fresh_replay_keeps_only_each_iterations_own_collection():
    # The paper's Algorithm 2 starts every call with an empty D: after an epoch, each
    # level's replay holds exactly the transitions of its last goal-conditioned iteration.
    trainer = HEAgent(dataclasses.replace(TINY, fresh_replay=True))
    state, stats = trainer.train_epoch(trainer.init())
    s = jax.tree.map(np.asarray, stats)
    for level in range(TINY.k):
        gc_items = np.flatnonzero((s.root == level) & (s.mode == MODE_GC))
        assert int(state.replay[level].size) == int(s.transitions[gc_items[-1]])
        assert int(s.transitions[gc_items].sum()) > int(state.replay[level].size)


def test_epoch_metrics_report_every_level():
    trainer, _, state, _, second = tiny_after_two_epochs()
    metrics = trainer.metrics(state, second, 1.0)
    assert metrics["epoch"] == 2 and len(metrics["levels"]) == 2
    for level in metrics["levels"]:
        assert level["volume"] == pytest.approx(np.prod(2 * np.asarray(level["half_width"])), rel=1e-4)
        assert 0.0 <= level["success"] <= 1.0
        assert np.isfinite(level["gc_critic_loss"]) and np.isfinite(level["gs_critic_loss"])
    assert metrics["env_steps_per_s"] > 0 and metrics["flip_resets"] == 0  # a point mass never flips
    used = metrics["levels"][0]["box_where_used"]
    assert used is not None and metrics["levels"][1]["box_where_used"] is None
    assert 0 < used["mean_half_width"] <= used["max_half_width"] and np.isfinite(used["max_abs_shift"])


def test_skill_paths_start_at_the_initial_state_and_stop_with_each_first_skill():
    trainer, _, state, _, _ = tiny_after_two_epochs()
    positions, mask = trainer.skill_paths(state, jax.random.key(4), skills=5)
    steps = int(np.prod(TINY.n))
    assert positions.shape == (steps + 1, 5, 2) and mask.shape == (steps + 1, 5)
    np.testing.assert_allclose(positions[0], np.broadcast_to(trainer.env.home_goal(), (5, 2)))
    assert mask[0].all()
    # Once a skill has ended, none of its later steps count (the mask never turns back on).
    assert (np.diff(mask.astype(int), axis=0) <= 0).all()
    # The agent moved: the counted points are not all the start.
    assert np.abs(positions[mask] - positions[0, 0]).max() > 1e-3


def test_box_where_used_reads_level_zero_box_at_level_one_states():
    # Fill level 1's replay with one known state: level 0's box there is the answer.
    trainer, _, state, _, _ = tiny_after_two_epochs()
    obs = jnp.asarray(trainer.initial_obs).at[2:].set(jnp.array([1.5, -0.7]))
    replay = state.replay[1]
    rows = replay.data.replace(obs=jnp.broadcast_to(obs, replay.data.obs.shape))
    filled = replay.replace(data=rows, size=jnp.asarray(7, jnp.int32))
    state = state.replace(replay=(state.replay[0], filled))
    shift, half_width = trainer.nets.learned_box(0)(state.goal_spaces[0].actor, obs)
    used = trainer.boxes_where_used(state, rows=16)[0]
    assert used["max_abs_shift"] == pytest.approx(float(jnp.abs(shift).max()), rel=1e-5)
    assert used["mean_half_width"] == pytest.approx(float(half_width.mean()), rel=1e-5)
    assert used["max_half_width"] == pytest.approx(float(half_width.max()), rel=1e-5)
    empty = state.replace(replay=(state.replay[0], replay.replace(size=jnp.zeros((), jnp.int32))))
    assert trainer.boxes_where_used(empty) == [None, None]


def test_restore_round_trips_observations():
    for name in ("point_mass", "ant_cage"):
        env = make_env(name)
        state = env.reset_to(jax.random.key(0), jnp.full(env.goal_size, 1.5))
        state = env.step(state, jnp.full(env.action_size, 0.5))
        obs = env.observe(state)
        np.testing.assert_allclose(env.observe(env.restore(jax.random.key(1), obs)), obs, rtol=1e-6)
    env = make_env("ant_cage")
    opened = env.observe(env.reset(jax.random.key(0))).at[-1].set(1.0)
    assert bool(env.cage.is_open(env.restore(jax.random.key(0), opened).data))


@pytest.mark.parametrize(
    "change, field",
    [
        (dict(n=()), "n"),
        (dict(sigma_gc=(0.4,)), "sigma_gc"),
        (dict(sigma_gs=(0.4, -1.0)), "sigma_gs"),
        (dict(eps=(0.3, 0.0)), "eps"),
        (dict(env="maze"), "env"),
        (dict(init_half_width=(0.3, 9.0)), "init_half_width"),
        (dict(gamma=1.0), "gamma"),
        (dict(num_envs=0), "num_envs"),
        (dict(heading_frame=True), "heading_frame: 'point_mass' has no free torso"),
        (dict(learn_from_resets=True, reset_outcome="first"), "reset_outcome: 'first' is unknown"),
        (dict(reset_outcome="start"), "reset_outcome: 'start' needs learn_from_resets"),
        (dict(tilt_cost=-1.0), "tilt_cost: must be >= 0"),
        (dict(flip_cost=-1.0), "flip_cost: must be >= 0"),
        (dict(tilt_cost=1.0), "tilt_cost: 'point_mass' has no torso to tilt"),
        (dict(level_repeats=(2,)), "level_repeats: empty .* or one entry >= 1 per level"),
        (dict(level_repeats=(2, 0)), "level_repeats"),
    ],
)
def test_bad_train_config_names_the_field(change, field):
    with pytest.raises(ConfigError, match=field):
        make_agent(HEConfig(**{**TINY.__dict__, **change}))  # the config is checked where its agent is built


def test_trainers_of_equal_configs_share_one_compiled_epoch():
    trainer, _, state, _, _ = tiny_after_two_epochs()
    twin = HEAgent(dataclasses.replace(TINY))
    assert twin is not trainer and twin == trainer and hash(twin) == hash(trainer)
    trainer.train_epoch(jax.tree.map(jnp.copy, state))  # compiled here, whatever earlier tests left
    before = traces(TRAIN_EPOCH_TRACE)
    twin.train_epoch(jax.tree.map(jnp.copy, state))
    assert traces(TRAIN_EPOCH_TRACE) == before, "an equal config recompiled the epoch"
    assert HEAgent(dataclasses.replace(TINY, seed=TINY.seed + 1)) != trainer


def test_seeds_under_one_vmap_train_as_separate_runs_do():
    """The agent is pure functions over its state: vmapping init and an epoch over two keys
    gives each key's separate run (so seeds can share one program, issue 16)."""
    trainer = tiny_trainer()
    keys = jax.random.split(jax.random.key(7), 2)
    together, _ = jax.jit(jax.vmap(trainer.train_epoch))(jax.vmap(trainer.init)(keys))
    for i, key in enumerate(keys):
        alone, _ = trainer.train_epoch(trainer.init(key))
        for mine, theirs in zip(jax.tree.leaves(alone.policies), jax.tree.leaves(together.policies)):
            np.testing.assert_allclose(mine, theirs[i], atol=1e-5)
    assert not np.allclose(jax.tree.leaves(together.policies)[0][0], jax.tree.leaves(together.policies)[0][1])


def box_after_svg(init_hw: float, reached: bool, steps: int = 300) -> tuple[float, float]:
    """Level 0's box half-width before and after one goal-space update of ``steps`` SVG steps
    on 256 samples around its box, whose goals were all reached or all missed (no movement)."""
    cfg = dataclasses.replace(TINY, init_half_width=(init_hw, 0.6), gs_grad_steps=steps, batch_size=64, gs_replay_capacity=256)
    t = HEAgent(cfg); s = t.init()
    obs = jnp.asarray(t.initial_obs); start = t.env.goal_of_obs(obs)
    n = 256; k1, k2 = jax.random.split(jax.random.key(0))
    mu = t.nets.goal_space_action(0, s.goal_spaces[0].actor, obs)
    shift, loghw = gce.split_goal_space_action(mu)
    jitter = jax.random.uniform(k1, (n, 2), minval=-0.4, maxval=0.4)
    actions = jnp.concatenate([jnp.broadcast_to(shift, (n, 2)), loghw + jitter], -1)
    noise = gce.goal_noise(k2, (n, 2)); z = jax.vmap(gce.sample_goal)(noise, actions)
    final = start + z if reached else jnp.broadcast_to(start, (n, 2))
    reward = jax.vmap(lambda zz, f, a: gce.goal_space_reward(start, zz, f, a, cfg.sigma_gs[0]))(z, final, actions)
    rows = GoalSpaceSample(obs=jnp.broadcast_to(obs, (n, obs.shape[0])), noise=noise, action=actions, reward=reward)
    gsr = (replay_insert(s.goal_space_replay[0], rows, jnp.ones(n, bool)),) + s.goal_space_replay[1:]
    before = float(t.nets.learned_box(0)(s.goal_spaces[0].actor, obs)[1].mean())
    (pol, gss), losses = t.gs_update(0)((s.policies, s.goal_spaces), s.replay, gsr, jax.random.key(1))
    after = float(t.nets.learned_box(0)(gss[0].actor, obs)[1].mean())
    return before, after


@pytest.mark.parametrize("init_half_width, reached, grows", [
    (0.3, True, True),    # every goal reached: only the entropy term varies, so the box grows
    (1.5, False, False),  # goals missed from a box wider than sigma_gs * sqrt(3/2): the misses cost more
    (0.3, False, True),   # ... below that width the entropy gain of a bigger box still wins
])
def test_the_goal_space_step_grows_a_reached_box_and_shrinks_a_missed_wide_one(init_half_width, reached, grows):
    before, after = box_after_svg(init_half_width, reached)
    assert before == pytest.approx(init_half_width, rel=1e-5)
    assert (after > 1.01 * before) if grows else (after < 0.99 * before), (before, after)


def test_reached_is_exactly_a_distance_to_goal_below_eps_at_every_level():
    from mjx_emp.rollout.hierarchy import jit_init_rollout, jit_rollout

    trainer, _, state, _, _ = tiny_after_two_epochs()
    plan = trainer.skill_chain(state)
    rollout = jit_init_rollout(plan.hierarchy, plan.params, plan.start, plan.start_params, jax.random.key(2), 16,
                               plan.root)
    _, transitions, _, _ = jit_rollout(plan.hierarchy, plan.params, plan.start, plan.start_params, rollout, 40)
    outcomes = set()
    for level in range(trainer.cfg.k):
        t = jax.tree.map(np.asarray, transitions[level])
        valid = t.valid.astype(bool)
        assert valid.any(), f"level {level} stored nothing"
        distance = np.linalg.norm(np.asarray(trainer.env.goal_of_obs(t.next_obs)) - t.goal, axis=-1)
        np.testing.assert_array_equal(t.reached[valid], distance[valid] < trainer.cfg.eps[level])
        outcomes |= set(t.reached[valid].tolist())
    assert outcomes == {True, False}  # both outcomes occur, so both are checked


def test_gc_critic_target_bootstraps_from_the_target_networks_at_the_next_state():
    """obs != next_obs and target networks != online ones, so a swap of either would show."""
    trainer = tiny_trainer()
    learner = trainer.init().policies[0]
    learner = learner.replace(target_actor=jax.tree.map(lambda x: x + 0.5, learner.target_actor),
                              target_critic=jax.tree.map(lambda x: x - 1.0, learner.target_critic))  # below the cap
    keys = jax.random.split(jax.random.key(4), 3)
    obs = 3.0 * jax.random.normal(keys[0], (6, trainer.env.obs_size))
    next_obs = 3.0 * jax.random.normal(keys[1], (6, trainer.env.obs_size))
    goal = trainer.env.goal_of_obs(next_obs) + 0.1 * jax.random.normal(keys[2], (6, 2))  # small rewards
    batch = GoalTransition(obs=obs, goal=goal, action=jnp.full((6, 2), 0.1),
                           next_obs=next_obs, reached=jnp.array([True, False, False, True, False, False]))
    critic_loss, _ = trainer.gc_losses(0, learner, None, batch)
    cap = reward_cap(2, TINY.sigma_gc[0], TINY.gamma)

    def loss_with(actor, critic, at):
        reward = gce.goal_conditioned_reward(batch.goal, trainer.env.goal_of_obs(next_obs), TINY.sigma_gc[0])
        act = greedy_batch(trainer.hierarchy.policies[0], actor, None)(at, batch.goal)
        bootstrap = jnp.minimum(trainer.nets.q_value(critic, at, batch.goal, act), cap)
        target = reward + jnp.where(batch.reached, 0.0, TINY.gamma) * bootstrap
        return float(jnp.mean(jnp.square(trainer.nets.q_value(learner.critic, obs, batch.goal, batch.action) - target)))

    actual = float(critic_loss(learner.critic))
    assert actual == pytest.approx(loss_with(learner.target_actor, learner.target_critic, next_obs), rel=1e-5)
    for wrong in (loss_with(learner.actor, learner.critic, next_obs),  # online networks
                  loss_with(learner.target_actor, learner.target_critic, obs)):  # the state before the step
        assert abs(wrong - actual) > 1e-3 * abs(actual), (wrong, actual)  # 100x the tolerance above


def test_start_buffers_begin_with_the_initial_state_and_stay_within_the_chains_reach():
    trainer = tiny_trainer()
    env, cfg = trainer.env, trainer.cfg
    home = np.asarray(env.goal_of_obs(jnp.asarray(trainer.initial_obs)))

    def reach(actions: int) -> float:
        """How far full thrust along x carries the point mass in ``actions`` actions from the
        initial state (the fastest way along one axis)."""
        pushed, step = env.restore(jax.random.key(0), jnp.asarray(trainer.initial_obs)), jax.jit(env.step)
        for _ in range(actions):
            pushed = step(pushed, jnp.array([1.0, 0.0]))
        return float(np.abs(np.asarray(env.goal_of(pushed)) - home)[0])

    state = trainer.init()
    for epoch in (1, 2):
        state, _ = trainer.train_epoch(state)
        # The chain has taken at most this many actions from the initial state: per epoch,
        # start_chain rollout calls of chunk_steps actions each.
        bound = math.sqrt(2) * reach(epoch * cfg.start_chain * cfg.chunk_steps) * 1.05
        for level in range(cfg.k):
            buffer = state.starts[level]
            size = int(buffer.size)
            rows = np.asarray(buffer.data[:size])
            if epoch == 1:  # before the ring wraps, row 0 is the initial state written at init
                assert 1 < size < buffer.capacity, (level, size)
                np.testing.assert_array_equal(rows[0], np.asarray(trainer.initial_obs))
                assert np.all(np.asarray(buffer.data[size:]) == 0), "rows past size stay empty"
            distance = np.linalg.norm(np.asarray(env.goal_of_obs(jnp.asarray(rows))) - home, axis=-1)
            assert np.all(distance <= bound), (epoch, level, distance.max(), bound)
            assert distance.max() > 1e-3, "rows are states the chain reached, not copies of the start"
    assert reach(1) > 1e-3, "the probe push moves the point mass"


def _one_episode_rows(env, positions, goal, successor):
    """Stored rows of a point-mass episode that walked through ``positions`` (one row per move)."""
    obs = jnp.zeros((len(positions), env.obs_size)).at[:, :2].set(jnp.asarray(positions))
    rows = len(positions) - 1
    return GoalTransition(obs=obs[:-1], goal=jnp.broadcast_to(jnp.asarray(goal), (rows, 2)),
                          action=jnp.zeros((rows, 2)), next_obs=obs[1:],
                          reached=jnp.linalg.norm(obs[1:, :2] - jnp.asarray(goal), axis=-1) < 0.3,
                          successor=jnp.asarray(successor, jnp.int32))


def test_hindsight_goals_are_states_the_episode_reached_later():
    env = make_env("point_mass")
    # Two episodes in one buffer of capacity 7: slots 0-3 (moves along x), slots 4-5 (along y); slot 6 empty.
    a = _one_episode_rows(env, [[0, 0], [1, 0], [2, 0], [3, 0], [4, 0]], [9.0, 9.0], [1, 2, 3, 7])
    b = _one_episode_rows(env, [[0, 0], [0, 1], [0, 2]], [-9.0, -9.0], [5, 7])
    rows = jax.tree.map(lambda x, y: jnp.concatenate([x, y, y[:1]]), a, b)
    slots = jnp.tile(jnp.arange(6), 50)
    batch = jax.tree.map(lambda x: x[slots], rows)
    relabelled = hindsight_goals(rows, slots, batch, jax.random.key(1), 1.0, env, 0.3, horizon=4)
    goal = np.asarray(relabelled.goal)
    later = {0: [1, 2, 3, 4], 1: [2, 3, 4], 2: [3, 4], 3: [4], 4: [1, 2], 5: [2]}  # achieved positions after each row
    for slot, g in zip(np.asarray(slots), goal):
        step = g[0] if slot < 4 else g[1]
        assert step in later[int(slot)] and g[1 if slot < 4 else 0] == 0.0
    assert {float(g[0]) for s, g in zip(np.asarray(slots), goal) if s == 0} == {1.0, 2.0, 3.0, 4.0}  # all of them drawn
    np.testing.assert_array_equal(relabelled.reached, np.linalg.norm(goal - np.asarray(batch.next_obs[:, :2]), axis=-1) < 0.3)
    assert np.asarray(relabelled.reached)[np.asarray(slots) == 3].all()  # the last row's only future is its own
    # Reward and discount of a relabelled row follow from its new goal.
    backup = one_step_backup(relabelled, env, 0.4, 0.9)
    np.testing.assert_allclose(backup.reward, gce.goal_conditioned_reward(relabelled.goal, batch.next_obs[:, :2], 0.4))
    np.testing.assert_allclose(backup.discount, np.where(np.asarray(relabelled.reached), 0.0, 0.9))
    untouched = hindsight_goals(rows, slots, batch, jax.random.key(1), 0.0, env, 0.3, horizon=4)
    np.testing.assert_array_equal(untouched.goal, batch.goal)


def test_n_step_target_equals_its_closed_form():
    env = make_env("point_mass")
    sigma, gamma = 0.5, 0.9
    goal = jnp.array([3.0, 0.0])
    # One episode: 0 -> 1 -> 2 -> 3 (reaches the goal) -> 4.
    rows = _one_episode_rows(env, [[0, 0], [1, 0], [2, 0], [3, 0], [4, 0]], goal, [1, 2, 3, 4])
    r = [float(gce.goal_conditioned_reward(goal, jnp.array([x, 0.0]), sigma)) for x in (1, 2, 3, 4)]
    slots = jnp.array([0, 1, 2, 3])
    batch = jax.tree.map(lambda x: x[slots], rows)
    backup = n_step_backup(rows, slots, batch, env, sigma, gamma, eps=0.3, steps=2)
    # row 0: r1 + g r2, bootstrap from x=2 with g^2; row 1: r2 + g r3, then reached (no bootstrap);
    # row 2: r3, reached at once; row 3: the episode's last row, r4 and bootstrap from x=4 with g.
    np.testing.assert_allclose(backup.reward, [r[0] + gamma * r[1], r[1] + gamma * r[2], r[2], r[3]], rtol=1e-6)
    np.testing.assert_allclose(backup.discount, [gamma ** 2, 0.0, 0.0, gamma], rtol=1e-6)
    np.testing.assert_array_equal(backup.next_obs[:, 0], [2.0, 3.0, 3.0, 4.0])
    one = n_step_backup(rows, slots, batch, env, sigma, gamma, eps=0.3, steps=1)
    expected = one_step_backup(batch, env, sigma, gamma)
    for got, want in zip(jax.tree.leaves(one), jax.tree.leaves(expected)):
        np.testing.assert_allclose(got, want, rtol=1e-6)


def test_n_step_target_ends_at_a_row_a_reset_cut():
    env = make_env("point_mass")
    sigma, gamma = 0.5, 0.9
    goal = jnp.array([9.0, 0.0])
    # One episode: 0 -> 1 -> 2, and a reset during the third action (its row scored at x=2, where it began).
    rows = _one_episode_rows(env, [[0, 0], [1, 0], [2, 0], [2, 0]], goal, [1, 2, 3])
    rows = rows.replace(cut=jnp.array([False, False, True]))
    r = [float(gce.goal_conditioned_reward(goal, jnp.array([x, 0.0]), sigma)) for x in (1, 2, 2)]
    slots = jnp.array([0, 1, 2])
    batch = jax.tree.map(lambda x: x[slots], rows)
    backup = n_step_backup(rows, slots, batch, env, sigma, gamma, eps=0.3, steps=3)
    fall = r[2] / (1 - gamma)  # the robot stays where it fell
    np.testing.assert_allclose(backup.reward, [r[0] + gamma * r[1] + gamma ** 2 * fall, r[1] + gamma * fall, fall],
                               rtol=1e-6)
    np.testing.assert_allclose(backup.discount, [0.0, 0.0, 0.0])
    one = n_step_backup(rows, slots, batch, env, sigma, gamma, eps=0.3, steps=1)
    np.testing.assert_allclose(one.reward, [r[0], r[1], fall], rtol=1e-6)
    np.testing.assert_allclose(one.discount, [gamma, gamma, 0.0], rtol=1e-6)


def test_a_flip_cost_keeps_the_rows_a_reset_cut_and_scores_them_as_an_absorbing_failure():
    """With ``flip_cost`` every level's replay keeps a ``cut`` mark, and a cut row's target is
    (r - flip_cost) / (1 - gamma) with nothing bootstrapped, one-step and n-step alike; rows no
    reset cut keep the paper's target."""
    from mjx_emp.learners.ddpg import GoalTransition

    gamma, cost = 0.9, 2.0
    plain = HEAgent(dataclasses.replace(TINY, gamma=gamma))
    agent = HEAgent(dataclasses.replace(TINY, gamma=gamma, flip_cost=cost))
    assert all(r.data.cut is None for r in plain.init(jax.random.key(0)).replay)
    state = agent.init(jax.random.key(0))
    assert all(r.data.cut is not None for r in state.replay)
    obs = jnp.broadcast_to(jnp.asarray(agent.initial_obs), (2, agent.initial_obs.size))
    rows = GoalTransition(obs=obs, goal=jnp.full((2, 2), 0.5), action=jnp.zeros((2, 2)), next_obs=obs,
                          reached=jnp.zeros(2, bool), successor=jnp.array([1, 2], jnp.int32),
                          cut=jnp.array([True, False]))
    slots = jnp.array([0, 1])
    for level in (0, 1):
        reward = float(gce.goal_conditioned_reward(jnp.full(2, 0.5), jnp.asarray(agent.initial_obs[:2]),
                                                   TINY.sigma_gc[level]))
        backup = agent.gc_backup(level, rows, slots, rows)
        np.testing.assert_allclose(backup.reward, [(reward - cost) / (1 - gamma), reward], rtol=1e-5)
        np.testing.assert_allclose(backup.discount, [0.0, gamma])
    walked = HEAgent(dataclasses.replace(agent.cfg, n_step=2)).gc_backup(0, rows, slots, rows)
    np.testing.assert_allclose(walked.reward[0], agent.gc_backup(0, rows, slots, rows).reward[0], rtol=1e-5)
    assert float(walked.discount[0]) == 0.0


def test_a_flip_cost_scores_a_half_cheetah_left_on_its_back_as_an_absorbing_failure():
    """The Half Cheetah is never reset: with ``flip_cost`` an action that leaves its torso upside
    down is scored (r - cost) / (1 - gamma) with nothing bootstrapped; upright rows, and every
    row without the cost, keep the paper's target."""
    env, gamma, cost = make_env("half_cheetah_field"), 0.9, 2.0
    start = env.observe(env.reset_to(jax.random.key(0), jnp.array([0.0])))
    obs = jnp.stack([start, start.at[env.torso.pitch].set(np.pi)])  # upright, on its back
    rows = GoalTransition(obs=jnp.stack([start, start]), goal=jnp.full((2, 1), 3.0),
                          action=jnp.zeros((2, env.action_size)), next_obs=obs, reached=jnp.zeros(2, bool))
    plain = one_step_backup(rows, env, 1.0, gamma)
    paid = one_step_backup(rows, env, 1.0, gamma, flip_cost=cost)
    np.testing.assert_allclose(paid.reward, [plain.reward[0], (plain.reward[1] - cost) / (1 - gamma)], rtol=1e-6)
    np.testing.assert_allclose(paid.discount, [gamma, 0.0])
    np.testing.assert_allclose(plain.discount, [gamma, gamma])


def test_tilt_cost_lowers_level_zero_rewards_by_the_torso_tilt():
    """One- and n-step targets pay ``tilt_cost`` times 1 - z of the torso's up axis at each
    next state; at 0 they are the paper's reward, and an upright torso pays nothing."""
    env = make_env("ant_field")
    sigma, gamma, cost = 1.0, 0.9, 0.5
    home = env.observe(env.reset_to(jax.random.key(0), jnp.array([0.0, 0.0])))
    q = env.torso.quat
    angles = np.array([0.0, np.pi / 2, np.pi])  # upright, on its side, upside down
    obs = jnp.stack([home.at[:2].set(jnp.array([float(i), 0.0])).at[q : q + 4].set(
        jnp.array([np.cos(a / 2), np.sin(a / 2), 0.0, 0.0])) for i, a in enumerate(angles)])
    goal = jnp.array([5.0, 0.0])
    rows = GoalTransition(obs=obs[:2], goal=jnp.broadcast_to(goal, (2, 2)), action=jnp.zeros((2, env.action_size)),
                          next_obs=obs[1:], reached=jnp.zeros(2, bool), successor=jnp.array([1, 2], jnp.int32))
    plain = np.asarray(one_step_backup(rows, env, sigma, gamma).reward)
    paid = np.asarray(one_step_backup(rows, env, sigma, gamma, tilt_cost=cost).reward)
    np.testing.assert_allclose(plain, [float(gce.goal_conditioned_reward(goal, jnp.array([x, 0.0]), sigma))
                                       for x in (1.0, 2.0)], rtol=1e-6)
    np.testing.assert_allclose(paid, plain - cost * np.array([1.0, 2.0]), rtol=1e-6)
    slots = jnp.array([0, 1])
    walked = n_step_backup(rows, slots, rows, env, sigma, gamma, eps=0.3, steps=2, tilt_cost=cost)
    np.testing.assert_allclose(walked.reward, [paid[0] + gamma * paid[1], paid[1]], rtol=1e-6)
    upright = rows.replace(next_obs=jnp.stack([home, home]))
    np.testing.assert_allclose(one_step_backup(upright, env, sigma, gamma, tilt_cost=cost).reward,
                               one_step_backup(upright, env, sigma, gamma).reward, rtol=1e-6)
    # An agent pays the cost at level 0 only, the level whose actions move the joints.
    agent = HEAgent(dataclasses.replace(TINY, env="ant_field", gamma=gamma, sigma_gc=(sigma, sigma), tilt_cost=cost))
    np.testing.assert_allclose(agent.gc_backup(0, rows, slots, rows).reward, paid, rtol=1e-6)
    np.testing.assert_allclose(agent.gc_backup(1, rows, slots, rows).reward, plain, rtol=1e-6)
    # The Half Cheetah's torso tilts by its pitch hinge: on its back it pays twice the cost.
    cheetah = make_env("half_cheetah_field")
    start = cheetah.observe(cheetah.reset_to(jax.random.key(0), jnp.array([0.0])))
    pitched = jnp.stack([start.at[2].set(a) for a in angles])
    goal = jnp.array([5.0])
    rows = GoalTransition(obs=pitched[:2], goal=jnp.broadcast_to(goal, (2, 1)), action=jnp.zeros((2, cheetah.action_size)),
                          next_obs=pitched[1:], reached=jnp.zeros(2, bool), successor=jnp.array([1, 2], jnp.int32))
    np.testing.assert_allclose(one_step_backup(rows, cheetah, sigma, gamma, tilt_cost=cost).reward,
                               one_step_backup(rows, cheetah, sigma, gamma).reward - cost * np.array([1.0, 2.0]), rtol=1e-5)


def test_phase_one_keeps_what_a_reset_cut_short_only_when_asked():
    """With ``learn_from_resets`` a reset's actions are stored as cut, unreached rows at the state
    before the reset and its episodes reach the goal-space replay; the update on them is finite.
    Without it neither is stored."""
    for learn in (False, True):
        agent = HEAgent(dataclasses.replace(TINY1, learn_from_resets=learn))
        state = agent.init()
        poisoned = state.replace(policies=tuple(
            p.replace(actor=jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), p.actor)) for p in state.policies))
        collect = jax.jit(agent._collect)
        gc, _ = collect(poisoned, jnp.int32(0), jnp.int32(MODE_GC), jax.random.key(1))
        gs, _ = collect(poisoned, jnp.int32(0), jnp.int32(MODE_GS), jax.random.key(2))
        size, gs_size = int(gc.replay[0].size), int(gs.goal_space_replay[0].size)
        if not learn:
            assert size == 0 and gs_size == 0 and gc.replay[0].data.cut is None
            continue
        assert size >= TINY.num_envs and gs_size >= TINY.num_envs
        rows = jax.tree.map(lambda x: np.asarray(x[:size]), gc.replay[0].data)
        assert rows.cut.all() and not rows.reached.any()
        np.testing.assert_allclose(rows.next_obs, rows.obs, atol=1e-6)  # every step reset: each ends where it began
        assert (rows.successor == gc.replay[0].capacity).all()  # a cut row ends its episode
        # The poisoned actor's actions were NaN; the rows train as a finite policy's would.
        replay = gc.replay[0].replace(data=gc.replay[0].data.replace(action=jnp.zeros_like(gc.replay[0].data.action)))
        _, losses = jax.jit(agent.gc_update(0))((state.policies, state.goal_spaces), (replay,) + gc.replay[1:],
                                                gc.goal_space_replay, jax.random.key(3))
        assert np.isfinite(np.asarray(losses)).all()


def test_reset_outcome_scores_a_fallen_skill_as_one_that_never_moved_only_when_asked():
    """The goal spaces score a cut episode at its last state ("last") or at its start ("start");
    episodes that ended normally score the same either way."""
    agent = HEAgent(dataclasses.replace(TINY, learn_from_resets=True))
    env, rng = agent.env, np.random.default_rng(0)
    obs = jnp.asarray(rng.normal(size=(4, env.obs_size)), jnp.float32)
    final = obs + 1.5  # every episode moved away from its start
    cut = jnp.array([True, False, True, False])
    episodes = EpisodeEnd(info=EpisodeInfo(obs=obs, noise=jnp.zeros((4, env.goal_size)),
                                           action=jnp.zeros((4, 2 * env.goal_size))),
                          final_obs=final, reached=jnp.zeros(4, bool), index=jnp.zeros(4, jnp.int32),
                          valid=~cut, cut=cut)
    last = np.asarray(agent._goal_space_sample(0, episodes).reward)
    start = np.asarray(HEAgent(dataclasses.replace(TINY, learn_from_resets=True, reset_outcome="start"))
                       ._goal_space_sample(0, episodes).reward)
    never_moved = np.asarray(agent._goal_space_sample(0, episodes.replace(final_obs=obs)).reward)
    np.testing.assert_allclose(start[~np.asarray(cut)], last[~np.asarray(cut)])
    np.testing.assert_allclose(start[np.asarray(cut)], never_moved[np.asarray(cut)])
    assert not np.allclose(start[np.asarray(cut)], last[np.asarray(cut)])
    # With a flip cost a goal whose skill flipped the robot also pays it; the others do not.
    costly = np.asarray(HEAgent(dataclasses.replace(TINY, learn_from_resets=True, flip_cost=3.0))
                        ._goal_space_sample(0, episodes).reward)
    np.testing.assert_allclose(costly, last - 3.0 * np.asarray(cut), rtol=1e-6)


def test_layer_norm_only_where_configured():
    def layer_norms(params) -> int:
        return sum("LayerNorm" in "/".join(str(k) for k in path) for path, _ in jax.tree_util.tree_leaves_with_path(params))

    for critic_ln, actor_ln in ((True, False), (False, True)):
        state = HEAgent(dataclasses.replace(TINY, critic_layer_norm=critic_ln, actor_layer_norm=actor_ln)).init()
        for level in range(TINY.k):
            assert layer_norms(state.policies[level].critic) == (2 * len(TINY.hidden) if critic_ln else 0)
            assert layer_norms(state.policies[level].actor) == (2 * len(TINY.hidden) if actor_ln else 0)
            assert layer_norms(state.goal_spaces[level].critic) == 0  # the goal-space critic stays the paper's


def test_stored_rows_link_to_the_next_row_of_their_episode():
    trainer, _, state, _, _ = tiny_after_two_epochs()
    for level in range(TINY.k):
        data, size = state.replay[level].data, int(state.replay[level].size)
        successor = np.asarray(data.successor[:size])
        linked = np.flatnonzero(successor < state.replay[level].capacity)
        assert linked.size > 0
        nxt = successor[linked]
        assert (nxt < size).all() and (nxt > linked).all()
        np.testing.assert_array_equal(data.obs[nxt], data.next_obs[linked])  # the episode goes on from s'
        np.testing.assert_array_equal(data.goal[nxt], data.goal[linked])
        assert not np.asarray(data.reached[linked]).any()  # a reached goal ends its episode


def test_start_subsets_split_the_buffer_at_the_initial_state():
    initial = jnp.array([1.0, 2.0])
    buffer = replay_insert(replay_init(initial, 8), jnp.array([[1.0, 2.0], [3.0, 4.0], [1.0, 2.0], [5.0, 6.0]]),
                           jnp.ones(4, bool))
    whole = start_subset(buffer, initial, 0)
    assert int(whole.size) == 4 and np.array_equal(whole.data, buffer.data)
    only_initial = start_subset(buffer, initial, 1)
    assert int(only_initial.size) == 2 and np.all(np.asarray(only_initial.data[:2]) == [1.0, 2.0])
    chained = start_subset(buffer, initial, 2)
    assert int(chained.size) == 2
    np.testing.assert_array_equal(chained.data[:2], [[3.0, 4.0], [5.0, 6.0]])
    empty_chain = start_subset(replay_insert(replay_init(initial, 8), initial[None], jnp.ones(1, bool)), initial, 2)
    assert int(empty_chain.size) == 1 and np.all(np.asarray(empty_chain.data[0]) == [1.0, 2.0])


def test_tilted_starts_turn_a_share_of_level_zeros_training_starts_and_change_no_other_draw():
    """With ``tilted_starts`` 0.5, about half of level 0's training starts (GC mode) are turned
    by up to ``tilted_start_angle`` (each goal drawn from the box at the turned state); the other
    half with their goals, and every start of evaluation and of the goal spaces' collection, are
    the draws the paper's starts make with the same keys."""
    base = dataclasses.replace(TINY1, env="ant_field", solver_iterations=4)
    plain = HEAgent(base)
    tilted = HEAgent(dataclasses.replace(base, tilted_starts=0.5, tilted_start_angle=1.0))
    state = plain.init()
    keys = jax.random.split(jax.random.key(2), 512)

    def starts(agent, mode):
        _, start_params = agent.rollout_inputs(state, jnp.int32(0), jnp.int32(mode))
        _, goals, info = jax.vmap(agent.start, (None, 0))(start_params, keys)
        return np.asarray(info.obs), np.asarray(goals)

    torso = tilted.env.torso
    obs_plain, goals_plain = starts(plain, MODE_GC)
    obs_tilted, goals_tilted = starts(tilted, MODE_GC)
    turned = np.any(obs_tilted != obs_plain, axis=-1)
    assert 0.4 < turned.mean() < 0.6, turned.mean()
    lift = obs_tilted[turned, torso.height] - obs_plain[turned, torso.height]
    assert np.all(lift > 0.0) and float(np.max(torso.tilt(obs_tilted))) <= 1.0 - math.cos(1.0) + 1e-4
    assert float(np.max(torso.tilt(obs_tilted))) > 0.3  # angles spread up to the largest
    np.testing.assert_array_equal(obs_tilted[~turned], obs_plain[~turned])
    np.testing.assert_array_equal(goals_tilted[~turned], goals_plain[~turned])
    for mode in (MODE_EVAL, MODE_GS):
        for got, want in zip(starts(tilted, mode), starts(plain, mode)):
            np.testing.assert_array_equal(got, want)
