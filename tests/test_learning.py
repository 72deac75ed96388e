"""Phase 1 learns on the point-mass CPU default: the goal space grows and stays reachable."""

import jax

from mjx_emp.experiments.presets import POINT_MASS_K1
from mjx_emp.train import Trainer


def test_point_mass_default_grows_its_goal_space_and_reaches_it():
    trainer = Trainer(POINT_MASS_K1)
    state = trainer.init()
    initial = trainer.goal_spaces(state)[0]["volume"]
    for _ in range(POINT_MASS_K1.epochs):
        state, _ = trainer.train_epoch(state)
    final = trainer.goal_spaces(state)[0]["volume"]
    assert final >= 10 * initial, f"goal space grew {final / initial:.1f}x"
    result = trainer.evaluate(state, 0, jax.random.key(7), rounds=8)  # 512 episodes
    assert result["success"] >= 0.8, result
