"""Every generated block of README.md and docs/*.md is what its command makes of the committed
rows: the block between ``<!-- report:NAME -->`` and ``<!-- /report:NAME -->`` is regenerated
with the `mjx-emp report` command it names and compared, character for character (a figure is
redrawn into a temporary folder, its link left out of the comparison)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from mjx_emp.blocks import read_block
from mjx_emp.cli import canonical_args, parse
from mjx_emp.report import report_spec

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
                       exp.reps, write=False, flip_table=exp.flip_table)
    regenerated = text.replace(f" --figure {figure}", f" --figure {exp.figure}")
    assert without_figure_links(block.rstrip("\n")) == without_figure_links(regenerated), (
        f"{page.name}: block {name} differs from what `mjx-emp report {command['args']}` makes of the rows; "
        f"rerun that command")


def test_the_pages_hold_generated_blocks():
    assert blocks(), "no page holds a generated block"


FIGURE = re.compile(r"--figure (?P<path>\S+) --curve (?P<curve>\S+)")


def figure_blocks() -> list[tuple[Path, str]]:
    return [(page, name) for page, name in blocks() if FIGURE.search(read_block(page, name))]


@pytest.mark.parametrize("page, name", figure_blocks(), ids=lambda v: v if isinstance(v, str) else v.name)
def test_a_generated_figure_shows_each_rows_curve_by_group_with_its_n_and_units(page, name, tmp_path, monkeypatch):
    """The figure a block links is drawn from the rows the block reads: one series per row name
    whose runs hold the curve, its n the runs that hold it, its first point their mean, the
    axes in env steps and in the curve's unit; and the committed PNG is there."""
    from mjx_emp.report import load_report_spec, seed_band_figure, spec_rows
    from mjx_emp.report_stats import METRICS

    monkeypatch.chdir(ROOT)
    block = read_block(page, name)
    figure = FIGURE.search(block)
    assert (ROOT / figure["path"]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{figure['path']} is not a committed PNG"
    _, exp = parse(canonical_args(["report", *shlex.split(REPRODUCE.search(block)["args"])]))
    spec = load_report_spec(exp.spec)
    rows = spec_rows(spec, Path(exp.results or f"results/{spec.name}.jsonl"))
    chart = seed_band_figure(rows, figure["curve"], tmp_path / "figure.png")
    holding: dict[str, list[dict]] = {}
    for row in rows:
        if row.get("curves", {}).get(figure["curve"]):
            holding.setdefault(row["row"], []).append(row)
    assert list(chart.series) == list(holding)
    for group, members in holding.items():
        assert chart.series[group].n == len(members)
        first = [row["curves"][figure["curve"]][0] for row in members]
        starts = [row["curves"]["phase2_env_steps" if figure["curve"].startswith("phase2_") else "env_steps"][0]
                  for row in members]
        if len(set(starts)) == 1:  # the same first step: the plotted first point is the plain mean
            assert chart.series[group].mean[0] == pytest.approx(sum(first) / len(first))
    assert chart.xlabel == "env steps"
    unit = METRICS[figure["curve"]].unit
    assert chart.ylabel.endswith(f"({unit})"), chart.ylabel
