"""Built-in robot descriptions by name (``omni``, ``none``...)."""

from __future__ import annotations

import numpy as np

from teleop_force.errors import ModelError
from teleop_force.omni import omni_description
from teleop_force.robot import RobotDescription

BUILTIN_ROBOTS = ("none", "omni")


def friction_only_description(n_joints: int) -> RobotDescription:
    """A robot with no rigid-body terms: friction and found effects only (``--robot none``)."""
    return RobotDescription(
        name="none",
        model=None,
        n_joints=n_joints,
        coupling=np.eye(n_joints),
        tip_frame=None,
        rotor_inertia_kgm2=np.zeros(n_joints),
    )


def resolve_robot(name: str, n_joints: int | None = None) -> RobotDescription:
    """Return the description called ``name`` (``none`` needs ``n_joints``)."""
    if name == "omni":
        return omni_description()
    if name == "none":
        if n_joints is None:
            raise ModelError("robot 'none' needs the number of joints")
        return friction_only_description(n_joints)
    raise ModelError(f"unknown robot {name!r}; built-in robots: {', '.join(BUILTIN_ROBOTS)}")
