"""Where the top goal-space box lies in a cage (experiments/cages.py)."""

import dataclasses

import numpy as np
import pytest
from cages import absolute_box, cage_figures, wall_bounds

from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.algos.registry import make_agent


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


@pytest.mark.parametrize("preset", ["ant-cage-cpu-k1", "half-cheetah-cage-cpu-k1"])
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
    on_button = np.asarray(agent.initial_obs).copy()
    on_button[-1], on_button[dims] = 1.0, button  # the walls gone, the torso on the button
    top = agent.goal_spaces(state, on_button)[-1]
    np.testing.assert_allclose(boxes["on_button"]["lower"], button + np.subtract(top["shift"], top["half_width"]),
                               rtol=1e-5)
    start = np.asarray(agent.initial_obs)[dims]
    closed = agent.goal_spaces(state)[-1]
    np.testing.assert_allclose(boxes["start_closed"]["upper"], start + np.add(closed["shift"], closed["half_width"]),
                               rtol=1e-5)
