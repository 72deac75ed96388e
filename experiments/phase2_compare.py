"""Phase 2 on point mass: one- and two-level agents on goal regions inside and beyond their skills.

For each seed, trains (or reuses, if BASE/<agent>-s<seed> already holds a run) three
phase-1 agents with the CLI's own functions:

- ``k1``: the point-mass-k1 preset (one level, n = 10);
- ``k2``: the point-mass-k2 preset (two levels, n = (10, 5): top-level skills of up to
  50 primitive actions);
- ``k1-n50``: one level with n = 50 and k2's 8 goal-space iterations per epoch, the flat
  agent with k2's skill horizon. The paper's level comparisons match the top skill's
  length in primitive actions this way (e.g. Half Cheetah Big: n = 200 against
  n = (20, 10)).

Then phase 2: ``reach-point-mass`` (2.4 x 2.4 region, inside k1's learned goal space) on k1,
and the 8 x 8 and 16 x 16 regions (``reach-point-mass-wide``, ``reach-point-mass-wider``,
3 attempts) on all three agents. Each phase-2 policy is evaluated greedily on 400 goals
before and after training, and the figures are aggregated over seeds (mean and standard
error).
``python experiments/phase2_compare.py --seeds 0 1 2``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import tyro

from mjx_emp.algos.he.config import HEConfig
from mjx_emp.algos.he.presets import POINT_MASS_K1, POINT_MASS_K2
from mjx_emp.commands import Phase2Experiment, TrainExperiment
from mjx_emp.metrics import mean_and_stderr
from mjx_emp.phase2.presets import PHASE2_PRESETS
from mjx_emp.run import jobs, store
from mjx_emp.tables import markdown_table, mean_stderr_text

AGENTS: dict[str, HEConfig] = {
    "k1": POINT_MASS_K1,
    "k2": POINT_MASS_K2,
    "k1-n50": dataclasses.replace(POINT_MASS_K1, n=(50,), max_half_width=(15.0,), gs_iterations=8),
}
# (task name, phase-2 preset, agents it runs on)
TASKS = (
    ("inside", "reach-point-mass", ("k1",)),
    ("wide", "reach-point-mass-wide", ("k1", "k2", "k1-n50")),
    ("wider", "reach-point-mass-wider", ("k1", "k2", "k1-n50")),
)


@dataclasses.dataclass
class Args:
    """Phase-2 comparison of point-mass agents over several seeds."""

    seeds: tuple[int, ...] = (0, 1, 2)
    """Seeds of phase 1 and phase 2."""
    base: str = "runs/phase2_compare"
    """Where the runs go (existing runs are reused)."""
    episodes: int = 400
    """Greedy evaluation episodes per policy."""
    out: str = "benchmarks/results/phase2_compare_cpu.json"


def _phase1(base: Path, agent: str, seed: int) -> Path:
    run_dir = base / f"{agent}-s{seed}"
    if not (run_dir / store.CONFIG_FILE).exists():
        jobs.train(TrainExperiment(config=dataclasses.replace(AGENTS[agent], seed=seed), run_dir=str(run_dir)))
    return run_dir


def _phase2(run_dir: Path, task: str, preset: str, seed: int, episodes: int) -> dict:
    out = run_dir / f"phase2-{task}"
    config = dataclasses.replace(PHASE2_PRESETS[preset][2], seed=seed)
    if not (out / store.CONFIG_FILE).exists():
        jobs.train_phase2(Phase2Experiment(run_dir=str(run_dir), config=config, out=str(out)))
    trainer, epoch, state = jobs.load_phase2(out)
    _, _, skills = jobs.load_run(run_dir)
    key = jax.random.key(1000 + seed)
    return {"run_dir": str(out), "epoch": epoch, "env_steps": float(state.env_steps),
            "skills_top_goal_space": trainer.phase1.goal_spaces(skills)[-1],
            "untrained": trainer.evaluate(trainer.init(skills), key, episodes),
            "trained": trainer.evaluate(state, key, episodes)}


def compare(seeds, base: Path, episodes: int) -> dict:
    """Every (task, agent) over ``seeds``: per-seed figures and their mean and standard error."""
    runs = {agent: {seed: _phase1(base, agent, seed) for seed in seeds} for agent in AGENTS}
    result = {}
    for task, preset, agents in TASKS:
        for agent in agents:
            per_seed = [_phase2(runs[agent][seed], task, preset, seed, episodes) for seed in seeds]
            summary = {
                when: {name: mean_and_stderr([r[when][name] for r in per_seed]) for name in ("min_distance", "success")}
                for when in ("untrained", "trained")
            }
            summary["top_volume"] = mean_and_stderr([r["skills_top_goal_space"]["volume"] for r in per_seed])
            result[f"{task}/{agent}"] = {"preset": preset, "seeds": list(seeds), "summary": summary, "runs": per_seed}
            print(f"{task}/{agent}: " + json.dumps(summary), flush=True)
    return result


def main(args: Args) -> None:
    result = compare(args.seeds, Path(args.base), args.episodes)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    headers = ("task / agent", "top goal-space volume", "untrained min distance", "trained min distance",
               "trained success")
    rows = [(name, *(mean_stderr_text(stat) for stat in (
        s["top_volume"], s["untrained"]["min_distance"], s["trained"]["min_distance"], s["trained"]["success"])))
        for name, s in ((name, row["summary"]) for name, row in result.items())]
    print(markdown_table(headers, rows))
    print(f"wrote {out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
