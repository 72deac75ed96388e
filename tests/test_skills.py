"""Flat skill learners (DIAYN, HIDIO, DADS, METRA): objectives against closed forms, SAC,
the flat rollout, and training, resuming and evaluating through the run layer and CLI."""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import subprocess

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image
from test_checkpoint import assert_bitwise_equal, kill_when
from tiny import TINY, cli_in_process, mjx_emp, run_cli

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.he.config import GcrlConfig
from mjx_emp.algos.registry import make_agent
from mjx_emp.algos.skills import objectives as obj
from mjx_emp.algos.skills.agent import SkillAgent
from mjx_emp.algos.skills.config import (
    DadsConfig,
    DiaynConfig,
    HidioConfig,
    MetraConfig,
)
from mjx_emp.commands import ResumeExperiment, TrainExperiment
from mjx_emp.envs.env import make_env
from mjx_emp.errors import ConfigError
from mjx_emp.learners.sac import SAC, SACBatch, squashed_sample
from mjx_emp.rollout.flat import flat_init, flat_rollout
from mjx_emp.run import jobs

TINY_SKILLS = dict(n=5, num_envs=8, collect_steps=5, iterations=2, grad_steps=3, batch_size=32,
                   replay_capacity=512, min_replay=40, hidden=(32,), epochs=3, seed=1)
METHODS = {"diayn": DiaynConfig, "hidio": HidioConfig, "dads": DadsConfig, "metra": MetraConfig}


def tiny(method: str):
    if method == "gcrl":
        return GcrlConfig(**{**dataclasses.asdict(TINY), "epochs": 3, "gs_iterations": 0, "goal_half_width": (0.5, 1.0)})
    extra = {"prior_samples": 4} if method == "dads" else {}
    return METHODS[method](**TINY_SKILLS, **extra)


# ---- objectives against closed forms --------------------------------------------------------

def test_diagonal_gaussian_log_prob_matches_the_density():
    x, mean, log_std = jnp.array([0.3, -1.0]), jnp.array([0.0, 0.5]), jnp.log(jnp.array([0.5, 2.0]))
    expected = sum(math.log(math.exp(-0.5 * ((xi - m) / s) ** 2) / (s * math.sqrt(2 * math.pi)))
                   for xi, m, s in [(0.3, 0.0, 0.5), (-1.0, 0.5, 2.0)])
    assert float(obj.diagonal_gaussian_log_prob(x, mean, log_std)) == pytest.approx(expected, rel=1e-6)


def test_posterior_reward_subtracts_the_uniform_prior():
    # q(z|.) = N(z; z, 1) in 2-D: log q = -log(2 pi); p(z) = 1/4 on [-1, 1]^2.
    log_q = obj.diagonal_gaussian_log_prob(jnp.array([0.2, 0.4]), jnp.array([0.2, 0.4]), jnp.zeros(2))
    assert float(obj.posterior_reward(log_q, 2)) == pytest.approx(-math.log(2 * math.pi) + math.log(4), rel=1e-6)


def test_dads_reward_is_zero_when_every_prior_skill_predicts_as_well_as_the_own():
    own = jnp.array([-1.0, -3.0])
    for count in (1, 5):
        assert np.allclose(obj.dads_reward(own, jnp.broadcast_to(own, (count, 2))), 0.0, atol=1e-6)
    # A skill far better than the prior's: reward log L minus nothing else when the others are -inf-like.
    reward = obj.dads_reward(jnp.array([0.0]), jnp.array([[0.0], [-1e4], [-1e4], [-1e4]]))
    assert float(reward[0]) == pytest.approx(math.log(4), rel=1e-6)


def test_metra_constraint_and_dual_update_signs():
    phi_obs = jnp.zeros((2, 2))
    phi_next = jnp.array([[0.5, 0.0], [2.0, 0.0]])  # a step of 0.5 keeps ||.|| <= 1, 2.0 violates it
    constraint = obj.metra_constraint(phi_obs, phi_next, slack=1e-3)
    assert float(constraint[0]) == pytest.approx(1e-3)  # capped at the slack
    assert float(constraint[1]) == pytest.approx(1.0 - 4.0)
    assert float(obj.metra_reward(phi_obs, phi_next, jnp.array([[1.0, 0.0], [0.0, 1.0]]))[0]) == pytest.approx(0.5)
    # Gradient descent on log lambda: violated -> lambda grows; satisfied -> it shrinks.
    grow = jax.grad(obj.metra_dual_loss)(jnp.log(30.0), constraint[1:])
    shrink = jax.grad(obj.metra_dual_loss)(jnp.log(30.0), constraint[:1])
    assert float(grow) < 0 < float(shrink)
    # phi's loss pushes a violating step back inside (its gradient shrinks ||phi(s') - phi(s)||).
    grad = jax.grad(lambda p: obj.metra_phi_loss(phi_obs[1:], p, jnp.array([[0.0, 1.0]]), 30.0, 1e-3))(phi_next[1:])
    assert float(grad[0, 0]) > 0


# ---- SAC ------------------------------------------------------------------------------------

