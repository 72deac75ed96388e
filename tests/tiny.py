"""A tiny two-level point-mass trainer shared by the test modules (compiled once per session)."""

from __future__ import annotations

import functools

import jax
import numpy as np

from mjx_emp.config import TrainConfig
from mjx_emp.train import Trainer, _jit_train_epoch

TINY = TrainConfig(
    env="point_mass", n=(3, 2), sigma_gc=(0.4, 0.8), sigma_gs=(0.4, 0.8), eps=(0.3, 0.6),
    init_half_width=(0.3, 0.6), max_half_width=(3.0, 6.0), num_envs=8, chunk_steps=3,
    gc_iterations=2, gc_grad_steps=3, gs_grad_steps=2, batch_size=16, replay_capacity=512,
    gs_replay_capacity=64, start_capacity=64, start_chain=2, hidden=(16,), seed=3,
)


@functools.cache
def tiny_trainer() -> Trainer:
    return Trainer(TINY)


@functools.cache
def tiny_after_two_epochs():
    trainer = tiny_trainer()
    state = trainer.init()
    initial = jax.tree.map(np.asarray, state.gs[0].actor)
    state, first = trainer.train_epoch(state)
    compiled = _jit_train_epoch._cache_size()
    state, second = trainer.train_epoch(state)
    assert _jit_train_epoch._cache_size() == compiled, "epoch 2 recompiled"
    return trainer, initial, state, first, second
