"""Markdown tables the experiment scripts print."""

from mjx_emp.metrics import mean_and_stderr
from mjx_emp.tables import markdown_table, mean_stderr_text, spread_text


def test_a_table_has_a_header_a_separator_and_one_line_per_row():
    table = markdown_table(("a", "b"), [(1, "x"), (2.5, "y")])
    assert table.splitlines() == ["| a | b |", "|---|---|", "| 1 | x |", "| 2.5 | y |"]


def test_mean_and_standard_error_print_with_three_and_two_digits():
    assert mean_stderr_text(mean_and_stderr([1.0, 2.0, 4.0])) == "2.33 ± 0.88"


def test_a_spread_gives_std_and_standard_error_and_no_spread_for_one_run():
    assert spread_text(mean_and_stderr([1.0, 2.0, 4.0])) == "2.33 ± 1.5 (se 0.88)"
    assert spread_text(mean_and_stderr([0.75])) == "0.75"
