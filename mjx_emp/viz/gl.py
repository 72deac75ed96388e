"""Which OpenGL MuJoCo renders offscreen with: set in the environment before ``mujoco`` is
first imported (plain Python, no MuJoCo), by the command line for ``render`` and for a tracked
run that films its end."""

from __future__ import annotations

import ctypes.util
import os

from mjx_emp.errors import RenderError

GL_BACKENDS = ("egl", "osmesa", "glx", "glfw")
"""The MUJOCO_GL values MuJoCo accepts on Linux for an offscreen renderer."""


def configure_headless_gl() -> None:
    """Default MuJoCo to headless EGL rendering; call before ``mujoco`` is first imported. A
    MUJOCO_GL that MuJoCo would refuse on import is a RenderError naming the values it takes."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    backend = os.environ["MUJOCO_GL"].lower().strip()
    if backend not in GL_BACKENDS:
        raise RenderError(f"MUJOCO_GL={os.environ['MUJOCO_GL']!r} is not a backend MuJoCo can render with; "
                          f"allowed values: {list(GL_BACKENDS)}")
    if backend == "egl":
        os.environ.setdefault("EGL_PLATFORM", "surfaceless")
    library = GL_LIBRARIES.get(backend)
    if library is not None:
        if not ctypes.util.find_library(library):  # import mujoco would fail deep inside PyOpenGL
            raise RenderError(f"MUJOCO_GL={backend}: the {library} library is not installed; install it (Debian: "
                              f"{GL_PACKAGES[backend]}) or set MUJOCO_GL to another of {list(GL_BACKENDS)}")


GL_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}
"""The shared library each headless backend loads."""
GL_PACKAGES = {"egl": "libegl1", "osmesa": "libosmesa6"}
"""The Debian package that provides it."""


def prefer_headless_gl() -> None:
    """Default MuJoCo to a headless backend whose library is installed (EGL, else OSMesa) for a
    command that renders only at its end; never raises: without one, that rendering fails alone
    (a RenderError) instead of ``import mujoco``. Call before ``mujoco`` is first imported."""
    if "MUJOCO_GL" in os.environ:
        return
    if ctypes.util.find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"
        os.environ.setdefault("EGL_PLATFORM", "surfaceless")
    elif ctypes.util.find_library("OSMesa"):
        os.environ["MUJOCO_GL"] = "osmesa"
