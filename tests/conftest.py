"""Test-session set-up: one persistent XLA compilation cache shared by the CLI subprocesses.

Identical programs compiled by several CLI subprocesses then compile once per session;
what they compute is unchanged. The cache lives in a temporary
directory, so every session starts cold, as CI does.
"""

import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

_CACHE = tempfile.mkdtemp(prefix="mjx-emp-xla-cache-")
atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)
os.environ["JAX_COMPILATION_CACHE_DIR"] = _CACHE
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "1"

import jax  # noqa: E402 (after the environment it reads)

# The CLI subprocesses share the cache; this process keeps its programs in memory only. One
# clean-clone run crashed (SIGSEGV) inside JAX's cache write of an in-process program,
# and did not crash again when rerun alone.
jax.config.update("jax_enable_compilation_cache", False)

sys.path.insert(0, str(Path(__file__).parent))  # shared helpers such as tiny.py
sys.path.insert(0, str(Path(__file__).parents[1] / "experiments"))  # the experiment scripts
