"""The paper's Table 1 and 2 at their real shapes, without a GPU: what each preset needs in memory.

For every Table-1 phase-1 preset and every phase-2 preset whose skills are a Table-1 preset:
the train state's exact bytes (``jax.eval_shape`` of its ``init``, nothing allocated), the
preflight's estimate of one epoch's working set, and whether their sum fits the planning
share (the preflight's HEADROOM) of an 80 GB and a 141 GB GPU. ``--epoch PRESET`` also runs
one real epoch of a phase-1 preset at its full shape on this machine and reports compile
and epoch time, peak resident memory and the metrics line (on a 2-core CPU this takes long:
4096 environments); ``--phase2-epoch PRESET`` does the same for a phase-2 preset. Prints a
Markdown table and appends one row per preset, compiled epoch (``compiled_epochs/PRESET``) and
real epoch (``full_shape_epochs/PRESET``) to ``results/bench-paper-shapes.jsonl`` (``--results``).

    python benchmarks/paper_shapes.py
    python benchmarks/paper_shapes.py --epoch ant-field-k1-paper-small --phase2-epoch reach-ant-field-k1-paper-small
"""

from __future__ import annotations

import dataclasses
import resource
import sys
import time
from pathlib import Path
from typing import Any, Callable

import jax
import tyro

from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.algos.names import parse_preset_name
from mjx_emp.algos.registry import make_agent
from mjx_emp.phase2.build import make_phase2_trainer
from mjx_emp.phase2.presets import PHASE2_PRESETS
from mjx_emp.run.preflight import HEADROOM, state_bytes, tree_bytes, working_set_bytes
from mjx_emp.run.rows import append_row, benchmark_row

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import RowNames  # noqa: E402

SPEC = "bench-paper-shapes"

GPUS = {"80 GB": 80e9, "141 GB": 141e9}
"""Device memories the shapes are held against (an A100/H100 80 GB; an H200)."""


@dataclasses.dataclass
class Args:
    """Memory of the paper-scale presets, and optionally one full-shape epoch."""

    compile: tuple[str, ...] = ("ant-field-k1-paper-small", "half-cheetah-field-k1-paper-small")
    """Phase-1 presets whose epoch is compiled at full shape (nothing runs): compile time and
    XLA's own memory figures for the program (arguments, outputs, temporaries)."""
    epoch: tuple[str, ...] = ()
    """Phase-1 presets to run one real epoch of at full shape (e.g. ant-field-k1-paper-small)."""
    phase2_epoch: tuple[str, ...] = ()
    """Phase-2 presets to run one real epoch of at full shape, over freshly initialised (untrained)
    skills of their phase-1 preset: the shapes and the work are a trained run's."""
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""


def fits(state: int, work: int) -> dict[str, bool]:
    """Whether state plus working set stays within the preflight's share of each GPU's memory."""
    return {name: state + work <= HEADROOM * size for name, size in GPUS.items()}


def phase1_row(name: str) -> dict:
    """A Table-1 preset's state bytes, working-set estimate and fit."""
    cfg = PRESETS[name][1]
    agent = make_agent(cfg)
    state, work = state_bytes(agent), working_set_bytes(cfg, agent.env)
    return {"preset": name, "phase": 1, "env": cfg.env, "k": cfg.k, "num_envs": cfg.num_envs,
            "replay_capacity": cfg.replay_capacity, "state_bytes": state, "working_set_bytes": work,
            "fits": fits(state, work)}


def phase2_row(name: str) -> dict:
    """A Table-2 phase-2 preset's bytes over its phase-1 preset's skills (the frozen skills'
    state included, as the phase-2 trainer holds it)."""
    _, phase1, cfg = PHASE2_PRESETS[name]
    trainer = make_phase2_trainer(make_agent(PRESETS[phase1][1]), cfg)
    shapes = jax.eval_shape(trainer.init, jax.eval_shape(trainer.phase1.init))
    state = tree_bytes(shapes)
    work = working_set_bytes(cfg, trainer.phase1.env)
    return {"preset": name, "phase": 2, "skills": phase1, "num_envs": cfg.num_envs, "state_bytes": state,
            "working_set_bytes": work, "fits": fits(state, work)}


def compiled_epoch(name: str) -> dict:
    """A phase-1 preset's epoch compiled at its full shape for this backend, run on nothing:
    compile seconds and the compiled program's memory (XLA's memory analysis), the figure the
    preflight's working-set estimate stands in for."""
    agent = make_agent(PRESETS[name][1])
    shapes = jax.eval_shape(agent.init)
    start = time.perf_counter()
    compiled = jax.jit(agent.train_epoch).lower(shapes).compile()
    seconds = time.perf_counter() - start
    memory = compiled.memory_analysis()
    figures = {field: int(getattr(memory, f"{field}_in_bytes")) for field in
               ("argument_size", "output_size", "alias_size", "temp_size", "generated_code_size")} if memory else {}
    return {"preset": name, "compile_s": seconds, "memory": figures,
            "preflight_state_bytes": state_bytes(agent),
            "preflight_working_set_bytes": working_set_bytes(agent.cfg, agent.env)}


