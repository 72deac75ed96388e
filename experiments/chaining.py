"""The chaining diagnostic: does phase 2 fall short of its skills, or do the skills fall short of the task?

For each given phase-1 run: trains phase 2 on its skills with the domain's preset (as `mjx-emp
phase2 RUN_DIR` does; resumed or kept where it is there), then evaluates on the same 400 goals
of the phase-2 region three policies on top of the frozen skills: the learned phase-2 policy,
the scripted ``aimed`` policy (each subgoal straight at the goal, clipped into the top goal
space at s) and ``random`` subgoals in that box. The aimed figure bounds what the skills do
without learning above them; a learned policy far behind it says phase 2 learns too little.
Rows (run, preset, phase-1 env steps, top box, the three policies' mean minimum distance,
success, fraction of episodes a flip ended early and mean minimum distance over the episodes
none ended, and the learned and aimed policies' episodes attempt by attempt: progress toward
the goal, and whether the robot ended on its back) are merged into ``--out``.

    python experiments/chaining.py --runs runs/ant-s0 runs/ant-s1
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import tyro
from baselines import merge_row, train_phase2

from mjx_emp.metrics import PHASE2_DIAGNOSTICS, PHASE2_FIGURES
from mjx_emp.run import jobs, store
from mjx_emp.run.evaluate import attempt_figures, phase2_figures


@dataclasses.dataclass
class Args:
    """Phase-1 runs whose skills are chained toward goals by learned and scripted policies."""

    runs: tuple[str, ...] = ()
    name: str = ""
    """The rows' ``variant`` (e.g. the preset the runs were trained with); empty: each run's directory name."""
    episodes: int = 400
    train: bool = True
    """Train (or resume) phase 2 first; False evaluates the phase-2 directories as they are."""
    learn_from_resets: bool = False
    """Phase 2 keeps the attempts a flip ended (``Phase2Config.learn_from_resets``)."""
    aim_prior: bool = False
    """Phase 2 starts as the aimed policy and learns a correction (``Phase2Config.aim_prior``)."""
    aim_weight: float = 0.0
    """With ``aim_prior``, the actor's cost of leaving it (``Phase2Config.aim_weight``)."""
    out: str = "benchmarks/results/chaining_cpu.json"


OPTION_TAGS = {"learn_from_resets": "resets", "aim_prior": "aim", "aim_weight": "w"}
"""Phase-2 options beyond the domain's preset, and the tag each adds (a number follows the tag of
a number): phase 2 with options is trained into RUN_DIR/phase2-<tag>[-<tag>] and its rows'
variant ends in +<tag>[+<tag>]."""


def options_of(args: Args) -> dict:
    """The phase-2 options ``args`` sets away from the preset's (off, 0), as config changes."""
    return {name: getattr(args, name) for name in OPTION_TAGS if getattr(args, name)}


def option_tag(name: str, value) -> str:
    """One option's tag: ``resets``, ``aim``, ``w1``."""
    return OPTION_TAGS[name] + ("" if isinstance(value, bool) else f"{value:g}")


def chaining_row(run_dir: Path, name: str, episodes: int, subdir: str = store.PHASE2_SUBDIR) -> dict:
    """One run's row: its top box and the phase-2 figures (of RUN_DIR/``subdir``) of every policy
    on the same goals."""
    agent, epoch, state = jobs.load_run(run_dir)
    top = agent.goal_spaces(state)[-1]
    trainer, phase2_epoch, phase2_state = jobs.load_phase2(run_dir / subdir)
    figures = phase2_figures(trainer, phase2_epoch, phase2_state, jax.random.key(7), episodes)
    attempts = {policy: attempt_figures(dataclasses.replace(trainer, top=policy), phase2_state, jax.random.key(8))
                for policy in ("learned", "aimed")}
    policies = {"learned": figures, **{p: figures[p] for p in PHASE2_DIAGNOSTICS if p in figures}}
    return {"variant": name or run_dir.name, "run_dir": str(run_dir), "env": agent.cfg.env, "k": agent.cfg.k,
            "seed": agent.cfg.seed, "phase1_epoch": epoch, "phase1_env_steps": float(state.env_steps.value()),
            "top_volume": top["volume"], "phase2_epoch": figures["epoch"], "region": figures["region"],
            "eps": figures["eps"], "attempts": figures["n"],
            **{f"{p}_{k}": v[k] for p, v in policies.items() for k in PHASE2_FIGURES},
            "per_attempt": attempts}


def main(args: Args) -> None:
    if not args.runs:
        raise SystemExit("runs: give at least one phase-1 run directory")
    changes = options_of(args)
    tags = [option_tag(name, value) for name, value in changes.items()]
    subdir = "-".join([store.PHASE2_SUBDIR, *tags])
    for run in map(Path, args.runs):
        if args.train:
            train_phase2(run, subdir, **changes)
        row = chaining_row(run, args.name, args.episodes, subdir)
        row["variant"] += "".join(f"+{tag}" for tag in tags)
        print(row, flush=True)
        merge_row(Path(args.out), row, key=("variant", "run_dir"))


if __name__ == "__main__":
    main(tyro.cli(Args))
