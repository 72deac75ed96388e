"""The goal-conditioned learner's options on the Ant, one JSON row per (variant, seed).

Each variant is ``ant-field-cpu-k1`` with some learner options changed (hindsight goals,
LayerNorm, n-step targets, update-to-data ratio). It is trained on the full curriculum
(``curriculum``: the goal space is learnt) or with the goal box held at +-1.5 m around the
start (``fixed-box``: goal-space learning off, the learner alone), to ``--env-steps`` or
the variant's epoch count, then evaluated as `mjx-emp eval` does (400 greedy goals from the
top box at the initial state, coverage cells of 48 greedy skills). Rows carry ``variant``,
``setting``, ``seed``, ``env_steps``, ``wall_s`` (training time summed from the run's
metrics, compile included), ``top_area``, ``success``, ``coverage_cells``, the config and
the per-epoch curve. ``python experiments/learner_ablation.py --variants her ln --seeds 0``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import tyro
from baselines import merge_row
from equal_steps import read_curve_at
from robots_cpu import evaluate_run

from mjx_emp.algos.he.config import HEConfig
from mjx_emp.algos.registry import retired_config
from mjx_emp.commands import ResumeExperiment, TrainExperiment
from mjx_emp.metrics import mean_and_stderr
from mjx_emp.run import jobs, store

ANT_FIELD_CPU_K1 = retired_config("ant-field-cpu-k1")
"""The learner every variant changes: the retired ``ant-field-cpu-k1`` (the model file's one
solver iteration, a plain critic), whose rows the reference curves are."""

LEARNER_OPTIONS: dict[str, dict] = {
    "base": {},
    "her": dict(her=0.5),
    "ln": dict(critic_layer_norm=True),
    "ln-utd2": dict(critic_layer_norm=True, gc_grad_steps=200),
    "nstep3": dict(n_step=3),
    "her-ln": dict(her=0.5, critic_layer_norm=True),
    "her-ln-nstep3": dict(her=0.5, critic_layer_norm=True, n_step=3),
    "iter4": dict(solver_iterations=4),
    "her-ln-nstep3-iter4": dict(her=0.5, critic_layer_norm=True, n_step=3, solver_iterations=4),
    "ln-iter4": dict(critic_layer_norm=True, solver_iterations=4),
}
"""Variant name -> the learner fields it changes in ant-field-cpu-k1 (``iter4``: the physics solver
takes 4 iterations instead of the model file's 1, which flips the Ant less often; ``ln-iter4``
adds a LayerNorm critic, against the goal-conditioned critic's loss growing over long runs)."""

STEPS_PER_EPOCH = 6720
"""Environment steps of one ant-field-cpu-k1 epoch: 16 environments x 20 steps x (10 goal-conditioned,
8 goal-space and 1 evaluation collections, 2 start-chain chunks)."""

FIXED_BOX = dict(init_half_width=(1.5,), gs_actor_lr=1e-9)
"""The fixed-box diagnostic: the goal box starts at +-1.5 m and its actor (almost) does not learn."""


@dataclasses.dataclass
class Args:
    """Learner variants x seeds on the Ant, trained and evaluated alike."""

    variants: tuple[str, ...] = tuple(LEARNER_OPTIONS)
    setting: str = "curriculum"
    """curriculum (the goal space is learnt) or fixed-box (the learner alone on a +-1.5 m box)."""
    seeds: tuple[int, ...] = (0,)
    env_steps: float | None = None
    """Train to about this many environment steps (whole epochs); None keeps the preset's epochs."""
    base: str = "runs/learner_ablation"
    episodes: int = 400
    out: str = "benchmarks/results/learner_ablation_cpu.json"
    report_only: bool = False
    """Train nothing: print the table of the rows in ``--out``."""
    reference: str = "benchmarks/results/robots_cpu.json"
    """Rows of the unchanged preset (``ant-field-cpu-k1``) whose training curves are read at each
    curriculum group's step budget, beside the group's own curves, for an equal-steps comparison."""
    at_epoch: int | None = None
    """Train nothing: evaluate each existing run's checkpoint of this epoch (it must still be
    kept), for runs stopped before their budget."""


def variant_config(variant: str, setting: str, seed: int, env_steps: float | None) -> HEConfig:
    """ant-field-cpu-k1 with VARIANT's learner options, in SETTING, for SEED, sized to ENV_STEPS."""
    if variant not in LEARNER_OPTIONS:
        raise SystemExit(f"variants: {variant!r} is unknown; allowed values: {sorted(LEARNER_OPTIONS)}")
    if setting not in ("curriculum", "fixed-box"):
        raise SystemExit(f"setting: {setting!r} is unknown; allowed values: ['curriculum', 'fixed-box']")
    config = dataclasses.replace(ANT_FIELD_CPU_K1, seed=seed, **LEARNER_OPTIONS[variant],
                                 **(FIXED_BOX if setting == "fixed-box" else {}))
    if env_steps is not None:
        config = dataclasses.replace(config, epochs=math.ceil(env_steps / STEPS_PER_EPOCH))
    return config


def table(rows: list[dict]) -> str:
    """The README's Markdown table of ablation rows: per setting and variant, sorted by budget."""
    lines = ["| setting | variant | options | seed | env steps | wall s | top box (m²) | success | "
             "success from s0 | success from chained starts | flipped | coverage cells |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["setting"], r["env_steps"], r["variant"], r["seed"])):
        top = r["levels"][-1]
        options = ", ".join(f"{k}={v}" for k, v in LEARNER_OPTIONS.get(r["variant"], {}).items()) or "(the preset's)"
        by_start = [f"{top[s]['success']:.2f}" if s in top else "-" for s in ("from_initial", "chained")]
        flipped = f"{top['cut_short']:.3f}" if "cut_short" in top else "-"
        lines.append(f"| {r['setting']} | {r['variant']} | {options} | {r['seed']} | {r['env_steps'] / 1e6:.2f} M | "
                     f"{r['wall_s']:.0f} | {r['top_area']:.1f} | {r['success']:.2f} | {' | '.join(by_start)} | "
                     f"{flipped} | {r['coverage_cells']} |")
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["setting"], r["variant"], r["env_steps"]), []).append(r)
    for (setting, variant, steps), group in sorted(groups.items()):
        if len(group) > 1:
            figures = {name: mean_and_stderr([r[name] for r in group]) for name in ("top_area", "success", "coverage_cells")}
            for name, pick in (("from s0", "from_initial"), ("chained", "chained")):
                figures[name] = mean_and_stderr([r["levels"][-1][pick]["success"] for r in group])
            figures["flipped"] = mean_and_stderr([r["levels"][-1]["cut_short"] for r in group])
            summary = ", ".join(f"{name} {f['mean']:.3g} ± {f['std']:.2g} (se {f['stderr']:.2g})"
                                for name, f in figures.items())
            lines.append(f"\n{setting} {variant} at {steps / 1e6:.2f} M steps, {len(group)} seeds, mean ± sample std: "
                         f"{summary}")
    return "\n".join(lines)


