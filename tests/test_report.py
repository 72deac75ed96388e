"""Reports of sweep rows: metric lookup, rliable's IQM and probability of improvement, the
Markdown table, the seed-band chart, generated blocks in Markdown files and the rows reader.
Synthetic rows only; nothing trains."""

import json
from pathlib import Path

import pytest

from mjx_emp.blocks import read_block, write_block
from mjx_emp.errors import ConfigError
from mjx_emp.report import markdown_table, seed_band_figure
from mjx_emp.report_stats import (
    METRICS,
    metric_named,
    metric_values,
    pairwise_improvement,
    probability_of_improvement,
    summary,
)
from mjx_emp.run.rows import read_rows

REPS = 500  # enough for stable intervals on a handful of runs, and quick


def make_row(row: str, seed: int, min_distance: float | None = None, coverage: int | None = None,
             curve: tuple[list[float], list[float]] | None = None, spec: str = "smoke") -> dict:
    """A row as the sweep writes it, with only the fields a test reads."""
    figures: dict = {"epoch": 3, "env_steps": 960_000.0, "coverage_cells": coverage, "posterior_std": None}
    if min_distance is not None:
        figures["phase2"] = {"min_distance": min_distance, "success": 0.5, "cut_short": 0.0}
    curves = {"env_steps": curve[0], "top_volume": curve[1]} if curve else {}
    return {"schema": 1, "spec": spec, "row": row, "seed": seed, "run_dir": f"runs/{row}-{seed}",
            "algorithm": row.split("-")[0], "env": "point_mass", "preset": "point-mass-k1",
            "overrides": {"epochs": 3, "batch_size": 64}, "figures": figures, "curves": curves,
            "provenance": {"commit": "abc123", "dirty": False}}


def test_iqm_is_the_mean_of_the_middle_half_and_its_interval_is_seeded():
    values = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 100.0]
    first = summary(values, reps=REPS, seed=3)
    assert first["iqm"] == pytest.approx(3.5)  # mean of 2, 3, 4, 5
    assert first["mean"] == pytest.approx(15.125)
    assert first["n"] == 8 and first["se"] == pytest.approx(first["std"] / 8 ** 0.5)
    assert first["iqm_low"] < first["iqm"] < first["iqm_high"]
    assert summary(values, reps=REPS, seed=3) == first


def test_one_run_has_its_value_as_interval_and_no_run_no_summary():
    assert summary([0.25], reps=REPS) == {"n": 1, "mean": 0.25, "std": 0.0, "se": 0.0,
                                          "iqm": 0.25, "iqm_low": 0.25, "iqm_high": 0.25}
    assert summary([], reps=REPS) is None


def test_metric_values_skip_rows_without_the_metric():
    rows = [make_row("he-k1", 0, 0.5), make_row("diayn", 0, coverage=7), make_row("he-k1", 1, float("nan"))]
    assert metric_values(rows, "phase2_min_distance") == [0.5]
    assert metric_values(rows, METRICS["coverage_cells"]) == [7.0]
    with pytest.raises(ConfigError, match="not one of"):
        metric_values(rows, "speed")


def test_the_sweeps_guide_names_every_metric_a_report_knows():
    guide = (Path(__file__).parents[1] / "docs" / "sweeps.md").read_text()
    assert [name for name in METRICS if f"`{name}`" not in guide] == []


def test_a_metric_path_steps_into_lists_by_index():
    rows = [{"figures": {"flip_table": [{"flip_share": 0.5}, {"flip_share": 0.25}],
                         "phase2": {"flip_table": {"flip_share": 0.125}}}}, {"figures": {"flip_table": []}}]
    assert metric_values(rows, "top_flip_share") == [0.25]  # the last level's; an empty list has none
    assert metric_values(rows, "figures.flip_table.0.flip_share") == [0.5]
    assert metric_values(rows, "phase2_flip_share") == [0.125]
    assert metric_values(rows, "figures.flip_table.2.flip_share") == []


