"""The grammar of preset names, and the listing ``mjx-emp presets`` prints.

A phase-1 preset is named ``[ALGO-]DOMAIN[-kK][-SIZE]``:

- ``ALGO``: omitted for Hierarchical Empowerment; ``gcrl``, ``diayn``, ``hidio``, ``dads`` or
  ``metra`` otherwise.
- ``DOMAIN``: the environment's name with ``_`` written ``-`` (``point-mass``, ``ant-field``,
  ``ant-cage``, ``half-cheetah-field``, ``half-cheetah-cage``).
- ``kK``: the number of levels, for the goal-space algorithms (HE; GCRL, always ``k1``);
  absent for the flat skill learners, whose skills have no levels.
- ``SIZE``: ``cpu`` (trains on a 2-core CPU: 16 environments), ``gpu`` (the paper's shape:
  4096 environments, minibatches of 1024), or one of the paper's Table-1 configs as the paper
  names them (``paper-small``, ``paper-big``, ``paper-xl`` on the fields, ``paper`` in the
  cages; HE only). Omitted for the point mass, which has one size.

A phase-2 task is named ``reach-DOMAIN[-kK][-SIZE][-VARIANT]``: ``reach-`` and the domain, then
``kK`` and the paper's size for a Table-2 task (one per Table-1 row, which it builds on), or
``cpu`` alone for a task sized for the 2-core CPU (one per robot domain, shared by every depth).
The point mass's tasks have no size; ``-wide`` and ``-wider`` name its larger goal regions.

Plain Python: the CLI lists and checks names before anything imports JAX.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from collections.abc import Iterable

from mjx_emp.errors import ConfigError

HE = "he"
"""The algorithm whose names carry no ALGO part."""
ALGOS = ("gcrl", "diayn", "hidio", "dads", "metra")
"""The ALGO parts, in the order the listing shows them."""
GOAL_SPACE_ALGOS = (HE, "gcrl")
"""Algorithms whose names carry kK: their skills are levels of goal spaces."""
DOMAINS = ("point-mass", "ant-field", "half-cheetah-field", "ant-cage", "half-cheetah-cage")
"""The DOMAIN parts, in the order the listing shows them."""
CPU, GPU = "cpu", "gpu"
PAPER_FIELD_SIZES = ("paper-small", "paper-big", "paper-xl")
PAPER_CAGE_SIZE = "paper"
SIZES = (CPU, GPU, *PAPER_FIELD_SIZES, PAPER_CAGE_SIZE)
POINT_MASS = "point-mass"
TASK_PREFIX = "reach-"
POINT_MASS_VARIANTS = ("wide", "wider")
"""The point mass's larger goal regions (8 x 8 and 16 x 16 beside the plain task's 2.4 x 2.4)."""
CPU_MAX_ENVS = 64
"""The most environments a ``cpu`` preset collects with (the point mass's HE presets: 64)."""
PAPER_ENVS = 4096
"""The environments of every ``gpu`` and ``paper`` preset: the paper's."""

_SIZE = "|".join(sorted(SIZES, key=len, reverse=True))  # the longest first: paper-small before paper
_PHASE1 = re.compile(
    rf"(?:(?P<algo>{'|'.join(ALGOS)})-)?(?P<domain>{'|'.join(DOMAINS)})(?:-k(?P<k>[1-9]))?(?:-(?P<size>{_SIZE}))?"
)
_TASK = re.compile(
    rf"{TASK_PREFIX}(?P<domain>{'|'.join(DOMAINS)})(?:-k(?P<k>[1-9]))?(?:-(?P<size>{_SIZE}))?"
    rf"(?:-(?P<variant>{'|'.join(POINT_MASS_VARIANTS)}))?"
)


@dataclasses.dataclass(frozen=True)
class PresetName:
    """The parts of a phase-1 preset's name. ``algo`` is ``he`` where the name has no ALGO part;
    ``k`` and ``size`` are None where the grammar leaves them out."""

    algo: str
    domain: str
    k: int | None
    size: str | None

    @property
    def env(self) -> str:
        """The environment's name as configs spell it (``ant_field``)."""
        return self.domain.replace("-", "_")

    def __str__(self) -> str:
        parts = [] if self.algo == HE else [self.algo]
        parts.append(self.domain)
        if self.k is not None:
            parts.append(f"k{self.k}")
        if self.size is not None:
            parts.append(self.size)
        return "-".join(parts)


@dataclasses.dataclass(frozen=True)
class TaskName:
    """The parts of a phase-2 task's name; ``k`` and ``size`` as in :class:`PresetName`,
    ``variant`` one of :data:`POINT_MASS_VARIANTS` or None."""

    domain: str
    k: int | None
    size: str | None
    variant: str | None

    @property
    def env(self) -> str:
        """The environment's name as configs spell it."""
        return self.domain.replace("-", "_")


def _check_size(domain: str, size: str | None, algo: str, what: str) -> None:
    """Raise ValueError where ``size`` does not fit ``domain`` and ``algo``: none for the point
    mass, one for every robot, ``paper*`` only for HE and only the field or cage spelling."""
    if domain == POINT_MASS:
        if size is not None:
            raise ValueError(f"{what}: the point mass has one size, so its names carry none")
        return
    if size is None:
        raise ValueError(f"{what}: a robot's name ends in its size, one of {list(SIZES)}")
    if size in (CPU, GPU):
        return
    if algo != HE:
        raise ValueError(f"{what}: only Hierarchical Empowerment has the paper's Table-1 sizes")
    allowed = (PAPER_CAGE_SIZE,) if domain.endswith("-cage") else PAPER_FIELD_SIZES
    if size not in allowed:
        raise ValueError(f"{what}: {domain}'s paper sizes are {list(allowed)}")


def parse_preset_name(name: str) -> PresetName:
    """The parts of a phase-1 preset's name; ValueError for a name outside the grammar
    ``[ALGO-]DOMAIN[-kK][-SIZE]`` (the module's docstring)."""
    match = _PHASE1.fullmatch(name)
    if match is None:
        raise ValueError(f"preset name {name!r} is not [ALGO-]DOMAIN[-kK][-SIZE] (ALGO one of {list(ALGOS)} or "
                         f"none, DOMAIN one of {list(DOMAINS)}, SIZE one of {list(SIZES)})")
    algo = match["algo"] or HE
    k = int(match["k"]) if match["k"] else None
    if algo in GOAL_SPACE_ALGOS and k is None:
        raise ValueError(f"preset name {name!r}: {algo}'s names give the number of levels (-kK)")
    if algo not in GOAL_SPACE_ALGOS and k is not None:
        raise ValueError(f"preset name {name!r}: {algo}'s skills have no levels, so its names carry no -kK")
    if algo == "gcrl" and k != 1:
        raise ValueError(f"preset name {name!r}: GCRL has one level (-k1)")
    _check_size(match["domain"], match["size"], algo, f"preset name {name!r}")
    return PresetName(algo, match["domain"], k, match["size"])


def parse_task_name(name: str) -> TaskName:
    """The parts of a phase-2 task's name; ValueError for a name outside the grammar
    ``reach-DOMAIN[-kK][-SIZE][-VARIANT]`` (the module's docstring)."""
    match = _TASK.fullmatch(name)
    if match is None:
        raise ValueError(f"task name {name!r} is not {TASK_PREFIX}DOMAIN[-kK][-SIZE][-VARIANT]")
    domain, size, variant = match["domain"], match["size"], match["variant"]
    k = int(match["k"]) if match["k"] else None
    what = f"task name {name!r}"
    _check_size(domain, size, HE, what)
    if size in (*PAPER_FIELD_SIZES, PAPER_CAGE_SIZE) and k is None:
        raise ValueError(f"{what}: a Table-2 task names its Table-1 row's levels (-kK)")
    if size not in (*PAPER_FIELD_SIZES, PAPER_CAGE_SIZE) and k is not None:
        raise ValueError(f"{what}: only a Table-2 task names levels; the others serve every depth")
    if size == GPU:
        raise ValueError(f"{what}: a gpu-size run's task is its domain's Table-2 task")
    if variant is not None and domain != POINT_MASS:
        raise ValueError(f"{what}: only the point mass's tasks have variants {list(POINT_MASS_VARIANTS)}")
    return TaskName(domain, k, size, variant)


def size_of_envs(num_envs: int) -> str:
    """``cpu`` or ``gpu``: the scale of a config that collects with ``num_envs`` environments."""
    return CPU if num_envs <= CPU_MAX_ENVS else GPU


def _is_paper(name: PresetName) -> bool:
    """Whether a name is one of the paper's Table-1 configs."""
    return name.size in (*PAPER_FIELD_SIZES, PAPER_CAGE_SIZE)


def _order(name: PresetName) -> tuple:
    """Where a name sorts in the listing: by algorithm, domain, levels, then size."""
    algos = (HE, *ALGOS)
    return (algos.index(name.algo), DOMAINS.index(name.domain), name.k or 0,
            SIZES.index(name.size) if name.size else -1)


def _size_first(name: PresetName) -> tuple:
    """A baseline's place on its line: the point mass, then each size's domains."""
    return (SIZES.index(name.size) if name.size else -1, DOMAINS.index(name.domain))


def recommended_names(presets: Iterable[str]) -> list[str]:
    """HE's presets that are not Table-1 configs (the recommended recipes), in listing order."""
    parsed = sorted((parse_preset_name(name) for name in presets), key=_order)
    return [str(name) for name in parsed if name.algo == HE and not _is_paper(name)]


def wrap_names(names: Iterable[str], width: int, indent: str = "  ") -> list[str]:
    """Names two spaces apart on lines of at most ``width`` characters (a longer name gets its own)."""
    lines: list[str] = []
    line = ""
    for name in names:
        if line and len(indent) + len(line) + 2 + len(name) > width:
            lines.append(indent + line)
            line = ""
        line = f"{line}  {name}" if line else name
    if line:
        lines.append(indent + line)
    return lines


def _task_group(name: str) -> int:
    """Where a task sorts in the listing: the point mass's, the CPU tasks, then Table 2's."""
    parsed = parse_task_name(name)
    return 0 if parsed.domain == POINT_MASS else 1 if parsed.size == CPU else 2


def listing_lines(presets: Iterable[str], tasks: Iterable[str], width: int = 100) -> list[str]:
    """What ``mjx-emp presets`` prints: the grammar, the recommended HE recipes (one line per
    domain and depth, cpu beside gpu), the paper's Table-1 configs, the baselines (one line
    per algorithm) and the phase-2 tasks; recommended first."""
    parsed = sorted((parse_preset_name(name) for name in presets), key=_order)
    he = [name for name in parsed if name.algo == HE]
    column = max((len(str(name)) for name in he if name.size == CPU), default=0) + 4
    lines = [
        "names: [ALGO-]DOMAIN[-kK][-SIZE] (no ALGO: Hierarchical Empowerment; K: levels; SIZE: cpu, gpu or paper-*)",
        "recommended, Hierarchical Empowerment (mjx-emp train NAME):",
        f"  {'cpu: 16 environments':{column}s}gpu: 4096 environments, minibatches of 1024",
    ]
    for domain in DOMAINS:
        for k in sorted({name.k for name in he if name.domain == domain and not _is_paper(name)}):
            row = {name.size: str(name) for name in he if (name.domain, name.k) == (domain, k) and not _is_paper(name)}
            if None in row:
                lines.append(f"  {row[None]:{column}s}(one size)")
            else:
                lines.append(f"  {row.get(CPU, '-'):{column}s}{row.get(GPU, '-')}".rstrip())
    lines.append("the paper's Table 1 (4096 environments, the paper's values):")
    lines += wrap_names((str(name) for name in he if _is_paper(name)), width)
    lines.append("baselines (gcrl: HE's learner with a hand-set goal box; the others: flat skill learners):")
    for algo in ALGOS:
        names = [str(name) for name in sorted(parsed, key=_size_first) if name.algo == algo]
        if names:
            lines.append(f"  {algo:6s} " + "  ".join(names))
    lines.append("phase 2 tasks (mjx-emp phase2 [TASK] RUN_DIR; without TASK, the run's own):")
    tasks = list(tasks)
    for group in range(3):
        lines += wrap_names((name for name in tasks if _task_group(name) == group), width)
    lines.append("mjx-emp train NAME --help shows a preset's fields; docs/presets.md describes each")
    return lines


def close_names(name: str, known: Iterable[str]) -> list[str]:
    """The known names closest to a misspelt one (at most three)."""
    return difflib.get_close_matches(name, list(known), n=3, cutoff=0.6)


def unknown_preset(name: str, known: Iterable[str], usage: str, retired: dict | None = None) -> ConfigError:
    """The error for a preset name that does not exist: for a name in ``retired`` (name ->
    :class:`~mjx_emp.algos.retired.Retired`), the command that gives its config; else the closest names."""
    if retired and name in retired:
        return ConfigError(f"preset: {name!r} left the catalogue; its config is "
                           f"`{usage.replace('PRESET', retired[name].command)}`")
    known = list(known)
    closest = close_names(name, known)
    hint = f"did you mean {', '.join(closest)}? " if closest else ""
    return ConfigError(f"preset: {name!r} is unknown ({usage}); {hint}`mjx-emp presets` lists all {len(known)}")
