"""Functional env API: resets, goal map, NaN guard, cages."""

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_emp.algos.he.config import HEConfig, check_train_config
from mjx_emp.envs.env import make_env
from mjx_emp.envs.registry import DOMAINS
from mjx_emp.errors import ConfigError


@functools.cache
def jitted_step(env):
    """One compiled ``env.step`` per domain for the whole module: a fresh ``jax.jit`` wrapper
    would compile the same step again in every test (10-20 s each on the robots)."""
    return jax.jit(env.step)


def torso_position(env, state) -> np.ndarray:
    """Torso body position computed by C MuJoCo from the state's qpos (independent of goal_of)."""
    d = mujoco.MjData(env.mj_model)
    d.qpos[:] = np.asarray(state.data.qpos)
    mujoco.mj_forward(env.mj_model, d)
    return d.body("torso").xpos.copy()


@pytest.mark.parametrize("name", sorted(DOMAINS))
def test_reset_to_places_torso_and_goal_of_matches(name):
    env = make_env(name)
    target = jnp.asarray([1.5, -2.25][: env.goal_size])
    state = jax.jit(env.reset_to)(jax.random.key(0), target)
    np.testing.assert_allclose(env.goal_of(state), target, atol=1e-6)
    np.testing.assert_allclose(torso_position(env, state)[: env.goal_size], target, atol=1e-6)
    np.testing.assert_array_equal(state.data.qvel, 0.0)
    joints = np.asarray(state.data.qpos).copy()
    joints[list(env.goal_qpos)] = env.home_qpos[list(env.goal_qpos)]
    np.testing.assert_allclose(joints, env.home_qpos, atol=1e-7)  # every other coordinate is home


@pytest.mark.parametrize("name", ["point_mass", "ant_field", "half_cheetah_field"])
def test_goal_of_tracks_torso_while_moving(name):
    env = make_env(name)
    step = jitted_step(env)
    state = env.reset(jax.random.key(1))
    key = jax.random.key(2)
    for _ in range(5):
        key, sub = jax.random.split(key)
        state = step(state, jax.random.uniform(sub, (env.action_size,), minval=-1, maxval=1))
    assert int(state.nan_resets) == 0
    moved = np.linalg.norm(np.asarray(env.goal_of(state)) - np.asarray(env.home_goal()))
    assert moved > 1e-4, "random actions should move the torso"
    np.testing.assert_allclose(env.goal_of(state), torso_position(env, state)[: env.goal_size], atol=1e-5)
    obs = env.observe(state)
    assert obs.shape == (env.obs_size,)
    np.testing.assert_array_equal(env.goal_of_obs(obs), env.goal_of(state))


def test_point_mass_action_moves_a_useful_distance():
    env = make_env("point_mass")
    step = jitted_step(env)
    state = env.reset(jax.random.key(0))
    for _ in range(20):
        state = step(state, jnp.array([1.0, 0.0]))
    # 20 full-thrust actions: a few metres, so n=20 skills span a useful region.
    assert 2.0 < float(env.goal_of(state)[0]) < 5.0


def test_nan_guard_resets_and_counts():
    env = make_env("point_mass")
    state = env.reset_to(jax.random.key(0), jnp.array([3.0, 4.0]))
    broken = state.replace(data=state.data.replace(qvel=jnp.array([jnp.nan, 0.0])))
    stepped = jitted_step(env)(broken, jnp.zeros(2))
    assert int(stepped.nan_resets) == 1
    np.testing.assert_allclose(env.goal_of(stepped), env.home_goal())
    assert np.isfinite(np.asarray(stepped.data.qvel)).all()
    again = jitted_step(env)(stepped, jnp.zeros(2))
    assert int(again.nan_resets) == 1, "a healthy step must not count"


def test_nan_guard_is_per_batch_member():
    env = make_env("point_mass")
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), 3))
    qvel = states.data.qvel.at[1, 0].set(jnp.inf)
    states = states.replace(data=states.data.replace(qvel=qvel))
    stepped = jax.jit(jax.vmap(env.step))(states, jnp.ones((3, 2)))
    np.testing.assert_array_equal(stepped.nan_resets, [0, 1, 0])
    assert float(stepped.data.qpos[0, 0]) > 0.0  # healthy members still moved


def upside_down(env, state):
    """``state`` with the torso rotated half a turn about x (a free torso) or about y (pitch)."""
    qpos = state.data.qpos
    if env.torso.free:
        qpos = qpos.at[env.torso.quat : env.torso.quat + 4].set(jnp.array([0.0, 1.0, 0.0, 0.0]))
        qpos = qpos.at[2].set(1.0)
    else:
        qpos = qpos.at[2].set(jnp.pi)
    return state.replace(data=state.data.replace(qpos=qpos))


