"""The results store: one append-only JSON-lines file of evaluation rows per sweep spec.

A row is appended whole, in one write, and flushed to disk; a reader skips a torn last line
(a writer killed mid-line) and refuses a damaged line elsewhere. A run evaluated again appends
a new row; the newest row of a (spec, row, seed) is the one that counts.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from mjx_emp.errors import ConfigError
from mjx_emp.run.provenance import UNKNOWN, provenance
from mjx_emp.run.store import output_target, writing

RESULTS_DIR = "results"
"""Where a spec's rows go by default: results/<spec name>.jsonl."""


ROW_SCHEMA = 1
"""The version of an evaluation row's layout (:func:`mjx_emp.run.evaluate.evaluation_row`)."""


def row_key(row: dict[str, Any]) -> tuple[str, str, str]:
    """What makes a row one result: (spec, row, seed); a later row with the same key replaces an
    earlier one."""
    return str(row.get("spec")), str(row.get("row")), str(row.get("seed"))


def append_row(path: Path, row: dict[str, Any]) -> None:
    """Append ``row`` as one line of ``path`` (created with its folder), flushed to disk. A torn
    line left by an earlier writer's kill is ended first, so it never swallows this row."""
    path = output_target(Path(path), "results", make_folder=True)
    with writing(path, chosen=True):
        line = json.dumps(row) + "\n"
        with open(path, "ab+") as f:
            f.seek(0, os.SEEK_END)
            if f.tell() > 0:
                f.seek(-1, os.SEEK_END)
                if f.read(1) != b"\n":
                    line = "\n" + line
            f.write(line.encode())
            f.flush()
            os.fsync(f.fileno())


def parse_row(line: str, path: Path, number: int) -> dict[str, Any]:
    """One line of a rows file as a row; a line that is not a JSON object of this schema is a
    ConfigError naming the file and line."""
    try:
        row = json.loads(line)
    except json.JSONDecodeError as err:
        raise ConfigError(f"rows: {path} line {number} is not JSON ({err.msg})") from None
    if not isinstance(row, dict):
        raise ConfigError(f"rows: {path} line {number} is not a JSON object")
    if row.get("schema", ROW_SCHEMA) != ROW_SCHEMA:
        raise ConfigError(f"rows: {path} line {number} has schema {row.get('schema')!r}; "
                          f"this version reads schema {ROW_SCHEMA}")
    return row


def is_torn(line: str) -> bool:
    """Whether a line fails to parse as JSON at all, as a write cut short leaves it (a complete
    line of the wrong shape is an error even at the end)."""
    try:
        json.loads(line)
    except json.JSONDecodeError:
        return True
    return False


def read_rows(path: Path | str) -> list[dict[str, Any]]:
    """The rows of a store, one per :func:`row_key`: the newest line wins, at the place where the
    key first appeared (so a table's order stays put as runs are re-evaluated). A missing file
    holds no rows; an unparseable last line (a write cut short) is skipped; a bad line anywhere
    else is a ConfigError naming the file and line."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        return []
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"rows: cannot read {path} ({err})") from None
    numbered = [(i, line) for i, line in enumerate(text.splitlines(), start=1) if line.strip()]
    rows: dict[tuple[str, str, str], dict] = {}
    for position, (number, line) in enumerate(numbered):
        try:
            row = parse_row(line, path, number)
        except ConfigError:
            if position == len(numbered) - 1 and is_torn(line):
                break
            raise
        rows[row_key(row)] = row
    return list(rows.values())


BENCHMARK = "benchmark"
"""The ``kind`` of a row a benchmark script measured (an evaluation row has none)."""


def benchmark_row(spec: str, row: str, figures: dict[str, Any], seed: int = 0, command: str | None = None,
                  preset: str | None = None, env_steps: float | None = None,
                  wall_s: float | None = None) -> dict[str, Any]:
    """A benchmark's measurement as a row of the evaluation rows' layout, so that one store and
    `mjx-emp report` serve both: ``figures`` hold its numbers (JSON-ready), ``train`` and
    ``evaluation`` this process's provenance (code, versions, machine, command, time).
    ``row`` names the measured setting; with ``seed`` it is the row's key in ``spec``."""
    made = provenance(command)
    return {"schema": ROW_SCHEMA, "kind": BENCHMARK, "spec": spec, "row": row, "seed": seed, "run_dir": None,
            "algorithm": figures.get("algorithm"), "env": figures.get("env"), "k": figures.get("k"),
            "preset": preset or UNKNOWN, "overrides": {}, "phase2_preset": None, "phase2_config": None,
            "figures": json.loads(json.dumps({**figures, "env_steps": env_steps} if env_steps is not None
                                             else figures)),
            "curves": {}, "train": {**made, "env_steps": env_steps, "wall_s": wall_s, "config": None},
            "evaluation": {"seed": None, "episodes": None, **made}}