def test_squashed_sample_log_prob_is_the_change_of_variables():
    mean, log_std = jnp.array([0.3, -2.0]), jnp.array([-0.5, 0.2])
    action, log_prob = squashed_sample(mean, log_std, jax.random.key(0))
    pre = jnp.arctanh(action)
    expected = obj.diagonal_gaussian_log_prob(pre, mean, log_std) - jnp.log(1 - action**2).sum()
    assert float(log_prob) == pytest.approx(float(expected), abs=1e-3)


def test_sac_learns_the_best_action_of_a_bandit():
    sac = SAC(hidden=(32,), action_size=1, actor_lr=3e-3, critic_lr=3e-3, alpha_lr=3e-3, init_alpha=0.01,
              target_entropy=-1.0)
    x = jnp.ones((64, 1))
    learner = sac.init(jax.random.key(0), x[0])

    def step(learner, key):
        act_key, step_key = jax.random.split(key)
        action = jax.random.uniform(act_key, (64, 1), minval=-1, maxval=1)
        batch = SACBatch(x=x, action=action, reward=-((action[:, 0] - 0.5) ** 2), next_x=x,
                         discount=jnp.zeros(64))
        return sac.step(learner, batch, step_key)

    learner, info = jax.lax.scan(step, learner, jax.random.split(jax.random.key(1), 600))
    assert float(sac.greedy(learner.actor, x[0])[0]) == pytest.approx(0.5, abs=0.1)
    assert all(np.isfinite(np.asarray(leaf)).all() for leaf in jax.tree.leaves(info))
    assert float(info.alpha[-1]) > 0 and info.entropy.shape == (600,)  # named fields, one per step


# ---- the flat rollout -----------------------------------------------------------------------

def test_flat_rollout_holds_a_skill_for_n_actions_then_restarts():
    env = make_env("point_mass")
    n, batch, steps = 4, 3, 10

    def start(_, key):
        return env.reset(key), jax.random.uniform(key, (2,), minval=-1, maxval=1)

    def toward_skill(params, obs, s0, skill, key):
        return skill

    state = flat_init(env, start, None, jax.random.key(0), batch)
    state, steps_ = jax.jit(flat_rollout, static_argnums=(0, 1, 3, 6, 7))(
        env, toward_skill, None, start, None, state, steps, n)
    last, skill, s0 = (np.asarray(x) for x in (steps_.last, steps_.skill, steps_.s0))
    np.testing.assert_array_equal(last[:, 0], [False, False, False, True] * 2 + [False, False])
    np.testing.assert_array_equal(skill[:4], np.broadcast_to(skill[0], skill[:4].shape))  # held for n actions
    assert not np.allclose(skill[4], skill[3])  # a new skill after the n-th action
    np.testing.assert_allclose(s0, np.broadcast_to(np.asarray(env.observe(env.reset(jax.random.key(0)))), s0.shape))
    np.testing.assert_array_equal(np.asarray(steps_.obs[4]), s0[4])  # the new episode starts at s0
    assert np.asarray(steps_.valid).all() and int(state.episodes_done.sum()) == 2 * batch


# ---- agents through the run layer -----------------------------------------------------------

# GCRL trains through HE's agent, whose resume test_checkpoint covers bit for bit: its case is in the slow tier.
@pytest.mark.parametrize("method", sorted(METHODS) + [pytest.param("gcrl", marks=pytest.mark.slow)])
def test_each_method_trains_stops_and_resumes_bitwise(method, tmp_path):
    cfg = tiny(method)
    straight = jobs.train(TrainExperiment(config=cfg, run_dir=str(tmp_path / "straight")))
    jobs.train(TrainExperiment(config=dataclasses.replace(cfg, epochs=2), run_dir=str(tmp_path / "stopped")))
    resumed = jobs.resume(ResumeExperiment(resume=str(tmp_path / "stopped"), epochs=3))
    assert_bitwise_equal(resumed, straight)
    lines = [json.loads(line) for line in (tmp_path / "stopped" / "metrics.jsonl").read_text().splitlines()]
    assert [m["epoch"] for m in lines] == [1, 2, 3]
    if method == "gcrl":
        return
    assert lines[-1]["algorithm"] == method
    assert lines[-1]["learned_iterations"] == 2 and lines[-1]["critic_loss"] is not None
    if method in ("diayn", "hidio"):
        assert 0 < lines[-1]["posterior_std"] < math.exp(2.0)
    if method == "metra":
        assert lines[-1]["dual_lambda"] > 0


