"""A robot driver's joint conventions, as data: how its JointState maps to the model's q, tau.

A driver publishes a ``sensor_msgs/JointState`` in its own conventions (names, signs, zero
pose, a relative elbow, torques in mN m...). A :class:`DriverInterface` says how to convert
one to the model's coordinates (docs/real_robot.md, "The driver's conventions"), once, on
reading. Positions and efforts have separate maps, because a driver may transform its
positions but pass its efforts through untouched (sawSensablePhantom does)::

    x   = the driver's positions of the joints named in ``positions`` (model joint order)
    q   = scale * (position_coupling @ (sign * x)) + offset_rad            [rad]
    e   = the driver's efforts of the joints named in ``efforts``
    tau = unit_scale * (effort_coupling @ (sign * e))                      [N m]

``q`` and ``tau`` are conjugate (``tau . qd`` is the power), as everywhere in the project.
If the driver's efforts are conjugate to its *published* positions, virtual work gives
``effort_coupling = K^-T`` with ``K = diag(scale) position_coupling diag(sign)`` (the
position map's linear part; :func:`effort_coupling_conjugate_to_positions`); a driver that
passes through torques conjugate to other angles (the device's raw ones) needs the coupling
that maps those.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from teleop_force.errors import DataError, ModelError

#: Effort units a driver may publish, and the factor to N m.
EFFORT_UNITS: dict[str, float] = {"N m": 1.0, "mN m": 1.0e-3}


@dataclass(frozen=True)
class PositionEntry:
    """One model joint's position: the driver joint it reads, its sign and offset.

    ``sign`` multiplies the driver's value before the coupling; ``scale`` and ``offset_rad``
    apply after it (``q_i = scale * (coupling @ (sign * x))_i + offset_rad``).
    """

    joint: str
    sign: float = 1.0
    offset_rad: float = 0.0
    scale: float = 1.0


@dataclass(frozen=True)
class EffortEntry:
    """One model joint's torque: the driver joint whose effort it reads, and its sign."""

    joint: str
    sign: float = 1.0


class DriverFieldError(ModelError):
    """A :class:`DriverInterface` field is wrong: names the driver, the field, the problem."""

    def __init__(self, driver: str, field_name: str, problem: str) -> None:
        self.driver = driver
        self.field = field_name
        self.problem = problem
        super().__init__(f"driver {driver or '?'}: field {field_name!r}: {problem}")


def _matrix(value: Any, n: int) -> np.ndarray:
    return np.eye(n) if value is None else np.asarray(value, dtype=float)


