"""The library from Python: presets, training with a progress callback, loading a run, greedy policies.

Everything here goes through the same run layer as the ``mjx-emp`` command, so a run trained
from a notebook is a run directory like any other (config.json, metrics.jsonl, checkpoints)
that ``mjx-emp eval``, ``plot``, ``render`` and ``resume`` accept, and the other way round.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mjx_emp.algos.registry import GOAL_SPACES, algorithm_of, all_presets, skill_kind
from mjx_emp.checks import config_from_dict
from mjx_emp.commands import ExportExperiment, TrainExperiment
from mjx_emp.errors import ConfigError
from mjx_emp.metrics import AGENT_FIELDS
from mjx_emp.run import jobs, store
from mjx_emp.run.evaluate import evaluation_row
from mjx_emp.run.sweep import sweep as run_sweep


def one_schema(line: dict, algorithm: str) -> dict:
    """An epoch's metrics line in the schema every algorithm shares: the epoch fields, the
    algorithm's name and ``levels``, one dict per level (an algorithm without levels, such as
    METRA, has one: level 0 with every other field of its line)."""
    if "levels" in line:
        return {**line, "algorithm": algorithm}
    epoch = {name: line[name] for name in AGENT_FIELDS if name in line}
    level = {"level": 0, **{name: value for name, value in line.items() if name not in epoch and name != "algorithm"}}
    return {**epoch, "algorithm": algorithm, "levels": [level]}


@dataclasses.dataclass(frozen=True)
class Run:
    """A run directory's agent (pure functions of the algorithm), its newest state, that state's
    epoch, the per-epoch metrics written so far and the directory."""

    agent: Any
    state: Any
    epoch: int
    metrics: list[dict]
    """One line per epoch, in the schema of :func:`one_schema` (metrics.jsonl holds them as written)."""
    run_dir: Path

    @property
    def config(self) -> Any:
        """The run's config dataclass."""
        return self.agent.cfg

    @property
    def algorithm(self) -> str:
        """The registry name of the run's algorithm (he, gcrl, diayn, hidio, dads, metra)."""
        return algorithm_of(self.agent.cfg).name

    @property
    def skills(self) -> str:
        """What the skills are: ``registry.GOAL_SPACES`` or ``registry.LATENT_SKILLS``."""
        return skill_kind(self.agent.cfg)

    def greedy_policy(self, level: int = 0) -> Callable[..., Any]:
        """The greedy policy over a batch. Goal spaces (HE, GCRL): (obs, goal) -> action of
        ``level`` (a primitive action at 0, a subgoal offset above). Latent skills: (obs, s0,
        skill) -> primitive action, ``s0`` the observation where the skill began."""
        if self.skills == GOAL_SPACES:
            return self.agent.greedy_policy(self.state, level)
        if level != 0:
            raise ConfigError(f"level: {self.algorithm} has one level of skills; got {level}")
        return self.agent.greedy_policy(self.state)


def presets() -> dict[str, Any]:
    """Every preset of every algorithm by name: its config (``mjx-emp presets`` lists them too)."""
    return {name: cfg for name, (_, cfg) in all_presets().items()}


def config(preset: str, **changes: Any) -> Any:
    """PRESET's config with the named fields replaced, e.g. ``config("point-mass-k1", epochs=5)``."""
    known = presets()
    if preset not in known:
        raise ConfigError(f"preset: {preset!r} is unknown; allowed values: {sorted(known)}")
    base = known[preset]
    cfg = config_from_dict({**dataclasses.asdict(base), **changes}, type(base))
    algorithm_of(cfg).check(cfg)
    return cfg


def train(cfg: Any, run_dir: str | Path = "", *, on_epoch: Callable[[dict], None] | None = None,
          keep_checkpoints: int = 3) -> Run:
    """Train a new run of ``cfg`` (a config, or a preset name) in ``run_dir`` (empty: a fresh
    runs/... name), handing each epoch's metrics line (:func:`one_schema`) to ``on_epoch``;
    returns the finished run.

    The run is written and checkpointed as ``mjx-emp train`` writes it; a config error raises
    :class:`~mjx_emp.errors.ConfigError` before anything is written.
    """
    if isinstance(cfg, str):
        cfg = config(cfg)
    run_dir = str(run_dir) or store.default_run_dir(cfg)
    name = algorithm_of(cfg).name
    report = None if on_epoch is None else (lambda line: on_epoch(one_schema(line, name)))
    jobs.train(TrainExperiment(config=cfg, run_dir=run_dir, keep_checkpoints=keep_checkpoints), on_epoch=report)
    return load(run_dir)


def load(run_dir: str | Path, epoch: int | None = None) -> Run:
    """A run directory's agent and its newest good checkpoint (or ``epoch``'s), with its metrics."""
    run_dir = Path(run_dir)
    agent, restored, state = jobs.load_run(run_dir, epoch=epoch)
    name = algorithm_of(agent.cfg).name
    return Run(agent, state, restored, [one_schema(line, name) for line in store.read_metrics(run_dir)], run_dir)


def export(run_dir: str | Path, out: str | Path, epoch: int | None = None) -> Path:
    """Write ``run_dir``'s skills without its replays to ``out`` (as ``mjx-emp export`` does), a
    small run directory that :func:`load`, phase 2, eval, plot and render read; returns ``out``."""
    written, _ = jobs.export_skills(ExportExperiment(str(run_dir), str(out), -1 if epoch is None else epoch))
    return written


def evaluate(run_dir: str | Path, seed: int = 0, episodes: int = 400) -> dict:
    """A run's evaluation row, as `mjx-emp eval` and `mjx-emp sweep` write it (figures of phase 1
    and phase 2 from the key ``jax.random.key(seed)``, curves, provenance; docs/sweeps.md)."""
    return evaluation_row(Path(run_dir), seed, episodes)


def sweep(spec: str | Path, runs: str | Path = "", results: str | Path = "", workers: int = 1) -> list[dict]:
    """Run a sweep spec as `mjx-emp sweep` does (train, resume and evaluate what is not done);
    returns the rows this call appended to the spec's results file."""
    return run_sweep(str(spec), str(runs), str(results), workers)
