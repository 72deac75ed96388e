"""Skill-learning algorithms by name: each a config type, its check, presets and agent.

A run directory's ``config.json`` records the algorithm beside the config's fields
(``"algorithm": "he"``; a file without the key is from before the registry and is HE), so
the run layer can rebuild any algorithm's agent from a run directory. An agent is what
:class:`Agent` describes: the run loop, checkpoints and reports need nothing else.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from mjx_emp.algos.he.config import SHARD_SPLIT as HE_SHARD_SPLIT
from mjx_emp.algos.he.config import (
    GcrlConfig,
    HEConfig,
    check_gcrl_config,
    check_train_config,
)
from mjx_emp.algos.he.presets import GCRL_PRESETS
from mjx_emp.algos.he.presets import PRESETS as HE_PRESETS
from mjx_emp.algos.retired import REDEFINED, RETIRED
from mjx_emp.algos.skills.config import SHARD_SPLIT as SKILL_SHARD_SPLIT
from mjx_emp.algos.skills.config import (
    DadsConfig,
    DiaynConfig,
    HidioConfig,
    MetraConfig,
    check_skill_config,
)
from mjx_emp.algos.skills.presets import PRESETS as SKILL_PRESETS
from mjx_emp.checks import config_from_dict, shard_config
from mjx_emp.errors import ConfigError

ALGORITHM_KEY = "algorithm"
"""The key of config.json that names the algorithm."""

GOAL_SPACES = "goal_spaces"
"""Skills of a learnt goal space: per level a box of goals and a goal-conditioned policy. Agents
of this kind also offer ``goal_spaces``, ``evaluate``, ``skill_chain`` and ``skill_paths`` (see
:class:`mjx_emp.algos.he.agent.HEAgent`); phase 2 commands them with subgoals."""
LATENT_SKILLS = "latent"
"""Skills z drawn from a prior, each run for a fixed length. Agents of this kind also offer
``skill_paths``, ``record_skills`` and ``posterior_std`` (see
:class:`mjx_emp.algos.skills.agent.SkillAgent`); phase 2 commands them with z."""
SKILL_KINDS = (GOAL_SPACES, LATENT_SKILLS)


class Agent(Protocol):
    """The static side of an algorithm for one config: pure functions over its state pytree."""

    cfg: Any

    def init(self, key: Any = None) -> Any:
        """A fresh state (parameters, buffers, keys, counters) for ``cfg``."""

    def train_epoch(self, state: Any) -> tuple[Any, Any]:
        """One epoch as one jitted call: (new state, per-item stats)."""

    def metrics(self, state: Any, stats: Any, seconds: float) -> dict[str, Any]:
        """One JSON-ready line of an epoch's metrics."""

    def divergence(self, state: Any, stats: Any) -> str | None:
        """Why this epoch must not be kept (a non-finite loss or parameter), or None."""

    def describe(self, metrics: dict) -> str:
        """A short human-readable summary of an epoch's metrics."""


@dataclasses.dataclass(frozen=True)
class Algorithm:
    """One algorithm: its name, config dataclass, config check, presets and agent builder.

    ``make_agent`` imports JAX when called; everything else is plain Python, so the CLI
    can list presets and reject bad configs before anything compiles.
    """

    name: str
    config_type: type
    check: Callable[[Any], None]
    presets: Mapping[str, tuple[str, Any]]
    make_agent: Callable[[Any, tuple[str, ...]], Agent]
    """(one shard's config, the axes its shards run along) -> agent."""
    shard_split: tuple[str, ...]
    """The config fields a shard of a split run takes its part of."""
    skills: str
    """What its skills are (one of :data:`SKILL_KINDS`): what eval, plot, render and phase 2 ask of
    an algorithm, so that none of them looks at its name or type."""
    hand_set_box: str | None = None
    """The config field that holds a goal box the user sets by hand (half-widths per goal
    dimension), for an algorithm whose top goal space is fixed rather than learned; None
    where there is none. Box sweeps ask for this field instead of an algorithm's name."""
    rebuilt_fields: tuple[str, ...] = ()
    """Fields of its train state that training refills as it goes (replays, the environments
    mid-episode) and that phase 2, eval, plot and render never read: a skills export
    (`mjx-emp export`) leaves them out, which makes it a fraction of a checkpoint's size."""
    run_dir_prefix: str | None = None
    """How its fresh run directories' names begin, before <env>-k<k>-<date>-<time> (None: its
    name; empty: nothing, for the library's own method)."""

    def __post_init__(self):
        if self.skills not in SKILL_KINDS:
            raise ValueError(f"skills: {self.skills!r} is unknown; allowed values: {list(SKILL_KINDS)}")


def _he_agent(cfg: HEConfig, shard_axes: tuple[str, ...]) -> Agent:
    from mjx_emp.algos.he.agent import (
        HEAgent,  # deferred: JAX loads only when an agent is built
    )

    return HEAgent(cfg, shard_axes)


