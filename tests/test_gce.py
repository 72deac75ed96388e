"""Goal-Conditioned Empowerment math against independent closed forms."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from mjx_emp import gce


def test_goal_conditioned_reward_is_gaussian_log_density():
    goal = jnp.array([1.0, -2.0])
    achieved = jnp.array([0.5, -1.0])
    sigma = 0.4
    expected = sum(
        -0.5 * ((g - a) / sigma) ** 2 - math.log(sigma * math.sqrt(2 * math.pi))
        for g, a in zip([1.0, -2.0], [0.5, -1.0])
    )
    np.testing.assert_allclose(gce.goal_conditioned_reward(goal, achieved, sigma), expected, rtol=1e-6)
    # best when the goal is achieved exactly, and it falls with distance
    at_goal = gce.goal_conditioned_reward(goal, goal, sigma)
    assert at_goal > gce.goal_conditioned_reward(goal, achieved, sigma)
    np.testing.assert_allclose(at_goal, -2 * math.log(sigma * math.sqrt(2 * math.pi)), rtol=1e-6)


def test_discount_is_zero_exactly_where_reached():
    reached = jnp.array([True, False, True])
    np.testing.assert_allclose(gce.goal_conditioned_discount(reached, 0.99), [0.0, 0.99, 0.0], rtol=1e-7, atol=0)


def test_box_log_prob_and_volume():
    action = jnp.array([0.3, -1.0, jnp.log(2.0), jnp.log(0.5)])  # shift (0.3, -1), half-widths (2, 0.5)
    np.testing.assert_allclose(gce.log_prob_box(action), -math.log(4.0 * 1.0), rtol=1e-6)
    np.testing.assert_allclose(gce.box_volume(action), 4.0, rtol=1e-6)


def test_samples_fill_the_box_and_match_its_density():
    action = jnp.array([1.0, math.log(3.0)])  # 1-D box [-2, 4]
    z = gce.sample_goal(gce.goal_noise(jax.random.key(0), (20000, 1)), action)
    assert float(z.min()) >= -2.0 and float(z.max()) <= 4.0
    assert float(z.min()) < -1.9 and float(z.max()) > 3.9
    hist, _ = np.histogram(np.asarray(z), bins=6, range=(-2.0, 4.0), density=True)
    np.testing.assert_allclose(hist, math.exp(float(gce.log_prob_box(action))), rtol=0.08)


def test_reparameterisation_gradient():
    noise = jnp.array([0.5, -0.25])
    action = jnp.array([0.1, 0.2, jnp.log(2.0), jnp.log(4.0)])
    jac = jax.jacobian(gce.sample_goal, argnums=1)(noise, action)
    # dz/dshift = I, dz/dlog_hw = diag(noise * half_width)
    np.testing.assert_allclose(jac[:, :2], np.eye(2), atol=1e-7)
    np.testing.assert_allclose(jac[:, 2:], np.diag([0.5 * 2.0, -0.25 * 4.0]), atol=1e-6)


def test_goal_space_reward_trades_accuracy_for_entropy():
    sigma = 1.75
    start, final = jnp.zeros(1), jnp.zeros(1)
    z = jnp.array([0.0])
    small, big = jnp.array([0.0, 0.0]), jnp.array([0.0, 2.0])
    # same accuracy: the bigger box earns exactly its extra log-volume
    gain = gce.goal_space_reward(start, z, final, big, sigma) - gce.goal_space_reward(start, z, final, small, sigma)
    np.testing.assert_allclose(gain, 2.0, rtol=1e-6)
    # the entropy part is linear in log half-width: d reward / d log_hw = 1 everywhere
    grad = jax.grad(lambda a: gce.goal_space_reward(start, z, final, a, sigma))(jnp.array([0.0, 5.0]))
    np.testing.assert_allclose(grad, [0.0, 1.0], atol=1e-6)
    # missing the goal costs the Gaussian term
    miss = gce.goal_space_reward(start, jnp.array([3.0]), final, small, sigma)
    np.testing.assert_allclose(
        gce.goal_space_reward(start, z, final, small, sigma) - miss, 0.5 * (3.0 / sigma) ** 2, rtol=1e-6
    )