def test_flips_per_100m_are_derived_from_the_attempts_a_row_holds():
    """Flips over metres gained toward the goal, summed over attempts weighted by their episodes:
    (10 x 0.1 + 5 x 0.2) flips over (10 x 2 + 5 x 1) m is 8 per 100 m; rows that gained nothing
    or hold no attempts have no value."""
    attempts = [{"episodes": 10, "flipped": 0.1, "progress": 2.0}, {"episodes": 5, "flipped": 0.2, "progress": 1.0}]
    still = [{"episodes": 4, "flipped": 0.25, "progress": -0.5}]
    rows = [{"figures": {"phase2": {"flip_table": {"by_attempt": attempts}}}},
            {"figures": {"phase2": {"flip_table": {"by_attempt": still}}}}, {"figures": {"phase2": {}}}]
    assert metric_values(rows, "phase2_flips_per_100m") == [pytest.approx(8.0)]


def test_smaller_distances_beat_larger_ones_for_a_lower_is_better_metric():
    near, far = [0.1, 0.2, 0.3], [0.5, 0.6, 0.7]
    assert probability_of_improvement(near, far, lower_is_better=True, reps=REPS) == (1.0, 1.0, 1.0)
    assert probability_of_improvement(near, far, lower_is_better=False, reps=REPS) == (0.0, 0.0, 0.0)
    p, low, high = probability_of_improvement([0.1, 0.6], [0.5, 0.7], lower_is_better=True, reps=REPS)
    assert p == 0.75 and low <= p <= high
    assert probability_of_improvement([], far, True, reps=REPS) is None


def test_the_pairwise_improvement_is_rliables_probability_of_improvement_bit_for_bit():
    """Our count over pairs gives what rliable's Mann-Whitney statistic gives for one task,
    ties (within and across the two sides) and identical sides included."""
    import numpy as np
    import rliable.metrics

    rng = np.random.default_rng(0)
    for _ in range(500):
        a = rng.integers(0, 4, size=rng.integers(1, 7)) * 0.37
        b = a.copy() if rng.random() < 0.1 else rng.integers(0, 4, size=rng.integers(1, 7)) * 0.37
        assert pairwise_improvement(a, b) == float(rliable.metrics.probability_of_improvement(a[:, None], b[:, None]))


TABLE_ROWS = [make_row("he-k1", 0, 0.5, 10), make_row("gcrl-k1", 0, 0.9, 4), make_row("he-k1", 1, 0.7, 14),
              make_row("gcrl-k1", 1, 1.1), make_row("diayn", 0, coverage=20)]
EXPECTED_TABLE = """\
| row | preset | seeds | env steps | phase-2 min distance (m) ↓ mean ± std (se) | phase-2 min distance IQM [95% CI] \
| coverage (cells) ↑ mean ± std (se) | coverage IQM [95% CI] | P(phase-2 min distance better than gcrl-k1) [95% CI] \
| P(coverage better than gcrl-k1) [95% CI] |
|---|---|---|---|---|---|---|---|---|---|
| he-k1 | point-mass-k1 --batch-size 64 --epochs 3 | 2 | 0.96 M | 0.6 ± 0.141 (0.1) | 0.6 [0.5, 0.7] \
| 12 ± 2.83 (2) | 12 [10, 14] | 1 [1, 1] | 1 [1, 1] |
| gcrl-k1 | point-mass-k1 --batch-size 64 --epochs 3 | 2 | 0.96 M | 1 ± 0.141 (0.1) | 1 [0.9, 1.1] \
| 4 n=1 | - | - | - |
| diayn | point-mass-k1 --batch-size 64 --epochs 3 | 1 | 0.96 M | - | - | 20 | - | - \
| 1 [1, 1] |"""


def test_the_table_has_a_line_per_group_with_spread_iqm_and_improvement_over_the_baseline():
    table = markdown_table(TABLE_ROWS, ["phase2_min_distance", "coverage_cells"], baseline="gcrl-k1", reps=REPS)
    assert table == EXPECTED_TABLE
    assert markdown_table(TABLE_ROWS, ["phase2_min_distance", "coverage_cells"], baseline="gcrl-k1",
                          reps=REPS) == table