def one_timed_epoch(init: Callable[[], Any], learner: Any) -> dict:
    """``init`` and then one ``learner.train_epoch``, each timed to completion (the epoch's time
    includes its compilation): seconds, peak resident memory and the epoch's metrics line."""
    start = time.perf_counter()
    state = jax.block_until_ready(init())
    init_s = time.perf_counter() - start
    start = time.perf_counter()
    state, stats = learner.train_epoch(state)
    jax.block_until_ready(state)
    epoch_s = time.perf_counter() - start
    return {"init_s": init_s, "first_epoch_s": epoch_s,
            "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
            "metrics": learner.metrics(state, stats, epoch_s)}


def full_shape_epoch(name: str) -> dict:
    """One real epoch of a phase-1 preset at its full shape (:func:`one_timed_epoch`)."""
    agent = make_agent(dataclasses.replace(PRESETS[name][1], epochs=1))
    timed = one_timed_epoch(agent.init, agent)
    return {"preset": name, "phase": 1, **timed, "env_steps": timed["metrics"]["env_steps"]}


def full_shape_phase2_epoch(name: str) -> dict:
    """One real phase-2 epoch of a preset at its full shape (:func:`one_timed_epoch`), over its
    phase-1 preset's skills as ``init`` makes them: phase 2 freezes them, so their values
    change nothing it computes or allocates."""
    _, phase1, cfg = PHASE2_PRESETS[name]
    trainer = make_phase2_trainer(make_agent(PRESETS[phase1][1]), dataclasses.replace(cfg, epochs=1))
    return {"preset": name, "phase": 2, "skills": phase1,
            **one_timed_epoch(lambda: trainer.init(trainer.phase1.init()), trainer)}


def gib(count: float) -> str:
    return f"{count / 2**30:.3g}"


def main(args: Args) -> None:
    table1 = [name for name in PRESETS if (parse_preset_name(name).size or "").startswith("paper")]
    table2 = [name for name, (_, phase1, _) in PHASE2_PRESETS.items() if phase1 in table1]
    names = RowNames()

    def stored(record: dict, group: str = "") -> dict:
        """``record``, appended as a row (with the preflight's headroom and the GPUs it is held against)."""
        figures = {**record, "headroom": HEADROOM, "gpus": GPUS}
        append_row(Path(args.results), benchmark_row(SPEC, names(record, group), figures, preset=record["preset"],
                                                     env_steps=record.get("env_steps")))
        return record

    rows = []
    for name in table1:
        rows.append(stored(phase1_row(name)))
        print(f"{name}: {gib(rows[-1]['state_bytes'])} GiB state", flush=True)
    for name in table2:
        rows.append(stored(phase2_row(name)))
        print(f"{name} (phase 2): {gib(rows[-1]['state_bytes'])} GiB state", flush=True)
    compiled = [stored(compiled_epoch(name), "compiled_epochs") for name in args.compile]
    epochs = [stored(full_shape_epoch(name), "full_shape_epochs") for name in args.epoch]
    epochs += [stored(full_shape_phase2_epoch(name), "full_shape_epochs") for name in args.phase2_epoch]
    print("\n| preset | phase | envs | state (GiB) | epoch working set (GiB) | fits 80 GB | fits 141 GB |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['preset']} | {r['phase']} | {r['num_envs']} | {gib(r['state_bytes'])} | "
              f"{gib(r['working_set_bytes'])} | {'yes' if r['fits']['80 GB'] else 'no'} | "
              f"{'yes' if r['fits']['141 GB'] else 'no'} |")
    for c in compiled:
        m = c["memory"]
        print(f"{c['preset']} epoch compiled at full shape in {c['compile_s']:.0f} s: arguments "
              f"{gib(m.get('argument_size', 0))} GiB, temporaries {gib(m.get('temp_size', 0))} GiB (preflight: state "
              f"{gib(c['preflight_state_bytes'])}, working set {gib(c['preflight_working_set_bytes'])} GiB)")
    for e in epochs:
        print(f"{e['preset']} (phase {e['phase']}): init {e['init_s']:.0f} s, first epoch {e['first_epoch_s']:.0f} s, "
              f"peak RSS {gib(e['peak_rss_bytes'])} GiB")
    print(f"appended {len(rows) + len(compiled) + len(epochs)} rows to {args.results}")


if __name__ == "__main__":
    main(tyro.cli(Args))
