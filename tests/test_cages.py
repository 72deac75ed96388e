"""Where the top goal-space box lies in a cage (experiments/cages.py)."""

import dataclasses

import jax
import numpy as np
import pytest
from cages import absolute_box, beyond_walls_counts, beyond_walls_figures, cage_figures, report_table, wall_bounds

from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.algos.registry import make_agent
from mjx_emp.phase2.goal_spaces import Phase2Trainer
from mjx_emp.phase2.presets import PHASE2_PRESETS


def test_wall_bounds_of_the_ant_cage_are_its_four_walls():
    walls = np.array([[4.0, 0, 0], [-4.0, 0, 0], [0, 4.0, 0], [0, -4.0, 0]])
    assert wall_bounds(walls, 2) == ([-4.0, -4.0], [4.0, 4.0])
    lower, upper = wall_bounds(np.array([[8.0, 0, 0]]), 1)
    assert lower == [-np.inf] and upper == [8.0]


def test_absolute_box_is_placed_about_the_state_and_checked_against_walls_and_button():
    walls = ([-4.0, -4.0], [4.0, 4.0])
    button, half = np.array([2.75, 2.75]), np.array([0.75, 0.75])
    box = {"shift": [0.5, 0.0], "half_width": [1.0, 1.0], "volume": 4.0}
    inside = absolute_box(box, np.zeros(2), walls, button, half)
    assert inside["lower"] == [-0.5, -1.0] and inside["upper"] == [1.5, 1.0]
    assert inside["within_walls"] and not inside["overlaps_button"]
    near = absolute_box(box, np.array([2.0, 2.0]), walls, button, half)
    assert near["overlaps_button"] and near["within_walls"]
    out = absolute_box(box, np.array([3.0, 0.0]), walls, button, half)
    assert not out["within_walls"]


@pytest.mark.parametrize("preset", ["ant-cage-k1-cpu", "half-cheetah-cage-k1-cpu", "ant-cage-k2-cpu",
                                    "half-cheetah-cage-k2-cpu"])
def test_cage_figures_give_the_top_box_at_the_start_with_walls_up_and_gone_and_on_the_button(preset):
    cfg = dataclasses.replace(PRESETS[preset][1], num_envs=2, batch_size=8, hidden=(8, 8), replay_capacity=256,
                              gs_replay_capacity=64, start_capacity=64)
    agent = make_agent(cfg)
    state = agent.init()
    figures = cage_figures(agent, state)
    dims = list(agent.env.goal_qpos)
    assert len(figures["walls_lower"]) == len(dims) and all(w < 0 for w in figures["walls_lower"])
    boxes = figures["boxes"]
    assert set(boxes) == {"start_closed", "start_open", "on_button"}
    button = np.asarray(figures["button_center"])
    on_button = agent.env.obs_with_cage_open(np.asarray(agent.initial_obs), True)
    on_button[dims] = button  # the walls gone, the torso on the button
    top = agent.goal_spaces(state, on_button)[-1]
    np.testing.assert_allclose(boxes["on_button"]["lower"], button + np.subtract(top["shift"], top["half_width"]),
                               rtol=1e-5)
    start = np.asarray(agent.initial_obs)[dims]
    closed = agent.goal_spaces(state)[-1]
    np.testing.assert_allclose(boxes["start_closed"]["upper"], start + np.add(closed["shift"], closed["half_width"]),
                               rtol=1e-5)
    levels = figures["level_boxes"]
    assert len(levels) == agent.cfg.k and levels[-1] == boxes
    bottom = agent.goal_spaces(state)[0]
    np.testing.assert_allclose(levels[0]["start_closed"]["lower"], start + np.subtract(bottom["shift"],
                                                                                       bottom["half_width"]), rtol=1e-5)


