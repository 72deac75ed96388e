"""Phase 2 over a flat skill learner's frozen skills (DIAYN, HIDIO, DADS, METRA).

The same task, attempts, eps, reward and metric as HE's phase 2 (:mod:`mjx_emp.phase2.goal_spaces`):
an episode starts at the initial state with a goal uniform in the region; the phase-2
policy has ``n`` attempts, each one skill z that the frozen skill policy executes greedily
for the skill's length (from where the attempt begins, so the skill's descriptor counts
displacement from there); an attempt that ends within ``eps`` of the goal ends the episode
as a success. The policy is goal-conditioned DDPG over z (tanh into [-1, 1]^d; METRA's z are
projected onto the unit sphere, the skills it trained), one transition per attempt,
rewarded log N(goal; h(s_end), sigma). The mean minimum distance counts every primitive
step; an episode cut short by a reset (a flipped Ant) ends there, scored at its last state
before the reset, as in HE's phase 2.

Every environment plays exactly one episode per collect call: a scan of n x (skill length)
steps in which environments whose episode has ended idle (their steps do not count).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from mjx_emp.algos.skills.agent import SkillAgent
from mjx_emp.algos.skills.state import SkillState
from mjx_emp.checks import compile_identity
from mjx_emp.counters import StepCounter
from mjx_emp.envs.env import EnvState
from mjx_emp.errors import ConfigError
from mjx_emp.learners.ddpg import DDPGLearner, GoalTransition
from mjx_emp.nets import goal_features
from mjx_emp.phase2.config import Phase2Config, check_phase2_config
from mjx_emp.phase2.goal_spaces import Phase2Loop
from mjx_emp.replay import ReplayBuffer, flatten_rows, replay_insert
from mjx_emp.rollout.collect import CollectTotals

TRAIN_EPOCH_TRACE = "downstream_flat.train_epoch"
"""Name under which :mod:`mjx_emp.tracing` counts traces (compiles) of the flat phase-2 epoch."""
Params = Any


@struct.dataclass
class FlatPhase2State:
    """Phase 2's learner and replay, with the frozen skill policy it commands."""

    skill_actor: Params
    learner: DDPGLearner
    replay: ReplayBuffer
    key: jax.Array
    epoch: jax.Array
    env_steps: StepCounter


@struct.dataclass
class Attempts:
    """Per environment during one collect call: its episode so far."""

    env: EnvState
    goal: jax.Array
    skill: jax.Array
    attempt_obs: jax.Array
    count: jax.Array
    attempts: jax.Array
    closest: jax.Array
    done: jax.Array
    reached: jax.Array
    cut: jax.Array
    """Whether a reset (a flipped Ant, broken physics) ended the episode."""
    key: jax.Array


