"""Plant family two's true friction: LuGre per joint plus a LuGre cable between joints 2 and 3.

Not Coulomb-viscous and not family one's static map (:mod:`true_friction`): each element has a
bristle state ``z`` (pre-sliding displacement), so the friction depends on the history of the
motion, sticks with a spring-like pre-sliding hysteresis before breakaway, and follows a
Stribeck curve when sliding (Canudas de Wit et al., 1995). For an element sliding at ``v``::

    g(v)   = Fc + (Fs - Fc) exp(-(v / vs)^2)                 Stribeck level
    dz/dt  = v - sigma0 |v| z / g(v)
    F      = sigma0 z + sigma1 exp(-(v / vd)^2) dz/dt + sigma2 v

The micro-damping ``sigma1`` fades with speed (``vd``), the usual choice that keeps the model
dissipative. Elements: joint ``i`` with ``v = qd_i`` (torque ``F_i`` on joint ``i``), and the
cable over the joint-2 pulley with ``w = qd2 - r qd3`` (``r``: pulley ratio), whose torque
``F_c`` acts as ``+F_c`` on joint 2 and ``-r F_c`` on joint 3: the cable's power is
``F_c w``, so the coupling is passive too. (Family one couples 2 and 3 by a static cable law
on ``qd2 - qd3`` and a load factor; this coupling has its own bristle, ratio and levels.)

At constant velocity ``z`` settles at ``g(v) sgn(v) / sigma0`` and ``F = g(v) sgn(v) +
sigma2 v``: :meth:`LuGreFriction.steady_state_torque`. Integration (:func:`lugre_step`):
with the velocity held over a sub-step ``h``, ``z`` relaxes exactly,
``z' = z_ss + (z - z_ss) exp(-sigma0 |v| h / g)``, stable at any speed, and the force uses the
new ``z`` and ``dz/dt = (z' - z) / h``. Sign: on the LEFT of ``M qdd + ... + tau_f = tau``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError, DataError

#: Number of bristle states: joints 1-3 and the cable.
N_STATES = 4
#: Packed parameters per element: sigma0, sigma1, sigma2, Fc, Fs, 1/vs, 1/vd.
_PER_ELEMENT = 7
#: After the 4 elements: the pulley ratio r.
PARAMETERS_SIZE = N_STATES * _PER_ELEMENT + 1

_Quad = tuple[float, float, float, float]


@njit_cached()
def _element(
    p: np.ndarray, row: int, v: float, z: float, h: float
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """One element over a sub-step: ``(force, new z, d force / d v)`` (the last for the solver)."""
    sigma0, sigma1, sigma2 = p[row], p[row + 1], p[row + 2]
    fc, fs, inv_vs, inv_vd = p[row + 3], p[row + 4], p[row + 5], p[row + 6]
    x = v * inv_vs
    level = fc + (fs - fc) * math.exp(-x * x)
    rate = sigma0 * abs(v) / level
    if rate * h < 1e-9:
        z_new = z + h * (v - rate * z)
    else:
        z_ss = v / rate
        z_new = z_ss + (z - z_ss) * math.exp(-rate * h)
    y = v * inv_vd
    damping = sigma1 * math.exp(-y * y)
    force = sigma0 * z_new + damping * (z_new - z) / h + sigma2 * v
    return force, z_new, damping + sigma2


@njit_cached()
def lugre_step(
    parameters: np.ndarray, z: np.ndarray, v0: float, v1: float, v2: float, h: float
) -> tuple[float, float, float, float, float, float, float, float]:  # pragma: no cover
    """Advance ``z`` (in place) by ``h``; return torques and the velocity slopes for the solver.

    Returns ``(tau1, tau2, tau3, D11, D22, D23, D32, D33)`` with ``D = d tau / d qd`` of the
    damping terms (micro-damping and viscous; the bristles' own response is not linearised).
    """
    f0, z0, d0 = _element(parameters, 0, v0, z[0], h)
    f1, z1, d1 = _element(parameters, _PER_ELEMENT, v1, z[1], h)
    f2, z2, d2 = _element(parameters, 2 * _PER_ELEMENT, v2, z[2], h)
    ratio = parameters[N_STATES * _PER_ELEMENT]
    fc, zc, dc = _element(parameters, 3 * _PER_ELEMENT, v1 - ratio * v2, z[3], h)
    z[0], z[1], z[2], z[3] = z0, z1, z2, zc
    return (
        f0,
        f1 + fc,
        f2 - ratio * fc,
        d0,
        d1 + dc,
        -ratio * dc,
        -ratio * dc,
        d2 + ratio * ratio * dc,
    )


def _quad(name: str, value: Any, *, positive: bool) -> _Quad:
    values = tuple(float(v) for v in np.asarray(value, dtype=float).reshape(-1))
    if len(values) != N_STATES:
        raise ConfigurationError(f"{name} needs 4 values (joints 1-3, cable), got {len(values)}")
    if any(not math.isfinite(v) or v < 0.0 or (positive and v == 0.0) for v in values):
        raise ConfigurationError(f"{name} must be {'> 0' if positive else '>= 0'}, got {values}")
    return values[0], values[1], values[2], values[3]


@dataclass(frozen=True)
class LuGreFriction:
    """LuGre friction of joints 1-3 and of the joint-2/3 cable (module docstring).

    Every per-element field holds 4 values: joints 1, 2, 3 and the cable.

    Attributes:
        bristle_stiffness_nm_per_rad: ``sigma0``.
        bristle_damping_nms_per_rad: ``sigma1`` (micro-damping at rest).
        viscous_nms_per_rad: ``sigma2``.
        coulomb_nm: ``Fc``, kinetic level.
        static_nm: ``Fs`` (>= ``Fc``), breakaway level.
        stribeck_velocity_rad_s: ``vs``.
        damping_velocity_rad_s: ``vd``, speed over which ``sigma1`` fades.
        pulley_ratio: ``r`` in ``w = qd2 - r qd3``.

    """

    bristle_stiffness_nm_per_rad: _Quad = (30.0, 25.0, 25.0, 20.0)
    bristle_damping_nms_per_rad: _Quad = (0.08, 0.06, 0.05, 0.04)
    viscous_nms_per_rad: _Quad = (4.0e-3, 3.5e-3, 3.0e-3, 2.5e-3)
    coulomb_nm: _Quad = (0.016, 0.013, 0.012, 0.006)
    static_nm: _Quad = (0.026, 0.021, 0.019, 0.010)
    stribeck_velocity_rad_s: _Quad = (0.06, 0.08, 0.07, 0.05)
    damping_velocity_rad_s: _Quad = (0.05, 0.05, 0.05, 0.05)
    pulley_ratio: float = 0.85
    _parameters: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name, positive in (
            ("bristle_stiffness_nm_per_rad", True),
            ("bristle_damping_nms_per_rad", False),
            ("viscous_nms_per_rad", False),
            ("coulomb_nm", True),
            ("static_nm", True),
            ("stribeck_velocity_rad_s", True),
            ("damping_velocity_rad_s", True),
        ):
            object.__setattr__(self, name, _quad(name, getattr(self, name), positive=positive))
        if any(s < c for s, c in zip(self.static_nm, self.coulomb_nm, strict=True)):
            raise ConfigurationError("static_nm must be >= coulomb_nm on every element")
        ratio = float(self.pulley_ratio)
        if not (math.isfinite(ratio) and ratio > 0.0):
            raise ConfigurationError(f"pulley_ratio must be > 0, got {ratio}")
        object.__setattr__(self, "pulley_ratio", ratio)
        packed = np.zeros(PARAMETERS_SIZE)
        for e in range(N_STATES):
            packed[e * _PER_ELEMENT : (e + 1) * _PER_ELEMENT] = (
                self.bristle_stiffness_nm_per_rad[e],
                self.bristle_damping_nms_per_rad[e],
                self.viscous_nms_per_rad[e],
                self.coulomb_nm[e],
                self.static_nm[e],
                1.0 / self.stribeck_velocity_rad_s[e],
                1.0 / self.damping_velocity_rad_s[e],
            )
        packed[-1] = ratio
        packed.flags.writeable = False
        object.__setattr__(self, "_parameters", packed)

    @property
    def kernel_parameters(self) -> np.ndarray:
        """The parameters packed for :func:`lugre_step` (read-only)."""
        return self._parameters

    def perturbed(self, rng: np.random.Generator, spread: float = 0.2) -> LuGreFriction:
        """Return a copy with every level and coefficient scaled by ``U(1 - spread, 1 + spread)``.

        The static level is kept above the kinetic one.
        """
        if not 0.0 <= spread < 1.0:
            raise ConfigurationError(f"spread must be in [0, 1), got {spread}")
        changes: dict[str, Any] = {}
        for name in (
            "bristle_stiffness_nm_per_rad",
            "bristle_damping_nms_per_rad",
            "viscous_nms_per_rad",
            "coulomb_nm",
            "static_nm",
            "stribeck_velocity_rad_s",
        ):
            scale = rng.uniform(1.0 - spread, 1.0 + spread, size=N_STATES)
            changes[name] = tuple(float(x) for x in np.asarray(getattr(self, name)) * scale)
        changes["static_nm"] = tuple(
            max(s, 1.1 * c)
            for s, c in zip(changes["static_nm"], changes["coulomb_nm"], strict=True)
        )
        changes["pulley_ratio"] = self.pulley_ratio * float(rng.uniform(0.9, 1.1))
        return dataclasses.replace(self, **changes)

    def stribeck_level_nm(self, v: np.ndarray, element: int) -> np.ndarray:
        """``g(v)`` of one element (0-2: joints, 3: cable)."""
        x = np.asarray(v, dtype=float) / self.stribeck_velocity_rad_s[element]
        fc, fs = self.coulomb_nm[element], self.static_nm[element]
        return np.asarray(fc + (fs - fc) * np.exp(-x * x))

    def steady_state_torque(self, qd_rad_s: np.ndarray) -> np.ndarray:
        """Friction torques once the bristles have settled at constant velocities (N, 3)/(3,)."""
        qd = np.asarray(qd_rad_s, dtype=float)
        if qd.shape[-1:] != (3,):
            raise DataError(f"qd must have shape (3,) or (N, 3), got {qd.shape}")
        out = np.zeros_like(qd)
        for j in range(3):
            v = qd[..., j]
            out[..., j] = (
                self.stribeck_level_nm(v, j) * np.sign(v) + self.viscous_nms_per_rad[j] * v
            )
        w = qd[..., 1] - self.pulley_ratio * qd[..., 2]
        cable = self.stribeck_level_nm(w, 3) * np.sign(w) + self.viscous_nms_per_rad[3] * w
        out[..., 1] += cable
        out[..., 2] -= self.pulley_ratio * cable
        return out

    def bristle_energy_j(self, z: np.ndarray) -> float:
        """Potential energy stored in the bristles, ``sum sigma0 z^2 / 2``."""
        values = np.asarray(z, dtype=float).reshape(N_STATES)
        return float(0.5 * np.sum(np.asarray(self.bristle_stiffness_nm_per_rad) * values**2))
