"""The flip table: where skills flip the robot, step by step, in phase 1 and in phase 2."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from tiny import TINY_PHASE2, tiny_after_two_epochs

from mjx_emp import flip_tables
from mjx_emp.envs.parts import Torso
from mjx_emp.rollout.structures import Transition
from mjx_emp.run import flips


@dataclasses.dataclass(frozen=True)
class PitchEnv:
    """What the flip table reads of an environment: h(s) is obs[0], the torso pitch obs[1], its
    rate obs[2] (the first velocity after one position)."""

    torso: Torso = Torso(nq=1, pitch=1)

    def goal_of_obs(self, obs):
        return obs[..., :1]


def planted_episodes() -> flips.FirstEpisodes:
    """One level, rows [T=6, B=3], pitch rising by 0.5 rad per step in environment 0 until a
    reset cuts its step 3 short (an Ant's flip), environment 1 left on its back by step 2 (a
    Half Cheetah's), environment 2 upright to its end at step 5 (its skill of 3 actions is
    reached at step 2, the next runs out at 5). Environment 0 ends at step 3, environment 1 at 4."""
    steps, envs = 6, 3
    obs = np.zeros((steps, envs, 3))
    obs[:, 0, 1] = 0.5 * np.arange(steps)
    obs[:, 0, 2] = 5.0
    obs[:, 1, 1] = [0.0, 0.2, 0.4, np.pi, np.pi, np.pi]
    obs[:, 2, 2] = 0.1
    next_obs = np.roll(obs, -1, axis=0)
    valid, cut, final = np.ones((steps, envs), bool), np.zeros((steps, envs), bool), np.zeros((steps, envs), bool)
    valid[3, 0], cut[3, 0] = False, True
    final[[2, 5], 2], final[3, 0], final[4, 1] = True, True, True
    rows = Transition(obs=obs, goal=np.zeros((steps, envs, 1)), action=np.zeros((steps, envs, 1)), next_obs=next_obs,
                      reached=np.zeros((steps, envs), bool), final=final, valid=valid, cut=cut)
    return flips.FirstEpisodes((rows,), first_end=np.array([3, 4, 5]), info=None)


def test_the_table_finds_each_planted_flip_where_and_how_it_happened():
    env, episodes = PitchEnv(), planted_episodes()
    flipped_at = flips.flip_steps(env, episodes)
    assert flipped_at.tolist() == [3, 2, -1]
    table = flips.episode_flips(env, episodes, actions_per_level=(4,))
    assert table["flips"] == 2 and table["flip_share"] == pytest.approx(2 / 3)
    (level,) = table["by_index"]
    # Indices in progress: env 0 steps 0-3 -> 0..3 (flip at index 3); env 1 -> 0..2 (flip at 2);
    # env 2 -> 0,1,2 then 0,1,2 after its first goal's final row at step 2.
    assert level["flips"] == [0, 0, 1, 1]
    assert level["attempts"] == [4, 4, 4, 1]  # actions ended before any flip, and the two in progress at one
    assert level["hazard"] == [0.0, 0.0, 0.25, 1.0]
    before = table["before_flip"]
    # Env 0's last states before its flip: pitch 1.5, 1.0, 0.5, 0 -> tilt 1 - cos; env 1's: 0.4, 0.2, 0.
    tilt0, tilt1 = 1 - np.cos([1.5, 1.0, 0.5, 0.0]), 1 - np.cos([0.4, 0.2, 0.0])
    expected = [(tilt0[0] + tilt1[0]) / 2, (tilt0[1] + tilt1[1]) / 2, (tilt0[2] + tilt1[2]) / 2, tilt0[3]]
    np.testing.assert_allclose(before["flipped_tilt"][:4], expected)
    assert before["flipped_tilt"][4] is None and before["upright_tilt"][:6] == [0.0] * 6
    np.testing.assert_allclose(before["flipped_angular_speed"][:3], [2.5, 2.5, 2.5])  # env 0 spins at 5, env 1 not
    warned = before["angular_speed_warning"]
    assert warned["threshold"] == pytest.approx(0.1) and warned["warned"] == 0.5 and warned["median_lead"] == 3.0


def test_an_episode_begun_on_its_back_has_not_flipped():
    episodes = planted_episodes()
    obs = np.asarray(episodes.levels[0].obs).copy()
    obs[:, 2, 1] = np.pi  # environment 2 starts on its back and stays there, as a Half Cheetah may
    rows = episodes.levels[0].replace(obs=obs, next_obs=np.roll(obs, -1, axis=0))
    on_its_back = dataclasses.replace(episodes, levels=(rows,))
    flipped_at = flips.flip_steps(PitchEnv(), on_its_back)
    assert flipped_at.tolist() == [3, 2, -1]
    # ... nor has it stayed upright: the steps before the end of the upright episodes, and the
    # threshold a reflex would read from them, leave it out (there are none left here).
    assert flips.stayed_upright(PitchEnv(), on_its_back, flipped_at).tolist() == [False, False, False]
    before = flips.before_flip(PitchEnv(), on_its_back, flipped_at)
    assert before["upright_tilt"] == [None] * flips.STEPS_BEFORE and before["upright_tilt_quantiles"] is None
    assert before["tilt_warning"]["threshold"] is None
    # Upright, the same environment is the baseline: its tilt 0 at every step.
    upright = flips.before_flip(PitchEnv(), episodes, flips.flip_steps(PitchEnv(), episodes))
    assert upright["upright_tilt_quantiles"]["max"] == 0.0


def test_goal_places_and_subgoal_sizes_bin_the_episodes_that_flipped():
    place = flips.goal_place(np.array([[0.1, -0.2], [0.9, 0.0], [-0.6, 0.3], [0.95, 0.99]]),
                             np.array([False, True, False, True]))
    assert place["episodes"] == [1, 0, 1, 2] and place["flips"] == [0, 0, 0, 2] and place["share"][3] == 1.0
    episodes = planted_episodes()
    top = dataclasses.replace(episodes.levels[0], action=np.full((6, 3, 2), 0.3))  # subgoals of 0.42 m
    sizes = flips.subgoal_flips(PitchEnv(), top, episodes.first_end)
    assert sizes["episodes"][0] == 4 + 5 + 6 and sum(sizes["episodes"]) == 15  # every row up to each first end
    assert sizes["flips"][0] == 2  # env 1's rows after its flip began on its back: not flips again


def test_tables_of_runs_pool_their_counts():
    env, episodes = PitchEnv(), planted_episodes()
    one = flips.episode_flips(env, episodes, (4,))
    both = flip_tables.pooled([one, one])
    assert both["episodes"] == 6 and both["flips"] == 4 and both["flip_share"] == pytest.approx(2 / 3)
    assert both["by_index"][0]["attempts"] == [8, 8, 8, 2]
    assert both["before_flip"]["flipped_tilt"] == one["before_flip"]["flipped_tilt"]


@pytest.fixture
def planted_flip(monkeypatch):
    """A point mass whose torso counts as upside down once h(s) passes x = 0: the table reads
    tilt through ``Torso.up_axis_z``, while the point mass is never reset."""
    def up_axis_z(self, obs):
        return np.where(np.asarray(obs)[..., 0] > 0.0, -1.0, 1.0)

    monkeypatch.setattr(Torso, "up_axis_z", up_axis_z)


def test_phase1_and_phase2_tables_of_a_trained_agent_find_the_planted_flip(planted_flip):
    from mjx_emp.phase2.goal_spaces import Phase2Trainer

    agent, _, state, _, _ = tiny_after_two_epochs()
    levels = flips.phase1_flips(agent, state, jax.random.key(0), episodes=16)
    assert [t["level"] for t in levels] == [0, 1] and all(t["episodes"] == 32 for t in levels)
    for level, table in enumerate(levels):
        rolled = [flips.roll_first_episodes(agent.greedy_episodes(state, level, starts),
                                            jax.random.fold_in(jax.random.fold_in(jax.random.key(0), level), i), 16)
                  for i, starts in enumerate(("initial", "chained"))]
        low = flips.joined(rolled).levels[0]
        turned = (np.asarray(low.obs)[..., 0] <= 0.0) & (np.asarray(low.next_obs)[..., 0] > 0.0)  # upright to "down"
        past = turned & flips.in_first_episode(low, flips.joined(rolled).first_end)
        assert table["flips"] == int(past.any(axis=0).sum()) > 0
        assert sum(table["by_index"][0]["flips"]) == table["flips"]
        assert sum(table["by_goal_place"]["episodes"]) == 32
    trainer = Phase2Trainer(agent, TINY_PHASE2)
    phase2 = flips.phase2_flips(trainer, trainer.init(state), jax.random.key(1), envs=8)
    assert phase2["episodes"] == 8 and phase2["flips"] > 0 and len(phase2["by_index"]) == 3
    assert phase2["by_attempt"][0]["episodes"] == 8
    text = "\n".join(flip_tables.flip_text([flip_tables.pooled([t]) for t in levels], flip_tables.pooled([phase2])))
    assert "| 0 | 32 |" in text and "level 0 flips per primitive step" in text and "phase 2:" in text
    assert "flips per 100 m gained toward the goal: " in text


def test_the_reflex_hands_control_back_to_phase_2_once_the_torso_tilts_past_it(monkeypatch):
    """A point mass whose tilt reads 100 x (x > 0): with ``reflex_tilt`` 0.5 no skill goes on
    past the step that took the tilt over 0.5 from an attempt that began at most 0.5 (it ends
    there and the top chooses again); without the reflex some do."""
    import jax.numpy as jnp

    from mjx_emp.phase2.goal_spaces import Phase2Trainer

    monkeypatch.setattr(Torso, "up_axis_z", lambda self, obs: 1.0 - 100.0 * jnp.maximum(obs[..., 0], 0.0))
    agent, _, skills_state, _, _ = tiny_after_two_epochs()
    trainer = Phase2Trainer(agent, TINY_PHASE2, top="aimed")
    plan = trainer.greedy_episodes(trainer.init(skills_state))
    threshold, top = 0.5, agent.cfg.k
    counts = {}
    for reflex in (0.0, threshold):
        # Goals no skill reaches, so that every skill runs its n actions and can cross mid-way.
        hierarchy = dataclasses.replace(plan.hierarchy, eps=(1e-4, 1e-4) + plan.hierarchy.eps[-1:], reflex_tilt=reflex)
        episodes = flips.roll_first_episodes(dataclasses.replace(plan, hierarchy=hierarchy), jax.random.key(4), 16)
        low, skill, root = episodes.levels[0], episodes.levels[top - 1], episodes.levels[top]
        live = flips.in_first_episode(low, episodes.first_end)
        # The state the root issued its current action in: the obs of the next root row that ends.
        ends = np.asarray(root.valid | root.cut)
        issue_tilt = np.full(ends.shape, np.nan)
        for b in range(ends.shape[1]):
            following = np.nan
            for t in reversed(range(ends.shape[0])):
                if ends[t, b]:
                    following = float(flips.tilt(PitchlessEnv(), np.asarray(root.obs)[t, b]))
                issue_tilt[t, b] = following
        crossed = live & np.asarray(low.valid) & (flips.tilt(PitchlessEnv(), low.next_obs) > threshold) \
            & (issue_tilt <= threshold)
        counts[reflex] = (int((crossed & ~np.asarray(skill.final)).sum()), int((crossed & np.asarray(skill.final)).sum()))
    assert counts[threshold][0] == 0 and counts[threshold][1] > 0, counts  # handed back at every crossing
    assert counts[0.0][0] > 0, counts  # without the reflex the skills go on past it


class PlantedTorso(Torso):
    """The tilt the reflex test plants, read back on the host: 100 x (x > 0)."""

    def up_axis_z(self, obs):
        return 1.0 - 100.0 * np.maximum(np.asarray(obs)[..., 0], 0.0)


@dataclasses.dataclass(frozen=True)
class PitchlessEnv:
    torso: Torso = PlantedTorso(nq=2)


def test_the_flip_figure_draws_each_tables_series():
    from mjx_emp.viz.flips import flip_figure
    from mjx_emp.viz.plots import axes_content

    table = flips.episode_flips(PitchEnv(), planted_episodes(), (4,))
    level = {**table, "level": 0, "by_goal_place": flips.goal_place(np.zeros((3, 1)) + [[0.1], [0.6], [0.9]],
                                                                        np.array([True, True, False]))}
    phase2 = {**table, "by_attempt": [{"attempt": 0, "episodes": 3, "cut_short": 1 / 3, "upside_down_after": 0.0,
                                                  "flipped": 1 / 3, "progress": 2.0}],
              "by_subgoal_size": {"edges": [0.0, 0.5, None], "episodes": [3, 0], "flips": [2, 0], "share": [2 / 3, None]}}
    hazard, tilt, spin, place, attempt, size = axes_content(flip_figure([flip_tables.pooled([level])], phase2))
    assert hazard.series["level 0"] == ([0.0, 1.0, 2.0, 3.0], [0.0, 0.0, 0.25, 1.0])
    assert hazard.series["phase 2"] == hazard.series["level 0"]
    np.testing.assert_allclose(tilt.series["level 0, flipped"][1], table["before_flip"]["flipped_tilt"][:4])
    np.testing.assert_allclose(spin.series["level 0, upright"][1][:3], [0.1, 0.1, 0.1], rtol=1e-6)  # float32
    assert place.series["level 0"] == ([0.125, 0.625, 0.875], [1.0, 1.0, 0.0])
    assert attempt.series["phase 2"] == ([0.0], [1 / 3]) and size.series["phase 2"] == ([0.0], [2 / 3])
    assert attempt.title == "phase 2: flips by attempt (16.67 per 100 m gained)"  # one flip over 3 x 2 m


def test_an_ant_started_rolling_over_flips_and_its_table_shows_where_and_how():
    """On the real Ant, untrained: every chained start is upright but rolling about its forward
    axis (8 rad/s) while rising (2 m/s), which lays it on its back within a few primitive steps
    whatever the legs do, and the env resets it; from s0 it stays up (eps 0.05: no goal is
    reached before the roll ends). The flip table counts the chained starts' flips and not s0's, its tilt climbs in the steps before a flip, and its count
    agrees with the episodes the agent's own evaluation sees a reset cut short."""
    from tiny import TINY1

    from mjx_emp.algos.he.agent import HEAgent
    from mjx_emp.replay import replay_init, replay_insert

    agent = HEAgent(dataclasses.replace(TINY1, env="ant_field", solver_iterations=4, n=(4,), eps=(0.05,),
                                       init_half_width=(2.0,)))
    state = agent.init()
    initial = np.asarray(agent.initial_obs)
    nq = agent.env.mj_model.nq
    rolling = initial.copy()
    rolling[nq + 2], rolling[nq + 3] = 2.0, 8.0  # qvel: up the world's z, about the torso's own x axis
    capacity = state.starts[0].data.shape[0]
    planted = replay_insert(replay_init(rolling, capacity), np.tile(rolling, (capacity, 1)), np.ones(capacity, bool))
    state = state.replace(starts=(planted,) + tuple(state.starts[1:]))
    table, = flips.phase1_flips(agent, state, jax.random.key(0), episodes=16)
    assert table["episodes"] == 32
    assert table["by_start"]["initial"] == 0.0 and table["by_start"]["chained"] == 1.0, table["by_start"]
    assert table["flips"] == 16
    tilts = table["before_flip"]["flipped_tilt"]
    assert tilts[0] is not None and tilts[0] > table["before_flip"]["upright_tilt"][0]
    cut = agent.evaluate(state, 0, jax.random.key(1), rounds=2, starts="chained")["cut_short"]
    assert cut == 1.0
    text = "\n".join(flip_tables.flip_text([flip_tables.pooled([table])], None))
    assert "level 0" in text and "16" in text
