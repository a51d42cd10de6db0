"""Plant family two's arm: the Omni description with every link's inertia perturbed per seed.

Each link's mass, each coordinate of its centre of mass and each entry of its rotational
inertia (about the centre of mass) is scaled by its own factor drawn from
``U(1 - spread, 1 + spread)`` (default +-20 %); an inertia that is not physical (a principal
moment above the sum of the other two, or not positive definite) is drawn again. Rotor
inertias are scaled the same way. Kinematics (lengths, axes, coupling, tip) are the Omni's:
a model of the Omni fits this arm, with other numbers.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin

from teleop_force.errors import ConfigurationError
from teleop_force.robots import omni
from teleop_force.robots.description import RobotDescription

#: Default relative spread of the perturbation.
DEFAULT_SPREAD = 0.2
_MAX_DRAWS = 1000


def _physical(inertia: np.ndarray) -> bool:
    values = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    if values[0] <= 0.0:
        return False
    return bool(values[2] <= values[0] + values[1])


def _perturbed_inertia(base: pin.Inertia, rng: np.random.Generator, spread: float) -> pin.Inertia:
    low, high = 1.0 - spread, 1.0 + spread
    mass = base.mass * rng.uniform(low, high)
    lever = np.asarray(base.lever) * rng.uniform(low, high, size=3)
    original = np.asarray(base.inertia)
    for _ in range(_MAX_DRAWS):
        factors = rng.uniform(low, high, size=(3, 3))
        factors = np.triu(factors) + np.triu(factors, 1).T
        candidate = original * factors
        if _physical(candidate):
            return pin.Inertia(mass, lever, candidate)
    raise ConfigurationError("no physical inertia found within the spread")  # pragma: no cover


def perturbed_omni_description(
    rng: np.random.Generator, spread: float = DEFAULT_SPREAD
) -> RobotDescription:
    """Return the Omni description with link and rotor inertias perturbed by ``rng``."""
    if not 0.0 <= spread < 1.0:
        raise ConfigurationError(f"spread must be in [0, 1), got {spread}")
    description = omni.omni_description()
    if description.model is None:  # pragma: no cover - the built-in Omni has a body
        raise ConfigurationError("the Omni description has no rigid-body model")
    model = description.model.copy()
    for j in range(1, model.njoints):
        model.inertias[j] = _perturbed_inertia(model.inertias[j], rng, spread)
    rotor = description.rotor_inertia_kgm2 * rng.uniform(1.0 - spread, 1.0 + spread, size=3)
    return dataclasses.replace(description, model=model, rotor_inertia_kgm2=rotor)
