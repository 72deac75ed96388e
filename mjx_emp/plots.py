"""Pictures of a run (matplotlib, PNG): how each level's goal space grew over the epochs."""

from __future__ import annotations

import json
from pathlib import Path


def read_metrics(run_dir: Path) -> list[dict]:
    """The per-epoch metric lines of a run directory, in order."""
    path = Path(run_dir) / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def plot_goal_space_growth(metrics: list[dict], path: Path) -> Path:
    """Goal-space volume (log scale) and greedy success per level against epoch, saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")  # files only; no display needed
    import matplotlib.pyplot as plt

    if not metrics:
        raise ValueError("no epochs to plot: metrics is empty")
    epochs = [m["epoch"] for m in metrics]
    levels = len(metrics[0]["levels"])
    fig, (volume_ax, success_ax) = plt.subplots(2, 1, sharex=True, figsize=(7, 6))
    for level in range(levels):
        volume_ax.plot(epochs, [m["levels"][level]["volume"] for m in metrics], label=f"level {level}")
        success = [m["levels"][level]["success"] for m in metrics]
        success_ax.plot(epochs, [float("nan") if s is None else s for s in success], label=f"level {level}")
    volume_ax.set_yscale("log")
    volume_ax.set_ylabel("goal-space volume at s0")
    volume_ax.legend()
    success_ax.set_ylabel("greedy success in own goal space")
    success_ax.set_xlabel("epoch")
    success_ax.set_ylim(0, 1.05)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
