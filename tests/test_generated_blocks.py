"""Every generated block of README.md and docs/*.md is what its command makes of the committed
rows: the block between ``<!-- report:NAME -->`` and ``<!-- /report:NAME -->`` is regenerated
with the `mjx-emp report` command it names and compared, character for character (a figure is
redrawn into a temporary folder, its link left out of the comparison)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from mjx_emp.cli import canonical_args, parse
from mjx_emp.report import read_block, report_spec

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
MARKER = re.compile(r"^<!-- report:(?P<name>[\w.-]+) -->$", re.MULTILINE)
REPRODUCE = re.compile(r"`mjx-emp report (?P<args>[^`]+)`")


def blocks() -> list[tuple[Path, str]]:
    return [(page, match["name"]) for page in PAGES for match in MARKER.finditer(page.read_text())]


def without_figure_links(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if not line.startswith("!["))


@pytest.mark.parametrize("page, name", blocks(), ids=lambda v: v if isinstance(v, str) else v.name)
def test_a_generated_block_is_what_its_command_makes_of_the_committed_rows(page, name, tmp_path, monkeypatch):
    block = read_block(page, name)
    command = REPRODUCE.search(block)
    assert command, f"{page.name}: block {name} names no `mjx-emp report ...` command"
    _, exp = parse(canonical_args(["report", *shlex.split(command["args"])]))
    monkeypatch.chdir(ROOT)  # specs, rows and pages are named relative to the repository
    figure = str(tmp_path / "figure.png") if exp.figure else ""
    text = report_spec(exp.spec, exp.results, exp.metrics, exp.baseline, figure, exp.curve, exp.into, exp.block,
                       exp.reps, write=False)
    regenerated = text.replace(f" --figure {figure}", f" --figure {exp.figure}")
    assert without_figure_links(block.rstrip("\n")) == without_figure_links(regenerated), (
        f"{page.name}: block {name} differs from what `mjx-emp report {command['args']}` makes of the rows; "
        f"rerun that command")


def test_the_pages_hold_generated_blocks():
    assert blocks(), "no page holds a generated block"
