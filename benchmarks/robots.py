"""Plausibility of the robot models: how they move under random actions and under a trained policy.

Per robot, B environments start at the home pose and take uniform random actions in
[-1, 1] through the library's own ``Env.step`` (so an Ant that flips is reset, as in
training). Reported:
- the fraction of environments that have been upside down (torso up axis below the
  horizon) at least once by action 20 and by action 100;
- the highest torso height reached;
- the mean displacement of h(s) per action (steps that ended in a reset excluded);
- random-action physics throughput (environment actions/s and physics steps/s) of the batch;
- with ``--runs ROBOT=RUN_DIR``, the mean displacement per action of 48 greedy top-level
  skills of that run's newest checkpoint, from the initial state (``HEAgent.skill_paths``);
- what the robot can do without learning: the longest net displacement in 20 actions of
  an open-loop gait that repeats two random actions (random search over 300 gaits in
  MuJoCo C; an Ant gait that flips is discarded).

Prints a Markdown table and appends one row per robot to ``results/bench-robot-models.jsonl``
(``--results``).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import tyro

from mjx_emp.envs.env import make_env
from mjx_emp.run.evaluate import COVERAGE_SKILLS
from mjx_emp.run.rows import append_row, benchmark_row

sys.path.insert(0, str(Path(__file__).parent))
from bench_rows import numbered_names  # noqa: E402

SPEC = "bench-robot-models"
ROBOTS = ("ant_field", "half_cheetah_field")
ROW_NAMES = numbered_names(ROBOTS)
"""Each robot's row name (``all``, ``all#2``: the robot is no naming field of its record); any
other robot's row is named after it."""


@dataclasses.dataclass
class Args:
    """Robot plausibility benchmark."""

    robots: tuple[str, ...] = ROBOTS
    batch_size: int = 256
    actions: int = 100
    seed: int = 0
    runs: tuple[str, ...] = ()
    """ROBOT=RUN_DIR pairs: trained runs whose greedy skills are measured too."""
    results: str = f"results/{SPEC}.jsonl"
    """The results store the rows are appended to."""


def torso_up_z(data) -> jax.Array:
    """z component of the torso's up axis (body 1), from the simulator's body frames."""
    return data.xmat[..., 1, 2, 2]


def random_walk(env, batch: int, actions: int, key: jax.Array):
    """Uniform random actions from the home pose; per action: upside down, height, displacement, reset."""

    def one_action(states, action_key):
        before = jax.vmap(env.goal_of)(states)
        action = jax.random.uniform(action_key, (batch, env.action_size), minval=-1.0, maxval=1.0)
        after = jax.vmap(env.step)(states, action)
        reset = after.resets > states.resets
        flipped = (after.flip_resets > states.flip_resets) | (torso_up_z(after.data) < 0.0)
        moved = jnp.linalg.norm(jax.vmap(env.goal_of)(after) - before, axis=-1)
        return after, (flipped, after.data.xpos[:, 1, 2], moved, reset)

    states = jax.vmap(env.reset)(jax.random.split(key, batch))
    _, per_action = jax.lax.scan(one_action, states, jax.random.split(jax.random.fold_in(key, 1), actions))
    return per_action


def measure_random(env, args: Args) -> dict:
    """The random-action figures of one robot, with throughput from a second (warm) call."""
    walk = jax.jit(random_walk, static_argnums=(0, 1, 2))
    key = jax.random.key(args.seed)
    jax.block_until_ready(walk(env, args.batch_size, args.actions, key))
    start = time.perf_counter()
    flipped, height, moved, reset = jax.block_until_ready(walk(env, args.batch_size, args.actions, key))
    seconds = time.perf_counter() - start
    ever = np.cumsum(np.asarray(flipped), axis=0) > 0
    moved, reset = np.asarray(moved), np.asarray(reset)
    steps = args.batch_size * args.actions
    return {
        "flipped_after_20": float(ever[min(20, args.actions) - 1].mean()),
        "flipped_after_100": float(ever[min(100, args.actions) - 1].mean()),
        "max_torso_height": float(np.asarray(height).max()),
        "random_displacement_per_action": float(moved[~reset].mean()),
        "resets": int(reset.sum()),
        "actions_per_s": steps / seconds,
        "physics_steps_per_s": steps * env.action_repeat / seconds,
    }