def test_an_ant_upside_down_is_reset_home_and_counted_and_an_upright_one_is_not():
    env = make_env("ant_field")
    step = jitted_step(env)
    state = env.reset_to(jax.random.key(0), jnp.array([3.0, -1.0]))
    upright = step(state, jnp.zeros(env.action_size))
    assert int(upright.flip_resets) == 0 and int(upright.resets) == 0
    flipped = step(upside_down(env, state), jnp.zeros(env.action_size))
    assert int(flipped.flip_resets) == 1 and int(flipped.nan_resets) == 0 and int(flipped.resets) == 1
    np.testing.assert_allclose(flipped.data.qpos, env.home_qpos, atol=1e-6)  # home pose at the origin
    # Tilted by 60 degrees about x it is still upright.
    tilted = state.data.qpos.at[3:7].set(jnp.array([np.cos(np.pi / 6), np.sin(np.pi / 6), 0.0, 0.0]))
    assert bool(env.torso.upright(tilted))


def test_up_axis_reads_the_tilt_from_an_observation_and_decides_upright():
    env = make_env("ant_field")
    obs = env.observe(env.reset_to(jax.random.key(0), jnp.array([1.0, 2.0])))
    q = env.torso.quat

    def turned(angle, scale=1.0):  # the torso rotated by ``angle`` about x; a quaternion of any length
        return obs.at[q : q + 4].set(scale * jnp.array([np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0]))

    angles = np.array([0.0, np.pi / 3, np.pi / 2 - 0.01, np.pi / 2 + 0.01, np.pi])
    up = [float(env.torso.up_axis_z(turned(a, scale=1.7))) for a in angles]
    np.testing.assert_allclose(up, np.cos(angles), atol=1e-6)
    qpos = jnp.stack([turned(a)[: env.mj_model.nq] for a in angles])
    assert [bool(env.torso.upright(x)) for x in qpos] == [True, True, True, False, False]
    batch = jnp.stack([turned(a) for a in angles])
    np.testing.assert_allclose(env.torso.up_axis_z(batch), np.cos(angles), atol=1e-6)  # over a batch too
    cheetah = make_env("half_cheetah_field")
    pitched = jnp.zeros((5, cheetah.obs_size)).at[:, 2].set(jnp.asarray(angles))  # rooty, the torso's pitch
    np.testing.assert_allclose(cheetah.torso.up_axis_z(pitched), np.cos(angles), atol=1e-6)
    assert [bool(cheetah.torso.upright(x[: cheetah.mj_model.nq])) for x in pitched] == [True] * 5
    point = make_env("point_mass")
    np.testing.assert_array_equal(point.torso.up_axis_z(jnp.zeros((3, point.obs_size))), np.ones(3))


def test_a_half_cheetah_on_its_back_keeps_running():
    env = make_env("half_cheetah_field")
    state = upside_down(env, env.reset_to(jax.random.key(0), jnp.array([2.0])))
    stepped = jitted_step(env)(state, jnp.ones(env.action_size))
    assert int(stepped.resets) == 0
    assert abs(float(env.goal_of(stepped)[0]) - 2.0) < 1.0  # not sent home to x = 0


def test_unknown_env_names_the_allowed_values():
    with pytest.raises(ValueError, match=r"^env name 'pointmass' is unknown; allowed values: \[.*'point_mass'\]$"):
        make_env("pointmass")


def test_half_cheetah_cage_wall_blocks_until_button_opens_it():
    env = make_env("half_cheetah_cage")
    step = jitted_step(env)
    wall_x = float(env.cage.home_mocap_pos[env.cage.wall_mocap_ids[0]][0])
    assert wall_x == 8.0
    # Head tip starts 0.1 short of the wall: driving into it, the torso cannot follow.
    state = env.reset_to(jax.random.key(0), jnp.array([wall_x - 0.85]))
    key = jax.random.key(1)
    for _ in range(30):
        key, sub = jax.random.split(key)
        state = step(state, jax.random.uniform(sub, (6,), minval=-1, maxval=1))
        assert float(env.goal_of(state)[0]) < wall_x - 0.5
    assert not bool(env.cage.is_open(state.data))
    assert float(env.observe(state)[-1]) == 0.0


