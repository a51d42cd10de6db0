"""Reading a friction model back from its model-file entry, whatever its kind."""

from __future__ import annotations

from typing import Any

from teleop_force.errors import ModelFileError
from teleop_force.friction.base import FrictionModel
from teleop_force.friction.coulomb_viscous import CoulombViscous, CoupledCoulombViscous
from teleop_force.friction.kinds import FRICTION_KINDS
from teleop_force.friction.model_coordinates import ModelCoordinateFriction
from teleop_force.friction.wavelet_network import WaveletNetwork


def friction_from_dict(data: dict[str, Any]) -> FrictionModel:
    """Rebuild a friction model from its ``to_dict`` form; ModelFileError names a bad field."""
    kind = data.get("kind") if isinstance(data, dict) else None
    if kind == CoulombViscous.kind:
        return CoulombViscous.from_dict(data)
    if kind == CoupledCoulombViscous.kind:
        return CoupledCoulombViscous.from_dict(data)
    if kind == ModelCoordinateFriction.kind:
        return ModelCoordinateFriction.from_dict(data)
    if kind == WaveletNetwork.kind:
        return WaveletNetwork.from_dict(data)
    expected = ", ".join(FRICTION_KINDS)
    raise ModelFileError(
        f"unknown friction kind {kind!r}; expected one of {expected}", column="kind"
    )
