"""The names of a benchmark's rows (a helper of the scripts here, not a benchmark).

Every benchmark appends one row per measured setting to ``results/<spec>.jsonl``
(:func:`mjx_emp.run.rows.benchmark_row`, :func:`mjx_emp.run.rows.append_row`). A row is named
from its record's own fields, as the rows carried over from the scripts' former JSON files were
named, so that a new measurement of a setting replaces the stored one (the store keeps the newest
row per spec, row and seed): ``GROUP/TEXT.../FIELDvalue...``, ``all`` where no field names it.
"""

from __future__ import annotations

from collections.abc import Iterable

NAMED_BY = ("variant", "setting", "preset", "env", "label", "name")
"""Text fields that name a row, in this order."""

COUNTED_BY = ("batch", "k", "num_envs", "devices", "seeds", "count")
"""Number fields that name a row after them, as ``FIELDvalue`` (``batch256``)."""


def row_name(record: dict, group: str = "") -> str:
    """``record``'s row name: its naming fields joined by "/" (a repeated one once), under ``group``."""
    parts = [record[field] for field in NAMED_BY if isinstance(record.get(field), str)]
    parts += [f"{field}{record[field]}" for field in COUNTED_BY
              if isinstance(record.get(field), (int, float)) and not isinstance(record.get(field), bool)]
    name = "/".join(dict.fromkeys(parts)) or "all"
    return f"{group}/{name}" if group else name


class RowNames:
    """:func:`row_name` for the records of one run, in order: a name met again with the same seed
    gets ``#2``, ``#3``, ... (so these names depend on the order the settings are measured in)."""

    def __init__(self) -> None:
        self.seen: dict[tuple[str, int], int] = {}

    def __call__(self, record: dict, group: str = "", seed: int = 0) -> str:
        name = row_name(record, group)
        count = self.seen[name, seed] = self.seen.get((name, seed), 0) + 1
        return name if count == 1 else f"{name}#{count}"


def numbered_names(settings: Iterable[str]) -> dict[str, str]:
    """Row names for settings whose records hold no naming field: ``all``, ``all#2``, ... in the
    order given (a benchmark's full list), as :class:`RowNames` names a run of them all, so that
    a run of some of them still replaces their own rows."""
    names = RowNames()
    return {setting: names({}) for setting in settings}


def lease_name(device: str) -> str:
    """A GPU lease's name, the first part of its rows' names: ``gpu_lease_`` and the device's
    model (``NVIDIA H200``: gpu_lease_h200; a CPU: gpu_lease_cpu)."""
    return "gpu_lease_" + device.split()[-1].lower()
