"""Time to the first epoch with the persistent compilation cache cold, warm and off.

For each preset, with an empty cache directory (``XDG_CACHE_HOME`` pointed at a temporary
one): `mjx-emp train PRESET --epochs 1` three times as a user runs it (one process each):
cold (compiles and stores), warm (loads what the first run stored) and with
``--no-compile-cache``. Reports the process's wall time and the first epoch's ``seconds``
(compile included) from its metrics. Prints a Markdown table and appends one row per preset to
``results/bench-compile-cache.jsonl`` (``--results``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import tyro

from mjx_emp.run.rows import append_row, benchmark_row

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import row_name  # noqa: E402

SPEC = "bench-compile-cache"


@dataclasses.dataclass
class Args:
    """Compile-cache benchmark."""

    presets: tuple[str, ...] = ("point-mass-k1", "ant-field-k1-cpu", "metra-ant-field-cpu")
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""


def one_run(preset: str, cache_home: Path, run_dir: Path, *flags: str) -> dict:
    """Wall seconds of `mjx-emp train PRESET --epochs 1` and its first epoch's seconds."""
    env = {**os.environ, "XDG_CACHE_HOME": str(cache_home)}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "mjx_emp.cli", "train", preset, "--epochs", "1", "--run-dir", str(run_dir),
                    *flags], env=env, check=True, capture_output=True)
    wall = time.perf_counter() - start
    first = json.loads((run_dir / "metrics.jsonl").read_text().splitlines()[0])
    return {"wall_s": wall, "first_epoch_s": first["seconds"]}


def main(args: Args) -> None:
    rows = []
    for preset in args.presets:
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            row = {"preset": preset,
                   "cold": one_run(preset, tmp / "cache", tmp / "cold"),
                   "warm": one_run(preset, tmp / "cache", tmp / "warm"),
                   "off": one_run(preset, tmp / "cache", tmp / "off", "--no-compile-cache")}
        rows.append(row)
        append_row(Path(args.results), benchmark_row(SPEC, row_name(row), row, preset=preset))
        print(json.dumps(row), flush=True)
    print("| preset | cold: wall s (first epoch s) | warm | cache off |")
    print("|---|---|---|---|")
    for r in rows:
        cells = [f"{r[k]['wall_s']:.1f} ({r[k]['first_epoch_s']:.1f})" for k in ("cold", "warm", "off")]
        print(f"| {r['preset']} | " + " | ".join(cells) + " |")
    print(f"appended {len(rows)} rows to {args.results}")


if __name__ == "__main__":
    main(tyro.cli(Args))
