"""The preset catalogue: one name grammar, the recommended recipes, the retired names and the listing."""

import dataclasses
import json
import re
from pathlib import Path

import pytest

from mjx_emp import cli
from mjx_emp.algos.he.presets import PRESETS as HE_PRESETS
from mjx_emp.algos.names import (
    CPU_MAX_ENVS,
    GOAL_SPACE_ALGOS,
    PAPER_ENVS,
    listing_lines,
    parse_preset_name,
    parse_task_name,
    recommended_names,
)
from mjx_emp.algos.registry import (
    algorithm_of,
    all_presets,
    config_from_json,
    retired_config,
)
from mjx_emp.algos.retired import REDEFINED, RETIRED, Retired, flag_text, retired_rows
from mjx_emp.phase2.presets import PHASE2_PRESETS, PHASE2_RETIRED, phase2_preset_for

ROOT = Path(__file__).resolve().parents[1]
OLD_CATALOGUE = json.loads((ROOT / "tests" / "data" / "retired_presets.json").read_text())
"""Every preset and phase-2 task as it stood before the catalogue was renamed: name -> config."""

ROBOTS = ("ant-field", "half-cheetah-field", "ant-cage", "half-cheetah-cage")
RECOMMENDED = ["point-mass-k1", "point-mass-k2"] + [f"{domain}-k{k}-{size}" for domain in ROBOTS for k in (1, 2)
                                                   for size in ("cpu", "gpu")]


@pytest.mark.parametrize("name", sorted(all_presets()))
def test_every_preset_name_follows_the_grammar_and_says_what_its_config_is(name):
    config = all_presets()[name][1]
    parsed = parse_preset_name(name)
    assert str(parsed) == name
    assert parsed.algo == algorithm_of(config).name
    assert parsed.env == config.env
    if parsed.algo in GOAL_SPACE_ALGOS:
        assert parsed.k == len(config.n)
    if parsed.size == "cpu" or parsed.size is None:
        assert config.num_envs <= CPU_MAX_ENVS
    else:
        assert config.num_envs == PAPER_ENVS


@pytest.mark.parametrize("name, message", [
    ("ant-field-cpu-k1", "is not"),  # the old order
    ("ant-field-k1", "ends in its size"),
    ("point-mass-k1-cpu", "one size"),
    ("diayn-ant-field-k1-cpu", "no levels"),
    ("gcrl-ant-field-k2-cpu", "one level"),
    ("gcrl-point-mass", "number of levels"),
    ("metra-ant-field-paper-small", "only Hierarchical Empowerment"),
    ("ant-field-k1-paper", "paper sizes"),
    ("ant-cage-k1-paper-small", "paper sizes"),
    ("moon-k1-cpu", "is not"),
])
def test_a_name_outside_the_grammar_is_refused_with_the_reason(name, message):
    with pytest.raises(ValueError, match=message):
        parse_preset_name(name)


def test_the_recommended_recipes_are_one_per_domain_and_depth_at_each_size():
    assert recommended_names(all_presets()) == RECOMMENDED
    assert set(RECOMMENDED) <= set(HE_PRESETS)


def test_a_gpu_recipe_is_its_cpu_recipe_at_the_papers_shape():
    """4096 environments and minibatches of 1024, as the H200 ran ant-field-k1; a recipe that
    stops at a CPU step budget runs epochs instead."""
    for domain in ROBOTS:
        for k in (1, 2):
            cpu, gpu = HE_PRESETS[f"{domain}-k{k}-cpu"][1], HE_PRESETS[f"{domain}-k{k}-gpu"][1]
            assert (gpu.num_envs, gpu.batch_size) == (4096, 1024)
            stops = {"epochs": gpu.epochs, "max_env_steps": gpu.max_env_steps}
            assert dataclasses.replace(cpu, num_envs=4096, batch_size=1024, **stops) == gpu
            assert gpu.max_env_steps is None
            if cpu.max_env_steps is None:
                assert gpu.epochs == cpu.epochs