def turned_world(env, obs: np.ndarray, goal: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """The same Ant state and goal with the whole world turned by ``angle`` about z (MuJoCo C math)."""
    turn = np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, turn)
    rotation = rotation.reshape(3, 3)
    obs = obs.copy()
    obs[:3] = rotation @ obs[:3]
    quat = np.zeros(4)
    mujoco.mju_mulQuat(quat, turn, obs[3:7].astype(np.float64))
    obs[3:7] = quat
    nq = env.mj_model.nq
    obs[nq : nq + 3] = rotation @ obs[nq : nq + 3]
    return obs, (rotation[:2, :2] @ goal).astype(np.float32)


def test_heading_frame_inputs_do_not_change_when_the_world_turns_and_world_inputs_do():
    env, world = make_env("ant_field", heading_frame=True), make_env("ant_field")
    m, rng = env.mj_model, np.random.default_rng(0)
    d = mujoco.MjData(m)
    d.qpos[:] = env.home_qpos
    for _ in range(30):  # a tumbled, moving Ant: tilt, yaw and velocity all nonzero
        d.ctrl[:] = rng.uniform(-1, 1, m.nu)
        for _ in range(env.action_repeat):
            mujoco.mj_step(m, d)
    obs = np.concatenate([d.qpos, d.qvel]).astype(np.float32)
    goal = obs[:2] + np.array([1.0, 0.5], np.float32)
    for angle in (0.3, 1.7, -2.9, np.pi):
        turned_obs, turned_goal = turned_world(env, obs, goal, angle)
        np.testing.assert_allclose(env.features(turned_obs), env.features(obs), atol=1e-4)
        np.testing.assert_allclose(env.goal_offset(turned_obs, turned_goal), env.goal_offset(obs, goal), atol=1e-5)
        assert np.abs(world.features(turned_obs) - world.features(obs)).max() > 0.1
    # Facing +x already, the goal offset is the world offset.
    np.testing.assert_allclose(env.goal_offset(env.home_qpos, env.home_qpos[:2] + np.array([1.0, 2.0])),
                               [1.0, 2.0], atol=1e-6)


def test_a_turned_start_tilts_the_torso_by_its_angle_lifts_it_and_keeps_the_rest():
    """``Torso.turned``: a free torso turned by a about any horizontal axis tilts by 1 - cos(a) (its
    quaternion stays a unit one, its heading's axis decides which way it leans); a planar torso
    pitches by +-a; both are lifted by TURN_LIFT sin(a); position, joints and velocities stay."""
    from mjx_emp.envs.parts import TURN_LIFT

    env = make_env("ant_field")
    obs = env.observe(env.reset_to(jax.random.key(0), jnp.array([1.0, 2.0])))
    q, z = env.torso.quat, env.torso.height
    angles = jnp.array([0.0, 0.3, 1.0, np.pi / 2])
    for heading in (0.0, 1.3, -2.5):
        turned = jax.vmap(lambda a, h=heading: env.torso.turned(obs, a, jnp.float32(h)))(angles)
        np.testing.assert_allclose(env.torso.tilt(turned), 1.0 - np.cos(angles), atol=1e-6)
        np.testing.assert_allclose(jnp.linalg.norm(turned[:, q:q + 4], axis=-1), 1.0, atol=1e-6)
        np.testing.assert_allclose(turned[:, z] - obs[z], TURN_LIFT * np.sin(angles), atol=1e-6)
        rest = np.delete(np.arange(obs.shape[0]), [z, q, q + 1, q + 2, q + 3])
        np.testing.assert_array_equal(turned[:, rest], jnp.broadcast_to(obs[rest], (4, rest.size)))
        # The up axis leans at right angles to the turn's axis: toward heading - 90 degrees (right-hand rule).
        w, x, y, zq = (turned[2, q + i] for i in range(4))
        lean = np.array([2 * (x * zq + w * y), 2 * (y * zq - w * x)])
        np.testing.assert_allclose(lean / np.linalg.norm(lean), [np.sin(heading), -np.cos(heading)], atol=1e-5)
    cheetah = make_env("half_cheetah_field")
    start = cheetah.observe(cheetah.reset(jax.random.key(0)))
    forward = cheetah.torso.turned(start, jnp.float32(0.4), jnp.float32(0.2))
    backward = cheetah.torso.turned(start, jnp.float32(0.4), jnp.float32(np.pi))
    assert float(forward[cheetah.torso.pitch] - start[cheetah.torso.pitch]) == pytest.approx(0.4)
    assert float(backward[cheetah.torso.pitch] - start[cheetah.torso.pitch]) == pytest.approx(-0.4)
    assert float(forward[cheetah.torso.height] - start[cheetah.torso.height]) == pytest.approx(TURN_LIFT * np.sin(0.4))
    point = make_env("point_mass")
    still = point.observe(point.reset(jax.random.key(0)))
    np.testing.assert_array_equal(point.torso.turned(still, jnp.float32(1.0), jnp.float32(0.0)), still)


