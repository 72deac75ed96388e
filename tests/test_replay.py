"""Replay buffer: masked insertion, ring wrap-around, sampling, rollout hand-off."""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_emp.replay import (
    episode_walk,
    flatten_rows,
    insertion_slots,
    link_episode_rows,
    replay_clear_where,
    replay_init,
    replay_insert,
    replay_sample,
)

insert = jax.jit(replay_insert)


def rows(values):
    values = jnp.asarray(values, jnp.float32)
    return {"x": values, "pair": jnp.stack([values, -values], axis=-1)}


def example():
    return {"x": jnp.zeros(()), "pair": jnp.zeros(2)}


def test_only_valid_rows_are_inserted_in_order():
    buffer = replay_init(example(), capacity=8)
    buffer = insert(buffer, rows([1, 2, 3, 4, 5]), jnp.array([True, False, True, False, True]))
    assert int(buffer.size) == 3 and int(buffer.insert_pos) == 3
    np.testing.assert_array_equal(buffer.data["x"][:3], [1, 3, 5])
    np.testing.assert_array_equal(buffer.data["pair"][:3, 1], [-1, -3, -5])
    np.testing.assert_array_equal(buffer.data["x"][3:], 0)


def test_clear_where_empties_only_when_asked_and_the_next_insert_starts_over():
    buffer = insert(replay_init(example(), capacity=8), rows([1, 2, 3]), jnp.ones(3, bool))
    kept = replay_clear_where(buffer, jnp.bool_(False))
    assert int(kept.size) == 3 and int(kept.insert_pos) == 3
    cleared = replay_clear_where(buffer, jnp.bool_(True))
    assert int(cleared.size) == 0 and int(cleared.insert_pos) == 0
    refilled = insert(cleared, rows([7]), jnp.ones(1, bool))
    assert int(refilled.size) == 1
    np.testing.assert_array_equal(replay_sample(refilled, jax.random.key(0), 4)["x"], [7, 7, 7, 7])


def test_ring_wraps_and_overwrites_oldest():
    buffer = replay_init(example(), capacity=5)
    buffer = insert(buffer, rows([1, 2, 3]), jnp.ones(3, bool))
    buffer = insert(buffer, rows([4, 5, 6, 7, 0]), jnp.array([True, True, True, True, False]))
    assert int(buffer.size) == 5 and int(buffer.insert_pos) == 2
    np.testing.assert_array_equal(buffer.data["x"], [6, 7, 3, 4, 5])


def test_oversized_insert_keeps_the_newest_rows():
    buffer = replay_init(example(), capacity=5)
    buffer = insert(buffer, rows([1]), jnp.ones(1, bool))
    buffer = insert(buffer, rows(np.arange(10, 18)), jnp.ones(8, bool))
    assert int(buffer.size) == 5 and int(buffer.insert_pos) == (1 + 8) % 5
    assert sorted(np.asarray(buffer.data["x"]).tolist()) == [13, 14, 15, 16, 17]
    one_by_one = replay_init(example(), capacity=5)
    for v in [1] + list(range(10, 18)):
        one_by_one = insert(one_by_one, rows([v]), jnp.ones(1, bool))
    np.testing.assert_array_equal(buffer.data["x"], one_by_one.data["x"])


def test_sample_draws_only_filled_rows():
    buffer = replay_init(example(), capacity=100)
    buffer = insert(buffer, rows([7, 8, 9]), jnp.ones(3, bool))
    sample = jax.jit(replay_sample, static_argnums=2)(buffer, jax.random.key(0), 256)
    assert sample["x"].shape == (256,) and sample["pair"].shape == (256, 2)
    assert set(np.asarray(sample["x"]).tolist()) == {7.0, 8.0, 9.0}


def test_rollout_transitions_flatten_into_the_buffer():
    t, b, obs = 4, 3, 5
    valid = jnp.array([[1, 0, 1], [0, 0, 1], [1, 1, 1], [0, 0, 0]], bool)
    tree = {"obs": jnp.arange(t * b * obs, dtype=jnp.float32).reshape(t, b, obs), "valid": valid}
    flat = flatten_rows(tree)
    assert flat["obs"].shape == (t * b, obs)
    buffer = replay_init(jax.tree.map(lambda x: x[0], flat), capacity=32)
    buffer = insert(buffer, flat, flat["valid"])
    assert int(buffer.size) == int(valid.sum())
    np.testing.assert_array_equal(buffer.data["obs"][: int(valid.sum())], np.asarray(flat["obs"])[np.asarray(flat["valid"])])


def test_episode_links_chain_each_environments_rows_until_its_episode_ends():
    # Two environments over three steps: env 0 stores every step and its episode ends at step 1
    # (a new one starts at step 2); env 1 stores steps 0 and 2 only, one episode throughout.
    buffer = replay_init(example(), capacity=16)
    valid = jnp.array([[True, True], [True, False], [True, True]])
    final = jnp.array([[False, False], [True, False], [False, False]])
    slots, count = insertion_slots(buffer, valid.reshape(-1))
    assert int(count) == 5
    slots = slots.reshape(valid.shape)
    none = buffer.capacity
    successor = jnp.full(16, 7, jnp.int32)  # stale links in reused slots must be forgotten
    successor, last = link_episode_rows(successor, slots, valid, final, jnp.full(2, none, jnp.int32))
    # slots in insertion order: (t0,e0)=0, (t0,e1)=1, (t1,e0)=2, (t2,e0)=3, (t2,e1)=4
    np.testing.assert_array_equal(successor[:5], [2, 4, none, none, none])
    np.testing.assert_array_equal(last, [3, 4])
    walk, exists = episode_walk(successor, jnp.array([0, 1, 3]), 3)
    np.testing.assert_array_equal(exists, [[True, True, True], [True, True, False], [False, False, False]])
    np.testing.assert_array_equal(walk[:2], [[0, 1, 3], [2, 4, 15]])


def test_episode_links_continue_across_chunks_through_last():
    buffer = replay_init(example(), capacity=8)
    successor = jnp.full(8, 8, jnp.int32)
    last = jnp.array([5, 8], jnp.int32)  # env 0's running episode ended its previous chunk at slot 5
    buffer = buffer.replace(insert_pos=jnp.int32(6), size=jnp.int32(6))
    slots, _ = insertion_slots(buffer, jnp.array([True, True]))
    successor, last = link_episode_rows(successor, slots.reshape(1, 2), jnp.array([[True, True]]),
                                        jnp.array([[False, True]]), last)
    assert int(successor[5]) == 6 and int(successor[6]) == 8 and int(successor[7]) == 8
    np.testing.assert_array_equal(last, [6, 8])
