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
from mjx_emp.run.store import writing

RESULTS_DIR = "results"
"""Where a spec's rows go by default: results/<spec name>.jsonl."""


def row_key(row: dict[str, Any]) -> tuple:
    """What identifies a row in a store: its spec, its row name and its seed."""
    return row.get("spec"), row.get("row"), row.get("seed")


def append_row(path: Path, row: dict[str, Any]) -> None:
    """Append ``row`` as one line of ``path`` (created with its folder), flushed to disk. A torn
    line left by an earlier writer's kill is ended first, so it never swallows this row."""
    path = Path(path)
    with writing(path, chosen=True):
        path.parent.mkdir(parents=True, exist_ok=True)
        line = json.dumps(row, allow_nan=True) + "\n"
        with open(path, "ab+") as f:
            f.seek(0, os.SEEK_END)
            if f.tell() > 0:
                f.seek(-1, os.SEEK_END)
                if f.read(1) != b"\n":
                    line = "\n" + line
            f.write(line.encode())
            f.flush()
            os.fsync(f.fileno())


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of a store, the newest of each :func:`row_key` only, in the order those were
    written. A torn last line is skipped; a bad line elsewhere raises
    ConfigError naming the file and line."""
    path = Path(path)
    try:
        lines = path.read_text().split("\n")
    except FileNotFoundError:
        return []
    while lines and not lines[-1].strip():
        lines.pop()
    newest: dict[tuple, dict] = {}
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
            if not isinstance(row, dict):
                raise ValueError("not a JSON object")
        except ValueError as err:
            if number == len(lines):
                break  # a writer killed mid-line: the row was never complete
            raise ConfigError(f"rows: {path} line {number} is not a row ({err})") from None
        key = row_key(row)
        newest.pop(key, None)
        newest[key] = row
    return list(newest.values())