def _skill_agent(cfg: Any, shard_axes: tuple[str, ...]) -> Agent:
    from mjx_emp.algos.skills.agent import (
        SkillAgent,  # deferred: JAX loads only when an agent is built
    )

    return SkillAgent(cfg, shard_axes)


def _skill_algorithm(name: str, config_type: type) -> Algorithm:
    presets = {preset: entry for preset, entry in SKILL_PRESETS.items() if preset.startswith(f"{name}-")}
    return Algorithm(name, config_type, check_skill_config, presets, _skill_agent, SKILL_SHARD_SPLIT, LATENT_SKILLS,
                     rebuilt_fields=SKILL_REBUILT_FIELDS)


HE_REBUILT_FIELDS = ("replay", "goal_space_replay", "chain")
"""HEState's replays and its start chain's environments; its start buffers stay (eval starts there)."""
SKILL_REBUILT_FIELDS = ("replay", "rollout")
"""SkillState's replay and its environments mid-skill."""

ALGORITHMS: dict[str, Algorithm] = {
    "he": Algorithm("he", HEConfig, check_train_config, HE_PRESETS, _he_agent, HE_SHARD_SPLIT, GOAL_SPACES,
                    rebuilt_fields=HE_REBUILT_FIELDS, run_dir_prefix=""),
    "gcrl": Algorithm("gcrl", GcrlConfig, check_gcrl_config, GCRL_PRESETS, _he_agent, HE_SHARD_SPLIT, GOAL_SPACES,
                      hand_set_box="goal_half_width", rebuilt_fields=HE_REBUILT_FIELDS),
    "diayn": _skill_algorithm("diayn", DiaynConfig),
    "hidio": _skill_algorithm("hidio", HidioConfig),
    "dads": _skill_algorithm("dads", DadsConfig),
    "metra": _skill_algorithm("metra", MetraConfig),
}


def algorithm_of(cfg: Any) -> Algorithm:
    """The algorithm whose config type ``cfg`` is."""
    for algorithm in ALGORITHMS.values():
        if type(cfg) is algorithm.config_type:
            return algorithm
    raise ConfigError(f"config: a {type(cfg).__name__} belongs to no algorithm; known: {sorted(ALGORITHMS)}")


def skill_kind(cfg: Any) -> str:
    """What the skills of ``cfg``'s algorithm are: one of :data:`SKILL_KINDS`."""
    return algorithm_of(cfg).skills


def config_to_json(cfg: Any) -> dict[str, Any]:
    """The JSON form of a config as config.json stores it: the algorithm's name, then the fields."""
    return {ALGORITHM_KEY: algorithm_of(cfg).name, **dataclasses.asdict(cfg)}


def config_from_json(values: dict[str, Any]) -> Any:
    """A config back from config.json's form (without the algorithm key: HE, as older runs)."""
    values = dict(values)
    name = values.pop(ALGORITHM_KEY, "he")
    if name not in ALGORITHMS:
        raise ConfigError(f"{ALGORITHM_KEY}: {name!r} is unknown; allowed values: {sorted(ALGORITHMS)}")
    return config_from_dict(values, ALGORITHMS[name].config_type)


def make_agent(cfg: Any, shard_axes: tuple[str, ...] = ()) -> Agent:
    """Check ``cfg`` and build its algorithm's agent: for a run split into shards, the agent
    of one shard (:func:`shard_config`), whose collectives run along ``shard_axes`` when the
    shards train together (empty: on its own, e.g. to evaluate a shard's state)."""
    algorithm = algorithm_of(cfg)
    algorithm.check(cfg)
    return algorithm.make_agent(shard_config(cfg, algorithm.shard_split), tuple(shard_axes))


def all_presets() -> dict[str, tuple[str, Any]]:
    """Every algorithm's presets by name: (description, config)."""
    presets: dict[str, tuple[str, Any]] = {}
    for algorithm in ALGORITHMS.values():
        clash = sorted(set(presets) & set(algorithm.presets))
        if clash:
            raise ValueError(f"preset names used by two algorithms: {clash}")
        presets.update(algorithm.presets)
    return presets


def retired_config(name: str) -> Any:
    """The config a retired preset name stood for (:data:`mjx_emp.algos.retired.RETIRED`), or
    the former config of a name the catalogue gave to another (``REDEFINED``): rows recorded
    under an old name are read with this."""
    entry = RETIRED.get(name) or REDEFINED.get(name)
    if entry is None:
        raise KeyError(f"{name!r} is neither a retired nor a redefined preset name")
    return entry.apply(all_presets()[entry.preset][1])


def preset_or_retired_config(name: str) -> Any:
    """A preset's config by name: the catalogue's, else the retired name's (:func:`retired_config`)."""
    presets = all_presets()
    return presets[name][1] if name in presets else retired_config(name)
