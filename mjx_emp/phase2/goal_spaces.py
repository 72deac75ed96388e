"""Phase 2: a goal-conditioned policy over a trained agent's frozen skills.

The paper's downstream task: reach a goal drawn uniformly from a hand-designed region
around the initial state (its Table 2). An added level k sits on top of the k skill
levels learned in phase 1. It has a goal-conditioned actor-critic and no goal-space
policy; its action is a subgoal for level k-1, squashed into the top level's learned
goal space at the current state (the paper's architecture with bounds and shifts from
mu_{k-1}). Each episode starts at the task's initial state and gives the policy ``n``
attempts, i.e. top-level skills, to come within ``eps`` of its goal. Phase 1's networks
are frozen.

Learning is phase 1's goal-conditioned DDPG at one more level: the reward is the
goal-conditioned reward log N(goal; h(s'), sigma) per attempt (the paper does not state
phase 2's reward; this is our choice), discounted, with the discount dropping to 0 once
the goal is reached. An epoch is one jitted call: a ``lax.scan`` over ``iterations``
collect-and-update items and ``eval_rounds`` greedy evaluation items, all through one
compiled k+1-level rollout.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.he.state import HEState
from mjx_emp.checks import compile_identity
from mjx_emp.counters import StepCounter
from mjx_emp.envs.registry import DOMAINS, tiltable
from mjx_emp.errors import ConfigError
from mjx_emp.learners.common import all_finite
from mjx_emp.learners.ddpg import (
    DDPGLearner,
    GoalTransition,
    ddpg_losses,
    ddpg_step,
    goal_transitions,
    stored_rows,
)
from mjx_emp.metrics import PHASE2_DIAGNOSTICS, epoch_header, running_min_distance
from mjx_emp.nets import (
    MLP,
    LevelParams,
    aimed_policy,
    central_box,
    goal_conditioned_q,
    goal_features,
    greedy_batch,
    level_policy,
    random_policy,
    scripted_policy,
)
from mjx_emp.phase2.config import Phase2Config, check_phase2_config, keeps_cut_attempts
from mjx_emp.replay import (
    ReplayBuffer,
    flatten_rows,
    replay_init,
    replay_insert,
    replay_sample,
)
from mjx_emp.rollout.collect import CollectTotals, collect
from mjx_emp.rollout.hierarchy import init_rollout
from mjx_emp.rollout.structures import Hierarchy, Params, RolloutPlan
from mjx_emp.tracing import count_trace

AIM_PRIOR_OUT_SCALE = 1e-4
"""Init scale of the actor's output layer under an aim prior: the policy starts within a few
per cent of the aimed one."""

TRAIN_EPOCH_TRACE = "downstream.train_epoch"
"""Name under which :mod:`mjx_emp.tracing` counts traces (compiles) of the phase-2 epoch."""


@struct.dataclass
class Phase2State:
    """Everything phase 2 learns or remembers, with the frozen skills it builds on.

    ``skills`` holds phase 1's goal-conditioned actors (levels 0..k-1) and ``boxes`` its
    goal-space actors, so a phase-2 checkpoint stands on its own.
    """

    skill_actors: tuple[Params, ...]
    goal_space_actors: tuple[Params, ...]
    learner: DDPGLearner
    replay: ReplayBuffer
    key: jax.Array
    epoch: jax.Array
    env_steps: StepCounter


@struct.dataclass
class Phase2Stats:
    """What one epoch item did: whether it trained, the episodes it saw, its losses."""

    train: jax.Array
    env_steps: jax.Array
    transitions: jax.Array
    episodes: jax.Array
    success: jax.Array
    min_distance: jax.Array
    critic_loss: jax.Array
    actor_loss: jax.Array


def evaluation_figures(totals: CollectTotals) -> dict[str, float]:
    """The figures :meth:`Phase2Loop.evaluate` reports of a greedy evaluation's totals."""
    return {
        "min_distance": float(totals.mean_distance()),
        "success": float(totals.success()),
        "cut_short": float(totals.cut_fraction()),
        "uncut_min_distance": float(totals.uncut_mean_distance()),
        "episodes": int(totals.episodes),
    }