def curve_comparison(rows: list[dict], reference: list[dict], window: int = 11) -> list[dict]:
    """Per curriculum group (variant, budget): its runs' curves and the reference preset's curves
    read alike at that budget (``equal_steps.read_curve_at``: the top volume there, success
    averaged over ``window`` epochs), as mean and spread over seeds."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        if r["setting"] == "curriculum":
            groups.setdefault((r["variant"], r["env_steps"]), []).append(r)
    base = [r for r in reference if r["preset"] == "ant-field-cpu-k1"]
    found = []
    for (variant, steps), group in sorted(groups.items()):
        for name, runs in ((variant, group), ("ant-field-cpu-k1 (reference curves)", base)):
            if not runs:
                continue
            points = [read_curve_at(r["curve"], steps, window) for r in runs]
            found.append({"variant": name, "env_steps": steps, "seeds": len(points),
                          "top_area": mean_and_stderr([p["top_volume"] for p in points]),
                          "success": mean_and_stderr([p["success"] for p in points])})
    return found


def main(args: Args) -> None:
    out = Path(args.out)
    for variant in [] if args.report_only else args.variants:
        for seed in args.seeds:
            config = variant_config(variant, args.setting, seed, args.env_steps)
            run_dir = Path(args.base) / f"{args.setting}-{variant}-s{seed}"
            if args.at_epoch is None:
                if (run_dir / store.CONFIG_FILE).exists():
                    jobs.resume(ResumeExperiment(resume=str(run_dir), epochs=config.epochs))
                else:
                    jobs.train(TrainExperiment(config=config, run_dir=str(run_dir)))
            row = {"variant": variant, "setting": args.setting,
                   **evaluate_run(run_dir, "ant-field-cpu-k1", seed, args.episodes, args.at_epoch)}
            summary = {k: v for k, v in row.items() if k not in ("levels", "curve", "gc_critic_loss", "config")}
            print(json.dumps(summary), flush=True)
            merge_row(out, row, key=("variant", "setting", "seed", "env_steps"))
    rows = json.loads(out.read_text())["rows"]
    print(table(rows))
    reference = json.loads(Path(args.reference).read_text())["rows"] if Path(args.reference).exists() else []
    print("\nCurves read at each curriculum budget (top box there, success over 11 epochs), mean ± sample std:")
    for c in curve_comparison(rows, reference):
        print(f"- {c['variant']} at {c['env_steps'] / 1e6:.2f} M steps ({c['seeds']} seeds): "
              f"{c['top_area']['mean']:.3g} ± {c['top_area']['std']:.2g} m² at {c['success']['mean']:.3g} ± "
              f"{c['success']['std']:.2g}")
    if not args.report_only:
        print(f"wrote {out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
