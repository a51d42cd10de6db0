"""The robot description file (see :mod:`teleop_force.robots.file`) as msgspec schemas.

Types, defaults, fixed sizes and unknown keys are checked here; what depends on the built
model (the joint count, frame and joint names) is checked by the reader.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from msgspec import Meta, Struct

from teleop_force.schema import Finite, NonEmptyStr

Vector3 = tuple[Finite, Finite, Finite]
Matrix3 = tuple[Vector3, Vector3, Vector3]
_ZERO3 = (0.0, 0.0, 0.0)


class Spring(Struct, forbid_unknown_fields=True, frozen=True):
    """A joint spring: its (1-based) joint and rest angle; the stiffness is identified."""

    joint: int
    rest_angle_rad: Finite = 0.0


class DhRow(Struct, forbid_unknown_fields=True, frozen=True):
    """One standard-DH row with the nominal link behind it."""

    alpha_rad: Finite
    a_m: Finite
    d_m: Finite
    theta_offset_rad: Finite = 0.0
    type: Literal["revolute", "prismatic"] = "revolute"
    mass_kg: Finite = 0.0
    com_m: Vector3 = _ZERO3
    inertia_kgm2: Matrix3 = (_ZERO3, _ZERO3, _ZERO3)


class DhSection(Struct, forbid_unknown_fields=True, frozen=True):
    """The ``[dh]`` table: rows in chain order, the tip in the last DH frame."""

    rows: Annotated[list[DhRow], Meta(min_length=1)]
    tip_offset_m: Vector3 = _ZERO3
    convention: Literal["standard"] = "standard"


class UrdfSection(Struct, forbid_unknown_fields=True, frozen=True):
    """The ``[urdf]`` table: the file, the joints used (chain order), locked joints' values."""

    path: NonEmptyStr
    joints: Annotated[list[NonEmptyStr], Meta(min_length=1)] | None = None
    locked: dict[str, Any] = {}  # numbers, checked with the joint they lock


class DriverPosition(Struct, forbid_unknown_fields=True, frozen=True):
    """One model joint's position in a ``[driver]`` table (``positions``, model order)."""

    joint: NonEmptyStr
    sign: Finite = 1.0
    offset_rad: Finite = 0.0
    scale: Finite = 1.0


class DriverEffort(Struct, forbid_unknown_fields=True, frozen=True):
    """One model joint's torque in a ``[driver]`` table (``efforts``, model order)."""

    joint: NonEmptyStr
    sign: Finite = 1.0


class DriverSection(Struct, forbid_unknown_fields=True, frozen=True):
    """The ``[driver]`` table: a driver's JointState conventions (robots/driver_interface.py)."""

    name: NonEmptyStr
    base_frame: NonEmptyStr
    rate_hz: Finite
    publishes_velocity: bool
    positions: Annotated[list[DriverPosition], Meta(min_length=1)]
    efforts: Annotated[list[DriverEffort], Meta(min_length=1)]
    effort_unit: NonEmptyStr = "N m"
    position_coupling: list[list[Finite]] | None = None
    effort_coupling: list[list[Finite]] | None = None
    base_rotation: list[list[Finite]] | None = None


class DriverFile(Struct, forbid_unknown_fields=True, frozen=True):
    """A stand-alone driver file: ``format = "teleop-force-driver"``, version 1, ``[driver]``."""

    format: Literal["teleop-force-driver"]
    version: Literal[1]
    driver: DriverSection


class RobotFile(Struct, forbid_unknown_fields=True, frozen=True):
    """A whole robot description file (one of ``urdf`` and ``dh``)."""

    format: Literal["teleop-force-robot"]
    version: Literal[1]
    name: NonEmptyStr
    joint_names: list[NonEmptyStr] | None = None
    gravity_mps2: Vector3 = (0.0, 0.0, -9.81)
    tip_frame: NonEmptyStr | None = None
    coupling: list[list[Finite]] | None = None
    rotor_inertia_kgm2: list[Finite] | None = None
    friction_inputs: list[list[int]] | None = None
    q_min_rad: list[Finite] | None = None
    q_max_rad: list[Finite] | None = None
    springs: list[Spring] = []
    urdf: UrdfSection | None = None
    dh: DhSection | None = None
    driver: DriverSection | None = None