@pytest.mark.parametrize("name", sorted(PHASE2_PRESETS))
def test_every_task_name_follows_the_grammar_and_names_its_domain(name):
    _, phase1, _ = PHASE2_PRESETS[name]
    parsed, base = parse_task_name(name), parse_preset_name(phase1)
    assert parsed.domain == base.domain
    if parsed.size is not None and parsed.size.startswith("paper"):
        assert name == f"reach-{phase1}"  # a Table-2 task is named after its Table-1 row
    elif parsed.size == "cpu":
        assert base.size == "cpu"


@pytest.mark.parametrize("name", ["reach-ant-field", "reach-ant-field-k1-cpu", "reach-ant-field-gpu",
                                  "reach-ant-field-paper-small", "reach-ant-field-cpu-wide", "ant-field-k1-cpu"])
def test_a_task_name_outside_the_grammar_is_refused(name):
    with pytest.raises(ValueError):
        parse_task_name(name)


def test_every_retired_name_gives_back_its_old_config():
    """Each name that left (or now names another config) rebuilds, from the catalogue and its
    changes, exactly the config it had; the names that stayed kept theirs."""
    presets = all_presets()
    for name, values in OLD_CATALOGUE["phase1"].items():
        old = config_from_json(values)
        if name in RETIRED or name in REDEFINED:
            assert retired_config(name) == old, name
        else:
            assert presets[name][1] == old, name
    assert not set(RETIRED) & set(presets)
    assert set(REDEFINED) <= set(presets)
    assert {entry.preset for entry in [*RETIRED.values(), *REDEFINED.values()]} <= set(presets)


@pytest.mark.parametrize("name", sorted({*RETIRED, *REDEFINED}))
def test_a_retired_names_command_parses_to_its_old_config(name):
    """The command RETIRED shows is spelled as `mjx-emp train` reads it."""
    entry = RETIRED.get(name) or REDEFINED[name]
    _, experiment = cli.parse(["train", *entry.command.split()])
    assert experiment.config == config_from_json(OLD_CATALOGUE["phase1"][name])


def test_every_retired_task_name_gives_back_its_old_task():
    for name, old in OLD_CATALOGUE["phase2"].items():
        task = json.loads(json.dumps(dataclasses.asdict(PHASE2_PRESETS[PHASE2_RETIRED[name].preset][2])))
        assert {field: task[field] for field in old["config"]} == old["config"], name
        default = json.loads(json.dumps(dataclasses.asdict(type(PHASE2_PRESETS[PHASE2_RETIRED[name].preset][2])())))
        assert all(task[field] == default[field] for field in set(task) - set(old["config"])), name  # added since
    assert not set(PHASE2_RETIRED) & set(PHASE2_PRESETS)


def test_flags_are_spelled_as_the_cli_spells_them():
    assert flag_text("tilt_cost", 1.0) == "--tilt-cost 1.0"
    assert flag_text("critic_layer_norm", False) == "--no-critic-layer-norm"
    assert flag_text("learn_from_resets", True) == "--learn-from-resets"
    assert flag_text("sigma_gs", (0.5, 1.0)) == "--sigma-gs 0.5 1.0"
    assert flag_text("level_repeats", ()) == "--level-repeats"
    assert Retired("ant-field-k1-cpu", (("tilt_cost", 4.0), ("epochs", 120))).command == \
        "ant-field-k1-cpu --tilt-cost 4.0 --epochs 120"