def test_a_column_no_group_fills_is_left_out_and_a_dotted_path_is_a_metric():
    rows = [{**make_row("bench", 0, coverage=3), "preset": "unknown", "figures": {"steps_per_s": 1500.0}}]
    table = markdown_table(rows, ["figures.steps_per_s"], reps=REPS)
    assert table.splitlines()[0] == "| row | seeds | steps per s mean ± std (se) |"  # a path says no direction
    assert table.splitlines()[2] == "| bench | 1 | 1500 |"
    with pytest.raises(ConfigError, match="figures.NAME"):
        metric_named("speed")


def test_a_specs_row_patterns_choose_the_rows_of_its_table():
    from mjx_emp.report import chosen_rows

    rows = [make_row(name, 0) for name in ("check/rollout/k1", "check/rollout/k2", "training/ant")]
    assert [r["row"] for r in chosen_rows(rows, ["check/rollout/*"])] == ["check/rollout/k1", "check/rollout/k2"]
    assert [r["row"] for r in chosen_rows(rows, ["training/*", "check/rollout/k2"])] == ["check/rollout/k2",
                                                                                          "training/ant"]
    assert chosen_rows(rows, []) == rows


def test_the_table_groups_by_any_field_and_refuses_an_unknown_baseline():
    table = markdown_table(TABLE_ROWS, ["coverage_cells"], group_by="algorithm", reps=REPS)
    assert [line.split(" | ")[0] for line in table.splitlines()[2:]] == ["| he", "| gcrl", "| diayn"]
    with pytest.raises(ConfigError, match="baseline: 'sac'.*he-k1, gcrl-k1, diayn"):
        markdown_table(TABLE_ROWS, ["coverage_cells"], baseline="sac", reps=REPS)


def test_the_chart_shows_each_groups_mean_over_its_seeds(tmp_path):
    rows = [make_row("he-k1", 0, curve=([0, 100, 200], [0.0, 1.0, 2.0])),
            make_row("he-k1", 1, curve=([0, 100, 200], [0.0, 3.0, 4.0])),
            make_row("gcrl-k1", 0, curve=([0, 100], [0.5, None])),
            make_row("diayn", 0)]
    (tmp_path / "figs").mkdir()
    chart = seed_band_figure(rows, "top_volume", out=tmp_path / "figs" / "volume.png")
    assert chart.path == tmp_path / "figs" / "volume.png"
    assert chart.path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert chart.xlabel == "env steps"
    assert chart.ylabel == "top-level goal-space volume (m² or m)"
    assert "top-level goal-space volume" in chart.title
    assert chart.legend == ["he-k1 (n=2)", "gcrl-k1 (n=1)"]
    assert list(chart.series) == ["he-k1", "gcrl-k1"]
    assert chart.series["he-k1"].x == [0.0, 100.0, 200.0]
    assert chart.series["he-k1"].mean == [0.0, 2.0, 3.0]
    assert chart.series["he-k1"].std == pytest.approx([0.0, 2 ** 0.5, 2 ** 0.5])
    assert chart.series["gcrl-k1"].n == 1 and chart.series["gcrl-k1"].mean == [0.5, 0.5]
    with pytest.raises(ConfigError, match="no row has a 'phase2_min_distance' curve"):
        seed_band_figure(rows, "phase2_min_distance", out=tmp_path / "none.png")