@dataclasses.dataclass(frozen=True)
class FlatPhase2Trainer(Phase2Loop):
    """Static side of phase 2 over a flat learner's skills; hashes by the two configs."""

    phase1: SkillAgent
    cfg: Phase2Config = dataclasses.field(compare=False)
    identity: Phase2Config = dataclasses.field(init=False, repr=False)
    """What it compares and hashes by, beside ``phase1``: ``cfg`` without its epoch count."""
    trace_name = TRAIN_EPOCH_TRACE  # a class attribute, not a field

    def __post_init__(self):
        check_phase2_config(self.cfg, self.phase1.env.goal_size)
        if self.cfg.aim_prior:
            raise ConfigError("aim_prior: a skill z has no subgoal to aim at the goal; allowed only over skills "
                              "addressed by goal-space subgoals (HE, GCRL), so use False here")
        if self.cfg.reflex_tilt > 0:
            raise ConfigError(f"reflex_tilt: the latent skills' phase 2 runs each skill for its fixed length; "
                              f"allowed only over skills addressed by goal-space subgoals (HE, GCRL), so use 0 "
                              f"here; got {self.cfg.reflex_tilt}")
        if self.cfg.flip_cost > 0:
            raise ConfigError(f"flip_cost: the latent skills' phase 2 scores a flipped attempt at its last state "
                              f"only; allowed only over skills addressed by goal-space subgoals (HE, GCRL), so use 0 "
                              f"here; got {self.cfg.flip_cost}")
        object.__setattr__(self, "identity", compile_identity(self.cfg))

    @property
    def action_size(self) -> int:
        """The phase-2 action: a skill z."""
        return self.phase1.cfg.skill_dim

    def greedy_actions(self, state: FlatPhase2State):
        """The greedy skills the critic is trained on."""
        return self.choose

    def as_skill(self, unit: jax.Array) -> jax.Array:
        """A point of [-1, 1]^d as a skill the learner trained: itself, or for METRA its direction."""
        return self.phase1.skill_method.as_skill(unit)

    def choose(self, actor: Params, obs: jax.Array, goal: jax.Array) -> jax.Array:
        """The greedy skill for (state, goal), one row or a batch."""
        return self.as_skill(jnp.tanh(self.actor_net.apply(actor, goal_features(self.env, obs, goal))))

    def explore(self, actor: Params, obs: jax.Array, goal: jax.Array, noise: jax.Array, key: jax.Array) -> jax.Array:
        """The skill with Gaussian exploration noise (std ``noise``) before the squashing into a skill."""
        unit = jnp.tanh(self.actor_net.apply(actor, goal_features(self.env, obs, goal)))
        unit = jnp.clip(unit + noise * jax.random.normal(key, unit.shape), -1.0, 1.0)
        return self.as_skill(unit)

    # ---- state ----------------------------------------------------------------------
    def init(self, skills_state: SkillState, key: jax.Array | None = None) -> FlatPhase2State:
        """Fresh phase-2 networks and an empty replay on top of ``skills_state``'s frozen policy."""
        return _jit_init(self, skills_state, jax.random.key(self.cfg.seed) if key is None else key)

    def _init(self, skills_state: SkillState, key: jax.Array) -> FlatPhase2State:
        key, actor_key, critic_key = jax.random.split(key, 3)
        learner, replay = self.fresh_learner(actor_key, critic_key)
        return FlatPhase2State(skill_actor=skills_state.sac.actor, learner=learner, replay=replay, key=key,
                               epoch=jnp.zeros((), jnp.int32), env_steps=StepCounter.zero())

    # ---- episodes -------------------------------------------------------------------
    def _collect(self, state: FlatPhase2State, noise: jax.Array, store: jax.Array, key: jax.Array):
        """One episode per environment; where ``store``, every attempt goes to the replay."""
        env, cfg, skill_steps = self.env, self.cfg, self.phase1.cfg.n
        batch = cfg.num_envs
        reset_key, goal_key, choose_key, key = jax.random.split(key, 4)
        low, high = self.region()
        initial = jnp.asarray(self.phase1.initial_obs)
        env_state = jax.vmap(lambda k: env.restore(k, initial))(jax.random.split(reset_key, batch))
        goal = jax.random.uniform(goal_key, (batch,) + low.shape, minval=low, maxval=high)
        obs = jax.vmap(env.observe)(env_state)
        carry = Attempts(
            env=env_state, goal=goal, skill=self.explore(state.learner.actor, obs, goal, noise, choose_key),
            attempt_obs=obs, count=jnp.zeros(batch, jnp.int32), attempts=jnp.zeros(batch, jnp.int32),
            closest=jnp.full(batch, jnp.inf), done=jnp.zeros(batch, bool), reached=jnp.zeros(batch, bool),
            cut=jnp.zeros(batch, bool), key=key,
        )

        def step(c: Attempts, _):
            key, choose_key = jax.random.split(c.key)
            obs = jax.vmap(env.observe)(c.env)
            action = jax.vmap(self.phase1.greedy, in_axes=(None, 0, 0, 0, None))(
                state.skill_actor, obs, c.attempt_obs, c.skill, key)
            stepped = jax.vmap(env.step)(c.env, action)
            broke = stepped.resets > c.env.resets
            next_obs = jax.vmap(env.observe)(stepped)
            active = ~c.done
            # A reset ends the episode, scored at its last state before the resetting action.
            scored = jnp.where(broke[:, None], obs, next_obs)
            distance = jnp.linalg.norm(env.goal_of_obs(scored) - c.goal, axis=-1)
            closest = jnp.where(active, jnp.minimum(c.closest, distance), c.closest)
            count = c.count + 1
            attempt_end = active & ((count >= skill_steps) | broke)
            reached = attempt_end & ~broke & (distance < cfg.eps)
            attempts = c.attempts + attempt_end.astype(jnp.int32)
            episode_end = attempt_end & (reached | (attempts >= cfg.n) | broke)
            fell = attempt_end & broke
            transition = GoalTransition(obs=c.attempt_obs, goal=c.goal, action=c.skill, next_obs=scored,
                                        reached=reached, cut=fell if cfg.learn_from_resets else None)
            following = self.explore(state.learner.actor, next_obs, c.goal, noise, choose_key)
            new_attempt = attempt_end & ~episode_end
            carry = Attempts(
                env=stepped, goal=c.goal,
                skill=jnp.where(new_attempt[:, None], following, c.skill),
                attempt_obs=jnp.where(new_attempt[:, None], next_obs, c.attempt_obs),
                count=jnp.where(attempt_end, 0, count), attempts=attempts, closest=closest,
                done=c.done | episode_end, reached=c.reached | reached, cut=c.cut | fell, key=key,
            )
            kept = attempt_end & ~broke
            return carry, (transition, kept | fell if cfg.learn_from_resets else kept, active)

        carry, (transitions, stored, active) = jax.lax.scan(step, carry, None, length=cfg.n * skill_steps)
        replay = replay_insert(state.replay, flatten_rows(transitions), flatten_rows(stored) & store)
        steps = active.sum(dtype=jnp.int32)
        totals = CollectTotals(
            env_steps=steps, transitions=jnp.where(store, stored.sum(dtype=jnp.int32), 0), episodes=jnp.int32(batch),
            reached=carry.reached.sum(dtype=jnp.int32), distance=carry.closest.sum(),
            flip_resets=carry.env.flip_resets.sum(), cut_short=carry.cut.sum(dtype=jnp.int32),
            cut_distance=jnp.where(carry.cut, carry.closest, 0.0).sum(),
        )
        return state.replace(replay=replay, env_steps=state.env_steps.add(steps)), totals

_jit_init = jax.jit(FlatPhase2Trainer._init, static_argnums=0)
