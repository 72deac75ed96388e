"""The wheel built from pyproject.toml is a library that works: it carries every domain's MJCF."""

import os
import subprocess
import sys
import zipfile
from pathlib import Path

from mjx_emp.envs.registry import DOMAINS

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_builds_every_domain(tmp_path: Path) -> None:
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(wheels)],
                   check=True, timeout=600)
    (wheel,) = wheels.glob("mjx_emp-*.whl")
    shipped = {Path(name).name for name in zipfile.ZipFile(wheel).namelist() if name.endswith(".xml")}
    assert {spec.xml for spec in DOMAINS.values()} <= shipped

    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
                   check=True, timeout=600)
    # Run from an empty folder with the installed copy first on the path, so neither the
    # checkout nor its top-level models/ can be what builds the domains.
    script = (
        "import mjx_emp, pathlib, sys\n"
        f"assert pathlib.Path(mjx_emp.__file__).is_relative_to({str(target)!r}), mjx_emp.__file__\n"
        "from mjx_emp.envs.env import make_env\n"
        "from mjx_emp.envs.registry import DOMAINS\n"
        "for name in DOMAINS:\n"
        "    env = make_env(name)\n"
        "    assert env.mj_model.nq > 0, name\n"
        "print('built', len(DOMAINS))\n"
    )
    environment = {**os.environ, "PYTHONPATH": str(target)}
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=environment,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"built {len(DOMAINS)}" in done.stdout
