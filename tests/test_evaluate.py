"""The paper's evaluation metric and the run pictures, on trajectories with known answers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mjx_emp import cli
from mjx_emp.metrics import (
    aggregate_phase2,
    aggregate_runs,
    coverage_cells,
    mean_and_stderr,
    running_min_distance,
)
from mjx_emp.viz.plots import (
    METHOD_COLOURS,
    axes_content,
    colour_of,
    goal_space_growth_figure,
    plot_goal_space_boxes,
    plot_goal_space_growth,
    plot_phase2_curves,
    plot_runs,
    seed_band,
)


def _distances(positions, goals):
    return np.linalg.norm(np.asarray(positions) - np.asarray(goals), axis=-1)


def test_min_distance_is_the_closest_approach_of_each_episode():
    # Env 0 walks along x toward (3, 4) and passes closest at (3, 0): distance 4.
    # Env 1 reaches its goal (3, 3) exactly at step 2, then leaves. Both episodes end at step 3.
    positions = [[[0.0, 0.0], [1.0, 1.0]], [[3.0, 0.0], [2.0, 2.0]], [[6.0, 0.0], [3.0, 3.0]],
                 [[9.0, 0.0], [4.0, 4.0]]]
    goals = [[3.0, 4.0], [3.0, 3.0]]
    ended = np.zeros((4, 2), bool)
    ended[3] = True
    running, per_step = running_min_distance(
        _distances(positions, goals), np.ones((4, 2), bool), ended, np.full(2, np.inf)
    )
    assert np.asarray(per_step)[3].tolist() == [4.0, 0.0]
    assert np.isinf(np.asarray(running)).all()  # both episodes ended: the next ones start afresh


def test_min_distance_follows_episodes_across_calls_and_restarts():
    # 1-D goal space (Half Cheetah). Env 0: an episode with distances 5, 2 ends at step 1, the
    # next one sees 7, 6 and continues into the second call, which brings 1 and ends it.
    first_call = np.array([[5.0], [2.0], [7.0], [6.0]])
    ended = np.array([[False], [True], [False], [False]])
    running, per_step = running_min_distance(first_call, np.ones((4, 1), bool), ended, np.full(1, np.inf))
    assert float(np.asarray(per_step)[1, 0]) == 2.0 and float(running[0]) == 6.0
    running, per_step = running_min_distance(np.array([[1.0]]), np.ones((1, 1), bool), np.ones((1, 1), bool), running)
    assert float(np.asarray(per_step)[0, 0]) == 1.0


def test_min_distance_ignores_steps_that_do_not_count():
    # A physics reset's step (valid False) is no approach to the goal; an episode with no
    # counted step has distance inf.
    distance = np.array([[5.0, 3.0], [0.0, 0.0]])
    valid = np.array([[True, False], [False, False]])
    ended = np.array([[False, False], [True, True]])
    _, per_step = running_min_distance(distance, valid, ended, np.full(2, np.inf))
    assert np.asarray(per_step)[1, 0] == 5.0 and np.isinf(np.asarray(per_step)[1, 1])


def test_coverage_counts_distinct_metre_cells_of_the_points_that_count():
    # Two skills in (x, y): one walks 2.5 m along x (cells x = 0, 1, 2 at y = 0), the other
    # steps into the negative quadrant (cell (-1, -1)) and then leaves its episode (masked).
    paths = np.array([
        [[0.2, 0.3], [0.2, 0.3]],
        [[1.1, 0.4], [-0.5, -0.2]],
        [[2.7, 0.9], [30.0, 30.0]],
    ])
    mask = np.array([[True, True], [True, True], [True, False]])
    assert coverage_cells(paths, mask) == 4  # (0,0) (1,0) (2,0) (-1,-1); (30,30) does not count
    assert coverage_cells(paths, mask, cell=2.0) == 3  # (0,0) (1,0) (-1,-1) in 2 m cells
    # 1-D goal space (Half Cheetah x): 1 m bins.
    assert coverage_cells(np.array([[0.5], [1.5], [1.9], [-0.1]]), np.ones(4, bool)) == 3
    assert coverage_cells(paths, np.zeros((3, 2), bool)) == 0


def test_mean_and_standard_error_over_seeds():
    result = mean_and_stderr([1.0, 2.0, 3.0, 6.0])
    assert result["mean"] == 3.0 and result["count"] == 4
    assert result["std"] == pytest.approx(np.std([1, 2, 3, 6], ddof=1))
    assert result["stderr"] == pytest.approx(result["std"] / 2)
    assert mean_and_stderr([2.5]) == {"mean": 2.5, "std": 0.0, "stderr": 0.0, "count": 1}


def test_goal_space_growth_plot_is_a_png_image(tmp_path):
    from PIL import Image

    metrics = [
        {"epoch": e, "levels": [{"volume": 0.16 * 1.1 ** e, "success": None if e == 1 else 0.9},
                                {"volume": 0.64 * 1.05 ** e, "success": 0.8}]}
        for e in range(1, 21)
    ]
    path = plot_goal_space_growth(metrics, tmp_path / "plots" / "growth.png")
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size == (700, 600)
        assert np.unique(np.asarray(image.convert("L"))).size > 2  # curves were drawn, not a blank canvas


def test_runs_aggregate_per_level_and_must_have_the_same_depth():
    def run(volumes, success):
        return {"levels": [{"volume": v, "success": success, "final_distance": 0.1, "cut_short": 1 - success,
                            "from_initial": {"success": success / 2}, "chained": {"success": success / 4}}
                           for v in volumes]}

    rows = aggregate_runs([run([1.0, 10.0], 0.9), run([3.0, 30.0], 0.7)])
    assert [row["volume"]["mean"] for row in rows] == [2.0, 20.0]
    assert rows[1]["volume"]["stderr"] == pytest.approx(10.0)  # std 14.14 / sqrt(2)
    assert rows[0]["success"]["mean"] == pytest.approx(0.8)
    assert rows[0]["success_from_initial"]["mean"] == pytest.approx(0.4)
    assert rows[0]["success_chained"]["mean"] == pytest.approx(0.2)
    assert rows[1]["cut_short"]["mean"] == pytest.approx(0.2)
    with pytest.raises(ValueError, match="same number of levels"):
        aggregate_runs([run([1.0], 0.9), run([1.0, 2.0], 0.9)])


def test_phase2_figures_aggregate_over_seeds():
    result = aggregate_phase2([{"min_distance": 0.2, "success": 1.0}, {"min_distance": 0.6, "success": 0.5}])
    assert result["min_distance"]["mean"] == pytest.approx(0.4)
    assert result["min_distance"]["stderr"] == pytest.approx(0.2)  # std 0.283 / sqrt(2)
    assert result["success"]["count"] == 2
    assert "cut_short" not in result  # figures an older report lacks are left out, not invented


def test_phase2_aggregate_keeps_the_flip_split_only_where_every_report_has_it():
    full = {"min_distance": 3.0, "success": 0.5, "cut_short": 0.2, "uncut_min_distance": 1.5}
    both = aggregate_phase2([full, {**full, "cut_short": 0.4, "uncut_min_distance": 2.5}])
    assert both["cut_short"]["mean"] == pytest.approx(0.3)
    assert both["uncut_min_distance"]["mean"] == pytest.approx(2.0)
    older = aggregate_phase2([full, {"min_distance": 1.0, "success": 1.0, "cut_short": 0.0}])
    assert older["cut_short"]["mean"] == pytest.approx(0.1) and "uncut_min_distance" not in older
    with pytest.raises(ValueError, match="success"):
        aggregate_phase2([{"min_distance": 1.0}])


def test_phase2_curves_plot_marks_eps(tmp_path):
    metrics = [{"env_steps": 1e4 * e, "min_distance": 2.0 / e, "success": min(1.0, 0.1 * e)} for e in range(1, 11)]
    pixels = drawn_png(plot_phase2_curves(metrics, 0.6, tmp_path / "phase2.png"))
    assert pixels.shape == (600, 700, 3)
    blue = np.array([31, 119, 180])
    assert (np.abs(pixels.astype(int) - blue).sum(axis=-1) < 30).sum() > 100  # the curves were drawn


def drawn_png(path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        assert image.format == "PNG"
        return np.asarray(image.convert("RGB"))


@pytest.mark.parametrize("dims", [1, 2])
def test_goal_space_boxes_plot_draws_every_level(tmp_path, dims):
    boxes = [{"shift": [0.1] * dims, "half_width": [1.0] * dims}, {"shift": [0.0] * dims, "half_width": [3.0] * dims}]
    trajectory = np.cumsum(np.full((20, dims), 0.1), axis=0)
    pixels = drawn_png(plot_goal_space_boxes([0.0] * dims, boxes, [trajectory], tmp_path / "boxes.png"))
    assert pixels.shape == (600, 600, 3)
    blue, orange = np.array([31, 119, 180]), np.array([255, 127, 14])  # matplotlib's first two colours
    for colour in (blue, orange):  # both level boxes appear
        assert (np.abs(pixels.astype(int) - colour).sum(axis=-1) < 30).sum() > 100


def test_plot_command_draws_a_run_and_names_the_field_when_there_is_none(tmp_path, capsys):
    from mjx_emp.algos.he.config import HEConfig
    from mjx_emp.run.store import write_config

    write_config(tmp_path, HEConfig(n=(10,), eps=(0.6,), sigma_gc=(0.6,), sigma_gs=(0.6,), init_half_width=(0.6,),
                                    max_half_width=(3.0,)))  # the point mass: (x, y) goals, volumes in m²
    lines = [{"epoch": e, "levels": [{"volume": 0.1 * e, "success": 0.5}]} for e in (1, 2, 3)]  # no env steps
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(m) + "\n" for m in lines))
    cli.main(["plot", str(tmp_path)])
    drawn = tmp_path / "plots" / "goal_space_growth.png"
    assert capsys.readouterr().out.splitlines()[1:] == [str(drawn)]  # no checkpoints, no phase 2: growth only
    title = "HE k=1 on point_mass: goal-space growth"
    volume, success = axes_content(goal_space_growth_figure(lines, "m²", title))
    assert volume.series == {"level 0": ([1.0, 2.0, 3.0], [0.1 * e for e in (1, 2, 3)])}  # epochs on the x axis
    assert success.series == {"level 0": ([1.0, 2.0, 3.0], [0.5, 0.5, 0.5])}
    assert (volume.title, volume.ylabel, volume.yscale) == (title, "goal-space volume at s0 (m²)", "log")
    assert volume.legend == ["level 0"]
    assert (success.xlabel, success.ylabel) == ("epoch", "greedy success in own goal space")
    # The command drew that very figure: its PNG is the checked figure's, pixel for pixel.
    expected = plot_goal_space_growth(lines, tmp_path / "expected.png", "m²", title)
    np.testing.assert_array_equal(drawn_png(drawn), drawn_png(expected))
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["plot", str(tmp_path / "missing")])
    assert exit_info.value.code == 2 and "run_dir" in capsys.readouterr().err


def test_seeds_meet_on_the_grid_of_the_run_that_ends_first():
    first = (np.array([0.0, 10.0, 20.0]), np.array([1.0, 3.0, 5.0]))
    second = (np.array([0.0, 5.0, 10.0, 15.0]), np.array([3.0, np.nan, 5.0, 9.0]))  # a NaN is skipped
    band = seed_band([first, second])
    assert band["steps"].tolist() == [0.0, 5.0, 10.0, 15.0] and band["count"] == 2
    assert band["mean"].tolist() == pytest.approx([2.0, 3.0, 4.0, 6.5])  # first at 5 and 15: 2.0 and 4.0
    assert band["std"][0] == pytest.approx(np.std([1.0, 3.0], ddof=1))


def test_two_seeds_of_two_methods_plot_as_bands_in_fixed_colours(tmp_path):
    from mjx_emp.algos.he.config import HEConfig
    from mjx_emp.run.store import write_config

    runs = []
    for k, offset in ((1, 0.0), (2, 5.0)):
        for seed in (0, 1):
            run_dir = tmp_path / f"k{k}-s{seed}"
            run_dir.mkdir()
            n, eps = (10,) * k, (0.6,) * k
            write_config(run_dir, HEConfig(n=n, eps=eps, sigma_gc=eps, sigma_gs=eps, init_half_width=eps,
                                           max_half_width=(3.0,) * k, seed=seed))
            lines = [{"epoch": e, "env_steps": 1000.0 * e, "levels": [
                {"volume": offset + e + seed, "success": 0.5 + 0.01 * e}] * k} for e in range(1, 11)]
            (run_dir / "metrics.jsonl").write_text("".join(json.dumps(m) + "\n" for m in lines))
            runs.append(run_dir)
    paths = plot_runs(runs, tmp_path / "figures")
    assert [p.name for p in paths] == ["learning_curves.png"]
    pixels = drawn_png(paths[0])
    for label in ("HE k=1", "HE k=2"):
        colour = np.array([int(METHOD_COLOURS[label][i:i + 2], 16) for i in (1, 3, 5)])
        assert (np.abs(pixels.astype(int) - colour).sum(axis=-1) < 30).sum() > 200, label


def test_a_label_without_a_fixed_colour_takes_one_no_other_label_has():
    from matplotlib.colors import to_hex

    taken = [METHOD_COLOURS["HE k=1"], METHOD_COLOURS["GCRL k=1"], (1.0, 0.4980392156862745, 0.054901960784313725)]
    spare = colour_of("GCRL 16x16 m", taken)
    assert to_hex(spare) not in {to_hex(c) for c in taken}  # hex and RGB forms of a colour are the same colour
    assert colour_of("HE k=1", []) == METHOD_COLOURS["HE k=1"]


def test_coverage_over_several_draws_is_the_mean_of_each_draws_count_with_its_spread():
    import jax

    from mjx_emp.run.evaluate import COVERAGE_SKILLS, coverage_figures

    def paths(key, skills):  # every skill of a draw walks 1-5 cells along x, the length set by the key
        length = 1 + int(jax.random.randint(key, (), 0, 5))
        positions = np.zeros((skills, 5, 2))
        positions[:, :, 0] = np.arange(5) + 0.5
        return positions, np.broadcast_to(np.arange(5) < length, (skills, 5))

    key = jax.random.key(7)
    one = coverage_figures(paths, key)
    assert one == {"coverage_cells": coverage_cells(*paths(key, COVERAGE_SKILLS))}
    several = coverage_figures(paths, key, draws=5)
    counts = [coverage_cells(*paths(jax.random.fold_in(key, d), COVERAGE_SKILLS)) for d in range(5)]
    assert several["coverage_draws"] == 5
    assert several["coverage_cells"] == pytest.approx(np.mean(counts))
    assert several["coverage_cells_std"] == pytest.approx(np.std(counts, ddof=1))
