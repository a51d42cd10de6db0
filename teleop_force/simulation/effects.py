"""Switchable effects of the simulated plant that the identification model does not contain.

Each effect is a small frozen dataclass acting on one joint, with a :attr:`~PlantEffect.name`
and ``torque(t_s, q_rad, qd_rad_s, tau_motor_nm)`` returning torques on all joints (zero except
on ``joint``). Inputs may be one sample ((n,) arrays, float time) or a batch ((N, n), (N,)).

Sign: like friction, an effect's torque is on the LEFT of the dynamics,
``M qdd + ... + tau_f + tau_effect = tau``: it is what the motors must additionally supply, so
``tau - model torque = tau_effect`` for a perfect model, and positive coefficients of the
friction-like effects dissipate energy.

Sign functions are smoothed (``tanh(qd / v)``) so the plant integrates them stably.
:func:`make_effect` builds any effect by name (see :data:`EFFECT_NAMES`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import ClassVar

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError, DataError

#: Default width of the smoothed sign of the friction-like effects [rad/s].
SMOOTHING_VELOCITY_RAD_S = 0.01


def _finite(name: str, value: float, *, positive: bool = False) -> float:
    value = float(value)
    if not math.isfinite(value) or (positive and value <= 0.0):
        raise ConfigurationError(
            f"{name} must be finite{' and > 0' if positive else ''}, got {value}"
        )
    return value


@dataclass(frozen=True)
class PlantEffect(ABC):
    """A torque on joint ``joint`` (0-based) of the plant, outside the identified model."""

    #: Registry name (``cogging``, ``position-friction``...).
    name: ClassVar[str]

    joint: int

    def __post_init__(self) -> None:
        if not isinstance(self.joint, int | np.integer) or self.joint < 0:
            raise ConfigurationError(f"{self.name}: joint must be an index >= 0, got {self.joint}")

    @abstractmethod
    def joint_torque(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Torque on :attr:`joint` alone: shape () for one sample, (N,) for a batch."""

    def velocity_slope(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """``d joint_torque / d qd[joint]`` (the plant integrates it implicitly); 0 by default."""
        return np.zeros(np.shape(q_rad)[:-1])

    def torque(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Torque on every joint, zero except on :attr:`joint`: (n,) or (N, n)."""
        t, q, qd, tau = _check_inputs(t_s, q_rad, qd_rad_s, tau_motor_nm)
        if max(self.joint, self.inputs_joint) >= q.shape[-1]:
            raise ConfigurationError(
                f"{self.name}: joint {max(self.joint, self.inputs_joint)} on a"
                f" {q.shape[-1]}-joint robot"
            )
        out = np.zeros_like(q)
        out[..., self.joint] = self.joint_torque(t, q, qd, tau)
        return out

    @property
    def inputs_joint(self) -> int:
        """The highest joint index the effect reads besides :attr:`joint` (0-based)."""
        return self.joint

    def describe(self) -> str:
        """One line: name, joint (1-based) and parameters."""
        fields = ", ".join(
            f"{key}={value:.4g}"
            for key, value in vars(self).items()
            if key != "joint" and value is not None
        )
        return f"{self.name} on joint {self.joint + 1} ({fields})"


def _check_inputs(
    t_s: float | np.ndarray, q_rad: np.ndarray, qd_rad_s: np.ndarray, tau_motor_nm: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    q = np.asarray(q_rad, dtype=float)
    qd = np.asarray(qd_rad_s, dtype=float)
    tau = np.asarray(tau_motor_nm, dtype=float)
    t = np.asarray(t_s, dtype=float)
    if q.ndim not in (1, 2) or qd.shape != q.shape or tau.shape != q.shape:
        raise DataError(f"q {q.shape}, qd {qd.shape} and tau {tau.shape} must share one shape")
    if t.shape != q.shape[:-1]:
        raise DataError(f"time has shape {t.shape}, expected {q.shape[:-1]}")
    return t, q, qd, tau


def _smooth_sign(v: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    s = np.tanh(v / width)
    return s, (1.0 - s * s) / width


@dataclass(frozen=True)
class Cogging(PlantEffect):
    """Position-periodic cogging ``A sin(k q_j + phi)``."""

    name: ClassVar[str] = "cogging"
    amplitude_nm: float = 0.01
    wavenumber_per_rad: float = 24.0
    phase_rad: float = 0.3

    def __post_init__(self) -> None:
        super().__post_init__()
        _finite("amplitude_nm", self.amplitude_nm)
        _finite("wavenumber_per_rad", self.wavenumber_per_rad, positive=True)
        _finite("phase_rad", self.phase_rad)

    def joint_torque(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return ``A sin(k q_j + phi)``."""
        return self.amplitude_nm * np.sin(
            self.wavenumber_per_rad * q_rad[..., self.joint] + self.phase_rad
        )


@dataclass(frozen=True)
class PositionDependentFriction(PlantEffect):
    """Dry friction whose level varies with the joint's angle.

    ``Fc (1 + sin(k q_j + phi)) / 2 * sgn(qd_j)``: between 0 and ``Fc`` along the range.
    """

    name: ClassVar[str] = "position-friction"
    coulomb_nm: float = 0.015
    wavenumber_per_rad: float = 3.0
    phase_rad: float = 0.0
    smoothing_velocity_rad_s: float = SMOOTHING_VELOCITY_RAD_S

    def __post_init__(self) -> None:
        super().__post_init__()
        _finite("coulomb_nm", self.coulomb_nm)
        _finite("wavenumber_per_rad", self.wavenumber_per_rad, positive=True)
        _finite("phase_rad", self.phase_rad)
        _finite("smoothing_velocity_rad_s", self.smoothing_velocity_rad_s, positive=True)

    def _level(self, q_rad: np.ndarray) -> np.ndarray:
        angle = self.wavenumber_per_rad * q_rad[..., self.joint] + self.phase_rad
        return 0.5 * self.coulomb_nm * (1.0 + np.sin(angle))

    def joint_torque(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return ``Fc(q_j) sgn(qd_j)``."""
        s, _ = _smooth_sign(qd_rad_s[..., self.joint], self.smoothing_velocity_rad_s)
        return self._level(q_rad) * s

    def velocity_slope(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return the slope of the smoothed sign times the level."""
        _, ds = _smooth_sign(qd_rad_s[..., self.joint], self.smoothing_velocity_rad_s)
        return self._level(q_rad) * ds


@dataclass(frozen=True)
class DriftingFriction(PlantEffect):
    """Dry friction growing linearly with time (warm-up, wear): ``r t sgn(qd_j)``."""

    name: ClassVar[str] = "drifting-friction"
    rate_nm_per_s: float = 1.0e-4
    smoothing_velocity_rad_s: float = SMOOTHING_VELOCITY_RAD_S

    def __post_init__(self) -> None:
        super().__post_init__()
        _finite("rate_nm_per_s", self.rate_nm_per_s)
        _finite("smoothing_velocity_rad_s", self.smoothing_velocity_rad_s, positive=True)

    def joint_torque(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return ``r t sgn(qd_j)``."""
        s, _ = _smooth_sign(qd_rad_s[..., self.joint], self.smoothing_velocity_rad_s)
        return self.rate_nm_per_s * t_s * s

    def velocity_slope(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return ``r t sgn'(qd_j)``."""
        _, ds = _smooth_sign(qd_rad_s[..., self.joint], self.smoothing_velocity_rad_s)
        return self.rate_nm_per_s * t_s * ds


@dataclass(frozen=True)
class LoadDependentFriction(PlantEffect):
    """Friction proportional to the transmitted motor torque: ``mu |tau_j| sgn(qd_j)``."""

    name: ClassVar[str] = "load-friction"
    coefficient: float = 0.1
    smoothing_velocity_rad_s: float = SMOOTHING_VELOCITY_RAD_S

    def __post_init__(self) -> None:
        super().__post_init__()
        _finite("coefficient", self.coefficient)
        _finite("smoothing_velocity_rad_s", self.smoothing_velocity_rad_s, positive=True)

    def joint_torque(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return ``mu |tau_j| sgn(qd_j)``."""
        s, _ = _smooth_sign(qd_rad_s[..., self.joint], self.smoothing_velocity_rad_s)
        return self.coefficient * np.abs(tau_motor_nm[..., self.joint]) * s

    def velocity_slope(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return ``mu |tau_j| sgn'(qd_j)``."""
        _, ds = _smooth_sign(qd_rad_s[..., self.joint], self.smoothing_velocity_rad_s)
        return self.coefficient * np.abs(tau_motor_nm[..., self.joint]) * ds


@dataclass(frozen=True)
class ElbowAngleBump(PlantEffect):
    """A skewed bump in ``d = q2 - q3`` acting on one joint (joint 3 by default).

    ``A exp(-((d - d0) / w)^2) (1 + tanh((d - d0) / (0.3 w)))``: a cable snag near one elbow
    angle, steeper on one side. ``first``/``second`` pick the two angles (0-based).
    """

    name: ClassVar[str] = "elbow-bump"
    amplitude_nm: float = 0.02
    centre_rad: float = 0.6
    width_rad: float = 0.15
    first: int = 1
    second: int = 2

    def __post_init__(self) -> None:
        super().__post_init__()
        _finite("amplitude_nm", self.amplitude_nm)
        _finite("centre_rad", self.centre_rad)
        _finite("width_rad", self.width_rad, positive=True)
        if self.first < 0 or self.second < 0 or self.first == self.second:
            raise ConfigurationError("first and second must be two different joint indices")

    def joint_torque(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return the bump at ``q[first] - q[second]``."""
        x = (q_rad[..., self.first] - q_rad[..., self.second] - self.centre_rad) / self.width_rad
        return self.amplitude_nm * np.exp(-x * x) * (1.0 + np.tanh(x / 0.3))


@dataclass(frozen=True)
class DirectionOffset(PlantEffect):
    """A constant torque present only while a joint moves in the + direction.

    ``offset (1 + sgn(qd_k)) / 2`` on joint ``joint``, where ``k`` is ``direction_joint``
    (default: ``joint`` itself). On its own joint it is asymmetric dry friction: a constant
    plus a Coulomb term, which the declared friction models already contain
    (``direction-offset``). Switched by another joint's direction it is a cross-joint effect
    nobody declared (``cross-direction-offset``: joint 3 offset while joint 1 moves +, e.g. a
    cable dragged by the base rotation).
    """

    name: ClassVar[str] = "direction-offset"
    offset_nm: float = 0.01
    smoothing_velocity_rad_s: float = SMOOTHING_VELOCITY_RAD_S
    direction_joint: int | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        _finite("offset_nm", self.offset_nm)
        _finite("smoothing_velocity_rad_s", self.smoothing_velocity_rad_s, positive=True)
        k = self.direction_joint
        if k is not None and (not isinstance(k, int | np.integer) or k < 0):
            raise ConfigurationError(f"{self.name}: direction_joint must be an index >= 0, got {k}")

    @property
    def switching_joint(self) -> int:
        """The joint whose direction of motion switches the offset (0-based)."""
        return self.joint if self.direction_joint is None else int(self.direction_joint)

    @property
    def inputs_joint(self) -> int:
        """The switching joint (checked against the robot's joint count)."""
        return max(self.joint, self.switching_joint)

    def joint_torque(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return ``offset (1 + sgn(qd_k)) / 2``."""
        s, _ = _smooth_sign(qd_rad_s[..., self.switching_joint], self.smoothing_velocity_rad_s)
        return 0.5 * self.offset_nm * (1.0 + s)

    def velocity_slope(
        self,
        t_s: float | np.ndarray,
        q_rad: np.ndarray,
        qd_rad_s: np.ndarray,
        tau_motor_nm: np.ndarray,
    ) -> np.ndarray:
        """Return ``d(torque)/d(qd_joint)``: ``offset sgn'(qd_j) / 2`` on its own joint, else 0."""
        if self.switching_joint != self.joint:
            return np.zeros_like(np.asarray(qd_rad_s, dtype=float)[..., self.joint])
        _, ds = _smooth_sign(qd_rad_s[..., self.joint], self.smoothing_velocity_rad_s)
        return 0.5 * self.offset_nm * ds


@dataclass(frozen=True)
class CrossDirectionOffset(DirectionOffset):
    """:class:`DirectionOffset` switched by another joint's direction (default: joint 1)."""

    name: ClassVar[str] = "cross-direction-offset"
    direction_joint: int | None = 0


# -- compiled evaluation (the plant's sub-steps) -----------------------------------------------

_COGGING, _POSITION, _DRIFTING, _LOAD, _ELBOW, _DIRECTION = range(6)
#: Columns of :func:`effect_kernel_table`: code, joint, then up to 5 parameters.
KERNEL_TABLE_COLUMNS = 7


def _kernel_row(effect: PlantEffect) -> tuple[float, ...] | None:
    # Exact types only: a subclass may redefine the torque, so it keeps the Python path.
    j = float(effect.joint)
    if type(effect) is Cogging:
        return (_COGGING, j, effect.amplitude_nm, effect.wavenumber_per_rad, effect.phase_rad)
    if type(effect) is PositionDependentFriction:
        return (
            _POSITION,
            j,
            effect.coulomb_nm,
            effect.wavenumber_per_rad,
            effect.phase_rad,
            effect.smoothing_velocity_rad_s,
        )
    if type(effect) is DriftingFriction:
        return (_DRIFTING, j, effect.rate_nm_per_s, effect.smoothing_velocity_rad_s)
    if type(effect) is LoadDependentFriction:
        return (_LOAD, j, effect.coefficient, effect.smoothing_velocity_rad_s)
    if type(effect) is ElbowAngleBump:
        return (
            _ELBOW,
            j,
            effect.amplitude_nm,
            effect.centre_rad,
            effect.width_rad,
            float(effect.first),
            float(effect.second),
        )
    if isinstance(effect, DirectionOffset) and type(effect) in _DIRECTION_TYPES:
        return (
            _DIRECTION,
            j,
            effect.offset_nm,
            effect.smoothing_velocity_rad_s,
            float(effect.switching_joint),
        )
    return None


_DIRECTION_TYPES = (DirectionOffset, CrossDirectionOffset)


def _highest_joint_read(effect: PlantEffect) -> int:
    if isinstance(effect, ElbowAngleBump):
        return max(effect.joint, effect.first, effect.second)
    return max(effect.joint, effect.inputs_joint)


def checked_effects(
    effects: Sequence[PlantEffect], n_joints: int = 3
) -> tuple[tuple[PlantEffect, ...], np.ndarray | None]:
    """Check a plant's effects; return them and their writable kernel table (or ``None``).

    What a plant's ``effects`` setter does (both plant families): ConfigurationError for
    something that is not a :class:`PlantEffect` or acts on a joint beyond ``n_joints``.
    """
    for effect in effects:
        if not isinstance(effect, PlantEffect):
            raise ConfigurationError(f"not a plant effect: {effect!r}")
        if effect.joint >= n_joints:
            raise ConfigurationError(f"{effect.name}: joint {effect.joint + 1} of {n_joints}")
    checked = tuple(effects)
    table = effect_kernel_table(checked, n_joints)
    return checked, None if table is None else np.array(table)


def effect_kernel_table(effects: Sequence[PlantEffect], n_joints: int = 3) -> np.ndarray | None:
    """Pack ``effects`` for :func:`effects_torque_slope` ((E, 7)), or ``None`` if one is unknown.

    Only the built-in effect classes (exactly, not subclasses) are compiled; ``None`` also when
    an effect reads a joint beyond ``n_joints`` (the Python path reports it).
    """
    table = np.zeros((len(effects), KERNEL_TABLE_COLUMNS))
    for row, effect in enumerate(effects):
        values = _kernel_row(effect)
        if values is None or _highest_joint_read(effect) >= n_joints:
            return None
        table[row, : len(values)] = values
    table.flags.writeable = False
    return table


@njit_cached()
def _pick(index: int, a: float, b: float, c: float) -> float:  # pragma: no cover - compiled
    if index == 0:
        return a
    if index == 1:
        return b
    return c


@njit_cached()
def effects_torque_slope(
    table: np.ndarray,
    t_s: float,
    q0: float,
    q1: float,
    q2: float,
    v0: float,
    v1: float,
    v2: float,
    tau0: float,
    tau1: float,
    tau2: float,
) -> tuple[float, float, float, float, float, float]:  # pragma: no cover - compiled
    """Sum the torques and ``d torque_j / d qd_j`` of a 3-joint effect table at one sample.

    The compiled twin of the classes' ``joint_torque`` and ``velocity_slope`` (same formulas,
    same order of operations); ``table`` comes from :func:`effect_kernel_table`. Returns
    ``(torque_1..3, slope_1..3)``.
    """
    e0 = e1 = e2 = 0.0
    s0 = s1 = s2 = 0.0
    for row in range(table.shape[0]):
        code = int(table[row, 0])
        joint = int(table[row, 1])
        p = table[row]
        torque = 0.0
        slope = 0.0
        if code == _COGGING:
            torque = p[2] * math.sin(p[3] * _pick(joint, q0, q1, q2) + p[4])
        elif code == _POSITION:
            level = 0.5 * p[2] * (1.0 + math.sin(p[3] * _pick(joint, q0, q1, q2) + p[4]))
            sign = math.tanh(_pick(joint, v0, v1, v2) / p[5])
            torque = level * sign
            slope = level * ((1.0 - sign * sign) / p[5])
        elif code == _DRIFTING:
            sign = math.tanh(_pick(joint, v0, v1, v2) / p[3])
            torque = p[2] * t_s * sign
            slope = p[2] * t_s * ((1.0 - sign * sign) / p[3])
        elif code == _LOAD:
            sign = math.tanh(_pick(joint, v0, v1, v2) / p[3])
            torque = p[2] * abs(_pick(joint, tau0, tau1, tau2)) * sign
            slope = p[2] * abs(_pick(joint, tau0, tau1, tau2)) * ((1.0 - sign * sign) / p[3])
        elif code == _ELBOW:
            first = _pick(int(p[5]), q0, q1, q2)
            second = _pick(int(p[6]), q0, q1, q2)
            x = (first - second - p[3]) / p[4]
            torque = p[2] * math.exp(-x * x) * (1.0 + math.tanh(x / 0.3))
        else:  # _DIRECTION
            switching = int(p[4])
            sign = math.tanh(_pick(switching, v0, v1, v2) / p[3])
            torque = 0.5 * p[2] * (1.0 + sign)
            if switching == joint:
                slope = 0.5 * p[2] * ((1.0 - sign * sign) / p[3])
        if joint == 0:
            e0 += torque
            s0 += slope
        elif joint == 1:
            e1 += torque
            s1 += slope
        else:
            e2 += torque
            s2 += slope
    return e0, e1, e2, s0, s1, s2


EffectFactory = Callable[[int, float], PlantEffect]

#: ``name -> (factory(joint, strength), default joint, default strength)``; strength is the
#: effect's main parameter (N m, except ``load-friction``: dimensionless, and
#: ``drifting-friction``: N m/s).
_REGISTRY: Mapping[str, tuple[EffectFactory, int, float]] = MappingProxyType(
    {
        Cogging.name: (lambda j, s: Cogging(joint=j, amplitude_nm=s), 0, 0.01),
        PositionDependentFriction.name: (
            lambda j, s: PositionDependentFriction(joint=j, coulomb_nm=s),
            1,
            0.015,
        ),
        DriftingFriction.name: (lambda j, s: DriftingFriction(joint=j, rate_nm_per_s=s), 0, 1.0e-4),
        LoadDependentFriction.name: (
            lambda j, s: LoadDependentFriction(joint=j, coefficient=s),
            1,
            0.1,
        ),
        ElbowAngleBump.name: (lambda j, s: ElbowAngleBump(joint=j, amplitude_nm=s), 2, 0.02),
        DirectionOffset.name: (lambda j, s: DirectionOffset(joint=j, offset_nm=s), 2, 0.01),
        CrossDirectionOffset.name: (
            lambda j, s: CrossDirectionOffset(joint=j, offset_nm=s),
            2,
            0.01,
        ),
    }
)

#: Names :func:`make_effect` accepts.
EFFECT_NAMES: tuple[str, ...] = tuple(_REGISTRY)


def default_strength(name: str) -> float:
    """Return the main parameter :func:`make_effect` gives ``name`` by default."""
    entry = _REGISTRY.get(name)
    if entry is None:
        raise ConfigurationError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
    return entry[2]


def make_effect(name: str, joint: int | None = None, strength: float | None = None) -> PlantEffect:
    """Build the effect ``name`` on ``joint`` (0-based) with main parameter ``strength``.

    ``joint`` and ``strength`` default per effect (e.g. ``elbow-bump`` on joint 3 = index 2).

    Raises:
        ConfigurationError: for an unknown name or an invalid joint/strength.

    """
    entry = _REGISTRY.get(name)
    if entry is None:
        raise ConfigurationError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
    factory, default_joint, default_strength = entry
    return factory(
        default_joint if joint is None else joint,
        default_strength if strength is None else strength,
    )


def total_effect_torque(
    effects: Sequence[PlantEffect],
    t_s: float | np.ndarray,
    q_rad: np.ndarray,
    qd_rad_s: np.ndarray,
    tau_motor_nm: np.ndarray,
) -> np.ndarray:
    """Sum of the effects' torques, (n,) or (N, n) (zeros without effects)."""
    total = np.zeros_like(np.asarray(q_rad, dtype=float))
    for effect in effects:
        total += effect.torque(t_s, q_rad, qd_rad_s, tau_motor_nm)
    return total