@pytest.mark.slow  # a second path: METRA's resume is bitwise above, a SIGKILL mid-run is test_checkpoint's (HE)
def test_sigkill_then_resume_of_a_baseline_is_bitwise_identical(tmp_path):
    args = ["metra-point-mass", "--num-envs", "8", "--hidden", "32", "--batch-size", "32", "--grad-steps", "3",
            "--iterations", "2", "--min-replay", "40", "--epochs", "4"]
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    assert run_cli("train", *args, "--run-dir", str(straight)).returncode == 0
    process = subprocess.Popen(mjx_emp("train", *args, "--run-dir", str(killed)),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    kill_when(process, lambda: (killed / "checkpoints" / "2").exists())
    assert process.returncode == -signal.SIGKILL
    result = run_cli("train", "--resume", str(killed))
    assert result.returncode == 0, result.stderr
    _, _, a = jobs.load_run(straight)
    _, _, b = jobs.load_run(killed)
    assert_bitwise_equal(a, b)


def test_eval_reports_coverage_and_posterior_std(tmp_path):
    cfg = tiny("diayn")
    jobs.train(TrainExperiment(config=cfg, run_dir=str(tmp_path / "run")))
    result = cli_in_process("eval", str(tmp_path / "run"))
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert 1 <= report["runs"][0]["figures"]["coverage_cells"] <= 48 * (cfg.n + 1)
    assert 0 < report["posterior_std"]["mean"] < math.exp(2.0)
    assert "coverage" in result.stdout


def test_gcrl_goal_spaces_stay_the_hand_set_boxes_while_the_policies_learn():
    trainer = HEAgent(tiny("gcrl"))
    state = trainer.init()
    actors = jax.tree.leaves(state.policies[0].actor)
    for _ in range(2):
        state, _ = trainer.train_epoch(state)
    for box, width in zip(trainer.goal_spaces(state), (0.5, 1.0)):
        np.testing.assert_allclose(box["half_width"], [width, width], rtol=1e-6)
        np.testing.assert_allclose(box["shift"], [0.0, 0.0], atol=1e-7)
    assert any(not np.array_equal(a, b) for a, b in zip(actors, jax.tree.leaves(state.policies[0].actor)))
    with pytest.raises(ConfigError, match="gs_iterations: GCRL learns no goal space; must be 0, got 1"):
        make_agent(dataclasses.replace(tiny("gcrl"), gs_iterations=1))


def test_skill_paths_start_at_the_initial_state_and_move():
    agent = SkillAgent(tiny("metra"))
    positions, mask = agent.skill_paths(agent.init(), jax.random.key(0), 6)
    assert positions.shape == (agent.cfg.n + 1, 6, 2) and mask.shape == (agent.cfg.n + 1, 6) and mask.all()
    np.testing.assert_allclose(positions[0], 0.0, atol=1e-6)
    assert np.abs(positions[-1] - positions[0]).max() > 1e-3


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(n=0), "n: must be >= 1; got 0"),
        (dict(env="maze"), "env: 'maze' is unknown"),
        (dict(actor_lr=float("nan")), "actor_lr: must be in (0, 1]; got nan"),
        (dict(init_alpha=float("inf")), "init_alpha: must be a finite number > 0; got inf"),
        (dict(min_replay=10_000), "min_replay: must be <= replay_capacity (512); got 10000"),
        (dict(dual_slack=0.0), "dual_slack: must be a finite number > 0; got 0.0"),
    ],
)
def test_bad_skill_config_names_the_field(change, message):
    with pytest.raises(ConfigError) as err:
        make_agent(dataclasses.replace(tiny("metra"), **change))
    assert message in str(err.value)


def test_plot_and_render_draw_a_flat_learners_run(tmp_path):
    run_dir = tmp_path / "metra"
    jobs.train(TrainExperiment(config=tiny("metra"), run_dir=str(run_dir)))
    plotted = cli_in_process("plot", str(run_dir))
    assert plotted.returncode == 0, plotted.stderr
    names = ["skill_learning.png", "skills.png"]
    assert [line.rsplit("/", 1)[-1] for line in plotted.stdout.splitlines()[1:]] == names
    for name in names:
        with Image.open(run_dir / "plots" / name) as image:
            assert image.format == "PNG" and np.asarray(image.convert("L")).std() > 0
    rendered = run_cli("render", str(run_dir), "--steps", "6", "--width", "64", "--height", "48")
    if rendered.returncode == 3:  # no offscreen OpenGL on this machine
        pytest.skip(rendered.stderr.strip())
    assert rendered.returncode == 0, rendered.stderr
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(run_dir / "skills.mp4"))  # the default: an MP4 in the run
    assert tuple(next(reader)["size"]) == (64, 48)
    frames = [np.frombuffer(raw, np.uint8).reshape(48, 64, 3) for raw in reader]
    assert len(frames) == 6 and all(frame.std() > 0 for frame in frames)


def test_recorded_skills_move_and_restart_from_the_start_state_every_n_actions():
    agent = SkillAgent(tiny("metra"))
    n = agent.cfg.n
    qpos, mocap = agent.record_skills(agent.init(), jax.random.key(3), 2 * n + 1)
    assert qpos.shape == (2 * n + 1, agent.env.mj_model.nq) and mocap.shape[0] == 2 * n + 1
    start = np.asarray(agent.env.reset(jax.random.key(0)).data.qpos)
    assert np.abs(qpos[n - 2] - start).max() > 1e-3  # the skill moved the point mass ...
    np.testing.assert_allclose(qpos[n - 1], start, atol=1e-6)  # ... and its n-th action began a new episode
