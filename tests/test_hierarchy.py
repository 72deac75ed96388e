"""The one-scan k-level rollout: control hand-over, limits, shapes, determinism, isolation."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_emp.envs.env import make_env
from mjx_emp.envs.scripted import bounded_hop, point_mass_pd
from mjx_emp.nets import mlp_agent
from mjx_emp.rollout.hierarchy import (
    decide,
    decision_buckets,
    default_start,
    jit_init_rollout,
    jit_rollout,
)
from mjx_emp.rollout.structures import Driver, Hierarchy

ENV = make_env("point_mass")
START = default_start(ENV, goal_half_width=3.0)


steer = point_mass_pd
hop = bounded_hop(0.6)


def small_agent(k: int):
    return mlp_agent(ENV, k, (32, 32), (1.5, 1.5), jax.random.key(10))


def run(h, params, key, batch, steps, root=None, start=START):
    state = jit_init_rollout(h, params, start, None, key, batch, root)
    new_state, transitions, _, stats = jit_rollout(h, params, start, None, state, steps)
    return state, new_state, transitions, stats


CONTROLLED = Hierarchy(ENV, (steer, hop), n=(20, 8), eps=(0.1, 0.3))


@functools.cache
def controlled_run():
    return run(CONTROLLED, (None, None), jax.random.key(0), 16, 120)


def test_reached_subgoal_hands_back_and_parent_reissues_in_same_step():
    _, _, (t0, t1), _ = controlled_run()
    t0, t1 = jax.tree.map(np.asarray, (t0, t1))
    pos_next = t0.next_obs[..., :2]
    reached = t0.reached & t0.valid
    assert reached.sum() > 50, "the PD controller should reach many subgoals"
    # Reaching ends level 0's goal and completes level 1's action in that very step.
    np.testing.assert_array_equal(t0.final[reached], True)
    np.testing.assert_array_equal(t1.valid, t0.final & t0.valid)
    # Early: the hand-back happened before level 0 used its n=20 actions.
    assert reached.sum() == t0.final.sum()
    # The next step already pursues the parent's next subgoal, issued from the new state.
    T = t0.goal.shape[0]
    for t in range(T - 1):
        same_episode = t0.final[t] & ~t1.final[t]
        expected = pos_next[t] + np.clip(t1.goal[t + 1] - pos_next[t], -0.6, 0.6)
        np.testing.assert_allclose(t0.goal[t + 1][same_episode], expected[same_episode], atol=1e-5)
        live = ~t1.final[t]  # otherwise the episode restarted from a fresh start state
        np.testing.assert_array_equal(t0.obs[t + 1][live], t0.next_obs[t][live])  # no idle step
        kept = ~t0.final[t]
        np.testing.assert_array_equal(t0.goal[t + 1][kept], t0.goal[t][kept])


def run_lengths(tr, n: int):
    """Check per env: actions between finals never exceed n; finals come from reach or n."""
    valid, final, reached = (np.asarray(x) for x in (tr.valid, tr.final, tr.reached))
    T, B = valid.shape
    longest = 0
    for b in range(B):
        count = 0
        for t in range(T):
            if not valid[t, b]:
                continue
            count += 1
            assert count <= n
            if final[t, b]:
                assert reached[t, b] or count == n
                longest = max(longest, count)
                count = 0
            else:
                assert count < n
    return longest


@pytest.mark.parametrize("k", [1, 2, 3])
def test_shapes_and_action_limits(k):
    policies, params = small_agent(k)
    n = (6, 4, 3)[:k]
    h = Hierarchy(ENV, policies, n=n, eps=(0.05, 0.1, 0.2)[:k])
    T, B = 90, 8
    state, new_state, transitions, stats = run(h, params, jax.random.key(k), B, T)
    assert len(transitions) == k
    for level, tr in enumerate(transitions):
        act = ENV.action_size if level == 0 else ENV.goal_size
        assert tr.obs.shape == tr.next_obs.shape == (T, B, ENV.obs_size)
        assert tr.goal.shape == (T, B, ENV.goal_size)
        assert tr.action.shape == (T, B, act)
        for mask in (tr.reached, tr.final, tr.valid):
            assert mask.shape == (T, B) and mask.dtype == bool
        assert run_lengths(tr, n[level]) >= 1
    assert int(stats.primitive_steps) == T * B
    assert int(stats.useful_steps) / int(stats.primitive_steps) >= 0.95
    # A level's actions complete exactly when the level below finishes.
    for lower, upper in zip(transitions[:-1], transitions[1:]):
        np.testing.assert_array_equal(upper.valid, lower.final & lower.valid)


def test_a_driver_hands_the_top_level_n_goals_per_episode_and_never_reaches():
    calls = []

    def toward_plus_x(params, obs, goal, key):  # the driver's goal is meaningless; it ignores it
        calls.append(1)
        return jnp.array([0.5, 0.0])

    h = Hierarchy(ENV, (steer, hop), n=(20, 8), eps=(0.1, 0.3), driver=Driver(toward_plus_x, n=3))
    assert (h.k, h.rows) == (2, 3)
    _, _, (t0, t1, t2), _ = run(h, (None, None, None), jax.random.key(0), 8, 400, root=2)
    t1, t2 = jax.tree.map(np.asarray, (t1, t2))
    assert not t2.reached.any()
    assert run_lengths(t2, 3) == 3  # only the count of 3 top-level skills ends a driver episode
    np.testing.assert_array_equal(t2.valid, t1.final & t1.valid)
    # Every top-level goal is the driver's offset from where the top level received it.
    offsets = (t1.goal - t1.obs[..., :2])[t1.valid]
    np.testing.assert_allclose(offsets, np.broadcast_to([0.5, 0.0], offsets.shape), atol=1e-5)
    assert t1.valid.sum() > 24 and len(calls) > 0
    with pytest.raises(ValueError, match=r"root must be in 0..2 \(2 is the driver\); got 3"):
        jit_init_rollout(h, (None, None, None), START, None, jax.random.key(0), 8, 3)


def test_controlled_run_respects_n_at_both_levels():
    _, _, (t0, t1), _ = controlled_run()
    assert run_lengths(t0, 20) <= 20
    assert run_lengths(t1, 8) <= 8


def test_rooted_at_a_lower_level_leaves_levels_above_root_idle():
    policies, params = small_agent(3)
    h = Hierarchy(ENV, policies, n=(5, 4, 3), eps=(0.05, 0.1, 0.2))
    goal = jnp.array([1.0, -1.0])

    def fixed_goal_start(_, key):
        return ENV.reset(key), goal, ()

    _, _, transitions, stats = run(h, params, jax.random.key(3), 4, 60, root=1, start=fixed_goal_start)
    assert len(transitions) == 3
    assert not np.asarray(transitions[2].valid).any() and int(stats.decisions[2]) == 0
    root_goals = np.asarray(transitions[1].goal)[np.asarray(transitions[1].valid)]
    assert len(root_goals) > 0 and np.all(root_goals == np.array([1.0, -1.0]))
    assert int(stats.decisions[1]) > 0
    with pytest.raises(ValueError, match=r"^root must be in 0\.\.2; got 3$"):
        jit_init_rollout(h, params, fixed_goal_start, None, jax.random.key(0), 4, 3)


def counting(policy, traces: list):
    """``policy`` that records each time JAX traces it (a trace means a compile)."""

    def traced(params, obs, goal, key):
        traces.append(1)
        return policy(params, obs, goal, key)

    return traced


def test_root_is_data_one_compiled_program_serves_every_level():
    traces = []
    h = Hierarchy(ENV, (steer, counting(hop, traces)), n=(10, 5), eps=(0.1, 0.3))
    state = jit_init_rollout(h, (None, None), START, None, jax.random.key(0), 8, root=0)
    state, (t0, t1), episodes, _ = jit_rollout(h, (None, None), START, None, state, 40)
    after_first = len(traces)
    assert not np.asarray(t1.valid).any()
    # Rooted at level 0, every level-0 pursuit is an episode.
    np.testing.assert_array_equal(episodes.valid, t0.final & t0.valid)
    state = jit_init_rollout(h, (None, None), START, None, jax.random.key(0), 8, root=1)
    state, (t0, t1), episodes, _ = jit_rollout(h, (None, None), START, None, state, 40)
    assert len(traces) == after_first
    np.testing.assert_array_equal(episodes.valid, t1.final & t1.valid)


def test_episode_end_returns_the_start_info_and_counts_episodes():
    def numbered_start(_, key):
        state, goal, _ = START(None, key)
        return state, goal, {"goal": goal, "tag": jax.random.uniform(key)}

    state = jit_init_rollout(CONTROLLED, (None, None), numbered_start, None, jax.random.key(2), 16)
    first_tags = np.asarray(state.episode["tag"])
    _, (_, t1), episodes, stats = jit_rollout(CONTROLLED, (None, None), numbered_start, None, state, 200)
    valid = np.asarray(episodes.valid)
    assert valid.sum() == int(stats.episodes_finished) > 16
    # The info handed back is that of the episode that ended: its root goal.
    np.testing.assert_array_equal(np.asarray(episodes.info["goal"])[valid], np.asarray(t1.goal)[valid])
    np.testing.assert_array_equal(np.asarray(episodes.reached)[valid], np.asarray(t1.reached)[valid])
    index = np.asarray(episodes.index)
    for env in range(16):
        ended = np.nonzero(valid[:, env])[0]
        np.testing.assert_array_equal(index[ended, env], np.arange(len(ended)))
        assert np.asarray(episodes.info["tag"])[ended[0], env] == first_tags[env]


def test_deterministic_under_fixed_key_and_key_matters():
    policies, params = small_agent(2)
    h = Hierarchy(ENV, policies, n=(5, 5), eps=(0.05, 0.1))
    a = run(h, params, jax.random.key(7), 8, 40)
    b = run(h, params, jax.random.key(7), 8, 40)
    c = run(h, params, jax.random.key(8), 8, 40)
    for x, y in zip(jax.tree.leaves(a[2]), jax.tree.leaves(b[2])):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[2][0].goal, c[2][0].goal)


def test_batch_members_are_independent():
    policies, params = small_agent(2)
    h = Hierarchy(ENV, policies, n=(5, 5), eps=(0.05, 0.1))
    state = jit_init_rollout(h, params, START, None, jax.random.key(4), 4)
    qpos = state.env.data.qpos.at[0].set(jnp.array([9.0, -9.0]))
    moved = state.replace(env=state.env.replace(data=state.env.data.replace(qpos=qpos)))
    _, base, _, _ = jit_rollout(h, params, START, None, state, 50)
    _, other, _, _ = jit_rollout(h, params, START, None, moved, 50)
    for x, y in zip(jax.tree.leaves(base), jax.tree.leaves(other)):
        x, y = np.asarray(x), np.asarray(y)
        np.testing.assert_allclose(x[:, 1:], y[:, 1:], rtol=1e-5, atol=1e-5)
    assert not np.allclose(np.asarray(base[0].obs)[:, 0], np.asarray(other[0].obs)[:, 0])


def test_nan_in_one_env_invalidates_its_step_and_restarts_it():
    h = CONTROLLED
    state = jit_init_rollout(h, (None, None), START, None, jax.random.key(5), 4)
    qvel = state.env.data.qvel.at[2].set(jnp.nan)
    state = state.replace(env=state.env.replace(data=state.env.data.replace(qvel=qvel)))
    new_state, (t0, t1), episodes, stats = jit_rollout(h, (None, None), START, None, state, 10)
    # The episode the reset cut short is handed back as cut, unreached, at its last state.
    cut = np.asarray(episodes.cut)
    assert cut.sum() == 1 and bool(cut[0, 2]) and not np.asarray(episodes.valid)[0, 2]
    assert not bool(episodes.reached[0, 2]) and bool(episodes.ended[0, 2])
    np.testing.assert_array_equal(
        ENV.goal_of_obs(episodes.final_obs[0, 2]), ENV.goal_of(jax.tree.map(lambda x: x[2], state.env))
    )
    assert int(stats.nan_resets) == 1
    assert int(new_state.env.nan_resets[2]) == 1
    assert int(stats.useful_steps) == 4 * 10 - 1
    assert not bool(t0.valid[0, 2]) and bool(t0.final[0, 2]) and bool(t1.final[0, 2])
    # Both levels' actions the reset ended are handed back as cut, unreached, ending where the step began.
    assert bool(t0.cut[0, 2]) and bool(t1.cut[0, 2]) and not (t0.reached[0, 2] or t1.reached[0, 2])
    assert int(np.asarray(t0.cut).sum()) == 1 and not (np.asarray(t0.cut) & np.asarray(t0.valid)).any()
    np.testing.assert_array_equal(t0.next_obs[0, 2], episodes.final_obs[0, 2])
    assert bool(t0.valid[1, 2]), "the restarted env continues with a live episode"
    assert np.isfinite(np.asarray(new_state.env.data.qpos)).all()


def test_second_call_does_not_recompile():
    traces = []
    h = Hierarchy(ENV, (counting(steer, traces), hop), n=(10, 5), eps=(0.1, 0.3))
    state = jit_init_rollout(h, (None, None), START, None, jax.random.key(0), 8)
    before_first = len(traces)
    state, _, _, _ = jit_rollout(h, (None, None), START, None, state, 20)
    after_first = len(traces)
    assert after_first > before_first, "the first rollout never traced the counting policy: nothing was compiled"
    state, _, _, _ = jit_rollout(h, (None, None), START, None, state, 20)
    assert len(traces) == after_first, "the second rollout traced the policy again: it recompiled"
    state = jit_init_rollout(h, (None, None), START, None, jax.random.key(1), 8)
    state, _, _, _ = jit_rollout(h, (None, None), START, None, state, 20)
    assert len(traces) == after_first, "a new start and key recompiled the rollout"


@pytest.mark.parametrize("count", [0, 1, 5, 8, 9, 31, 64])
def test_gathered_decisions_equal_full_batch_decisions(count):
    batch = 64
    (_, policy), (_, params) = mlp_agent(ENV, 2, (16,), (1.0,), jax.random.key(0))
    obs = jax.random.normal(jax.random.key(1), (batch, 4))
    goals = jax.random.normal(jax.random.key(2), (batch, 2))
    keys = jax.random.split(jax.random.key(3), batch)
    need = jnp.zeros(batch, bool).at[jax.random.permutation(jax.random.key(4), batch)[:count]].set(True)
    old = jnp.full((batch, 2), 7.0)
    new, n = jax.jit(lambda nd: decide(policy, params, obs, goals, keys, nd, old))(need)
    full = jax.vmap(policy, (None, 0, 0, 0))(params, obs, goals, keys)
    expected = jnp.where(need[:, None], full, old)
    np.testing.assert_allclose(new, expected, rtol=1e-5, atol=1e-6)
    assert int(n) == count
    assert decision_buckets(64) == (8, 16, 32, 64)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(policies=(), n=(), eps=()), "policies"),
        (dict(policies=(steer, hop), n=(5,), eps=(0.1, 0.2)), "n and eps"),
        (dict(policies=(steer,), n=(0,), eps=(0.1,)), "n"),
        (dict(policies=(steer,), n=(5,), eps=(0.0,)), "eps"),
    ],
)
def test_invalid_hierarchy_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Hierarchy(ENV, **kwargs)
