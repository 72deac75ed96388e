"""How much METRA's coverage figure moves with the draw of its 48 skills, for runs already trained.

The coverage count (1 m cells visited by 48 greedy skills from the initial state) samples its
skills from the agent's skill space (HE and GCRL: the top goal space; the flat learners:
their prior), so one run gives different counts for different draws. For every row of
``--rows`` (the comparison's JSON, filtered by ``--env``) this reloads the run's newest
checkpoint and counts coverage for ``--draws`` independent draws, writing one row per run
(``preset``, ``seed``, ``cells`` per draw, their mean and sample std) to ``--out``; runs
already counted there are kept, not recounted, so new runs can be added to one file.
``python experiments/coverage_spread.py --env ant_field --draws 8``; for the robots' runs
``--rows benchmarks/results/robots_cpu.json --presets ant-field-cpu-k2 --out ...``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import tyro

from mjx_emp.metrics import coverage_cells, mean_and_stderr
from mjx_emp.run import jobs, store
from mjx_emp.run.evaluate import COVERAGE_SKILLS


@dataclasses.dataclass
class Args:
    """Runs listed in a comparison's JSON, recounted over several skill draws."""

    rows: tuple[str, ...] = ("benchmarks/results/baselines_cpu.json",)
    """Comparison JSON files whose runs are recounted."""
    env: str = "ant_field"
    """Only the rows of this environment (rows that name one: the comparison's JSON)."""
    presets: tuple[str, ...] = ()
    """Only the rows of these presets instead (for JSON whose rows name no environment,
    such as ``robots_cpu.json``)."""
    draws: int = 8
    """Independent draws of the coverage skills per run."""
    out: str = "benchmarks/results/coverage_spread_cpu.json"


def coverage_over_draws(run_dir: Path, seed: int, draws: int) -> list[int]:
    """Coverage cells of RUN_DIR's newest checkpoint for ``draws`` independent draws of
    :data:`COVERAGE_SKILLS` skills (keys fixed by seed, so a rerun gives the same counts)."""
    agent, _, state = jobs.load_run(run_dir)
    return [coverage_cells(*agent.skill_paths(state, jax.random.key(5000 + 100 * seed + draw), COVERAGE_SKILLS))
            for draw in range(draws)]


def counted_rows(out: Path, env: str, draws: int) -> list[dict]:
    """The rows OUT already holds, checked to be counted for ENV with DRAWS draws (else a clear error)."""
    if not out.exists():
        return []
    previous = json.loads(out.read_text())
    if (previous["env"], previous["draws"]) != (env, draws):
        raise SystemExit(f"--out: {out} holds env {previous['env']!r} with {previous['draws']} draws, "
                         f"not --env {env!r} with --draws {draws}; pick another --out")
    return previous["rows"]


def write_rows(out: Path, env: str, draws: int, rows: list[dict]) -> None:
    """OUT rewritten with ROWS, atomically, so a run stopped midway keeps every count made so far."""
    store.write_atomically(out, json.dumps({"backend": jax.default_backend(), "env": env, "draws": draws,
                                            "skills_per_draw": COVERAGE_SKILLS, "rows": rows}, indent=1))


def main(args: Args) -> None:
    rows = [r for f in args.rows for r in json.loads(Path(f).read_text())["rows"]]
    if args.presets:
        rows = [r for r in rows if r["preset"] in args.presets]
        if not rows:
            raise SystemExit(f"--presets: no rows of {list(args.presets)} in {list(args.rows)}")
    else:
        rows = [r for r in rows if r.get("env") == args.env]
        if not rows:
            raise SystemExit(f"--env: no rows of {args.env!r} in {list(args.rows)}")
    out = Path(args.out)
    out_rows = counted_rows(out, args.env, args.draws)
    counted = {r["run_dir"] for r in out_rows}
    for row in [r for r in rows if r["run_dir"] not in counted]:
        cells = coverage_over_draws(Path(row["run_dir"]), row["seed"], args.draws)
        spread = mean_and_stderr(cells)
        out_rows.append({"preset": row["preset"], "seed": row["seed"], "run_dir": row["run_dir"], "cells": cells,
                         "mean": spread["mean"], "std": spread["std"]})
        print(json.dumps(out_rows[-1]), flush=True)
        write_rows(out, args.env, args.draws, out_rows)
    print("| preset | runs | coverage cells, mean of draws (mean ± std over runs) | std over draws within a run (mean) |")
    print("|---|---|---|---|")
    for preset in dict.fromkeys(r["preset"] for r in out_rows):
        mine = [r for r in out_rows if r["preset"] == preset]
        over_runs = mean_and_stderr([r["mean"] for r in mine])
        print(f"| {preset} | {len(mine)} | {over_runs['mean']:.3g} ± {over_runs['std']:.2g} "
              f"| {mean_and_stderr([r['std'] for r in mine])['mean']:.2g} |")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
