"""The algorithm registry: config.json names the algorithm, and runs of any algorithm rebuild."""

import dataclasses
import json

import pytest
from tiny import TINY

from mjx_emp.algos.he.config import HEConfig
from mjx_emp.algos.he.presets import PRESETS
from mjx_emp.algos.registry import (
    ALGORITHMS,
    GOAL_SPACES,
    LATENT_SKILLS,
    algorithm_of,
    all_presets,
    config_from_json,
    config_to_json,
    make_agent,
)
from mjx_emp.errors import ConfigError


def test_config_json_names_the_algorithm_and_round_trips():
    values = json.loads(json.dumps(config_to_json(TINY)))
    assert values["algorithm"] == "he"
    assert config_from_json(values) == TINY


def test_a_config_json_without_an_algorithm_is_an_older_he_run():
    values = json.loads(json.dumps(dataclasses.asdict(TINY)))
    assert config_from_json(values) == TINY


def test_an_unknown_algorithm_is_refused_naming_the_key_and_the_choices():
    allowed = r"\['dads', 'diayn', 'gcrl', 'he', 'hidio', 'metra'\]"
    with pytest.raises(ConfigError, match=r"algorithm: 'nope' is unknown; allowed values: " + allowed):
        config_from_json({"algorithm": "nope", **dataclasses.asdict(TINY)})


def test_presets_of_every_algorithm_are_listed_once():
    presets = all_presets()
    assert set(PRESETS) <= set(presets)
    assert set(ALGORITHMS) == {"he", "gcrl", "diayn", "hidio", "dads", "metra"}
    for name, (_, cfg) in presets.items():
        algorithm = algorithm_of(cfg)
        assert type(cfg) is algorithm.config_type and name in algorithm.presets
        assert name.startswith(f"{algorithm.name}-") or algorithm.name == "he"
        algorithm.check(cfg)  # every preset is a valid config
        assert config_from_json(json.loads(json.dumps(config_to_json(cfg)))) == cfg


def test_make_agent_checks_the_config_before_building():
    with pytest.raises(ConfigError, match="env: 'moon' is unknown"):
        make_agent(dataclasses.replace(TINY, env="moon"))
    assert make_agent(TINY).cfg == TINY


def test_table_1_presets_keep_the_papers_learner_and_physics():
    paper = {name: cfg for name, (description, cfg) in PRESETS.items() if description.startswith("the paper's Table 1")}
    assert len(paper) == 12
    default = HEConfig()
    for name, cfg in paper.items():
        for field in ("her", "n_step", "critic_layer_norm", "actor_layer_norm", "relabel", "critics",
                      "solver_iterations", "integrator", "fresh_replay", "heading_frame", "learn_from_resets",
                      "reset_outcome", "tilt_cost", "flip_cost", "level_repeats"):
            assert getattr(cfg, field) == getattr(default, field), (name, field)
    assert all("-paper" in name for name in paper)


ABILITIES = {GOAL_SPACES: ("goal_spaces", "evaluate", "skill_chain", "skill_paths"),
             LATENT_SKILLS: ("skill_paths", "record_skills", "posterior_std")}


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_each_algorithms_agent_offers_what_its_kind_of_skills_promises(name):
    """eval, plot, render and phase 2 ask the registry entry what the skills are, then call these."""
    algorithm = ALGORITHMS[name]
    cfg = next(cfg for _, cfg in algorithm.presets.values() if cfg.env == "point_mass")
    agent = make_agent(cfg)
    missing = [ability for ability in ABILITIES[algorithm.skills] if not callable(getattr(agent, ability, None))]
    assert not missing, f"{name} ({algorithm.skills}) lacks {missing}"


def test_an_unknown_kind_of_skills_is_refused():
    he = ALGORITHMS["he"]
    with pytest.raises(ValueError, match="skills: 'options' is unknown; allowed values"):
        dataclasses.replace(he, skills="options")


def test_a_hand_set_box_names_a_config_field_of_its_algorithm():
    """Box sweeps replace the field the registry names; an algorithm that learns its goal space names none."""
    boxes = {name: algorithm.hand_set_box for name, algorithm in ALGORITHMS.items()}
    assert boxes["gcrl"] == "goal_half_width"
    assert boxes["he"] is None and boxes["metra"] is None
    for name, field in boxes.items():
        if field is not None:
            assert field in {f.name for f in dataclasses.fields(ALGORITHMS[name].config_type)}, name


def test_a_fresh_run_directory_is_named_by_the_registry_entrys_prefix():
    from mjx_emp.run.store import default_run_dir

    presets = all_presets()
    he, gcrl, metra = (presets[name][1] for name in ("ant-field-k1-cpu", "gcrl-ant-field-k1-cpu", "metra-ant-field-cpu"))
    assert default_run_dir(he).startswith("runs/ant_field-k1-")
    assert default_run_dir(gcrl).startswith("runs/gcrl-ant_field-k1-")
    assert default_run_dir(metra).startswith(f"runs/metra-ant_field-k{metra.k}-")
