"""Phase 2 over a flat skill learner's frozen skills: episodes, attempts, learning, resume, eval."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_checkpoint import assert_bitwise_equal
from test_skills import tiny
from tiny import TINY_PHASE2, cli_in_process

from mjx_emp.algos.skills.agent import SkillAgent
from mjx_emp.commands import Phase2Experiment, ResumeExperiment, TrainExperiment
from mjx_emp.errors import ConfigError
from mjx_emp.phase2.build import make_phase2_trainer
from mjx_emp.phase2.latent import FlatPhase2Trainer
from mjx_emp.run import jobs


@pytest.fixture(scope="module")
def metra_phase2():
    skills = SkillAgent(tiny("metra"))
    skills_state = skills.init()
    trainer = make_phase2_trainer(skills, TINY_PHASE2)
    return trainer, skills_state, trainer.init(skills_state)


def test_the_factory_picks_the_flat_trainer_and_it_chooses_unit_length_skills(metra_phase2):
    trainer, _, state = metra_phase2
    assert isinstance(trainer, FlatPhase2Trainer)
    obs = jnp.broadcast_to(jnp.asarray(trainer.phase1.initial_obs), (5, trainer.env.obs_size))
    goals = jax.random.uniform(jax.random.key(0), (5, 2), minval=-2, maxval=2)
    skills = trainer.choose(state.learner.actor, obs, goals)
    np.testing.assert_allclose(np.linalg.norm(skills, axis=-1), 1.0, rtol=1e-5)


def test_an_aim_prior_over_latent_skills_is_refused_naming_the_field(metra_phase2):
    trainer, _, _ = metra_phase2
    with pytest.raises(ConfigError, match="aim_prior: a skill z has no subgoal"):
        make_phase2_trainer(trainer.phase1, dataclasses.replace(TINY_PHASE2, aim_prior=True))


def test_a_collect_plays_one_episode_per_env_with_at_most_n_attempts(metra_phase2):
    trainer, _, state = metra_phase2
    cfg, skill_steps = trainer.cfg, trainer.phase1.cfg.n
    new, totals = jax.jit(trainer._collect)(state, jnp.float32(0.2), jnp.bool_(True), jax.random.key(1))
    assert int(totals.episodes) == cfg.num_envs
    assert 0 < int(totals.env_steps) <= cfg.num_envs * cfg.n * skill_steps
    # every attempt lasts the skill's length unless it ends the episode by a reset
    assert cfg.num_envs <= int(totals.transitions) <= cfg.num_envs * cfg.n
    assert int(new.replay.size) == int(totals.transitions)
    assert 0.0 <= float(totals.success()) <= 1.0 and np.isfinite(float(totals.mean_distance()))
    # a stored attempt's next state is skill_steps actions from its first: the skill moved the point mass
    rows = jax.tree.map(lambda x: np.asarray(x[: int(new.replay.size)]), new.replay.data)
    assert np.abs(rows.next_obs[:, :2] - rows.obs[:, :2]).max() > 1e-3
    assert int(totals.cut_short) == 0  # a point mass under sane skills never resets


def test_a_reset_ends_a_flat_phase_2_episode_and_is_counted(metra_phase2):
    """Skills that break the physics (NaN actions) reset every environment at its first step;
    with ``learn_from_resets`` each such attempt is stored, marked cut."""
    trainer, skills_state, state = metra_phase2
    broken = state.replace(skill_actor=jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), state.skill_actor))
    _, totals = jax.jit(trainer._collect)(broken, jnp.float32(0.0), jnp.bool_(False), jax.random.key(1))
    assert int(totals.cut_short) == trainer.cfg.num_envs and int(totals.reached) == 0
    assert int(totals.env_steps) == trainer.cfg.num_envs  # each episode ended at its first step
    keeping = dataclasses.replace(trainer, cfg=dataclasses.replace(trainer.cfg, learn_from_resets=True))
    kept = keeping.init(skills_state).replace(skill_actor=broken.skill_actor)
    new, totals = jax.jit(keeping._collect)(kept, jnp.float32(0.0), jnp.bool_(True), jax.random.key(1))
    rows = jax.tree.map(lambda x: np.asarray(x[: int(new.replay.size)]), new.replay.data)
    assert len(rows.cut) == trainer.cfg.num_envs and rows.cut.all() and not rows.reached.any()
    np.testing.assert_allclose(rows.next_obs, np.broadcast_to(trainer.phase1.initial_obs, rows.next_obs.shape),
                               atol=1e-6)  # scored at the state before the reset


def test_flat_phase2_trains_resumes_bitwise_and_eval_reports_it(tmp_path):
    run_dir = tmp_path / "metra"
    jobs.train(TrainExperiment(config=tiny("metra"), run_dir=str(run_dir)))
    straight = jobs.train_phase2(Phase2Experiment(run_dir=str(run_dir), config=TINY_PHASE2))  # into RUN_DIR/phase2
    jobs.train_phase2(Phase2Experiment(run_dir=str(run_dir), config=dataclasses.replace(TINY_PHASE2, epochs=1),
                                      out=str(tmp_path / "b")))
    resumed = jobs.resume_phase2(ResumeExperiment(resume=str(tmp_path / "b"), epochs=TINY_PHASE2.epochs))
    assert_bitwise_equal(resumed, straight)
    lines = [json.loads(line) for line in (run_dir / "phase2" / "metrics.jsonl").read_text().splitlines()]
    assert lines[-1]["critic_loss"] is not None and 0 <= lines[-1]["success"] <= 1
    result = cli_in_process("eval", str(run_dir), "--episodes", "16")  # the CLI finds the flat run's phase 2 beside it
    assert result.returncode == 0, result.stderr
    report = json.loads((run_dir / "eval.json").read_text())
    assert report["runs"][0]["figures"]["phase2"]["episodes"] >= 16 and "phase 2" in result.stdout
