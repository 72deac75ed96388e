"""Summarise one GPU lease's files (what ``benchmarks/device_lease.sh`` leaves in $OUT):
the lease's settings, the prepared check's figures, each training row's epochs and each row's
phase 2, as Markdown tables and rows of ``results/gpu-leases.jsonl`` (``--results``).

The check's rows (``check.jsonl``, written on the GPU machine by ``benchmarks/device_check.py``)
are appended as they are; each training row and each phase 2 becomes a row
``LEASE/training/RUN`` or ``LEASE/phase2/RUN``. ``LEASE`` is the lease's ``LEASE=``
setting, else ``gpu_lease_<GPU model>`` as the check names its rows (``--name`` overrides).
A dry run's rows (``DRY=1``) go to ``results/gpu-leases-dry-run.jsonl``.

    python benchmarks/gpu_summary.py /tmp/out
"""

from __future__ import annotations

import dataclasses
import re
import statistics
import sys
from pathlib import Path

import tyro

from mjx_emp.run.rows import RESULTS_DIR, append_row, benchmark_row, read_rows
from mjx_emp.run.store import parse_metrics, read_metrics_text, warn_metrics

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import lease_name, row_name  # noqa: E402

SPEC = "gpu-leases"
DRY_RUN_SPEC = "gpu-leases-dry-run"
CHECK_ROWS = "check.jsonl"
"""The check's rows in a lease folder (``device_check.py --results``)."""


@dataclasses.dataclass
class Args:
    """One lease folder in, one summary out."""

    lease: tyro.conf.Positional[str]
    results: str = ""
    """The results store the rows are appended to; empty means results/<spec>.jsonl."""
    name: str = ""
    """The lease's name, the first part of its rows' names; empty: see the module's text."""


def read_versions(path: Path) -> dict:
    """The GPU's name and the package versions the lease's smoke test printed."""
    if not path.exists():
        return {}
    text = path.read_text()
    found = {name: version for name, version in re.findall(r"^([a-z][\w-]*) (\d[\w.]*|missing)$", text, re.M)}
    gpu = re.search(r"NVIDIA [A-Z]\w+", text)
    return {"gpu": gpu.group(0) if gpu else None, "packages": found}


def read_settings(path: Path) -> dict:
    """The lease's settings (rows, flags, time budgets): the ``NAME=value`` lines the lease
    writes at the top of ``versions.txt``."""
    if not path.exists():
        return {}
    return dict(re.findall(r"^([A-Z][A-Z0-9_]*)=(.*)$", path.read_text(), re.M))


def read_epochs(path: Path) -> list[dict]:
    """A lease file's per-epoch metric lines (phase 1's or phase 2's), read as the library reads
    metrics.jsonl: a line a kill cut short is named on stderr and skipped."""
    valid, problems = parse_metrics(read_metrics_text(path))
    warn_metrics(path, problems, "skipped")
    return [entry for _, entry in valid]


def check_figures(rows: list[dict]) -> dict:
    """The check's figures by step (``not_run``: the steps it did not finish, each with why)."""
    steps: dict = {"rollout": [], "train": [], "seeds": [], "memory": [], "not_run": []}
    for row in rows:
        figures = row["figures"]
        steps["not_run" if "why" in figures else figures["step"]].append(figures)
    return steps


def training_row(path: Path) -> dict:
    """One training row's throughput and where its top goal space stood when the lease ended."""
    epochs = read_epochs(path)
    warm = epochs[1:] or epochs
    top = [e["levels"][-1] for e in epochs]
    largest = max(range(len(top)), key=lambda i: top[i]["volume"])
    return {
        "preset": path.name.removesuffix(".metrics.jsonl"),
        "epochs": len(epochs),
        "env_steps": epochs[-1]["env_steps"],
        "first_epoch_s": epochs[0]["seconds"],
        "median_epoch_s": statistics.median(e["seconds"] for e in warm),
        "median_env_steps_per_s": statistics.median(e["env_steps_per_s"] for e in warm),
        "flips_per_1000_env_steps": 1000 * sum(e.get("flip_resets", 0) for e in epochs) / epochs[-1]["env_steps"],
        "final_volume": top[-1]["volume"], "final_success": top[-1]["success"],
        "largest_volume": top[largest]["volume"], "largest_volume_epoch": epochs[largest]["epoch"],
        "success_at_largest": top[largest]["success"],
        "top_box_by_epoch": [[e["epoch"], e["levels"][-1]["volume"], e["levels"][-1]["success"]] for e in epochs],
    }


