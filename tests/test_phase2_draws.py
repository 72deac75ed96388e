"""experiments/phase2_draws.py: each policy's phase-2 figures over draws of goals."""

import pytest
from phase2_draws import summarise


def _draw(distance: float, uncut: float | None = None) -> dict:
    figures = {"min_distance": distance, "success": 0.5, "cut_short": 0.1}
    return figures if uncut is None else {**figures, "uncut_min_distance": uncut}


def test_summary_over_draws_holds_the_flip_split_and_the_paired_difference():
    per_policy = {"learned": [_draw(2.0, 1.0), _draw(4.0, 2.0)], "aimed": [_draw(3.0, 1.5), _draw(3.0, 2.5)]}
    summary = summarise(per_policy)
    learned = summary["summary"]["learned"]
    assert set(learned) == {"min_distance", "success", "cut_short", "uncut_min_distance"}
    assert learned["min_distance"]["mean"] == pytest.approx(3.0)
    assert learned["uncut_min_distance"]["mean"] == pytest.approx(1.5)
    assert summary["learned_minus_aimed"]["per_draw"] == pytest.approx([-1.0, 1.0])


def test_summary_leaves_out_a_figure_a_stored_draw_lacks():
    summary = summarise({"learned": [_draw(2.0, 1.0), _draw(4.0)]})
    assert "uncut_min_distance" not in summary["summary"]["learned"]
    assert "learned_minus_aimed" not in summary
