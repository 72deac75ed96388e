"""Names that left the preset catalogue, each with the command that reproduces its config.

The catalogue keeps one recipe per domain, depth and size (:mod:`mjx_emp.algos.names`); the
variants that single experiments trained (another solver, a tilt cost, a tighter box) left
it. Each retired name maps to a preset of the catalogue and the config fields to change,
spelled as ``mjx-emp train`` spells them, so that results recorded under the old name stay
reproducible and ``mjx-emp train OLDNAME`` can say what to type instead.

Plain data and pure functions: the CLI reads them before anything imports JAX.
"""

from __future__ import annotations

import dataclasses
from typing import Any


@dataclasses.dataclass(frozen=True)
class Retired:
    """A retired name's config: ``preset`` of the catalogue with the fields ``changes`` replaced."""

    preset: str
    changes: tuple[tuple[str, Any], ...] = ()

    @property
    def command(self) -> str:
        """The preset and its flags as ``mjx-emp train`` (or ``phase2``) reads them."""
        return " ".join([self.preset, *(flag_text(field, value) for field, value in self.changes)])

    def apply(self, config: Any) -> Any:
        """``config`` (the preset's) with the changes made."""
        return dataclasses.replace(config, **dict(self.changes))


def flag_text(field: str, value: Any) -> str:
    """One config field's flag as the CLI spells it: ``--tilt-cost 1.0``, ``--critic-layer-norm``
    or ``--no-critic-layer-norm``, ``--level-repeats 4 1`` (an empty tuple: the bare flag),
    ``--max-env-steps None``."""
    flag = "--" + field.replace("_", "-")
    if isinstance(value, bool):
        return flag if value else f"--no-{field.replace('_', '-')}"
    if isinstance(value, tuple):
        return " ".join([flag, *(repr(item) if isinstance(item, float) else str(item) for item in value)])
    if isinstance(value, float):
        return f"{flag} {value!r}"
    return f"{flag} {value}"


def _retired(preset: str, **changes: Any) -> Retired:
    return Retired(preset, tuple(changes.items()))


_MODEL_PHYSICS = dict(solver_iterations=0, critic_layer_norm=False)
"""The model file's one solver iteration and a plain critic: the first CPU robot learner's."""
_FLAT_LEARNERS = ("diayn", "hidio", "dads", "metra")