class Phase2Loop:
    """What every phase-2 trainer (over HE's or a flat learner's skills) does the same way: the
    epoch (``iterations`` collect-and-update items, then ``eval_rounds`` greedy items, one
    jitted call), the paper's figures of the greedy policy, the metrics line, its summary and
    the divergence check, and the goal-conditioned DDPG learner over its actions (networks,
    fresh state, update). A subclass provides ``cfg``, ``phase1`` (with ``env`` and
    ``initial_obs``), ``trace_name``, ``action_size``, ``greedy_actions(state)`` and
    ``_collect(state, noise, store, key, *args) -> (state, CollectTotals)`` (``args``: what
    :meth:`diagnostic_figures` passes to pick a scripted policy, where it has any)."""

    cfg: Phase2Config
    trace_name: str = TRAIN_EPOCH_TRACE

    @property
    def env(self):
        return self.phase1.env

    @property
    def action_size(self) -> int:
        """Size of the phase-2 policy's action (a subgoal, or a skill z)."""
        raise NotImplementedError

    def greedy_actions(self, state: Any):
        """(actor, obs [B, ...], goal [B, ...]) -> the greedy actions the critic is trained on."""
        raise NotImplementedError

    @functools.cached_property
    def actor_net(self) -> MLP:
        """The phase-2 actor; with an aim prior its output starts near zero (the prior alone)."""
        out_scale = AIM_PRIOR_OUT_SCALE if self.cfg.aim_prior else 1.0
        return MLP(tuple(self.cfg.hidden), self.action_size, out_scale=out_scale)

    @functools.cached_property
    def critic_net(self) -> MLP:
        return MLP(tuple(self.cfg.hidden), 1)

    @functools.cached_property
    def optimizers(self) -> tuple[optax.GradientTransformation, optax.GradientTransformation]:
        return optax.adam(self.cfg.actor_lr), optax.adam(self.cfg.critic_lr)

    def q_value(self, params: Params, obs: jax.Array, goal: jax.Array, action: jax.Array) -> jax.Array:
        """Q(s, goal, action) of the phase-2 critic."""
        return goal_conditioned_q(self.critic_net, self.env, params, obs, goal, action)

    def region(self) -> tuple[np.ndarray, np.ndarray]:
        """The goal region as absolute (low, high) corners in goal space."""
        centre = self.env.goal_of_obs(self.phase1.initial_obs) + np.asarray(self.cfg.region_offset)
        half = np.asarray(self.cfg.region) / 2
        return centre - half, centre + half

    def fresh_learner(self, actor_key: jax.Array, critic_key: jax.Array) -> tuple[DDPGLearner, ReplayBuffer]:
        """New phase-2 actor and critic (targets equal to them) and an empty replay."""
        env = self.env
        obs, goal = jnp.asarray(self.phase1.initial_obs), jnp.zeros(env.goal_size)
        action = jnp.zeros(self.action_size)
        actor = self.actor_net.init(actor_key, goal_features(env, obs, goal))
        critic = self.critic_net.init(critic_key, jnp.concatenate([goal_features(env, obs, goal), action]))
        actor_tx, critic_tx = self.optimizers
        learner = DDPGLearner(actor, critic, actor, critic, actor_tx.init(actor), critic_tx.init(critic))
        row = GoalTransition(obs, goal, action, obs, jnp.zeros((), bool),
                             cut=jnp.zeros((), bool) if keeps_cut_attempts(self.cfg) else None)
        return learner, replay_init(row, self.cfg.replay_capacity)

    def update(self, state: Any, key: jax.Array) -> tuple[Any, jax.Array]:
        """``grad_steps`` DDPG steps on replayed attempts (phase 1's learner, one level up)."""
        cfg = self.cfg
        actor_tx, critic_tx = self.optimizers
        act = self.greedy_actions(state)

        def step(learner: DDPGLearner, step_key):
            batch = replay_sample(state.replay, step_key, cfg.batch_size)
            losses = ddpg_losses(act, self.q_value, learner, batch, self.env, cfg.sigma, cfg.gamma, flip_cost=cfg.flip_cost)
            if cfg.aim_weight > 0:
                losses = (losses[0], self.anchored_actor_loss(act, batch))
            return ddpg_step(learner, losses, actor_tx, critic_tx, cfg.tau)

        learner, losses = jax.lax.scan(step, state.learner, jax.random.split(key, cfg.grad_steps))
        return state.replace(learner=learner), losses.mean(axis=0)

    def anchored_actor_loss(self, act, batch: GoalTransition):
        """The actor's loss under a weighted aim prior (``Phase2Config.aim_weight``): the critic's
        gain normalised by its mean magnitude, less the cost of the correction f the actor adds
        to the aimed subgoal before the tanh."""
        weight = self.cfg.aim_weight

        def actor_loss(actor, critic):
            q = self.q_value(critic, batch.obs, batch.goal, act(actor, batch.obs, batch.goal))
            correction = self.actor_net.apply(actor, goal_features(self.env, batch.obs, batch.goal))
            scale = jax.lax.stop_gradient(jnp.mean(jnp.abs(q))) + 1e-6
            return -jnp.mean(q) / scale + weight * jnp.mean(jnp.square(correction))

        return actor_loss

    def _train_epoch(self, state: Any) -> tuple[Any, Phase2Stats]:
        count_trace(self.trace_name)
        cfg = self.cfg

        def item(state, train: jax.Array):
            key, collect_key, update_key = jax.random.split(state.key, 3)
            noise = jnp.where(train, cfg.action_noise, 0.0)
            state, totals = self._collect(state.replace(key=key), noise, train, collect_key)
            state, losses = jax.lax.cond(
                train, self.update, lambda s, _: (s, jnp.full(2, jnp.nan)), state, update_key
            )
            stats = Phase2Stats(
                train=train, env_steps=totals.env_steps, transitions=totals.transitions,
                episodes=totals.episodes, success=totals.success(), min_distance=totals.mean_distance(),
                critic_loss=losses[0], actor_loss=losses[1],
            )
            return state, stats

        schedule = jnp.asarray([True] * cfg.iterations + [False] * cfg.eval_rounds)
        state, stats = jax.lax.scan(item, state, schedule)
        return state.replace(epoch=state.epoch + 1), stats

    def train_epoch(self, state: Any) -> tuple[Any, Phase2Stats]:
        """One phase-2 epoch as one jitted call; returns per-item stats."""
        return _jit_train_epoch(self, state)

    def _evaluate(self, state: Any, key: jax.Array, rounds: int, *collect_args: jax.Array) -> CollectTotals:
        def one(_, round_key):
            _, totals = self._collect(state, jnp.zeros(()), jnp.bool_(False), round_key, *collect_args)
            return None, totals

        _, totals = jax.lax.scan(one, None, jax.random.split(key, rounds))
        return jax.tree.map(lambda per_round: per_round.sum(axis=0), totals)

    def evaluate(self, state: Any, key: jax.Array, episodes: int = 400) -> dict[str, float]:
        """The paper's phase-2 figures of the greedy policy on at least ``episodes`` fresh goals.

        Whole rounds of num_envs episodes; returns the mean minimum distance to goal, the
        success rate (within eps), the fraction of episodes a reset (a flipped Ant) ended
        early, the mean minimum distance over the episodes no reset ended (``uncut_min_distance``,
        NaN if every one was cut: how far the policy gets where it stays upright), and the
        number of episodes.
        """
        return evaluation_figures(_jit_evaluate(self, state, key, self.evaluation_rounds(episodes)))

    def evaluation_rounds(self, episodes: int) -> int:
        """Whole rounds of num_envs episodes that hold at least ``episodes``."""
        return max(1, math.ceil(episodes / self.cfg.num_envs))

    def diagnostic_figures(self, state: Any, key: jax.Array, episodes: int = 400) -> dict[str, dict[str, float]]:
        """:meth:`evaluate`'s figures of each scripted policy this trainer can put in its learned
        policy's place, on the same goals (the same ``key``); none here."""
        return {}

    def metrics(self, state: Any, stats: Phase2Stats, seconds: float) -> dict[str, Any]:
        """One JSON-ready line of an epoch: greedy min distance and success from the evaluation
        items, training figures from the others."""
        s = jax.tree.map(np.asarray, stats)
        train, evals = s.train, ~s.train

        def mean(field, rows):
            values = getattr(s, field)[rows]
            return float(values.mean()) if values.size else None

        return {
            **epoch_header(state, float(s.env_steps.sum()), seconds),
            "min_distance": mean("min_distance", evals),
            "success": mean("success", evals),
            "train_min_distance": mean("min_distance", train),
            "train_success": mean("success", train),
            "critic_loss": mean("critic_loss", train),
            "actor_loss": mean("actor_loss", train),
            "transitions": float(s.transitions.sum()),
        }

    def describe(self, metrics: dict) -> str:
        """A short human-readable summary of an epoch's metrics."""
        return (f"{metrics['env_steps']:.3g} env steps  {metrics['env_steps_per_s']:.3g} steps/s  "
                f"min distance {metrics['min_distance']:.3g} (eps {self.cfg.eps:g})  "
                f"success {metrics['success']:.2f}")

    def divergence(self, state: Any, stats: Phase2Stats) -> str | None:
        """Why this epoch's result must not be kept (a non-finite loss or parameter), or None."""
        s = jax.tree.map(np.asarray, stats)
        for name in ("critic_loss", "actor_loss"):
            values = getattr(s, name)[s.train]
            if not np.isfinite(values).all():
                return f"phase-2 {name.replace('_', ' ')} is {values[~np.isfinite(values)][0]}"
        if not bool(all_finite(state.learner)):
            return "a phase-2 network parameter or optimizer state is not finite"
        return None


