"""Small agents shared by the test modules: an in-process trainer and a CLI config; and a
benchmark script loaded as a module."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import importlib.util
import io
import logging
import os
import subprocess
import sys
import threading
from pathlib import Path

import jax
import numpy as np

from mjx_emp.algos.he.agent import HEAgent
from mjx_emp.algos.he.config import HEConfig
from mjx_emp.algos.he.state import TRAIN_EPOCH_TRACE
from mjx_emp.phase2.config import Phase2Config
from mjx_emp.tracing import traces

TINY = HEConfig(
    env="point_mass", n=(3, 2), sigma_gc=(0.4, 0.8), sigma_gs=(0.4, 0.8), eps=(0.3, 0.6),
    init_half_width=(0.3, 0.6), max_half_width=(3.0, 6.0), num_envs=8, chunk_steps=3,
    gc_iterations=2, gc_grad_steps=3, gs_grad_steps=2, batch_size=16, replay_capacity=512,
    gs_replay_capacity=64, start_capacity=64, start_chain=2, hidden=(16,), seed=3,
)

TINY1 = dataclasses.replace(
    TINY, n=(3,), sigma_gc=(0.4,), sigma_gs=(0.4,), eps=(0.3,), init_half_width=(0.3,), max_half_width=(3.0,),
)
"""TINY with one level: what tests of the run layer (devices, seeds, damage, tracking) train,
where a second level would only cost compile time."""

TINY_PHASE2 = Phase2Config(
    n=3, eps=0.6, sigma=0.6, region=(2.0, 2.0), region_offset=(0.0, 0.0), num_envs=8, iterations=2,
    grad_steps=3, batch_size=16, replay_capacity=256, eval_rounds=1, hidden=(16,), epochs=2, seed=5,
)


@functools.cache
def tiny_trainer() -> HEAgent:
    return HEAgent(TINY)


@functools.cache
def tiny_after_two_epochs():
    trainer = tiny_trainer()
    state = trainer.init()
    initial = jax.tree.map(np.asarray, state.goal_spaces[0].actor)
    state, first = trainer.train_epoch(state)
    compiled = traces(TRAIN_EPOCH_TRACE)
    state, second = trainer.train_epoch(state)
    assert traces(TRAIN_EPOCH_TRACE) == compiled, "epoch 2 recompiled"
    return trainer, initial, state, first, second


# A CLI training config. Its large replay buffer makes each checkpoint write take long
# enough (~0.1 s) to be caught in the act; every test that runs it (the checkpoint kills,
# rendering) shares one compilation through the session's persistent cache.
SMALL = ["point-mass-k1", "--num-envs", "8", "--hidden", "32", "32", "--batch-size", "32",
         "--gc-iterations", "2", "--gc-grad-steps", "20", "--replay-capacity", "3000000",
         "--start-chain", "2", "--epochs", "4"]


def mjx_emp(*args: str) -> list[str]:
    """The command line that runs ``mjx-emp ARGS`` with this interpreter."""
    return [sys.executable, "-m", "mjx_emp.cli", *args]


def run_cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """Run ``mjx-emp ARGS`` to completion (in ``env``, else this process's environment), capturing its output."""
    return subprocess.run(mjx_emp(*args), capture_output=True, text=True, timeout=600, env=env)


def cli_in_process(*args: str) -> subprocess.CompletedProcess:
    """``mjx-emp ARGS`` run in this process through the command line's entry point, with what it
    prints and the code it exits with, as :func:`run_cli` gives them.

    For tests of what the command line decides (parsing, checks, the one-line message and exit
    code of a failure) that need no process of their own: a new interpreter spends seconds
    importing JAX and tracing what this process has traced already. What only a process shows
    (signals, a kill, what is printed at exit, OpenGL chosen before MuJoCo loads) keeps
    :func:`run_cli`. The libraries' hooks and the environment variables the command line sets are
    put back afterwards.
    """
    from mjx_emp.cli import main
    from mjx_emp.run.noise import LOGGERS

    loggers = [logging.getLogger(name) for name in LOGGERS]
    saved = [(logger, list(logger.handlers), logger.propagate) for logger in loggers]
    hooks, environ = (threading.excepthook, sys.unraisablehook), dict(os.environ)
    stdout, stderr = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            main(list(args))
        code = 0
    except SystemExit as stop:
        code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
        if isinstance(stop.code, str):
            stderr.write(stop.code + "\n")
    finally:
        for logger, handlers, propagate in saved:
            logger.handlers[:] = handlers
            logger.propagate = propagate
        threading.excepthook, sys.unraisablehook = hooks
        os.environ.clear()
        os.environ.update(environ)  # e.g. the OpenGL backend render chose
    return subprocess.CompletedProcess(["mjx-emp", *args], code, stdout.getvalue(), stderr.getvalue())


@functools.cache
def benchmark(name: str):
    """``benchmarks/NAME.py`` as a module, loaded from its file (benchmarks are not a package, and
    no test adds their folder to the import path)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the script runs
    spec.loader.exec_module(module)
    return module