RETIRED: dict[str, Retired] = {
    # Hierarchical Empowerment on the robots, CPU size.
    "ant-field-cpu-k1": _retired("ant-field-k1-cpu", **_MODEL_PHYSICS),
    "ant-field-cpu-k2": _retired("ant-field-k2-cpu", **_MODEL_PHYSICS, level_repeats=()),
    "ant-field-cpu-k2-wide": _retired("ant-field-k2-cpu", **_MODEL_PHYSICS, level_repeats=(), sigma_gs=(0.5, 1.0),
                                      epochs=300),
    "ant-field-cpu-k1-4iter": _retired("ant-field-k1-cpu", critic_layer_norm=False),
    "ant-field-cpu-k2-4iter": _retired("ant-field-k2-cpu", critic_layer_norm=False, level_repeats=()),
    "ant-field-cpu-k1-4iter-ln": _retired("ant-field-k1-cpu"),
    "ant-field-cpu-k2-4iter-ln": _retired("ant-field-k2-cpu", level_repeats=()),
    "ant-field-cpu-k1-4iter-ln-gs0.25": _retired("ant-field-k1-cpu", sigma_gs=(0.25,)),
    "ant-field-cpu-k1-4iter-ln-resets": _retired("ant-field-k1-cpu", learn_from_resets=True),
    "ant-field-cpu-k1-4iter-ln-resets-start": _retired("ant-field-k1-cpu", learn_from_resets=True,
                                                       reset_outcome="start"),
    "ant-field-cpu-k1-4iter-ln-tilt1": _retired("ant-field-k1-cpu", tilt_cost=1.0),
    "ant-field-cpu-k2-4iter-ln-tilt1": _retired("ant-field-k2-cpu", level_repeats=(), tilt_cost=1.0),
    "ant-field-cpu-k2-4iter-ln-rep4": _retired("ant-field-k2-cpu"),
    "ant-field-cpu-k2-4iter-ln-rep4-tilt4": _retired("ant-field-k2-cpu", tilt_cost=4.0),
    "ant-field-cpu-k1-4iter-ln-tilt4": _retired("ant-field-k1-cpu", tilt_cost=4.0),
    "ant-field-cpu-k1-her-ln": _retired("ant-field-k1-cpu", solver_iterations=0, her=0.5, epochs=120),
    "half-cheetah-cpu-k1": _retired("half-cheetah-field-k1-cpu", tilt_cost=0.0),
    "half-cheetah-cpu-k2": _retired("half-cheetah-field-k2-cpu", tilt_cost=0.0, level_repeats=()),
    "half-cheetah-cpu-k2-rep4": _retired("half-cheetah-field-k2-cpu", tilt_cost=0.0),
    "half-cheetah-cpu-k1-gs2": _retired("half-cheetah-field-k1-cpu", tilt_cost=0.0, sigma_gs=(2.0,)),
    "half-cheetah-cpu-k1-tilt1": _retired("half-cheetah-field-k1-cpu", tilt_cost=1.0),
    "half-cheetah-cpu-k1-tilt1-gs2": _retired("half-cheetah-field-k1-cpu", tilt_cost=1.0, sigma_gs=(2.0,)),
    "half-cheetah-cpu-k1-tilt4": _retired("half-cheetah-field-k1-cpu"),
    "half-cheetah-cpu-k1-tilt4-gs40": _retired("half-cheetah-field-k1-cpu", gs_grad_steps=40),
    "half-cheetah-cpu-k2-rep4-tilt1": _retired("half-cheetah-field-k2-cpu", tilt_cost=1.0),
    "half-cheetah-cpu-k2-rep4-tilt4": _retired("half-cheetah-field-k2-cpu"),
    "half-cheetah-cpu-k1-4iter": _retired("half-cheetah-field-k1-cpu", tilt_cost=0.0, solver_iterations=4),
    "ant-cage-cpu-k1": _retired("ant-cage-k1-cpu"),
    "ant-cage-cpu-k2": _retired("ant-cage-k2-cpu"),
    "half-cheetah-cage-cpu-k1": _retired("half-cheetah-cage-k1-cpu"),
    "half-cheetah-cage-cpu-k2": _retired("half-cheetah-cage-k2-cpu"),
    # The paper's Table 1, renamed.
    "ant-field-small-k1": _retired("ant-field-k1-paper-small"),
    "ant-field-big-k1": _retired("ant-field-k1-paper-big"),
    "ant-field-big-k2": _retired("ant-field-k2-paper-big"),
    "ant-field-xl-k2": _retired("ant-field-k2-paper-xl"),
    "ant-field-xl-k3": _retired("ant-field-k3-paper-xl"),
    "half-cheetah-small-k1": _retired("half-cheetah-field-k1-paper-small"),
    "half-cheetah-big-k1": _retired("half-cheetah-field-k1-paper-big"),
    "half-cheetah-big-k2": _retired("half-cheetah-field-k2-paper-big"),
    "ant-cage-k1": _retired("ant-cage-k1-paper"),
    "ant-cage-k2": _retired("ant-cage-k2-paper"),
    "half-cheetah-cage-k1": _retired("half-cheetah-cage-k1-paper"),
    "half-cheetah-cage-k2": _retired("half-cheetah-cage-k2-paper"),
    # GCRL.
    "gcrl-point-mass": _retired("gcrl-point-mass-k1"),
    "gcrl-ant-field-cpu": _retired("gcrl-ant-field-k1-cpu", **_MODEL_PHYSICS),
    "gcrl-ant-field-cpu-4iter-ln": _retired("gcrl-ant-field-k1-cpu"),
    "gcrl-half-cheetah-cpu": _retired("gcrl-half-cheetah-field-k1-cpu"),
    "gcrl-ant-field-small": _retired("gcrl-ant-field-k1-gpu"),
    "gcrl-half-cheetah-small": _retired("gcrl-half-cheetah-field-k1-gpu"),
    # The flat skill learners.
    **{f"{algo}-half-cheetah-cpu": _retired(f"{algo}-half-cheetah-field-cpu") for algo in _FLAT_LEARNERS},
    **{f"{algo}-ant-field-cpu-4iter": _retired(f"{algo}-ant-field-cpu") for algo in _FLAT_LEARNERS},
    **{f"{algo}-ant-field-small": _retired(f"{algo}-ant-field-gpu") for algo in _FLAT_LEARNERS},
    **{f"{algo}-half-cheetah-small": _retired(f"{algo}-half-cheetah-field-gpu") for algo in _FLAT_LEARNERS},
}
"""Retired phase-1 name -> the catalogue's preset and the changes that give its config."""

REDEFINED: dict[str, Retired] = {
    f"{algo}-ant-field-cpu": _retired(f"{algo}-ant-field-cpu", solver_iterations=0) for algo in _FLAT_LEARNERS
}
"""Names still in the catalogue that used to name another config: ``ALGO-ant-field-cpu`` now
runs the 4-iteration physics of HE's Ant recipe; the rows recorded under the name before were
trained with the model file's one iteration, which these changes give back."""



def retired_rows(retired: dict[str, Retired], usage: str) -> list[str]:
    """Markdown table rows for docs/presets.md: each retired name beside ``usage`` (such as
    ``mjx-emp train PRESET``) with PRESET replaced by the command that gives its config."""
    return [f"| `{name}` | `{usage.replace('PRESET', entry.command)}` |" for name, entry in retired.items()]
