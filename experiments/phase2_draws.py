"""How far a phase-2 figure moves between draws of goals, and whether learned and aimed differ beyond it.

The chaining diagnostic compares the learned phase-2 policy with the scripted ones on one draw
of 400 goals. This evaluates, for each given phase-1 run with a trained RUN_DIR/phase2, the
learned policy and the ``aimed`` one on ``draws`` independent draws of ``episodes`` goals each
(draw i uses key 7 + i, so draw 0 is the chaining diagnostic's), both policies on the same goals
in each draw. A row per run holds each draw's phase-2 figures (`metrics.PHASE2_FIGURES`) per
policy, their mean, std and standard error over the draws, and the
learned-minus-aimed difference per draw (paired: the same goals). Rows are merged into ``--out``.

    python experiments/phase2_draws.py --runs runs/ant-s0 runs/ant-s1 --draws 3
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import tyro
from baselines import merge_row

from mjx_emp.metrics import mean_and_stderr, shared_phase2_figures
from mjx_emp.run import jobs, store


@dataclasses.dataclass
class Args:
    """Phase-1 runs whose phase 2 is evaluated on several draws of goals."""

    runs: tuple[str, ...] = ()
    name: str = ""
    """The rows' ``variant``; empty: each run's directory name."""
    draws: int = 3
    episodes: int = 400
    """Goals per draw."""
    policies: tuple[str, ...] = ("learned", "aimed")
    out: str = "benchmarks/results/phase2_draws_cpu.json"


def summarise(per_policy: dict[str, list[dict]]) -> dict:
    """Each policy's figures over the draws (mean, std, stderr), and where both were drawn the
    learned-minus-aimed difference of the minimum distance per draw (the same goals in a draw)."""
    summary = {"summary": {policy: {figure: mean_and_stderr([d[figure] for d in rows])
                                    for figure in shared_phase2_figures(rows)}
                           for policy, rows in per_policy.items()}}
    if {"learned", "aimed"} <= set(per_policy):
        differences = [a["min_distance"] - b["min_distance"] for a, b in zip(per_policy["learned"], per_policy["aimed"])]
        summary["learned_minus_aimed"] = {"per_draw": differences, **mean_and_stderr(differences)}
    return summary


def draws_row(run_dir: Path, name: str, draws: int, episodes: int, policies: tuple[str, ...]) -> dict:
    """One run's row: each policy's figures on each draw of goals, and their summary."""
    trainer, phase2_epoch, state = jobs.load_phase2(run_dir / store.PHASE2_SUBDIR)
    per_policy = {}
    for policy in policies:
        top = trainer if policy == "learned" else dataclasses.replace(trainer, top=policy)
        per_policy[policy] = [top.evaluate(state, jax.random.key(7 + i), episodes) for i in range(draws)]
        print(run_dir.name, policy, [round(d["min_distance"], 3) for d in per_policy[policy]], flush=True)
    return {"variant": name or run_dir.name, "run_dir": str(run_dir), "seed": trainer.phase1.cfg.seed,
            "phase2_epoch": phase2_epoch, "draws": draws, "episodes": episodes, "per_draw": per_policy,
            **summarise(per_policy)}


def main(args: Args) -> None:
    if not args.runs:
        raise SystemExit("runs: give at least one phase-1 run directory with a trained phase 2")
    if args.draws < 1 or args.episodes < 1:
        raise SystemExit(f"draws, episodes: each must be >= 1; got {args.draws}, {args.episodes}")
    for run in map(Path, args.runs):
        row = draws_row(run, args.name, args.draws, args.episodes, args.policies)
        merge_row(Path(args.out), row, key=("variant", "run_dir"))


if __name__ == "__main__":
    main(tyro.cli(Args))
