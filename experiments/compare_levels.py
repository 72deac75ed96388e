"""Does a k=2 agent learn a larger top-level goal space than k=1 for the same env steps?

Trains the two-level preset for ``--epochs`` epochs, then the one-level preset (same
bottom-level n) until it has used at least as many environment steps, and prints and
saves both top-level goal spaces. ``python experiments/compare_levels.py``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import tyro

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.he.presets import POINT_MASS_K1, POINT_MASS_K2


@dataclasses.dataclass
class Args:
    """k=2 against k=1 at an equal environment-step budget (point mass)."""

    epochs: int = 150
    """Epochs of the two-level agent; the one-level agent gets the same env steps."""
    k1_num_envs: int = 256
    """Environments of the one-level agent (more than k=2's 64 so it needs fewer epochs)."""
    out: str = "runs/compare_levels.json"


def _train(cfg, stop) -> dict:
    trainer = HEAgent(cfg)
    state = trainer.init()
    start = time.perf_counter()
    epochs = 0
    while not stop(epochs, float(state.env_steps.value())):
        state, _ = trainer.train_epoch(state)
        epochs += 1
    jax.block_until_ready(state)
    top = trainer.goal_spaces(state)[-1]
    evaluation = trainer.evaluate(state, cfg.k - 1, jax.random.key(7), rounds=8)
    return {"k": cfg.k, "n": list(cfg.n), "num_envs": cfg.num_envs, "epochs": epochs,
            "env_steps": float(state.env_steps.value()), "seconds": time.perf_counter() - start,
            "top_goal_space": top, "top_success": evaluation["success"],
            "all_levels": trainer.goal_spaces(state)}


def compare(epochs: int = 150, k1_num_envs: int = 256) -> dict[str, dict]:
    """Train point-mass-k2 for ``epochs``, then point-mass-k1 up to the same env steps.

    Returns both agents' top goal spaces, greedy success, steps and wall time.
    """
    two = _train(POINT_MASS_K2, lambda done, steps: done >= epochs)
    print(json.dumps(two), flush=True)
    one_cfg = dataclasses.replace(POINT_MASS_K1, num_envs=k1_num_envs)
    one = _train(one_cfg, lambda done, steps: steps >= two["env_steps"])
    print(json.dumps(one), flush=True)
    return {"k2": two, "k1": one}


def main(args: Args) -> None:
    result = compare(args.epochs, args.k1_num_envs)
    two, one = result["k2"], result["k1"]
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"k=2 top volume {two['top_goal_space']['volume']:.2f} (success {two['top_success']:.2f}) vs "
          f"k=1 {one['top_goal_space']['volume']:.2f} (success {one['top_success']:.2f}) "
          f"at {two['env_steps']:.3g} / {one['env_steps']:.3g} env steps")


if __name__ == "__main__":
    main(tyro.cli(Args))
