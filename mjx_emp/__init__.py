"""mjx-emp: Hierarchical Empowerment and the skill learners it is compared with, on MuJoCo MJX + JAX.

The Python API (:mod:`mjx_emp.api`): ``presets()``, ``config(preset, **changes)``,
``train(config, run_dir, on_epoch=...)``, ``load(run_dir)`` and the :class:`Run` they return,
``evaluate(run_dir)`` (a run's evaluation row) and ``sweep(spec)``.
Importing the package loads none of JAX; the API loads on first use.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Run", "config", "evaluate", "load", "presets", "sweep", "train"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from mjx_emp import api  # on first use: `import mjx_emp.errors` stays light

        return getattr(api, name)
    raise AttributeError(f"module 'mjx_emp' has no attribute {name!r}")
