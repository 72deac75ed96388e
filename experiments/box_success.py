"""How well a goal-space learner (HE or GCRL) reaches goals in its own top box at the end of training.

A hand-set GCRL box that is too large shows as a learner that rarely reaches its own goals;
one too small as one that always does but covers little. For every row of the ``--rows``
files whose run's metrics carry goal-space levels, reads RUN_DIR/metrics.jsonl and writes the
top level's box (volume, half-widths) at the run's last epoch and its greedy success on that
epoch's goals averaged over the last ``--last`` epochs (``num_envs`` goals each). Rows already
in ``--out`` whose runs are not on disk are kept, so new runs can be added to one file.
``python experiments/box_success.py --rows benchmarks/results/equal_budget_ant_cpu.json
--out benchmarks/results/box_success_ant_cpu.json``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np
import tyro

from mjx_emp.run import store
from mjx_emp.run.store import read_metrics


@dataclasses.dataclass
class Args:
    """Result files whose rows name run directories; where the box figures go."""

    rows: tuple[str, ...]
    out: str
    last: int = 20
    """How many final epochs the success is averaged over."""


def box_at_end(metrics: list[dict], last: int) -> dict | None:
    """The top level's box at the last epoch and its mean greedy success over the final
    ``last`` epochs; None for a run whose metrics have no goal-space levels (a flat learner)."""
    if last < 1:
        raise SystemExit(f"last: must be >= 1; got {last}")
    with_levels = [m for m in metrics if m.get("levels") and m["levels"][-1].get("success") is not None]
    if not with_levels:
        return None
    tail = with_levels[-last:]
    top = tail[-1]["levels"][-1]
    successes = np.array([m["levels"][-1]["success"] for m in tail])
    return {"epoch": tail[-1]["epoch"], "env_steps": tail[-1]["env_steps"], "volume": top["volume"],
            "half_width": top["half_width"], "success_mean": float(successes.mean()),
            "success_std": float(successes.std()), "epochs_averaged": len(tail)}


def main(args: Args) -> None:
    out = Path(args.out)
    out_rows = json.loads(out.read_text())["rows"] if out.exists() else []  # runs no longer on disk keep their rows
    for path in args.rows:
        for row in json.loads(Path(path).read_text())["rows"]:
            run_dir = Path(row["run_dir"])
            if not (run_dir / store.METRICS_FILE).exists():
                print(f"skipped {row['preset']} seed {row['seed']}: no metrics in {run_dir}")
                continue
            box = box_at_end(read_metrics(run_dir), args.last)
            if box is None:
                continue
            out_rows = [r for r in out_rows if (r["preset"], r["seed"]) != (row["preset"], row["seed"])]
            out_rows.append({"preset": row["preset"], "seed": row["seed"], "run_dir": str(run_dir), **box})
            print(json.dumps(out_rows[-1]), flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    store.write_atomically(out, json.dumps({"backend": jax.default_backend(), "last": args.last, "rows": out_rows},
                                           indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
