"""Markdown tables of results, as the experiment scripts print them for the README."""

from __future__ import annotations

from collections.abc import Sequence


def mean_stderr_text(stat: dict[str, float]) -> str:
    """``mean ± stderr`` of a :func:`mjx_emp.metrics.mean_and_stderr` result, 3 and 2 significant digits."""
    return f"{stat['mean']:.3g} ± {stat['stderr']:.2g}"


def spread_text(stat: dict[str, float]) -> str:
    """A :func:`mjx_emp.metrics.mean_and_stderr` result as ``mean ± std (se stderr)``, or the
    value alone where it comes from one run (a "± 0" would only say n = 1)."""
    if stat["count"] == 1:
        return f"{stat['mean']:.3g}"
    return f"{stat['mean']:.3g} ± {stat['std']:.2g} (se {stat['stderr']:.2g})"


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table: a header row, the separator, then one line per row (cells as str)."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)
