"""Whether two runs wrote the same metrics: every field of every epoch's line but the wall-clock ones.

A refactor that must not change behaviour is checked by training the same config before and
after it and comparing the two runs' metrics.jsonl: ``python experiments/same_metrics.py
BEFORE_RUN AFTER_RUN [...more pairs]``. Prints the first differences and exits 1 if any.
"""

from __future__ import annotations

import sys
from pathlib import Path

from mjx_emp.run.store import read_metrics

WALL_CLOCK = frozenset({"seconds", "env_steps_per_s", "checkpoint_blocked_s"})
"""Fields that measure time, not what was computed."""


def differences(before: object, after: object, where: str = "") -> list[str]:
    """Where two JSON values differ (wall-clock fields skipped), as readable paths."""
    if isinstance(before, dict) and isinstance(after, dict):
        keys = sorted((set(before) | set(after)) - WALL_CLOCK)
        return [d for k in keys for d in differences(before.get(k, "<missing>"), after.get(k, "<missing>"), f"{where}.{k}")]
    if isinstance(before, list) and isinstance(after, list) and len(before) == len(after):
        return [d for i, (b, a) in enumerate(zip(before, after)) for d in differences(b, a, f"{where}[{i}]")]
    return [] if before == after else [f"{where}: {before!r} != {after!r}"]


def compare_runs(before: Path, after: Path) -> list[str]:
    """Differences between two run directories' metrics, line by line."""
    lines_before, lines_after = read_metrics(before), read_metrics(after)
    if len(lines_before) != len(lines_after):
        return [f"{len(lines_before)} lines != {len(lines_after)} lines"]
    return [d for i, (b, a) in enumerate(zip(lines_before, lines_after)) for d in differences(b, a, f"line {i + 1}")]


def main(argv: list[str]) -> int:
    if len(argv) < 2 or len(argv) % 2:
        print(__doc__, file=sys.stderr)
        return 2
    failed = False
    for before, after in zip(argv[::2], argv[1::2]):
        found = compare_runs(Path(before), Path(after))
        lines = len(read_metrics(Path(before)))
        print(f"{before} vs {after}: {lines} lines, " + ("same" if not found else f"{len(found)} differences"))
        for line in found[:10]:
            print("  ", line)
        failed |= bool(found)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
