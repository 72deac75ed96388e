"""The flat skill learners' train state and what an epoch reports: transitions, the method's
model, the state pytree and the per-iteration stats."""

from __future__ import annotations

from typing import Any

import jax
import optax
from flax import struct

from mjx_emp.counters import StepCounter
from mjx_emp.learners.sac import SACInfo, SACLearner
from mjx_emp.replay import (
    ReplayBuffer,
)
from mjx_emp.rollout.flat import FlatState

SKILL_EPOCH_TRACE = "skills.train_epoch"
"""Name under which :mod:`mjx_emp.tracing` counts traces (compiles) of a flat learner's epoch."""
Params = Any


@struct.dataclass
class SkillTransition:
    """One stored step: where its episode began, the step itself, and the skill it served."""

    s0: jax.Array
    obs: jax.Array
    skill: jax.Array
    action: jax.Array
    next_obs: jax.Array


@struct.dataclass
class SkillModel:
    """The method's own model and its Adam state; ``log_lam`` and ``lam_opt`` are METRA's
    dual variable (kept, unused, by the others so that every method has one state shape)."""

    params: Params
    opt: optax.OptState
    log_lam: jax.Array
    lam_opt: optax.OptState


@struct.dataclass
class SkillState:
    """Everything a flat skill learner carries between epochs."""

    sac: SACLearner
    model: SkillModel
    replay: ReplayBuffer
    rollout: FlatState
    key: jax.Array
    epoch: jax.Array
    env_steps: StepCounter


@struct.dataclass
class IterationStats:
    """Per iteration of an epoch (stacked [iterations]); NaN where nothing was learnt or ended."""

    env_steps: jax.Array
    learned: jax.Array
    sac: SACInfo
    model_loss: jax.Array
    reward: jax.Array
    posterior_std: jax.Array
    dual_lambda: jax.Array
    constraint: jax.Array
    episodes: jax.Array
    displacement: jax.Array
    flip_resets: jax.Array