def phase2_row(path: Path) -> dict:
    """One row's phase 2: its epochs' greedy minimum distance and success, and where it ended."""
    epochs = read_epochs(path)
    return {
        "preset": path.name.removesuffix(".phase2.jsonl"),
        "epochs": len(epochs),
        "env_steps": epochs[-1]["env_steps"],
        "median_epoch_s": statistics.median(e["seconds"] for e in epochs[1:] or epochs),
        "min_distance_by_epoch": [e["min_distance"] for e in epochs],
        "success_by_epoch": [e["success"] for e in epochs],
        "final_min_distance": epochs[-1]["min_distance"], "final_success": epochs[-1]["success"],
    }


def markdown(summary: dict) -> str:
    """The tables docs/gpu.md shows."""
    lines = ["| B | k | raw mjx.step (physics steps/s) | k-level rollout (useful steps/s) | of raw |",
             "|---|---|---|---|---|"]
    for row in summary["check"]["rollout"]:
        lines.append(f"| {row['batch']} | {row['k']} | {row['raw_physics_steps_per_s']:.3g} | "
                     f"{row['hier_useful_physics_steps_per_s']:.3g} | {row['hier_over_raw']:.2f} |")
    lines += ["", "| row | epochs | env steps | first epoch (s) | epoch (s, median) | env steps/s | "
                  "flips per 1,000 steps | top box at the end |", "|---|---|---|---|---|---|---|---|"]
    for row in summary["training"]:
        lines.append(f"| {row['preset']} | {row['epochs']} | {row['env_steps'] / 1e6:.1f} M | "
                     f"{row['first_epoch_s']:.1f} | "
                     f"{row['median_epoch_s']:.2f} | {row['median_env_steps_per_s']:.3g} | "
                     f"{row['flips_per_1000_env_steps']:.2f} | "
                     f"{row['final_volume']:.1f} at {row['final_success']:.2f} |")
    if summary["phase2"]:
        lines += ["", "| row | phase-2 epochs | env steps | epoch (s, median) | min distance (m) by epoch | "
                      "success at the end |", "|---|---|---|---|---|---|"]
    for row in summary["phase2"]:
        distances = ", ".join(f"{d:.1f}" for d in row["min_distance_by_epoch"])
        lines.append(f"| {row['preset']} | {row['epochs']} | {row['env_steps'] / 1e6:.1f} M | "
                     f"{row['median_epoch_s']:.1f} | {distances} | {row['final_success']:.2f} |")
    return "\n".join(lines)


def main(args: Args) -> dict:
    lease = Path(args.lease)
    settings = read_settings(lease / "versions.txt")
    machine = read_versions(lease / "versions.txt")
    checked = read_rows(lease / CHECK_ROWS)
    summary = {"lease": str(lease), "settings": settings, **machine, "check": check_figures(checked),
               "training": [training_row(path) for path in sorted(lease.glob("*.metrics.jsonl"))],
               "phase2": [phase2_row(path) for path in sorted(lease.glob("*.phase2.jsonl"))]}
    print(markdown(summary))
    spec = DRY_RUN_SPEC if settings.get("DRY") == "1" else SPEC
    results = Path(args.results or Path(RESULTS_DIR) / f"{spec}.jsonl")
    name = args.name or settings.get("LEASE") or lease_name(machine.get("gpu") or "cpu")
    rows = [] if results.resolve() == (lease / CHECK_ROWS).resolve() else list(checked)  # measured on the GPU
    about = {"lease": str(lease), **machine, "settings": settings}
    rows += [benchmark_row(spec, row_name(record, f"{name}/{group}"), {**record, **about})
             for group in ("training", "phase2") for record in summary[group]]
    for row in rows:
        append_row(results, row)
    print(f"appended {len(rows)} rows to {results}")
    return summary


if __name__ == "__main__":
    main(tyro.cli(Args))
