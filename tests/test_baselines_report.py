"""The comparison table of experiments/baselines.py: rows at one budget, mean ± std (stderr)."""

from baselines import chart_colours, chart_label, chart_labels, report_table, rows_at_budget


def _row(preset, seed, steps, cells, distance):
    return {"preset": preset, "seed": seed, "env_steps": steps, "wall_s": 10.0, "coverage_cells": cells,
            "posterior_std": None, "phase2_min_distance": distance, "phase2_success": 0.5}


def test_rows_at_budget_keeps_rows_within_one_percent():
    rows = [_row("a", 0, 960_000.0, 4, 1.0), _row("b", 0, 960_960.0, 4, 1.0), _row("c", 0, 2_016_000.0, 4, 1.0)]
    assert [r["preset"] for r in rows_at_budget(rows, 960_000.0)] == ["a", "b"]
    assert rows_at_budget(rows, None) == rows


def test_report_table_gives_mean_std_and_standard_error_per_preset():
    rows = [_row("a", 0, 1e6, 2, 10.0), _row("a", 1, 1e6, 6, 12.0), _row("b", 0, 1e6, 5, None)]
    lines = report_table(rows).splitlines()
    a_line = next(line for line in lines if line.startswith("| a |"))
    assert "| 2 |" in a_line and "4 ± 2.8 (2)" in a_line and "11 ± 1.4 (1)" in a_line
    b_line = next(line for line in lines if line.startswith("| b |"))
    assert b_line.endswith("| - | - | - | - |")  # no phase 2 trained
    assert a_line.endswith("| - | - |")  # rows without a flip fraction or an aimed figure (older results)
    flips = [{**_row("c", seed, 1e6, 2, 3.0), "phase2_cut_short": cut, "phase2_aimed_min_distance": aimed}
             for seed, cut, aimed in ((0, 0.1, 2.0), (1, 0.3, 4.0))]
    c_line = next(line for line in report_table(flips).splitlines() if line.startswith("| c |"))
    assert c_line.endswith("| 0.20 ± 0.14 (0.1) | 3 ± 1.4 (1) |")


def test_charts_draw_methods_with_and_without_phase2_curves(tmp_path):
    from baselines import draw_charts

    with_curve = {**_row("ant-field-k1-cpu", 0, 1e6, 12, 12.0), "env": "ant_field",
                  "phase2_curve": [[0.0, 15.0], [1000.0, 12.0]]}
    without = {**_row("metra-ant-field-cpu", 0, 1e6, 8, 14.0), "env": "ant_field", "run_dir": str(tmp_path / "gone")}
    path = draw_charts([with_curve, without], tmp_path / "chart.png")
    assert path.exists() and path.stat().st_size > 10_000


def test_chart_labels_name_the_method_and_a_hand_set_box_by_its_side():
    assert chart_label("ant-field-k2-cpu") == "HE k=2"
    assert chart_label("metra-ant-field-cpu") == "METRA"
    assert chart_label("gcrl-ant-field-k1-cpu") == "GCRL 4x4 m"  # the preset's own box, half-width 2 m
    assert chart_label("gcrl-ant-field-k1-cpu-w0.5") == "GCRL 1x1 m"
    assert chart_label("gcrl-half-cheetah-field-k1-cpu-w15") == "GCRL 30 m box"  # one goal dimension
    assert chart_label("gcrl-half-cheetah-cpu-w15") == "GCRL 30 m box"  # a row recorded under a retired name


def test_presets_that_share_a_label_are_told_apart_by_the_fields_where_they_differ_from_the_base():
    """Rows recorded under retired names (the variants left the catalogue) keep their configs."""
    labels = chart_labels(["ant-field-cpu-k1-4iter-ln-gs0.25", "ant-field-cpu-k1-4iter-ln", "metra-ant-field-cpu",
                           "gcrl-ant-field-cpu-w2", "gcrl-ant-field-cpu-w8", "ant-field-cpu-k1-4iter-ln-resets-start",
                           "ant-field-cpu-k1-4iter-ln-tilt1"])
    assert labels == ["HE k=1, sigma_gs 0.25", "HE k=1", "METRA", "GCRL 4x4 m", "GCRL 16x16 m",
                      "HE k=1, learn_from_resets True, reset_outcome start", "HE k=1, tilt_cost 1.0"]


def test_chart_colours_keep_one_hue_per_method_and_never_share_a_colour():
    from matplotlib.colors import rgb_to_hsv, to_rgb

    presets = ["ant-field-k1-cpu", "gcrl-ant-field-k1-cpu-w0.5", "gcrl-ant-field-k1-cpu-w2",
               "gcrl-ant-field-k1-cpu-w8", "gcrl-ant-field-k1-cpu-w20", "metra-ant-field-cpu", "diayn-ant-field-cpu",
               "hidio-ant-field-cpu", "dads-ant-field-cpu"]
    colours = chart_colours(presets)
    assert len(set(colours)) == len(presets)
    hues = [rgb_to_hsv(to_rgb(c))[0] for c in colours[1:5]]
    assert max(hues) - min(hues) < 0.02  # GCRL's four boxes: shades of its one colour


def test_spread_recounts_replace_one_draw_by_the_mean_of_draws_for_their_run_only():
    from baselines import with_spread_coverage

    rows = [{**_row("a", 0, 1e6, 2, 10.0), "run_dir": "/runs/a-s0"}, {**_row("a", 1, 1e6, 6, 12.0), "run_dir": "/runs/a-s1"}]
    spread = [{"preset": "a", "seed": 0, "run_dir": "/runs/a-s0", "cells": [3, 5, 4, 4]}]
    recounted = with_spread_coverage(rows, spread)
    assert recounted[0]["coverage_cells"] == 4.0 and recounted[0]["coverage_draws"] == [3, 5, 4, 4]
    assert recounted[1] == rows[1]
    a_line = next(line for line in report_table(recounted).splitlines() if line.startswith("| a |"))
    assert "| 5 ± 1.4 (1) | 1-4 |" in a_line  # mean of 4.0 and 6; one seed of 1 draw, one of 4
