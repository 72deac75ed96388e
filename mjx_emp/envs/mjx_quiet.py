"""Quiet import of ``mujoco.mjx``.

mujoco-mjx prints two "Failed to import warp" lines on stdout when the optional
Warp backend is absent (always, on CPU). We use the JAX backend only, so the lines
are noise that would pollute CLI output and JSON written to stdout.
"""

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401

__all__ = ["mjx"]
