"""A tip payload (a tool, a held mass) for either plant family: a point mass at the tip frame.

``with_tip_payload(description, mass_kg)`` adds a point mass at the tip frame's origin to the
last link's inertia (its mass, centre of mass and rotational inertia change together, as
the residual loop would name a payload: a change of the last link's inertial parameters).
Both plant families take it as ``tip_mass_kg``
(:func:`~teleop_force.simulation.families.make_plant`,
:func:`~teleop_force.simulation.session.simulate_session` and every protocol builder).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pinocchio as pin

from teleop_force.errors import ConfigurationError, ModelError
from teleop_force.robots.description import RobotDescription


def check_tip_mass(mass_kg: float) -> float:
    """Return ``mass_kg`` as a float, or raise ConfigurationError unless finite and >= 0."""
    value = float(mass_kg)
    if not (math.isfinite(value) and value >= 0.0):
        raise ConfigurationError(f"tip_mass_kg must be finite and >= 0, got {mass_kg}")
    return value


def with_tip_payload(description: RobotDescription, mass_kg: float) -> RobotDescription:
    """Return a copy of ``description`` carrying a point mass ``mass_kg`` at its tip frame.

    ``mass_kg == 0`` returns ``description`` itself.

    Raises:
        ConfigurationError: for a negative or non-finite mass.
        ModelError: without a rigid-body model or a tip frame.

    """
    mass = check_tip_mass(mass_kg)
    if mass == 0.0:
        return description
    if description.model is None or description.tip_frame is None:
        raise ModelError(f"{description.name}: a payload needs a rigid-body model and a tip")
    model = description.model.copy()
    frame = model.frames[model.getFrameId(description.tip_frame)]
    joint = int(frame.parentJoint)
    point = pin.Inertia(mass, np.array(frame.placement.translation), np.zeros((3, 3)))
    model.inertias[joint] = model.inertias[joint] + point
    return dataclasses.replace(description, model=model)
