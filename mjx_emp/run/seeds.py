"""Several seeds of one config trained as one program: `mjx-emp train PRESET --seeds 0 1 2 3`.

Every agent is pure functions over a pytree, so the train states of S seeds stack on a
leading seed axis and one ``jax.vmap`` of the agent's epoch trains them all in a single
compiled program (one compile; the batched work of S seeds per kernel instead of S
programs one after another). Each seed still gets its own run directory, config (with its
own ``seed``), metrics and checkpoints, so it resumes, evaluates and plots on its own.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from mjx_emp.algos.registry import make_agent
from mjx_emp.commands import TrainExperiment
from mjx_emp.run import loop, store
from mjx_emp.run.checkpoint import Checkpoints
from mjx_emp.run.provenance import run_record


@dataclasses.dataclass(frozen=True)
class SeedGroup:
    """The agent of one config (any seed's: the seed only picks the initial key) and the
    seeds trained together. A static jit argument: hashes by the agent and the seeds."""

    agent: Any
    seeds: tuple[int, ...]

    def init(self) -> Any:
        """Each seed's fresh state, stacked: seed i's slice is ``agent.init(key(seeds[i]))``,
        i.e. the state a run of that seed alone starts from."""
        keys = jnp.stack([jax.random.key(seed) for seed in self.seeds])
        return _jit_group_init(self, keys)

    def train_epoch(self, state: Any) -> tuple[Any, Any]:
        """One epoch of every seed, as one jitted vmap of the agent's epoch."""
        return _jit_group_epoch(self, state)

    def split(self, state: Any, stats: Any) -> list[tuple[Any, Any]]:
        """Each seed's (state, stats) slice, in ``seeds`` order (stats may be None)."""
        return [(seed_slice(state, i), None if stats is None else seed_slice(stats, i))
                for i in range(len(self.seeds))]


def seed_slice(tree: Any, index: int) -> Any:
    """Seed ``index``'s part of a pytree stacked on a leading seed axis."""
    return jax.tree.map(lambda x: x[index], tree)


@functools.partial(jax.jit, static_argnums=0)
def _jit_group_init(group: SeedGroup, keys: jax.Array) -> Any:
    return jax.vmap(group.agent.init)(keys)


@functools.partial(jax.jit, static_argnums=0, donate_argnums=1)
def _jit_group_epoch(group: SeedGroup, state: Any) -> tuple[Any, Any]:
    return jax.vmap(group.agent.train_epoch)(state)


def train_seeds(exp: TrainExperiment, record: dict | None = None) -> Any:
    """Train ``exp.seeds`` of ``exp.config`` as one vmapped program, one run directory per
    seed (RUN_DIR-s<seed>), each keeping ``record`` (how it was asked for); returns the stacked
    final state. The request is one that :func:`mjx_emp.commands.check_train` accepted
    (``jobs.train`` checks it); the config is checked as the seeds' agents are built, before
    any directory is made."""
    agents = [make_agent(dataclasses.replace(exp.config, seed=seed)) for seed in exp.seeds]
    base = exp.run_dir or store.default_run_dir(exp.config)
    dirs = [store.fresh_run_dir(path, "run_dir", "a run", "mjx-emp train") for path in store.seed_run_dirs(base, exp.seeds)]
    print(f"run directories: {', '.join(str(d) for d in dirs)}", flush=True)
    together = {"seed_group": [str(d) for d in dirs]}  # a resume continues them together (resume_seeds)
    with contextlib.ExitStack() as locks:
        for agent, run_dir in zip(agents, dirs):
            locks.enter_context(store.run_lock(run_dir, "run_dir"))
            store.write_run_record(run_dir, {**(record or run_record(None, {})), **together})
            store.write_config(run_dir, agent.cfg)
        group = SeedGroup(agents[0], tuple(exp.seeds))
        members = [loop.Member(agent, Path(run_dir)) for agent, run_dir in zip(agents, dirs)]
        with loop.progress_reporter(exp.config.epochs, 0, agents[0].describe) as report:
            return loop.train(group, group.init(), members, exp.keep_checkpoints, (report,), group.split)


def resume_seeds(dirs: list[Path], configs: list[Any], keep_checkpoints: int = 3) -> Any:
    """Continue seeds that trained as one program, as one program again, from the newest epoch
    every seed has a good checkpoint of; returns the stacked final state.

    A kill can land between two seeds' checkpoints of one epoch, so one seed may be an epoch
    ahead: its newer checkpoints are set aside (RUN_DIR/rejected-checkpoints) and its metrics cut
    back, and the group trains that epoch again together. Resuming each seed alone instead would
    run a program of another batch shape, whose floating-point results differ slightly; as a
    group the resumed seeds end where an uninterrupted group would. ``configs`` are the seeds'
    configs (epochs and step budget may differ from the runs' own, as for ``mjx-emp resume``).
    """
    agents = [make_agent(cfg) for cfg in configs]
    group = SeedGroup(agents[0], tuple(cfg.seed for cfg in configs))
    members = [loop.Member(agent, Path(run_dir)) for agent, run_dir in zip(agents, dirs)]
    with contextlib.ExitStack() as locks:
        for run_dir in dirs:
            locks.enter_context(store.run_lock(run_dir, "resume"))
        epoch, states = _restore_common_epoch(members)
        print(f"resuming {', '.join(str(d) for d in dirs)} from epoch {epoch} as one program", flush=True)
        state = jax.tree.map(lambda *leaves: jnp.stack(leaves), *states)
        with loop.progress_reporter(configs[0].epochs, epoch, agents[0].describe) as report:
            return loop.train(group, state, members, keep_checkpoints, (report,), group.split)


def _restore_common_epoch(members: list[loop.Member]) -> tuple[int, list[Any]]:
    """The newest epoch every member has a checkpoint of, and each member's state of it; a
    member's newer checkpoints are set aside and its metrics cut back to that epoch."""
    with contextlib.ExitStack() as stack:
        kept = [stack.enter_context(Checkpoints(member.run_dir)) for member in members]
        epoch = min(checkpoints.epochs()[-1] for checkpoints in kept)
        template = jax.eval_shape(members[0].trainer.init)
        states = []
        for member, checkpoints in zip(members, kept):
            states.append(checkpoints.restore(epoch, template, member.trainer.cfg))
            checkpoints.set_aside_newer_than(epoch)
            store.keep_metrics_through(member.run_dir / store.METRICS_FILE, epoch)
            store.write_config(member.run_dir, member.trainer.cfg)
    return epoch, states


def seed_group_of(run_dir: Path) -> list[Path]:
    """The run directories trained in one program with ``run_dir`` (itself included; just itself
    for a run trained alone), as its provenance records them."""
    group = store.read_run_record(Path(run_dir)).get("seed_group")
    return [Path(d) for d in group] if isinstance(group, list) and len(group) > 1 else [Path(run_dir)]