def test_heading_frame_needs_a_free_torso():
    with pytest.raises(ValueError, match="heading_frame: 'half_cheetah_field' has no free torso"):
        make_env("half_cheetah_field", heading_frame=True)


@pytest.mark.parametrize("name", ["ant_cage", "half_cheetah_cage"])
def test_the_button_opens_the_cage_and_the_latch_ignores_presses_outside_it_and_stays_open(name):
    env = make_env(name)
    step = jitted_step(env)
    center, half = np.asarray(env.cage.button_center), np.asarray(env.cage.button_half_size)
    outside = env.reset_to(jax.random.key(0), jnp.asarray(center - half - 0.3))  # just short of every edge
    assert not bool(env.cage.is_open(step(outside, jnp.zeros(env.action_size)).data))
    on_button = env.reset_to(jax.random.key(0), jnp.asarray(center))
    assert not bool(env.cage.is_open(on_button.data))  # closed until a step finds the torso on the button
    opened = step(on_button, jnp.zeros(env.action_size))
    assert bool(env.cage.is_open(opened.data)) and bool(env.cage.open_of_obs(env.observe(opened)))
    walls = np.asarray(opened.data.mocap_pos)[list(env.cage.wall_mocap_ids)]
    assert np.all(np.linalg.norm(walls, axis=-1) > 1000.0)  # the walls are moved out of the way
    assert not bool(env.cage.is_open(env.reset(jax.random.key(1)).data))  # a new episode closes the cage again
    # carried far from the button (the latch is all that remembers the press), it stays open
    far = opened.data.qpos.at[jnp.asarray(env.goal_qpos)].set(jnp.asarray(center + 10 * half + 5.0))
    moved = opened.replace(data=opened.data.replace(qpos=far))
    for _ in range(3):
        moved = step(moved, jnp.zeros(env.action_size))
    assert bool(env.cage.is_open(moved.data)) and bool(env.cage.open_of_obs(env.observe(moved)))


def test_an_observation_with_the_cage_opened_restores_a_state_with_the_walls_gone():
    env = make_env("ant_cage")
    start = np.asarray(env.observe(env.reset(jax.random.key(0))))
    assert not bool(env.cage.open_of_obs(start))
    opened = env.cage.obs_opened(start, True)
    assert bool(env.cage.open_of_obs(opened)) and not bool(env.cage.open_of_obs(start))  # a copy, start untouched
    assert bool(env.cage.is_open(env.restore(jax.random.key(1), jnp.asarray(opened)).data))
    assert not bool(env.cage.is_open(env.restore(jax.random.key(1), jnp.asarray(start)).data))
    assert make_env("ant_field").cage is None and make_env("point_mass").cage is None


def test_physics_overrides_reach_the_model_and_bad_ones_name_their_field():
    env = make_env("point_mass", False, 7, "rk4")
    assert env.mj_model.opt.iterations == 7 and int(env.model.opt.iterations) == 7
    assert env.mj_model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    default = make_env("point_mass")
    assert default.mj_model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert default.mj_model.opt.iterations != 7
    with pytest.raises(ConfigError, match="integrator: 'verlet' is unknown"):
        make_env("point_mass", False, 0, "verlet")
    with pytest.raises(ConfigError, match="solver_iterations: must be >= 0"):
        check_train_config(HEConfig(solver_iterations=-1))


def test_flat_skill_learners_take_the_same_physics_overrides_as_he():
    """A comparison under accurate contacts gives every method 4 solver iterations, not only HE."""
    from mjx_emp.algos.registry import make_agent
    from mjx_emp.algos.skills.config import MetraConfig
    from mjx_emp.algos.skills.presets import PRESETS as SKILL_PRESETS

    agent = make_agent(MetraConfig(solver_iterations=7, integrator="rk4"))
    assert agent.env.mj_model.opt.iterations == 7
    assert agent.env.mj_model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    with pytest.raises(ConfigError, match="solver_iterations: must be >= 0"):
        make_agent(MetraConfig(solver_iterations=-1))
    with pytest.raises(ConfigError, match="integrator: 'verlet' is unknown"):
        make_agent(MetraConfig(integrator="verlet"))
    for name, (_, cfg) in SKILL_PRESETS.items():
        assert cfg.solver_iterations == (4 if name.endswith("-ant-field-cpu") else 0), name  # as HE's Ant recipe