def open_loop_gait_search(env, candidates: int = 300, period: int = 2, actions: int = 20, seed: int = 0) -> dict:
    """Best net displacement of h(s) after ``actions`` actions of a repeated ``period``-action gait.

    Random search in MuJoCo C from the home pose: each candidate repeats ``period`` random
    actions (signs +-1 times magnitudes in [0.3, 1]); gaits that leave the torso upside
    down are discarded. A lower bound on what a policy could reach per skill.
    """
    m, rng = env.mj_model, np.random.default_rng(seed)
    best, kept = 0.0, 0
    for _ in range(candidates):
        gait = rng.choice([-1.0, 1.0], size=(period, m.nu)) * rng.uniform(0.3, 1.0, size=(period, m.nu))
        d = mujoco.MjData(m)
        d.qpos[:] = env.home_qpos
        upright = True
        for t in range(actions):
            d.ctrl[:] = gait[t % period]
            for _ in range(env.action_repeat):
                mujoco.mj_step(m, d)
            upright &= bool(env.torso.upright(d.qpos))
        if upright:
            kept += 1
            best = max(best, float(np.linalg.norm(d.qpos[list(env.goal_qpos)] - env.home_qpos[list(env.goal_qpos)])))
    return {"gait_best_displacement": best, "gait_actions": actions, "gait_candidates": candidates,
            "gait_upright": kept}


def measure_trained(run_dir: str, seed: int) -> dict:
    """Mean displacement per action of greedy top-level skills of a trained run, from the initial state."""
    from mjx_emp.run import jobs

    trainer, _, state = jobs.load_run(Path(run_dir))
    positions, mask = trainer.skill_paths(state, jax.random.key(seed), COVERAGE_SKILLS)
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=-1)
    counted = mask[1:]
    return {
        "run_dir": run_dir,
        "epoch": int(state.epoch),
        "policy_displacement_per_action": float(steps[counted].mean()),
        "policy_actions": int(counted.sum()),
    }


def markdown(rows: list[dict]) -> str:
    """The results as a Markdown table."""
    lines = [
        "| robot | control s | flipped @20 | flipped @100 | max torso z (m) | m/action random | "
        "m/action trained | best 2-action gait, m in 20 actions | actions/s (B) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        trained = r.get("trained", {}).get("policy_displacement_per_action")
        lines.append(
            f"| {r['robot']} | {r['control_dt']:.4g} | {r['flipped_after_20']:.2f} | {r['flipped_after_100']:.2f} | "
            f"{r['max_torso_height']:.2f} | {r['random_displacement_per_action']:.3f} | "
            f"{'-' if trained is None else f'{trained:.3f}'} | {r['gait_best_displacement']:.2f} | "
            f"{r['actions_per_s']:,.0f} ({r['batch_size']}) |"
        )
    return "\n".join(lines)


def main(args: Args) -> None:
    trained = dict(pair.split("=", 1) for pair in args.runs)
    rows = []
    for robot in args.robots:
        env = make_env(robot)
        row = {"robot": robot, "control_dt": env.control_dt, "batch_size": args.batch_size,
               "actions": args.actions, "total_mass": float(env.mj_model.body_mass.sum()),
               **measure_random(env, args), **open_loop_gait_search(env, seed=args.seed)}
        if robot in trained:
            row["trained"] = measure_trained(trained[robot], args.seed)
        rows.append(row)
        append_row(Path(args.results), benchmark_row(SPEC, ROW_NAMES.get(robot, robot), row))
        print(json.dumps(row), flush=True)
    print(markdown(rows))
    print(f"appended {len(rows)} rows to {args.results}")


if __name__ == "__main__":
    main(tyro.cli(Args))
