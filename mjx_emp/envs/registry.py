"""The domains that exist, by name, and what distinguishes them (no JAX import).

The CLI and configs validate domain names against this registry before anything
compiles; :func:`mjx_emp.envs.env.make_env` builds an environment from an entry.
"""

from __future__ import annotations

import dataclasses

from mjx_emp.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class DomainSpec:
    """What distinguishes one domain from another: its MJCF file and its knobs."""

    xml: str
    action_repeat: int
    goal_qpos: tuple[int, ...]
    caged: bool = False
    torso_quat: int | None = None
    """Where the free torso's quaternion starts in qpos, for robots reset when upside down."""
    torso_pitch: int | None = None
    """Where a planar robot's torso pitch hinge is in qpos (the Half Cheetah's rooty): its up
    axis is tilted by that angle. Such a robot is never reset when upside down."""
    torso_height: int | None = None
    """Where the torso's height above the floor is in qpos (a free joint's z, the Half Cheetah's
    rootz): what a tilted start lifts so that no foot begins below the floor."""
    standardize: bool = False
    """Standardise network features by a random-action rollout's statistics (see
    :func:`random_action_feature_stats`)."""


# Control intervals follow the paper's Brax systems: 0.1875 s per Ant action (Brax's 10
# substeps; here 10 physics steps of 0.01875 s) and 0.15 s per Half Cheetah action (Brax
# used 48 substeps for its position-based solver; MuJoCo is stable with 10 of 0.015 s).
# The point mass, which the paper does not use, acts every 0.1 s (up to 0.2 m per action).
# An Ant that ends upside down cannot right itself: it is reset to its home pose (Gym's
# convention for an unhealthy Ant) and the episode it was in ends (``flip_resets``). A
# flipped Half Cheetah is never reset (as in Gym and Brax); its tilt is read from its torso's
# pitch hinge, for levels that pay for tilting (``tilt_cost``).
ANT_TORSO_QUAT = 3
ANT_TORSO_HEIGHT = 2
HALF_CHEETAH_PITCH = 2
HALF_CHEETAH_HEIGHT = 1
DOMAINS: dict[str, DomainSpec] = {
    "point_mass": DomainSpec("point_mass.xml", action_repeat=5, goal_qpos=(0, 1)),
    "ant_field": DomainSpec("ant_field.xml", action_repeat=10, goal_qpos=(0, 1), torso_quat=ANT_TORSO_QUAT,
                            torso_height=ANT_TORSO_HEIGHT, standardize=True),
    "ant_cage": DomainSpec("ant_cage.xml", action_repeat=10, goal_qpos=(0, 1), caged=True,
                           torso_quat=ANT_TORSO_QUAT, torso_height=ANT_TORSO_HEIGHT, standardize=True),
    "half_cheetah_field": DomainSpec("half_cheetah_field.xml", action_repeat=10, goal_qpos=(0,),
                                     torso_pitch=HALF_CHEETAH_PITCH, torso_height=HALF_CHEETAH_HEIGHT,
                                     standardize=True),
    "half_cheetah_cage": DomainSpec(
        "half_cheetah_cage.xml", action_repeat=10, goal_qpos=(0,), caged=True, torso_pitch=HALF_CHEETAH_PITCH,
        torso_height=HALF_CHEETAH_HEIGHT, standardize=True,
    ),
}
DOMAIN_NAMES: tuple[str, ...] = tuple(DOMAINS)


INTEGRATORS = ("model", "euler", "implicitfast", "rk4")
"""Integrators a config may ask for; "model" keeps the MJCF file's (Euler in every domain)."""


IMPLS = ("jax", "warp")
"""MJX backends: jax (MJX's XLA implementation, any device) and warp (MuJoCo Warp, CUDA only)."""


def check_physics(solver_iterations: int, integrator: str, impl: str = "jax") -> None:
    """Raise ConfigError naming the field if the physics overrides are not allowed values."""
    if impl not in IMPLS:
        raise ConfigError(f"impl: {impl!r} is unknown; allowed values: {list(IMPLS)}")
    if integrator not in INTEGRATORS:
        raise ConfigError(f"integrator: {integrator!r} is unknown; allowed values: {list(INTEGRATORS)}")
    if solver_iterations < 0:
        raise ConfigError(f"solver_iterations: must be >= 0 (0 keeps the model's); got {solver_iterations}")


def tiltable(spec: DomainSpec) -> bool:
    """Whether a domain's torso can tilt (a free torso or a planar pitch hinge), so a level can
    pay for tilting it (``tilt_cost``)."""
    return spec.torso_quat is not None or spec.torso_pitch is not None
