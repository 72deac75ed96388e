"""How a figure was made: the code, the packages, the machine and the command behind a run or a row.

Every evaluation row carries two of these: the training run's (written into the run
directory when it starts, ``provenance.json``) and the evaluation's own. What cannot be
known is recorded as :data:`UNKNOWN`, never guessed.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

UNKNOWN = "unknown"
"""The value of a provenance field nobody recorded."""

PROVENANCE_FILE = "provenance.json"
"""A run directory's record of how its training was started."""

EXPORT_OF = "export_of"
"""The provenance field of a skills export (`mjx-emp export`): the run directory it was taken from."""

PACKAGES = ("mjx-emp", "jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax", "orbax-checkpoint")
"""The packages whose versions decide what a run computes."""

SOURCE = Path(__file__).resolve().parents[2]
"""The checkout the package runs from (its git state is the code's commit)."""


def package_versions() -> dict[str, str]:
    """The installed version of each of :data:`PACKAGES` (``unknown`` where one is not installed)."""
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = UNKNOWN
    return versions


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(["git", "-C", str(SOURCE), *args], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout if done.returncode == 0 else None


def code_state() -> dict[str, Any]:
    """The commit the package's checkout is at and whether its tracked files differ from it
    (``dirty``); ``unknown`` for both outside a git checkout (an installed wheel)."""
    commit = _git("rev-parse", "HEAD")
    if commit is None:
        return {"commit": UNKNOWN, "dirty": UNKNOWN}
    status = _git("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit.strip(), "dirty": UNKNOWN if status is None else bool(status.strip())}


def machine() -> dict[str, Any]:
    """The host and, where JAX is already loaded, the device it computes on (JAX is never
    imported here: a light process records its host only)."""
    info: dict[str, Any] = {"host": platform.node() or UNKNOWN, "system": platform.system(),
                            "processor": platform.machine(), "cpus": os.cpu_count() or UNKNOWN,
                            "python": platform.python_version()}
    jax = sys.modules.get("jax")
    if jax is not None:
        devices = jax.devices()
        info["backend"] = jax.default_backend()
        info["devices"] = f"{len(devices)} x {devices[0].device_kind}"
    return info


def command_line(argv: list[str] | None = None) -> str:
    """The command that is running, as a shell would take it back."""
    argv = sys.argv if argv is None else argv
    program = Path(argv[0]).name if argv else "python"
    return shlex.join([program, *argv[1:]])


def provenance(command: str | None = None) -> dict[str, Any]:
    """This process's provenance: code state, package versions, machine, command and time."""
    return {**code_state(), "versions": package_versions(), "machine": machine(),
            "command": command or command_line(), "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def run_record(preset: str | None, overrides: dict[str, Any], command: str | None = None) -> dict[str, Any]:
    """What a run directory's ``provenance.json`` holds: the preset and overrides it was started
    from (``preset`` None where it was given as a config) and this process's provenance."""
    return {"preset": preset if preset is not None else UNKNOWN, "overrides": dict(overrides),
            **provenance(command)}


def overrides_of(base: Any, cfg: Any) -> dict[str, Any]:
    """The fields of config ``cfg`` that differ from ``base`` (its preset's), JSON-ready: what
    `mjx-emp train PRESET --FIELD VALUE` was given beyond the preset."""
    if type(base) is not type(cfg):
        return {}
    theirs, ours = dataclasses.asdict(base), dataclasses.asdict(cfg)
    return json.loads(json.dumps({name: value for name, value in ours.items() if theirs.get(name) != value}))
