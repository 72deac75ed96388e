"""``mjx-emp`` command line: bad input exits 2 naming the field; the main job runs."""

import json
import subprocess
import sys

import pytest


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mjx_emp.cli", *args], capture_output=True, text=True, timeout=600
    )


@pytest.mark.parametrize(
    "args, field",
    [
        (["--env", "pointmass"], "point_mass"),  # tyro lists the allowed choices
        (["--n", "20", "10", "--eps", "0.5"], "eps"),
        (["--n", "0"], "n"),
        (["--n", "20", "--eps", "-1"], "eps"),
        (["--n", "20", "10", "10", "--eps", "1", "1", "1", "--subgoal-half-width", "2"], "subgoal_half_width"),
        (["--batch-size", "0"], "batch_size"),
    ],
)
def test_bad_rollout_config_exits_2_naming_the_field(args, field):
    result = cli("rollout", *args)
    assert result.returncode == 2, result.stderr
    assert field in result.stderr


def test_help_explains_fields():
    result = cli("rollout", "--help")
    assert result.returncode == 0
    assert "Max actions per level" in result.stdout


def test_rollout_main_job_reports_statistics():
    result = cli("rollout", "--n", "5", "3", "--eps", "0.3", "0.6", "--batch-size", "16",
                 "--steps", "30", "--calls", "1", "--hidden", "32", "32")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["k"] == 2 and report["primitive_steps"] == 16 * 30
    assert report["useful_step_fraction"] >= 0.95
    assert len(report["goals_ended_per_level"]) == 2
    assert report["goals_ended_per_level"][0] >= 16 * 30 // 5  # level 0 ends a goal at least every n actions
