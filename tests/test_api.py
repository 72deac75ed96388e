"""The Python API: the README's example runs as written; bad input names the field."""

import subprocess
import sys
from pathlib import Path

import pytest

import mjx_emp
from mjx_emp.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def readme_example() -> str:
    """The python block after the README's api-example marker."""
    lines = (ROOT / "README.md").read_text().splitlines()
    start = lines.index("<!-- api-example -->") + 2
    end = lines.index("```", start)
    return "\n".join(lines[start:end])


def test_the_readme_example_trains_reports_each_epoch_and_loads(tmp_path):
    done = subprocess.run([sys.executable, "-c", readme_example()], cwd=tmp_path, capture_output=True,
                          text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.splitlines()
    reported = [line.split()[:3] for line in lines if line.split()[2:3] == ["success"]]  # on_epoch's lines
    assert reported == [["epoch", str(e), "success"] for e in (1, 2, 3)]
    assert "he 3 3" in lines
    assert "(1, 2)" in lines
    assert (tmp_path / "runs/api-example/config.json").exists()


def test_config_names_an_unknown_preset_or_field():
    with pytest.raises(ConfigError, match="preset: 'point-mass' is unknown; allowed values: .*'point-mass-k1'"):
        mjx_emp.config("point-mass")
    with pytest.raises(ConfigError, match="epoch: not a HEConfig field; allowed: "):
        mjx_emp.config("point-mass-k1", epoch=3)
    with pytest.raises(ConfigError, match="eps: every entry must be > 0"):
        mjx_emp.config("point-mass-k1", eps=(0.0,))


def test_the_package_exports_the_api_without_loading_jax():
    code = "import sys, mjx_emp; assert 'jax' not in sys.modules; print(sorted(mjx_emp.__all__))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "['Run', 'config', 'evaluate', 'load', 'presets', 'sweep', 'train']"
    with pytest.raises(AttributeError, match="has no attribute 'nothing'"):
        mjx_emp.nothing  # noqa: B018


def test_the_cli_imports_helps_lists_and_reports_without_loading_jax():
    """`import mjx_emp.cli`, `--help` (the CLI's, a command's and a preset's), `presets` and
    `report` (tables and flip tables) load none of JAX, MuJoCo, orbax, flax or optax: they answer at once; JAX loads with
    a command's handler. Parsing a command loads none either: `render` chooses MuJoCo's OpenGL
    after the parse, before MuJoCo is imported."""
    code = """
import sys
import mjx_emp.cli as cli
for argv in (["--help"], ["sweep", "--help"], ["train", "ant-field-k1-cpu", "--help"], ["presets"],
             ["report", "experiments/point-mass-levels.toml", "--reps", "10"],
             ["report", "experiments/ant-flips.toml", "--flip-table", "he-k1"]):
    sys.argv = ["mjx-emp", *argv]
    try:
        cli.main()
    except SystemExit as stop:
        assert stop.code in (0, None), (argv, stop.code)
for argv in (["render", "some-run"], ["train", "point-mass-k1", "--epochs", "3"]):
    cli.parse(cli.canonical_args(argv))  # parsed before the OpenGL set-up, so it must not import MuJoCo
heavy = [name for name in ("jax", "mujoco", "orbax", "flax", "optax") if name in sys.modules]
assert not heavy, heavy
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage: mjx-emp" in done.stdout and "ant-field-k1-cpu" in done.stdout and "| row |" in done.stdout
    assert "flips per 100 m gained toward the goal" in done.stdout


def test_every_algorithm_reports_in_one_schema():
    he_line = {"epoch": 2, "env_steps": 10.0, "seconds": 1.0, "flip_resets": 0,
               "levels": [{"level": 0, "success": 0.5}, {"level": 1, "success": 0.25}]}
    metra_line = {"epoch": 2, "env_steps": 10.0, "seconds": 1.0, "algorithm": "metra", "critic_loss": 0.1,
                  "dual_lambda": 3.0, "flip_resets": 1}
    from mjx_emp.api import one_schema

    he = one_schema(he_line, "he")
    metra = one_schema(metra_line, "metra")
    assert he == {**he_line, "algorithm": "he"}
    assert metra == {"epoch": 2, "env_steps": 10.0, "seconds": 1.0, "flip_resets": 1, "algorithm": "metra",
                     "levels": [{"level": 0, "critic_loss": 0.1, "dual_lambda": 3.0}]}
    assert set(he) == set(metra)
