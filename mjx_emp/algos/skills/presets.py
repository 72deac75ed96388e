"""Presets of the flat skill learners, ``ALGO-point-mass`` for ALGO in diayn, hidio, dads, metra.

Shared choices, with their source: METRA's published code (seohongpark/METRA,
tests/main.py) for everything SAC (rates 1e-4, initial alpha 0.01, target entropy -|A|/2,
tau 5e-3, discount 0.99, minibatch 256), lambda 30 and slack 1e-3 for METRA's dual, L =
100 prior skills for DADS (its ``num_alt_samples``); DIAYN and HIDIO as Levy et al. ran
them (continuous z in [-1, 1]^2, a diagonal-Gaussian posterior). Ours, for the 2-core CPU:
two hidden layers of 256 (METRA: 1024), 16 environments, and skills of n = 10 actions,
the horizon of HE's ``point-mass-k1`` skills, so that coverage compares skills of equal
length.
"""

from __future__ import annotations

from mjx_emp.algos.skills.config import DadsConfig, DiaynConfig, HidioConfig, MetraConfig, SkillConfig

_POINT_MASS = dict(env="point_mass", skill_dim=2, n=10, epochs=200, num_envs=16, collect_steps=10, iterations=10,
                   grad_steps=25, batch_size=256, replay_capacity=100_000, min_replay=1_000, hidden=(256, 256))


def _point_mass(config_type: type[SkillConfig]) -> SkillConfig:
    return config_type(**_POINT_MASS)


PRESETS: dict[str, tuple[str, SkillConfig]] = {
    "diayn-point-mass": ("DIAYN: continuous skills in [-1, 1]^2, posterior q(z|s0,s_t)", _point_mass(DiaynConfig)),
    "hidio-point-mass": ("HIDIO: posterior q(z|s0,a_t-1,s_t)", _point_mass(HidioConfig)),
    "dads-point-mass": ("DADS: skill dynamics q(s'|s,z), L = 100 prior skills", _point_mass(DadsConfig)),
    "metra-point-mass": ("METRA: phi under ||phi(s')-phi(s)|| <= 1, unit-length skills", _point_mass(MetraConfig)),
}
"""Name -> (description, config)."""
