"""Experiment: evaluate one or more phase-1 runs (seeds) and aggregate them."""

from __future__ import annotations

import dataclasses

import tyro


@dataclasses.dataclass(frozen=True)
class EvalExperiment:
    """Phase-1 figures of each run's newest checkpoint (goal-space extent per level and greedy
    goal-conditioned success on goals from its own goal space) and, where RUN_DIR/phase2
    exists, the paper's phase-2 figure: the mean over episodes of the minimum distance to
    goal. Several runs (seeds) are aggregated to mean and standard error."""

    run_dirs: tyro.conf.Positional[tuple[str, ...]]
    """Run directories written by `mjx-emp train` (one per seed)."""
    episodes: int = 400
    """Evaluation episodes per level and run, and phase-2 episodes per run (each rounded up
    to whole batches of num_envs)."""
    seed: int = 0
    """Seed of the evaluation goals and start states."""
    out: str = ""
    """JSON output; empty means eval.json in the first run directory."""