def test_write_block_replaces_only_the_block(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("# Title\n\n<!-- report:smoke -->\nold table\nold line\n<!-- /report:smoke -->\n\ntail\n")
    assert write_block(readme, "smoke", "| a |\n|---|") is True
    assert readme.read_text() == "# Title\n\n<!-- report:smoke -->\n| a |\n|---|\n<!-- /report:smoke -->\n\ntail\n"
    assert read_block(readme, "smoke") == "| a |\n|---|"
    assert write_block(readme, "smoke", "| a |\n|---|") is False
    assert [p.name for p in tmp_path.iterdir()] == ["README.md"]  # no temporary file left behind


def test_write_block_without_markers_names_the_file_and_the_lines_to_add(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("# Title\n<!-- report:other -->\n<!-- /report:other -->\n")
    with pytest.raises(ConfigError, match=r"block: .*README\.md .*<!-- report:smoke --> and <!-- /report:smoke -->"):
        write_block(readme, "smoke", "text")
    assert readme.read_text() == "# Title\n<!-- report:other -->\n<!-- /report:other -->\n"


def test_write_block_into_a_missing_file_names_the_into_flag_and_creates_nothing(tmp_path):
    with pytest.raises(ConfigError, match=r"^into: .*missing\.md does not exist$"):
        write_block(tmp_path / "missing.md", "smoke", "text")
    assert list(tmp_path.iterdir()) == []


def write_lines(path: Path, rows: list, tail: str = "") -> Path:
    path.write_text("".join(json.dumps(row) + "\n" for row in rows) + tail)
    return path


def test_read_rows_skips_a_torn_last_line_and_keeps_the_newest_duplicate(tmp_path):
    first, other, again = make_row("he-k1", 0, 0.5), make_row("he-k1", 1, 0.7), make_row("he-k1", 0, 0.4)
    path = write_lines(tmp_path / "smoke.jsonl", [first, other, again], tail='{"schema": 1, "spec": "sm')
    rows = read_rows(path)
    assert [(r["seed"], r["figures"]["phase2"]["min_distance"]) for r in rows] == [(0, 0.4), (1, 0.7)]
    assert len(read_rows(write_lines(tmp_path / "b.jsonl", [first, make_row("he-k1", 0, 0.5, spec="b")]))) == 2


def test_read_rows_names_the_file_and_line_of_a_bad_line_before_the_last(tmp_path):
    path = write_lines(tmp_path / "smoke.jsonl", [make_row("he-k1", 0, 0.5)], tail="{oops\n" + json.dumps({}) + "\n")
    with pytest.raises(ConfigError, match=r"rows: .*smoke\.jsonl line 2 is not JSON"):
        read_rows(path)


def test_a_rows_flip_table_is_its_runs_tables_pooled_and_a_row_without_one_is_named():
    from mjx_emp.flip_tables import flip_text, pooled
    from mjx_emp.report import row_flip_table

    level = {"level": 0, "episodes": 10, "flips": 1, "flip_share": 0.1,
             "by_index": [{"level": 0, "index": [0, 1], "attempts": [10, 9], "flips": [0, 1], "hazard": [0.0, 1 / 9]}],
             "before_flip": {"steps_before": [0, 1], "flipped_tilt": [0.9, 0.5], "upright_tilt": [0.0, 0.0],
                             "flipped_angular_speed": [2.0, 1.0], "upright_angular_speed": [1.0, 1.0],
                             "tilt_warning": {"threshold": 0.3, "warned": 1.0, "median_lead": 1.0},
                             "angular_speed_warning": {"threshold": 3.0, "warned": 0.0, "median_lead": None}},
             "by_start": {"initial": 0.0, "chained": 0.2},
             "by_goal_place": {"edges": [0.0, 0.5, 1.0], "episodes": [5, 5], "flips": [0, 1], "share": [0.0, 0.2]}}
    rows = [{"row": "he-k1", "seed": s, "figures": {"flip_table": [level], "phase2": None}} for s in (0, 1)]
    text = row_flip_table(rows + [{"row": "metra", "seed": 0, "figures": {"flip_table": None}}], "he-k1")
    assert text == "\n".join(flip_text([pooled([level, level])], None))
    assert "| 0 | 20 | 10.0% | 0.0% | 20.0% |" in text
    with pytest.raises(ConfigError, match="flip_table: row 'metra' has no flip table .*rows with one: he-k1"):
        row_flip_table(rows + [{"row": "metra", "seed": 0, "figures": {"flip_table": None}}], "metra")


def test_a_report_whose_rows_file_is_missing_says_where_it_looked_and_how_to_name_one(tmp_path, monkeypatch):
    from mjx_emp.report import report_spec

    spec = Path(__file__).parents[1] / "experiments" / "smoke-point-mass.toml"
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"results/smoke-point-mass.jsonl does not exist \(looked for from .*--results"):
        report_spec(str(spec))
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "smoke-point-mass.jsonl").write_text(json.dumps(make_row("he", 0, spec="other")) + "\n")
    with pytest.raises(ConfigError, match="holds no row of spec 'smoke-point-mass'"):
        report_spec(str(spec))
