"""The simulated plant families, and :func:`make_plant` to build either behind ``Device``.

- :attr:`PlantFamily.ONE`: :class:`~teleop_force.simulation.plant.SimulatedOmni`, the Omni
  description, static Stribeck + cable friction (:mod:`true_friction`), white actuator noise,
  a linear tissue (:class:`~teleop_force.simulation.contact.PlaneContact`).
- :attr:`PlantFamily.TWO`: :class:`~teleop_force.simulation.plant_two.SimulatedOmniTwo`, an
  Omni with inertias perturbed per seed, LuGre friction, DAC, ripple and coloured noise,
  floored encoders and a Hunt-Crossley floor
  (:class:`~teleop_force.simulation.floor_contact.HuntCrossleyFloor`).

A model identified on one family and tested on the other (or on another instance of family
two) has not seen the plant it is tested on. Both take the effects of
:mod:`~teleop_force.simulation.effects` and a tip payload (``tip_mass_kg``,
:mod:`~teleop_force.simulation.payload`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike

from teleop_force.errors import ConfigurationError
from teleop_force.robots import omni
from teleop_force.robots.device import Device
from teleop_force.simulation.contact import PlaneContact
from teleop_force.simulation.effects import PlantEffect
from teleop_force.simulation.floor_contact import HuntCrossleyFloor
from teleop_force.simulation.payload import check_tip_mass, with_tip_payload
from teleop_force.simulation.plant import PlantConfig, SimulatedOmni
from teleop_force.simulation.plant_two import Contact, PlantTwoConfig, SimulatedOmniTwo


class PlantFamily(StrEnum):
    """Which simulated plant: ``one`` (the project's plant) or ``two`` (the held-out family)."""

    ONE = "one"
    TWO = "two"

    @classmethod
    def parse(cls, value: PlantFamily | str) -> PlantFamily:
        """Return the family named ``value`` (ConfigurationError if unknown)."""
        try:
            return cls(value)
        except ValueError as error:
            names = ", ".join(member.value for member in cls)
            raise ConfigurationError(f"unknown plant family {value!r}; known: {names}") from error


def default_contact(family: PlantFamily | str, surface_y_m: float) -> Contact:
    """Return the family's soft surface at ``y = surface_y_m``: a tissue (one) or a floor (two)."""
    if PlantFamily.parse(family) is PlantFamily.ONE:
        return PlaneContact.horizontal(surface_y_m)
    return HuntCrossleyFloor.horizontal(surface_y_m)


def make_plant(
    family: PlantFamily | str,
    *,
    seed: int | np.random.SeedSequence | None,
    effects: Sequence[PlantEffect] = (),
    contact: Contact | None = None,
    tip_mass_kg: float = 0.0,
    config: PlantConfig | PlantTwoConfig | None = None,
    q0_rad: ArrayLike | None = None,
    qd0_rad_s: ArrayLike | None = None,
) -> Device:
    """Build a plant of ``family`` (a :class:`Device`) at ``q0_rad`` (default mid-range).

    ``seed`` seeds the actuator noise; for family two it also picks the arm (inertias,
    friction, spring) unless ``config`` (a :class:`PlantTwoConfig`) is given: an integer
    ``seed`` gives ``PlantTwoConfig(instance_seed=seed)``. ``tip_mass_kg`` adds a payload on
    top of ``config``'s. Family one takes a :class:`PlaneContact` only.

    Raises:
        ConfigurationError: for an unknown family, a config or contact of the other family.

    """
    family = PlantFamily.parse(family)
    mass = check_tip_mass(tip_mass_kg)
    q0 = None if q0_rad is None else np.asarray(q0_rad, dtype=float)
    qd0 = None if qd0_rad_s is None else np.asarray(qd0_rad_s, dtype=float)
    if family is PlantFamily.ONE:
        if config is not None and not isinstance(config, PlantConfig):
            raise ConfigurationError("plant family one takes a PlantConfig")
        if contact is not None and not isinstance(contact, PlaneContact):
            raise ConfigurationError("plant family one takes a PlaneContact")
        description = with_tip_payload(omni.omni_description(), mass) if mass > 0.0 else None
        return SimulatedOmni(
            config,
            seed=seed,
            effects=effects,
            contact=contact,
            q0_rad=q0,
            qd0_rad_s=qd0,
            description=description,
        )
    if config is not None and not isinstance(config, PlantTwoConfig):
        raise ConfigurationError("plant family two takes a PlantTwoConfig")
    if config is None:
        instance = int(seed) if isinstance(seed, int | np.integer) else 0
        config = PlantTwoConfig(instance_seed=instance)
    if mass > 0.0:
        config = dataclasses.replace(config, tip_mass_kg=config.tip_mass_kg + mass)
    return SimulatedOmniTwo(
        config, seed=seed, effects=effects, contact=contact, q0_rad=q0, qd0_rad_s=qd0
    )
