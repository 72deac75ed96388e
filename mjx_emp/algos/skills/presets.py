"""Presets of the flat skill learners, for ALGO in diayn, hidio, dads, metra: ``ALGO-point-mass``,
``ALGO-ant-field-cpu``, ``ALGO-half-cheetah-field-cpu``, ``ALGO-ant-field-gpu`` and
``ALGO-half-cheetah-field-gpu`` (names as :mod:`mjx_emp.algos.names`; no levels, so no kK).

Shared choices, with their source: METRA's published code (seohongpark/METRA,
tests/main.py) for everything SAC (rates 1e-4, initial alpha 0.01, target entropy -|A|/2,
tau 5e-3, discount 0.99, minibatch 256), lambda 30 and slack 1e-3 for METRA's dual; DIAYN
and HIDIO as Levy et al. ran them (continuous z in [-1, 1]^2, a diagonal-Gaussian
posterior). Ours, for the 2-core CPU: two hidden layers of 256 (METRA: 1024), 16
environments, skills of n = 10 actions on the point mass (the horizon of HE's
``point-mass-k1`` skills, so that coverage compares skills of equal length), and L = 16
prior skills in DADS's reward instead of the 100 of METRA's code (``num_alt_samples``):
with 100, every gradient step evaluates the skill dynamics on 25,600 rows (256 x 100), which
makes DADS's epoch many times DIAYN's on a 2-core CPU.
"""

from __future__ import annotations

import dataclasses

from mjx_emp.algos.skills.config import (
    DadsConfig,
    DiaynConfig,
    HidioConfig,
    MetraConfig,
    SkillConfig,
)

_POINT_MASS = dict(env="point_mass", skill_dim=2, n=10, epochs=200, num_envs=16, collect_steps=10, iterations=10,
                   grad_steps=25, batch_size=256, replay_capacity=100_000, min_replay=1_000, hidden=(256, 256))


# The robots: skills of n = 20 actions (HE's ant-field-k1-cpu and half-cheetah-field-k1-cpu
# skill length: 3.75 s on the Ant, 3 s on the Half Cheetah), 300 epochs of 3,200 environment
# steps and 250 gradient steps each (0.96 M steps; HE's k=1 robot presets simulate 2.0-2.2 M).
# The Ant runs the constraint solver at 4 iterations, as HE's Ant recipe does.
_ROBOTS = dict(skill_dim=2, n=20, epochs=300, num_envs=16, collect_steps=20, iterations=10, grad_steps=25,
               batch_size=256, replay_capacity=300_000, min_replay=5_000, hidden=(256, 256))


# The GPU rows beside Table 1's Ant Field Small and Half Cheetah Small (HE's
# ant-field-k1-paper-small and half-cheetah-field-k1-paper-small: skills of n = 20 actions,
# 4096 environments): skills of 20 actions, 4096 environments, METRA's 1024-wide
# networks and L = 100 prior skills for DADS (METRA's code), 50 gradient steps on
# minibatches of 1024 per iteration, 500 epochs of 819,200 environment steps (0.41 B).
_GPU = dict(skill_dim=2, n=20, epochs=500, num_envs=4096, collect_steps=20, iterations=10, grad_steps=50,
            batch_size=1024, replay_capacity=1_000_000, min_replay=20_000, hidden=(1024, 1024))


def _cpu_extras(config_type: type[SkillConfig]) -> dict:
    return {"prior_samples": 16} if config_type is DadsConfig else {}


def _point_mass(config_type: type[SkillConfig]) -> SkillConfig:
    return config_type(**_POINT_MASS, **_cpu_extras(config_type))


def _robot(config_type: type[SkillConfig], env: str) -> SkillConfig:
    return config_type(env=env, **_ROBOTS, **_cpu_extras(config_type))


PRESETS: dict[str, tuple[str, SkillConfig]] = {
    "diayn-point-mass": ("DIAYN: continuous skills in [-1, 1]^2, posterior q(z|s0,s_t)", _point_mass(DiaynConfig)),
    "hidio-point-mass": ("HIDIO: posterior q(z|s0,a_t-1,s_t)", _point_mass(HidioConfig)),
    "dads-point-mass": ("DADS: skill dynamics q(s'|s,z), L = 16 prior skills", _point_mass(DadsConfig)),
    "metra-point-mass": ("METRA: phi under ||phi(s')-phi(s)|| <= 1, unit-length skills", _point_mass(MetraConfig)),
}
for _name, _type in (("diayn", DiaynConfig), ("hidio", HidioConfig), ("dads", DadsConfig), ("metra", MetraConfig)):
    PRESETS[f"{_name}-ant-field-cpu"] = (f"{_name.upper()} on the paper's Ant, skills of 20 actions, 4 solver "
                                         f"iterations as ant-field-k1-cpu (CPU)",
                                         dataclasses.replace(_robot(_type, "ant_field"), solver_iterations=4))
    PRESETS[f"{_name}-half-cheetah-field-cpu"] = (f"{_name.upper()} on the paper's Half Cheetah, skills of 20 "
                                                  f"actions (CPU)", _robot(_type, "half_cheetah_field"))
    PRESETS[f"{_name}-ant-field-gpu"] = (f"{_name.upper()} beside Table 1's Ant Field Small (GPU scale)",
                                         _type(env="ant_field", **_GPU))
    PRESETS[f"{_name}-half-cheetah-field-gpu"] = (f"{_name.upper()} beside Table 1's Half Cheetah Small (GPU "
                                                  f"scale)", _type(env="half_cheetah_field", **_GPU))
"""Name -> (description, config)."""
