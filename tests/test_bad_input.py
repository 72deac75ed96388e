"""Every numeric flag of every command, drawn at random (negative, zero, huge, NaN, inf, words,
fractions for counts): the command line is either accepted or refused with one line naming the
flag, never a traceback. Hypothesis draws the values; the property runs the command's parse and
its checks in-process (what the CLI does before any work), and a few drawn cases run through
the real command line to tie the two together (exit code 2, one line on stderr)."""

from __future__ import annotations

import dataclasses
import math
import typing

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tiny import cli_in_process

from mjx_emp import cli, commands
from mjx_emp.algos.registry import algorithm_of, all_presets
from mjx_emp.errors import ConfigError
from mjx_emp.phase2.config import Phase2Config, check_phase2_config
from mjx_emp.phase2.presets import PHASE2_PRESETS


def numeric_fields(*types: type) -> list[str]:
    """The fields of ``types`` (dataclasses, nested ones followed) holding numbers or tuples of numbers."""
    found = []
    for kind in types:
        hints = typing.get_type_hints(kind)
        for field in dataclasses.fields(kind):
            hint = hints[field.name]
            if dataclasses.is_dataclass(hint):
                found += numeric_fields(hint)
                continue
            args = [a for a in typing.get_args(hint) if a is not type(None) and a is not Ellipsis]
            if hint in (int, float) or (args and all(a in (int, float) for a in args)):
                found.append(field.name)
    return sorted(set(found))


def check_sweep(exp: commands.SweepExperiment) -> None:
    if exp.workers < 1:
        raise ConfigError(f"workers: must be >= 1; got {exp.workers}")


def check_report(exp: commands.ReportExperiment) -> None:
    if exp.reps < 1:
        raise ConfigError(f"reps: must be >= 1; got {exp.reps}")


def check_train(exp: commands.TrainExperiment) -> None:
    """The request's checks, then the config's, which building the agent runs."""
    commands.check_train(exp)
    algorithm_of(exp.config).check(exp.config)


def check_phase2(exp: commands.Phase2Experiment) -> None:
    """The request's checks, then the config's, which building the phase-2 trainer runs."""
    commands.check_phase2(exp)
    check_phase2_config(exp.config)


PHASE1 = type(all_presets()["point-mass-k1"][1])
COMMANDS = {
    "train": (["train", "point-mass-k1"], check_train, numeric_fields(commands.TrainExperiment, PHASE1)),
    "resume": (["resume", "no-run"], commands.check_resume, numeric_fields(commands.ResumeExperiment)),
    "phase2": (["phase2", next(iter(PHASE2_PRESETS)), "no-run"], check_phase2,
               numeric_fields(commands.Phase2Experiment, Phase2Config)),
    "export": (["export", "no-run", "--out", "no-export"], commands.check_export,
               numeric_fields(commands.ExportExperiment)),
    "eval": (["eval", "no-run"], commands.check_eval, numeric_fields(commands.EvalExperiment)),
    "render": (["render", "no-run"], commands.check_render, numeric_fields(commands.RenderExperiment)),
    "rollout": (["rollout"], commands.check_rollout, numeric_fields(commands.RolloutExperiment)),
    "sweep": (["sweep", "no-spec.toml"], check_sweep, numeric_fields(commands.SweepExperiment)),
    "report": (["report", "no-spec.toml"], check_report, numeric_fields(commands.ReportExperiment)),
}

VALUES = st.one_of(
    st.integers(min_value=-(10**30), max_value=10**30).map(str),
    st.sampled_from(["0", "-1", "1e20", "2e64", str(2**64), str(2**63), "nan", "inf", "-inf", "NaN", "0.5",
                     "-0.0", "1_000", "", "abc", "None", "True", "0x10", "1,2"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(alphabet="abcxyz-_.09 ", min_size=1, max_size=6),
)


def checked(argv: list[str]) -> str | None:
    """Parse ``argv`` as the CLI does and run its command's checks: None if accepted, else the one
    line the CLI prints for it."""
    command, exp = cli.parse(cli.canonical_args(argv))
    COMMANDS[argv[0]][1](exp)
    return None


def flag(field: str) -> str:
    return "--" + field.replace("_", "-")


@pytest.mark.parametrize("name", sorted(COMMANDS))
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_every_numeric_flag_is_accepted_or_refused_in_one_line(name, data):
    base, _, fields = COMMANDS[name]
    field = data.draw(st.sampled_from(fields), label="field")
    value = data.draw(VALUES, label="value")
    try:
        checked([*base, flag(field), value])
    except ConfigError as err:
        message = str(err)
        assert "\n" not in message and message, message
        assert "Traceback" not in message


def test_the_property_covers_every_numeric_flag():
    counts = {name: len(fields) for name, (_, _, fields) in COMMANDS.items()}
    assert counts["train"] >= 30 and counts["phase2"] >= 15 and min(counts.values()) >= 1, counts
    assert {"epochs", "seed", "max_env_steps", "num_envs", "video_steps", "join_timeout"} <= set(COMMANDS["train"][2])


@pytest.mark.parametrize("argv, named", [
    (["train", "point-mass-k1", "--epochs", "1e20"], "--epochs"),
    (["train", "point-mass-k1", "--epochs", str(10**20)], "epochs: must be at most"),
    (["train", "point-mass-k1", "--seed", str(2**64)], "seed: must be in [0, 9,223,372,036,854,775,807]"),
    (["train", "point-mass-k1", "--video-steps", str(10**11)], "video_steps: must be in [0, 100000]"),
    (["render", "no-run", "--width", "100000", "--height", "100000"], "width: must be in [1, 8192]"),
    (["eval", "no-run", "--seed", str(2**64)], "seed: must be in [0, 9,223,372,036,854,775,807]"),
    (["train", "point-mass-k1", "--num-envs", "nan"], "--num-envs"),
    (["eval", "no-run", "--bogus", "1"], "Unrecognized options"),
])
def test_the_command_line_refuses_nonsense_with_exit_2_and_one_line(argv, named):
    result = cli_in_process(*argv)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-1500:]
    assert named in lines[0] and lines[0].startswith("mjx-emp: invalid configuration: ")


def test_huge_and_non_finite_floats_are_refused_by_name():
    for value in ("nan", "inf", "-inf"):
        with pytest.raises(ConfigError, match="fps: must be a finite number"):
            checked(["render", "no-run", "--fps", value])
    assert not math.isfinite(float("inf"))
