"""Does phase 2 still learn at the end of its budget? Its per-epoch figures averaged over windows.

Reads RUN_DIR/phase2/metrics.jsonl of each run (nothing is trained or evaluated) and averages,
over consecutive windows of ``--window`` epochs, the training episodes' mean minimum distance
and success (every training episode of the epoch, with exploration noise) and the greedy
per-epoch evaluation's (``eval_rounds`` batches of goals, so noisier). A policy that still
learns ends its last window closer than the one before; one that has levelled off does not,
and more phase-2 epochs would not bring it nearer.

    python experiments/phase2_windows.py --runs runs/ant-s0 runs/ant-s1 --name ant-field-cpu-k1
"""

from __future__ import annotations

import dataclasses
import statistics
from pathlib import Path

import tyro
from baselines import merge_row

from mjx_emp.run import store

FIGURES = ("train_min_distance", "train_success", "min_distance", "success")
"""Per-epoch phase-2 metrics averaged per window (training episodes, then the greedy evaluation)."""


@dataclasses.dataclass
class Args:
    """Phase-1 runs whose phase-2 learning curves are averaged over windows of epochs."""

    runs: tuple[str, ...] = ()
    name: str = ""
    """The rows' ``variant`` (e.g. the preset the runs were trained with)."""
    window: int = 10
    """Epochs per window (a last, shorter window is dropped)."""
    out: str = "benchmarks/results/phase2_windows_cpu.json"


def window_means(lines: list[dict], window: int) -> list[dict]:
    """Each whole window of ``window`` epochs: its first and last epoch and the mean of each of
    :data:`FIGURES` over its epochs."""
    if window < 1:
        raise SystemExit(f"window: must be >= 1; got {window}")
    rows = []
    for start in range(0, len(lines) - window + 1, window):
        part = lines[start:start + window]
        rows.append({"first_epoch": part[0]["epoch"], "last_epoch": part[-1]["epoch"],
                     **{name: statistics.fmean(m[name] for m in part) for name in FIGURES}})
    return rows


def run_row(run_dir: Path, name: str, window: int) -> dict:
    """One run's windows, and the change of the training distance from its second-to-last window
    to its last (negative: still getting closer)."""
    phase2_dir = Path(run_dir) / store.PHASE2_SUBDIR
    if not (phase2_dir / store.METRICS_FILE).exists():
        raise SystemExit(f"runs: {run_dir} has no {store.PHASE2_SUBDIR}/{store.METRICS_FILE}")
    windows = window_means(store.read_metrics(phase2_dir), window)
    change = windows[-1]["train_min_distance"] - windows[-2]["train_min_distance"] if len(windows) > 1 else None
    return {"variant": name or Path(run_dir).name, "run_dir": str(run_dir), "window": window, "windows": windows,
            "last_window_change_m": change}


def main(args: Args) -> None:
    rows = [run_row(Path(run), args.name, args.window) for run in args.runs]
    for row in rows:
        spans = "  ".join(f"{w['first_epoch']}-{w['last_epoch']}: {w['train_min_distance']:.2f} m "
                          f"({w['train_success']:.0%})" for w in row["windows"])
        print(f"{row['run_dir']}  training episodes  {spans}")
        merge_row(Path(args.out), row, key=("run_dir",))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
