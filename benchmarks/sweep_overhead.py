"""What `mjx-emp sweep` costs beyond the runs it drives, measured against the same runs by hand.

For a spec (default: the smoke spec), "by hand" is what a user would type for each row: one
`mjx-emp train PRESET --FIELD VALUE ... --seeds S0 S1 ...` (the seeds as one program, as the sweep
trains them), then per seed `mjx-emp phase2 TASK RUN_DIR ...` and `mjx-emp eval RUN_DIR`. The
sweep is `mjx-emp sweep SPEC` into a fresh runs root. A first, untimed sweep fills the compile
cache both then read; the two are then timed alternately (by hand, sweep, by hand, sweep, ...),
and each pair's ratio is reported with its wall times. Each pair is a row of
``results/bench-sweep-overhead.jsonl`` (``--results``), row ``all`` with the pair's number as its
seed.

    python benchmarks/sweep_overhead.py --repeats 2
"""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import tyro

from mjx_emp.algos.retired import flag_text
from mjx_emp.run.rows import append_row, benchmark_row
from mjx_emp.run.specs import load_spec

ROOT = Path(__file__).resolve().parents[1]
SPEC = "bench-sweep-overhead"


@dataclasses.dataclass
class Args:
    spec: str = str(ROOT / "experiments" / "smoke-point-mass.toml")
    """The sweep spec whose runs are timed (its rows replace another spec's: give that its own
    ``--results``)."""
    repeats: int = 2
    """Timed (by hand, sweep) pairs."""
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""


def mjx_emp(*args: str) -> list[str]:
    return [sys.executable, "-m", "mjx_emp.cli", *args]


def flags(overrides: dict) -> list[str]:
    """A row's overrides as the command line spells them."""
    return [part for field, value in overrides.items()
            for part in flag_text(field, tuple(value) if isinstance(value, list) else value).split()]


def by_hand_commands(spec_path: str, runs: Path) -> list[list[str]]:
    """The commands that train, phase-2 and evaluate every run of the spec one by one."""
    spec = load_spec(spec_path)
    commands = []
    for row in spec.rows:
        base = runs / row.name
        budget = [] if row.config.max_env_steps is None else ["--max-env-steps", str(row.config.max_env_steps)]
        commands.append(mjx_emp("train", row.preset, *flags(row.overrides), *budget, "--run-dir", str(base),
                                "--seeds", *map(str, row.seeds)))
        for seed in row.seeds:
            run_dir = f"{base}-s{seed}"
            if row.phase2 is not None:
                commands.append(mjx_emp("phase2", row.phase2_preset, run_dir, *flags(row.phase2_overrides)))
            commands.append(mjx_emp("eval", run_dir, "--episodes", str(row.episodes), "--seed", str(spec.eval_seed)))
    return commands


def timed(commands: list[list[str]]) -> float:
    start = time.perf_counter()
    for command in commands:
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"{' '.join(command)} failed:\n{done.stderr[-3000:]}")
    return time.perf_counter() - start


def sweep_command(spec: str, work: Path, name: str) -> list[str]:
    return mjx_emp("sweep", spec, "--runs", str(work / name), "--results", str(work / f"{name}.jsonl"))


def main(args: Args) -> None:
    work = Path(tempfile.mkdtemp(prefix="sweep-overhead-"))
    try:
        print("warming the compile cache with one untimed sweep ...", flush=True)
        timed([sweep_command(args.spec, work, "warm")])
        for repeat in range(args.repeats):
            by_hand = timed(by_hand_commands(args.spec, work / f"hand{repeat}"))
            swept = timed([sweep_command(args.spec, work, f"sweep{repeat}")])
            row = {"spec_file": args.spec, "by_hand_s": by_hand, "sweep_s": swept, "sweep_over_by_hand": swept / by_hand,
                   "by_hand_commands": len(by_hand_commands(args.spec, work))}
            append_row(Path(args.results), benchmark_row(SPEC, "all", row, seed=repeat))
            print(f"repeat {repeat}: by hand {by_hand:.1f} s, sweep {swept:.1f} s, ratio {swept / by_hand:.3f}",
                  flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main(tyro.cli(Args))
