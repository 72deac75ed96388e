"""Phase 2 over any algorithm's skills: the trainer its kind of skills calls for."""

from __future__ import annotations

from typing import Any

from mjx_emp.algos.registry import LATENT_SKILLS, skill_kind
from mjx_emp.phase2.config import Phase2Config
from mjx_emp.phase2.goal_spaces import Phase2Trainer
from mjx_emp.phase2.latent import FlatPhase2Trainer


def make_phase2_trainer(skills: Any, cfg: Phase2Config) -> Phase2Trainer | FlatPhase2Trainer:
    """Phase 2 over any algorithm's skills, as its registry entry says they are: subgoals in
    learnt goal spaces (HE, GCRL) or a flat learner's z."""
    if skill_kind(skills.cfg) == LATENT_SKILLS:
        return FlatPhase2Trainer(skills, cfg)
    return Phase2Trainer(skills, cfg)
