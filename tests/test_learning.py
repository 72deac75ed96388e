"""Phase 1 learns on the point-mass CPU default: the goal space grows and stays reachable."""

import jax
import pytest

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.he.presets import POINT_MASS_K1

EPOCHS = 100
"""Two thirds of the preset's 150: its default run grows the box 17x by epoch 80 and 23x by 100
(0.161 to 3.66, success 0.95); the test asks for 10x, which the run passed at epoch 69."""


@pytest.mark.slow  # four minutes of CPU: learning is measured by experiments; the README's first run trains this preset
def test_point_mass_default_grows_its_goal_space_and_reaches_it():
    trainer = HEAgent(POINT_MASS_K1)
    state = trainer.init()
    initial = trainer.goal_spaces(state)[0]["volume"]
    for _ in range(EPOCHS):
        state, _ = trainer.train_epoch(state)
    final = trainer.goal_spaces(state)[0]["volume"]
    assert final >= 10 * initial, f"goal space grew {final / initial:.1f}x"
    result = trainer.evaluate(state, 0, jax.random.key(7), rounds=8)  # 512 episodes
    assert result["success"] >= 0.8, result