def test_every_preset_whose_domain_has_a_task_gets_a_task_of_its_domain():
    """Runs of every preset find their phase-2 task: CPU runs of any depth the domain's CPU task,
    GPU runs the Table-2 task of their domain and depth, Table-1 rows their own."""
    task_domains = {parse_task_name(name).domain for name in PHASE2_PRESETS}
    for name, (_, config) in all_presets().items():
        parsed = parse_preset_name(name)
        if parsed.domain not in task_domains:
            continue
        task = phase2_preset_for(config)
        assert task is not None, name
        assert parse_task_name(task).domain == parsed.domain, (name, task)
        seeded = dataclasses.replace(config, seed=config.seed + 1, epochs=config.epochs + 1)
        assert phase2_preset_for(seeded) == task, name  # seed and epochs do not change the task
        if parsed.size == "cpu":
            assert task == f"reach-{parsed.domain}-cpu", name
        elif parsed.size == "gpu":
            assert parse_task_name(task).k == (parsed.k or 1) and task.endswith(("-paper", "-paper-small",
                                                                                 "-paper-big")), (name, task)
        elif parsed.size is not None:
            assert task == f"reach-{name}"
    assert phase2_preset_for(HE_PRESETS["point-mass-k1"][1]) == "reach-point-mass"
    assert phase2_preset_for(HE_PRESETS["point-mass-k2"][1]) == "reach-point-mass-wide"
    assert phase2_preset_for(HE_PRESETS["ant-field-k1-gpu"][1]) == "reach-ant-field-k1-paper-small"
    assert phase2_preset_for(HE_PRESETS["ant-field-k2-gpu"][1]) == "reach-ant-field-k2-paper-big"
    assert phase2_preset_for(dataclasses.replace(HE_PRESETS["point-mass-k1"][1], env="moon")) is None


def test_the_listing_fits_a_screen_and_shows_the_recommended_recipes_first():
    lines = listing_lines(all_presets(), PHASE2_PRESETS)
    assert len(lines) <= 40
    listed = [word for line in lines[1:] for word in line.split() if word in all_presets() or word in PHASE2_PRESETS]
    assert listed[:len(RECOMMENDED)] == RECOMMENDED
    assert sorted(listed) == sorted([*all_presets(), *PHASE2_PRESETS])  # each name once


def test_mjx_emp_presets_prints_the_listing(capsys):
    cli.main(["presets"])
    out = capsys.readouterr().out.splitlines()
    assert out == listing_lines(all_presets(), PHASE2_PRESETS)
    assert len(out) <= 40


@pytest.mark.parametrize("argv, message", [
    (["train", "ant-field-cpu-k1-4iter-ln-tilt1"],
     "'ant-field-cpu-k1-4iter-ln-tilt1' left the catalogue; its config is "
     "`mjx-emp train ant-field-k1-cpu --tilt-cost 1.0`"),
    (["train", "ant-field-small-k1", "--epochs", "3"],
     "'ant-field-small-k1' left the catalogue; its config is `mjx-emp train ant-field-k1-paper-small`"),
    (["phase2", "ant-field-cpu-k1", "runs/none"],
     "'ant-field-cpu-k1' left the catalogue; its config is `mjx-emp phase2 reach-ant-field-cpu RUN_DIR`"),
])
def test_a_retired_name_exits_2_with_the_command_that_replaces_it(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


def test_the_presets_page_lists_every_retired_name_with_its_command():
    page = (ROOT / "docs" / "presets.md").read_text()
    rows = [*retired_rows(RETIRED, "mjx-emp train PRESET"), *retired_rows(REDEFINED, "mjx-emp train PRESET"),
            *retired_rows(PHASE2_RETIRED, "mjx-emp phase2 PRESET RUN_DIR")]
    assert [row for row in rows if row not in page.splitlines()] == []
    assert "\n## Names\n" in page


def test_every_command_in_the_docs_names_a_preset_of_the_catalogue():
    """`mjx-emp train NAME` and `mjx-emp phase2 NAME` in the README and docs run: NAME is a preset
    or task (for phase 2, else a run directory)."""
    unknown = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for line in page.read_text().splitlines():
            for command, name in re.findall(r"mjx-emp (train|phase2) ([a-z][\w.-]*)", line):
                known = all_presets() if command == "train" else PHASE2_PRESETS
                if name not in known and (command == "train" or name in PHASE2_RETIRED):
                    unknown.append(f"{page.name}: {line.strip()}")
    assert unknown == []
