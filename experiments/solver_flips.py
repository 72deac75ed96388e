"""Do the robots' cheap physics settings flip the Ant where an accurate solver does not?

For each trained run, evaluates its top-level skills under several physics settings
(``ITERATIONS:INTEGRATOR``; ``0:model`` is the model file's, the paper's 1 iteration and
Euler) with the same networks: greedy success and the fraction of skills a flip cut short,
from the initial state and from chained start states (``HEAgent.evaluate``). Each
setting's cost is the warm wall time of one such evaluation (the trained k-level rollout
over ``--episodes`` skills), timed round-robin with the others so that a shared machine's
drifts cancel; the ratio to ``0:model`` is the median over rounds.
``python experiments/solver_flips.py RUN_DIR [RUN_DIR ...]``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import statistics
import time
from pathlib import Path

import jax
import tyro

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.run import jobs


@dataclasses.dataclass
class Args:
    """Flip rate and success of trained skills under other physics settings."""

    run_dirs: tyro.conf.Positional[tuple[str, ...]]
    settings: tuple[str, ...] = ("0:model", "30:implicitfast", "4:model", "1:implicitfast")
    """ITERATIONS:INTEGRATOR (0 keeps the model's iterations, model its integrator)."""
    episodes: int = 400
    repeats: int = 3
    """Timed rounds per setting (after one untimed call that compiles)."""
    out: str = "benchmarks/results/solver_flips_cpu.json"


def physics(setting: str) -> dict:
    """``ITERATIONS:INTEGRATOR`` as HEConfig fields."""
    iterations, integrator = setting.split(":")
    return {"solver_iterations": int(iterations), "integrator": integrator}


def main(args: Args) -> None:
    rows = []
    for run_dir in args.run_dirs:
        trained, epoch, state = jobs.load_run(Path(run_dir))
        trainers = {s: HEAgent(dataclasses.replace(trained.cfg, **physics(s))) for s in args.settings}
        rounds = max(1, math.ceil(args.episodes / trained.cfg.num_envs))
        top = trained.cfg.k - 1
        figures, times = {}, {s: [] for s in args.settings}
        for setting, trainer in trainers.items():
            figures[setting] = {starts: trainer.evaluate(state, top, jax.random.key(7), rounds, starts)
                                for starts in ("initial", "chained")}
        for _ in range(args.repeats):
            for setting, trainer in trainers.items():
                began = time.perf_counter()
                trainer.evaluate(state, top, jax.random.key(8), rounds, "chained")
                times[setting].append(time.perf_counter() - began)
        base = args.settings[0]
        for setting in args.settings:
            ratio = statistics.median(t / b for t, b in zip(times[setting], times[base]))
            row = {"run_dir": run_dir, "epoch": epoch, "setting": setting, **physics(setting),
                   "episodes": rounds * trained.cfg.num_envs, **figures[setting],
                   "eval_s": statistics.median(times[setting]), f"cost_over_{base}": ratio}
            print(json.dumps(row), flush=True)
            rows.append(row)
    out = Path(args.out)
    out.write_text(json.dumps({"backend": jax.default_backend(), "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