SCRIPTED = "scripted"
"""``Phase2Trainer.top`` for any of the scripted diagnostics, the one a call names by its index in
:data:`~mjx_emp.metrics.PHASE2_DIAGNOSTICS`: all of them through one compiled program."""
TOP_POLICIES = ("learned",) + PHASE2_DIAGNOSTICS + (SCRIPTED,)
"""What can sit on top of the frozen skills in phase 2 (see ``Phase2Trainer.top``)."""


@dataclasses.dataclass(frozen=True)
class Phase2Trainer(Phase2Loop):
    """Static side of phase 2: the skill agent, the added level's networks, the k+1-level rollout.

    A static jit argument that hashes and compares by its two configs (phase 1's and
    phase 2's), so equal configs share compiled programs.
    """

    phase1: HEAgent
    cfg: Phase2Config = dataclasses.field(compare=False)
    top: str = "learned"
    """The added level's policy: ``learned`` (the phase-2 actor), or for the chaining
    diagnostic ``aimed`` (each subgoal straight at the goal, clipped into the top box at s),
    ``aimed_half`` (the same, clipped into the box's central half) or ``random`` (uniform in
    that box), or ``scripted``: the diagnostic each rollout names (:meth:`diagnostic_figures`).
    The diagnostics ignore the actor."""
    hierarchy: Hierarchy = dataclasses.field(init=False, compare=False, repr=False)
    identity: Phase2Config = dataclasses.field(init=False, repr=False)
    """What it compares and hashes by, beside ``phase1`` and ``top``: ``cfg`` without its epoch count."""

    def __post_init__(self):
        check_phase2_config(self.cfg, self.phase1.env.goal_size)
        if self.cfg.reflex_tilt > 0 and not tiltable(DOMAINS[self.phase1.cfg.env]):
            allowed = sorted(name for name, spec in DOMAINS.items() if tiltable(spec))
            raise ConfigError(f"reflex_tilt: {self.phase1.cfg.env!r} has no torso to tilt; allowed only over skills of "
                              f"env in {allowed}")
        if self.top not in TOP_POLICIES:
            raise ConfigError(f"top: {self.top!r} is unknown; allowed values: {list(TOP_POLICIES)}")
        object.__setattr__(self, "identity", compile_identity(self.cfg))
        k, phase1 = self.level, self.phase1.cfg
        box = self.phase1.nets.learned_box(k - 1)
        scripted = {"aimed": lambda: aimed_policy(self.env, box),
                    "aimed_half": lambda: aimed_policy(self.env, central_box(box, 0.5)),
                    "random": lambda: random_policy(box)}
        policy = {"learned": lambda: level_policy(self.env, self.actor_net, central_box(box, self.cfg.subgoal_reach),
                                                  aim_prior=self.cfg.aim_prior),
                  SCRIPTED: lambda: scripted_policy([scripted[name]() for name in PHASE2_DIAGNOSTICS]),
                  **scripted}[self.top]()
        hierarchy = Hierarchy(
            self.env, self.phase1.hierarchy.policies + (policy,),
            n=tuple(phase1.n) + (self.cfg.n,), eps=tuple(phase1.eps) + (self.cfg.eps,),
            reflex_tilt=self.cfg.reflex_tilt,
        )
        object.__setattr__(self, "hierarchy", hierarchy)

    @property
    def level(self) -> int:
        """The added level's index: k, on top of the k skill levels."""
        return self.phase1.cfg.k

    @property
    def action_size(self) -> int:
        """The added level's action: a subgoal in goal space."""
        return self.env.goal_size

    # ---- state ----------------------------------------------------------------------
    def init(self, skills_state: HEState, key: jax.Array | None = None) -> Phase2State:
        """Fresh phase-2 networks and an empty replay on top of ``skills_state``'s frozen skills."""
        return _jit_init(self, skills_state, jax.random.key(self.cfg.seed) if key is None else key)

    def _init(self, skills_state: HEState, key: jax.Array) -> Phase2State:
        key, actor_key, critic_key = jax.random.split(key, 3)
        learner, replay = self.fresh_learner(actor_key, critic_key)
        return Phase2State(
            skill_actors=tuple(g.actor for g in skills_state.policies), goal_space_actors=tuple(g.actor for g in skills_state.goal_spaces),
            learner=learner, replay=replay, key=key,
            epoch=jnp.zeros((), jnp.int32), env_steps=StepCounter.zero(),
        )

    # ---- episodes -------------------------------------------------------------------
    def start(self, _: Any, key: jax.Array):
        """A new episode: the task's initial state, with a goal uniform in the region."""
        env_key, goal_key = jax.random.split(key)
        low, high = self.region()
        goal = jax.random.uniform(goal_key, low.shape, minval=low, maxval=high)
        return self.env.restore(env_key, jnp.asarray(self.phase1.initial_obs)), goal, ()

    def rollout_params(self, state: Phase2State, noise: jax.Array,
                       diagnostic: jax.Array | None = None) -> tuple[LevelParams, ...]:
        """Per-level policy params: the frozen skills, then the added level with ``noise`` (its
        actor slot holds ``diagnostic``, the scripted policy's index, under the ``scripted`` top)."""
        k, zero = self.level, jnp.zeros(())
        skills = tuple(
            LevelParams(actor=state.skill_actors[level], box=None if level == 0 else state.goal_space_actors[level - 1], noise=zero)
            for level in range(k)
        )
        actor = diagnostic if self.top == SCRIPTED else state.learner.actor
        return skills + (LevelParams(actor=actor, box=state.goal_space_actors[k - 1], noise=noise),)

    def greedy_episodes(self, state: Phase2State) -> RolloutPlan:
        """Greedy phase-2 episodes (goals from the region), showing the task's goal as level
        k's and the subgoals below it."""
        params = self.rollout_params(state, jnp.zeros(()))
        return RolloutPlan(self.hierarchy, params, self.start, None, root=self.level)

    @property
    def longest_episode(self) -> int:
        """Primitive steps of an episode that uses every attempt, each skill to its last action."""
        return self.cfg.n * math.prod(self.phase1.cfg.n)

    def max_chunks(self) -> int:
        """Rollout calls that let every environment finish one episode (every attempt used)."""
        return math.ceil(self.longest_episode / self.phase1.cfg.chunk_steps) + 1

    def _collect(self, state: Phase2State, noise: jax.Array, store: jax.Array, key: jax.Array,
                 diagnostic: jax.Array | None = None):
        """Run num_envs episodes (each environment to the end of its first at least).

        Where ``store``, every attempt goes to the replay; ``diagnostic`` picks the scripted
        policy under the ``scripted`` top. Returns the new state and the
        call's :class:`CollectTotals`; ``distance`` sums each first episode's minimum
        distance to goal.
        """
        hierarchy, k, chunk_steps = self.hierarchy, self.level, self.phase1.cfg.chunk_steps
        params = self.rollout_params(state, noise, diagnostic)
        first = init_rollout(hierarchy, params, self.start, None, key, self.cfg.num_envs, k)

        def absorb(kept, transitions, episodes, stats):
            replay, running, totals = kept
            top, bottom = transitions[k], transitions[0]
            keep_cut = keeps_cut_attempts(self.cfg)  # the attempt a reset ended, at its last state before the reset
            rows, stored = goal_transitions(top, keep_cut=keep_cut), stored_rows(top, keep_cut)
            replay = replay_insert(replay, flatten_rows(rows), flatten_rows(stored) & store)
            distance = jnp.linalg.norm(self.env.goal_of_obs(bottom.next_obs) - top.goal, axis=-1)
            running, per_step = running_min_distance(distance, bottom.valid, top.final, running)
            counted = episodes.first_ended
            totals = totals.add(stats, top.valid & store, counted, episodes.reached, per_step, episodes.cut)
            return replay, running, totals

        running = jnp.full(self.cfg.num_envs, jnp.inf)
        _, (replay, _, totals) = collect(
            hierarchy, params, self.start, None, first, chunk_steps, self.max_chunks(), absorb,
            (state.replay, running, CollectTotals.zero()),
        )
        return state.replace(replay=replay, env_steps=state.env_steps.add(totals.env_steps)), totals

    def diagnostic_figures(self, state: Phase2State, key: jax.Array, episodes: int = 400) -> dict[str, dict[str, float]]:
        """:meth:`evaluate`'s figures of each scripted policy of
        :data:`~mjx_emp.metrics.PHASE2_DIAGNOSTICS` in the learned policy's place, on the same
        goals (the same ``key``), all through the one compiled program of the ``scripted`` top."""
        scripted, rounds = dataclasses.replace(self, top=SCRIPTED), self.evaluation_rounds(episodes)
        return {name: evaluation_figures(_jit_evaluate(scripted, state, key, rounds, jnp.int32(index)))
                for index, name in enumerate(PHASE2_DIAGNOSTICS)}

    # ---- learning -------------------------------------------------------------------
    def greedy_actions(self, state: Phase2State):
        """The added level's greedy subgoals, squashed into the top goal space of ``state``'s skills."""
        policy, box = self.hierarchy.policies[self.level], state.goal_space_actors[self.level - 1]
        return lambda actor, obs, goal: greedy_batch(policy, actor, box)(obs, goal)


_jit_init = jax.jit(Phase2Trainer._init, static_argnums=0)
_jit_train_epoch = jax.jit(Phase2Loop._train_epoch, static_argnums=0, donate_argnums=1)
_jit_evaluate = jax.jit(Phase2Loop._evaluate, static_argnums=(0, 3))
