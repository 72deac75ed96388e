"""Test-session set-up: one persistent XLA compilation cache shared by the test processes and
their CLI subprocesses.

Identical programs compiled by both pytest workers, or by a test and a CLI subprocess, then
compile once per session; what they compute is unchanged. The cache lives in a temporary
directory, so every session starts cold, as CI does.
"""

import atexit
import gc
import os
import shutil
import sys
import tempfile
from pathlib import Path

FAST_CODEGEN = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")
"""XLA's CPU back end set to compile fast, for this process and every subprocess.

Almost all of the suite's time is XLA compiling small programs that then run for
milliseconds. LLVM without its optimisation passes, and XLA's older fusion code generator in
place of its MLIR fusion emitters, compile them in less than half the time
(``benchmarks/compile_flags.py``). Results may differ from the default flags' in a float's
last bits; every test compares programs compiled under these same flags, in this process and
in its subprocesses, which inherit them."""
for flag in FAST_CODEGEN:
    if flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip()

if "MJX_EMP_TEST_CACHE" not in os.environ:  # the first pytest process; its workers inherit the directory
    os.environ["MJX_EMP_TEST_CACHE"] = tempfile.mkdtemp(prefix="mjx-emp-xla-cache-")
    atexit.register(shutil.rmtree, os.environ["MJX_EMP_TEST_CACHE"], ignore_errors=True)
os.environ["JAX_COMPILATION_CACHE_DIR"] = os.environ["MJX_EMP_TEST_CACHE"]
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
"""Every program is kept, however fast it compiled (the command line keeps those over 1 s): the suite
runs the same configs in many processes, and an evaluation alone compiles about 170 programs, most
of them small. One smoke-sweep run's `mjx-emp eval` took 44 s cold, 21.5 s warm with the 1 s threshold
and 18.9 s warm with every program kept (measured beside a training run)."""

import jax  # noqa: E402 (after the environment it reads)
import pytest  # noqa: E402

SLOW = os.environ.get("MJX_EMP_SLOW") == "1"


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a test the default suite leaves out (set MJX_EMP_SLOW=1 to run it): "
                                       "a second path to what a default test already covers, or minutes of CPU")


def pytest_collection_modifyitems(config, items):
    """Skip the tests marked slow unless MJX_EMP_SLOW=1, so the default suite stays within its time."""
    if SLOW:
        return
    skip = pytest.mark.skip(reason="slow tier; run with MJX_EMP_SLOW=1")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


MAPPINGS_BEFORE_CLEARING = 20_000
"""A third of Linux's default limit of 65530 memory mappings per process (vm.max_map_count)."""


def memory_mappings() -> int:
    """How many memory mappings this process holds (0 where /proc is not available)."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


@pytest.fixture(autouse=True)
def release_compiled_programs():
    """Drop every compiled program once the process holds many memory mappings.

    Each XLA CPU executable holds dozens of memory mappings, and JAX keeps every program it
    compiled for as long as the process lives. Over the whole suite one pytest process
    reached Linux's limit (vm.max_map_count, 65530) in test_skills and died with SIGSEGV
    inside XLA's compiler (measured: 64155 mappings at the 190th test). Clearing after every
    test instead made the suite recompile so much that it took 23.5 minutes instead of 18
    (one process, clean-clone runs).
    """
    yield
    if memory_mappings() > MAPPINGS_BEFORE_CLEARING:
        jax.clear_caches()
        gc.collect()


sys.path.insert(0, str(Path(__file__).parent))  # shared helpers such as tiny.py