@dataclass(frozen=True, eq=False)
class DriverInterface:
    """How a driver's JointState maps to the model's coordinates (see the module docstring).

    Attributes:
        name: The driver (``sawSensablePhantom``).
        base_frame: The frame the driver's Cartesian pose (``measured_cp``) is in.
        rate_hz: How often the driver publishes its JointState.
        publishes_velocity: Whether its JointState carries velocities (if not, the service
            derives them, as for lab logs).
        positions: One entry per model joint, in the model's order.
        efforts: One entry per model joint, in the model's order (same driver joints).
        effort_unit: A key of :data:`EFFORT_UNITS`.
        position_coupling, effort_coupling: ``n x n`` (default identity), invertible.
        base_rotation: The driver's base-frame axes in the model's base frame (3 x 3,
            default identity): ``p_model_axes = base_rotation @ p_driver``.

    """

    name: str
    base_frame: str
    rate_hz: float
    publishes_velocity: bool
    positions: tuple[PositionEntry, ...]
    efforts: tuple[EffortEntry, ...]
    effort_unit: str = "N m"
    position_coupling: np.ndarray | None = None
    effort_coupling: np.ndarray | None = None
    base_rotation: np.ndarray | None = None
    _k: np.ndarray = field(init=False, repr=False)
    _e: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = len(self.positions)
        if not self.name:
            raise self._error("name", "must not be empty")
        if n < 1:
            raise self._error("positions", "needs one entry per model joint, got none")
        if len(self.efforts) != n:
            raise self._error("efforts", f"needs {n} entries (one per model joint)")
        if not self.base_frame:
            raise self._error("base_frame", "must not be empty")
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise self._error("rate_hz", f"must be > 0, got {self.rate_hz!r}")
        if self.effort_unit not in EFFORT_UNITS:
            raise self._error(
                "effort_unit",
                f"unknown unit {self.effort_unit!r} (known: {', '.join(EFFORT_UNITS)})",
            )
        groups: tuple[tuple[str, Sequence[PositionEntry | EffortEntry]], ...] = (
            ("positions", self.positions),
            ("efforts", self.efforts),
        )
        for kind, entries in groups:
            seen: set[str] = set()
            for i, entry in enumerate(entries):
                if not entry.joint:
                    raise self._error(f"{kind}[{i}].joint", "must not be empty")
                if entry.joint in seen:
                    raise self._error(f"{kind}[{i}].joint", f"{entry.joint!r} is listed twice")
                seen.add(entry.joint)
                if entry.sign not in (1.0, -1.0):
                    raise self._error(f"{kind}[{i}].sign", f"must be +1 or -1, got {entry.sign!r}")
        for i, entry in enumerate(self.positions):
            if not np.isfinite(entry.offset_rad):
                raise self._error(f"positions[{i}].offset_rad", "must be finite")
            if not (np.isfinite(entry.scale) and entry.scale != 0):
                raise self._error(f"positions[{i}].scale", "must be finite and non-zero")
        if {e.joint for e in self.efforts} != {p.joint for p in self.positions}:
            raise self._error(
                "efforts", "must name the same driver joints as 'positions' (one JointState)"
            )
        for attr in ("position_coupling", "effort_coupling"):
            value = _matrix(getattr(self, attr), n)
            if value.shape != (n, n):
                raise self._error(attr, f"must be {n}x{n}, got shape {value.shape}")
            if not np.all(np.isfinite(value)):
                raise self._error(attr, "must be finite")
            if abs(np.linalg.det(value)) < 1e-9:
                raise self._error(attr, "is singular")
            object.__setattr__(self, attr, value)
        rotation = _matrix(self.base_rotation, 3)
        if rotation.shape != (3, 3) or not np.allclose(rotation @ rotation.T, np.eye(3)):
            raise self._error("base_rotation", "must be a 3x3 rotation matrix")
        if np.linalg.det(rotation) < 0:
            raise self._error("base_rotation", "must be a rotation (determinant +1)")
        object.__setattr__(self, "base_rotation", rotation)
        sign_p = np.array([p.sign for p in self.positions])
        scale = np.array([p.scale for p in self.positions])
        sign_e = np.array([e.sign for e in self.efforts])
        object.__setattr__(self, "_k", scale[:, None] * self.coupling_p * sign_p[None, :])
        object.__setattr__(self, "_e", self.unit_scale * self.coupling_e * sign_e[None, :])

    def _error(self, field_name: str, problem: str) -> DriverFieldError:
        return DriverFieldError(self.name, field_name, problem)

    @property
    def n_joints(self) -> int:
        """Number of model joints."""
        return len(self.positions)

    @property
    def coupling_p(self) -> np.ndarray:
        """The position coupling as an array (identity if not given)."""
        return np.asarray(self.position_coupling)

    @property
    def coupling_e(self) -> np.ndarray:
        """The effort coupling as an array (identity if not given)."""
        return np.asarray(self.effort_coupling)

    @property
    def rotation(self) -> np.ndarray:
        """The base rotation as an array (identity if not given)."""
        return np.asarray(self.base_rotation)

    @property
    def unit_scale(self) -> float:
        """Factor from the driver's effort unit to N m."""
        return EFFORT_UNITS[self.effort_unit]

    @property
    def position_matrix(self) -> np.ndarray:
        """``K`` of ``q = K x + offset``: ``diag(scale) position_coupling diag(sign)``."""
        return self._k.copy()

    @property
    def effort_matrix(self) -> np.ndarray:
        """``E`` of ``tau = E e``: ``unit_scale * effort_coupling diag(sign)``."""
        return self._e.copy()

    @property
    def offsets_rad(self) -> np.ndarray:
        """The model-coordinate offsets ``offset_rad`` of ``positions``."""
        return np.array([p.offset_rad for p in self.positions])

    @property
    def driver_joints(self) -> tuple[str, ...]:
        """The driver joint names the positions read, in the model's order."""
        return tuple(p.joint for p in self.positions)

    def _columns(self, names: Sequence[str], entries: Sequence[Any], what: str) -> np.ndarray:
        index = {name: i for i, name in enumerate(names)}
        missing = [e.joint for e in entries if e.joint not in index]
        if missing:
            raise DataError(
                f"driver {self.name}: JointState has no {what} joint "
                f"{', '.join(map(repr, missing))} (it names {', '.join(map(repr, names))})"
            )
        return np.array([index[e.joint] for e in entries], dtype=int)

    def to_model(
        self,
        names: Sequence[str],
        position: np.ndarray | Sequence[float],
        effort: np.ndarray | Sequence[float] | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Convert a driver JointState to the model's ``(q [rad], tau [N m])``.

        ``position`` / ``effort`` hold one value per name (the last axis; leading axes are
        samples). ``tau`` is None when ``effort`` is None or empty (a JointState may leave
        it out).

        Raises:
            DataError: a joint the description reads is not in ``names``, or the arrays do
                not have one value per name.

        """
        names = list(names)
        x_all = np.asarray(position, dtype=float)
        if x_all.shape[-1:] != (len(names),):
            raise DataError(
                f"driver {self.name}: {len(names)} joint names but position has shape {x_all.shape}"
            )
        x = x_all[..., self._columns(names, self.positions, "position")]
        q = x @ self._k.T + self.offsets_rad
        if effort is None or np.size(effort) == 0:
            return q, None
        e_all = np.asarray(effort, dtype=float)
        if e_all.shape != x_all.shape:
            raise DataError(
                f"driver {self.name}: effort has shape {e_all.shape}, position {x_all.shape}"
            )
        e = e_all[..., self._columns(names, self.efforts, "effort")]
        return q, e @ self._e.T

    def to_driver(
        self, q: np.ndarray | Sequence[float], tau: np.ndarray | Sequence[float] | None = None
    ) -> tuple[tuple[str, ...], np.ndarray, np.ndarray | None]:
        """Invert :meth:`to_model`: the driver's ``(names, position, effort)``.

        Names are :attr:`driver_joints`; ``effort`` is in the driver's unit, in that order.
        """
        q = np.asarray(q, dtype=float)
        x = np.linalg.solve(self._k, (q - self.offsets_rad).T).T
        if tau is None:
            return self.driver_joints, x, None
        e_model_order = np.linalg.solve(self._e, np.asarray(tau, dtype=float).T).T
        order = [self.driver_joints.index(e.joint) for e in self.efforts]
        effort = np.empty_like(e_model_order)
        effort[..., order] = e_model_order
        return self.driver_joints, x, effort


def effort_coupling_conjugate_to_positions(interface: DriverInterface) -> np.ndarray:
    """Return ``K^-T``: ``tau = K^-T e`` for efforts conjugate to the published positions.

    From virtual work: with ``q = K x + b``, ``e . xd = e . K^-1 qd = (K^-T e) . qd``.
    The signs and scales of ``K`` are in it (use it with effort signs +1, unit N m).
    """
    return np.linalg.inv(interface.position_matrix).T