def test_beyond_walls_counts_goals_only_a_robot_outside_the_cage_can_reach():
    """Walls at +-4, eps 1: a goal at x = 6 is beyond them, one at x = 4.5 is not (within eps of
    the wall line); an episode counts as reached where any live step comes within eps, and as
    pressed where the cage was open at a live step."""
    walls = ([-4.0, -4.0], [4.0, 4.0])
    goal = np.array([[6.0, 0.0], [4.5, 0.0], [0.0, -7.0], [1.0, 1.0]])
    position = np.zeros((3, 4, 2))
    position[1, 0] = [5.5, 0.0]  # episode 0 reaches its goal beyond the walls, at step 1
    position[2, 2] = [0.0, -6.5]  # episode 2 would reach its goal, but only after its episode ended
    position[:, 3] = [1.2, 1.0]  # episode 3 sits on its goal inside
    live = np.ones((3, 4), bool)
    live[2, 2] = False
    opened = np.zeros((3, 4), bool)
    opened[1, 0] = True
    opened[2, 2] = True  # not live: does not count
    counts = beyond_walls_counts(goal, position, live, opened, walls, eps=1.0)
    assert counts == {"episodes": 4, "goals_beyond": 2, "reached_beyond": 1, "goals_within": 2,
                      "reached_within": 1, "opened": 0.25, "opened_beyond": 0.5}


def test_beyond_walls_figures_count_greedy_phase_2_episodes_in_the_ant_cage():
    """An untrained Ant-cage phase 2 (tiny networks): every episode is counted once, with its goal
    from the phase-2 region."""
    cfg = dataclasses.replace(PRESETS["ant-cage-k1-cpu"][1], num_envs=2, batch_size=8, hidden=(8, 8),
                              replay_capacity=256, gs_replay_capacity=64, start_capacity=64)
    agent = make_agent(cfg)
    phase2_cfg = dataclasses.replace(PHASE2_PRESETS["reach-ant-cage-cpu"][2], n=2, num_envs=2, hidden=(8,),
                                     replay_capacity=64, batch_size=8)
    trainer = Phase2Trainer(agent, phase2_cfg)
    state = trainer.init(agent.init())
    walls = ([-4.0, -4.0], [4.0, 4.0])
    counts = beyond_walls_figures(trainer, state, jax.random.key(0), walls, envs=6)
    assert counts["episodes"] == 6 and counts["goals_within"] + counts["goals_beyond"] == 6
    assert 0 <= counts["reached_beyond"] <= counts["goals_beyond"] and 0.0 <= counts["opened"] <= 1.0


def _cage_row(preset: str, seed: int, phase2: dict | None, counts: dict | None) -> dict:
    box = {"volume": 12.14, "within_walls": True}
    return {"preset": preset, "seed": seed, "env_steps": 2_150_400.0, "success": 0.941, "phase2": phase2,
            "cage": {"boxes": {"start_closed": box, "start_open": {"volume": 20.0, "within_walls": False}},
                     **({"phase2": counts} if counts else {})}}


def test_report_table_gives_each_cage_row_its_boxes_phase_2_policies_and_goals_beyond_the_walls():
    phase2 = {"min_distance": 2.764, "aimed": {"min_distance": 4.31}, "random": {"min_distance": 6.16}}
    counts = {"goals_beyond": 145, "reached_beyond": 23, "goals_within": 255, "reached_within": 225}
    rows = [_cage_row("half-cheetah-cage-k2-cpu", 0, phase2, counts), _cage_row("ant-cage-k1-cpu", 1, None, None),
            _cage_row("ant-cage-k1-cpu", 0, {"min_distance": 3.0}, None)]
    lines = report_table(rows).splitlines()
    assert [line.split(" | ")[0:2] for line in lines[2:]] == [["| ant-cage-k1-cpu", "0"], ["| ant-cage-k1-cpu", "1"],
                                                             ["| half-cheetah-cage-k2-cpu", "0"]]  # sorted
    assert lines[4] == ("| half-cheetah-cage-k2-cpu | 0 | 2.15 M | 12.1 (within), 0.94 | 20.0 (past the walls) | "
                        "2.76, 4.31, 6.16 | 23 of 145 | 225 of 255 |")
    assert "| 3.00, -, - | - | - |" in lines[2]  # a phase 2 without the scripted policies' figures
    assert lines[3].endswith("| 20.0 (past the walls) | - | - | - |")  # no phase 2
