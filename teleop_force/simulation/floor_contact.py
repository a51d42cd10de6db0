"""Plant family two's soft floor: a nonlinear Hunt-Crossley normal law and Coulomb sliding.

The floor fills the half-space below a plane through ``point_in_base_m`` with outward unit
normal ``normal_in_base``. With ``delta = max(0, -(p - point) . n)`` the penetration,
``delta_dot = -v . n`` its rate and ``v_t = v - (v . n) n`` the sliding velocity::

    f_n   = max(0, k delta^e (1 + 1.5 alpha delta_dot))             Hunt-Crossley, exponent e
    F_env = f_n n - mu f_n v_t / sqrt(|v_t|^2 + v_eps^2)            regularised Coulomb sliding

``e = 1.5`` is Hertz's exponent for a rounded tip on a soft half-space: the floor stiffens as
the tip sinks (family one's tissue, :class:`~teleop_force.simulation.contact.PlaneContact`,
is linear in the penetration, ``e = 1``, with viscous sliding drag). ``F_env`` is the force of
the floor ON THE TIP; the force reported everywhere (docs/conventions.md) is ``F = -F_env``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError, DataError

#: Packed parameters: normal (3), surface point (3), k, exponent, alpha, mu, v_eps.
PARAMETERS_SIZE = 11


@njit_cached()
def floor_contact_force(
    parameters: np.ndarray, px: float, py: float, pz: float, vx: float, vy: float, vz: float
) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """Force of the floor ON THE TIP ``F_env`` [N] and the sliding law's secant slope [N s/m].

    ``parameters``: :attr:`HuntCrossleyFloor.kernel_parameters`. The slope ``c`` (the force
    per unit of sliding velocity, ``mu f_n / sqrt(|v_t|^2 + v_eps^2)``) lets the plant treat
    the sliding friction implicitly.
    """
    nx, ny, nz = parameters[0], parameters[1], parameters[2]
    distance = (px - parameters[3]) * nx + (py - parameters[4]) * ny + (pz - parameters[5]) * nz
    if distance >= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    v_normal = vx * nx + vy * ny + vz * nz
    depth = -distance
    f_n = parameters[6] * depth ** parameters[7] * (1.0 - 1.5 * parameters[8] * v_normal)
    if f_n <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    tx, ty, tz = vx - v_normal * nx, vy - v_normal * ny, vz - v_normal * nz
    eps = parameters[10]
    slope = parameters[9] * f_n / math.sqrt(tx * tx + ty * ty + tz * tz + eps * eps)
    return f_n * nx - slope * tx, f_n * ny - slope * ty, f_n * nz - slope * tz, slope


@dataclass(frozen=True)
class HuntCrossleyFloor:
    """A soft floor below a plane (force law in the module docstring).

    Attributes:
        point_in_base_m: A point of the undeformed surface, base frame [m].
        normal_in_base: Outward normal (normalised on construction).
        stiffness_n_per_m_e: ``k`` [N / m^e].
        exponent: ``e`` (> 1 for a nonlinear law; 1.5 by default).
        damping_s_per_m: ``alpha``, Hunt-Crossley damping per unit penetration rate [s/m].
        sliding_friction: ``mu``, Coulomb coefficient of sliding.
        sliding_velocity_m_s: ``v_eps``, regularisation of the sliding direction [m/s].

    """

    point_in_base_m: tuple[float, float, float] = (0.0, -0.06, 0.0)
    normal_in_base: tuple[float, float, float] = (0.0, 1.0, 0.0)
    stiffness_n_per_m_e: float = 3200.0
    exponent: float = 1.5
    damping_s_per_m: float = 0.3
    sliding_friction: float = 0.25
    sliding_velocity_m_s: float = 0.005
    _kernel_parameters: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        point = np.asarray(self.point_in_base_m, dtype=float).reshape(-1)
        normal = np.asarray(self.normal_in_base, dtype=float).reshape(-1)
        if point.shape != (3,) or normal.shape != (3,):
            raise ConfigurationError("point_in_base_m and normal_in_base need 3 values each")
        if not (np.all(np.isfinite(point)) and np.all(np.isfinite(normal))):
            raise ConfigurationError("point_in_base_m and normal_in_base must be finite")
        norm = float(np.linalg.norm(normal))
        if norm < 1e-9:
            raise ConfigurationError("normal_in_base must not be zero")
        normal = normal / norm
        object.__setattr__(self, "point_in_base_m", tuple(float(x) for x in point))
        object.__setattr__(self, "normal_in_base", tuple(float(x) for x in normal))
        for name in (
            "stiffness_n_per_m_e",
            "exponent",
            "damping_s_per_m",
            "sliding_friction",
            "sliding_velocity_m_s",
        ):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value < 0.0:
                raise ConfigurationError(f"{name} must be finite and >= 0, got {value}")
            object.__setattr__(self, name, value)
        if self.stiffness_n_per_m_e == 0.0 or self.sliding_velocity_m_s == 0.0:
            raise ConfigurationError("stiffness_n_per_m_e and sliding_velocity_m_s must be > 0")
        if not 1.0 <= self.exponent <= 3.0:
            raise ConfigurationError(f"exponent must be in [1, 3], got {self.exponent}")
        packed = np.array(
            [
                *self.normal_in_base,
                *self.point_in_base_m,
                self.stiffness_n_per_m_e,
                self.exponent,
                self.damping_s_per_m,
                self.sliding_friction,
                self.sliding_velocity_m_s,
            ]
        )
        packed.flags.writeable = False
        object.__setattr__(self, "_kernel_parameters", packed)

    @classmethod
    def horizontal(cls, surface_y_m: float, **parameters: float) -> HuntCrossleyFloor:
        """Floor below the horizontal plane ``y = surface_y_m`` (normal +y)."""
        return cls(point_in_base_m=(0.0, surface_y_m, 0.0), **parameters)  # type: ignore[arg-type]

    @property
    def kernel_parameters(self) -> np.ndarray:
        """The parameters packed for :func:`floor_contact_force` (read-only, 11 values)."""
        return self._kernel_parameters

    def signed_distance_m(self, p_in_base_m: ArrayLike) -> np.ndarray:
        """Height of the tip above the surface (negative inside): (3,) -> (), (N, 3) -> (N,)."""
        p = _points(p_in_base_m, "p_in_base_m")
        return np.asarray((p - np.array(self.point_in_base_m)) @ np.array(self.normal_in_base))

    def force_on_environment(self, p_in_base_m: ArrayLike, v_in_base_m_s: ArrayLike) -> np.ndarray:
        """Force of the tip on the floor ``F = -F_env`` [N]: (3,) -> (3,), (N, 3) -> (N, 3)."""
        p = _points(p_in_base_m, "p_in_base_m")
        v = _points(v_in_base_m_s, "v_in_base_m_s")
        if p.shape != v.shape:
            raise DataError(f"positions {p.shape} and velocities {v.shape} differ in shape")
        flat_p, flat_v = p.reshape(-1, 3), v.reshape(-1, 3)
        out = np.empty_like(flat_p)
        for row in range(flat_p.shape[0]):
            fx, fy, fz, _ = floor_contact_force(
                self._kernel_parameters, *(float(x) for x in flat_p[row]),
                *(float(x) for x in flat_v[row]),
            )  # fmt: skip
            out[row] = (-fx, -fy, -fz)
        return out.reshape(p.shape)


def _points(value: ArrayLike, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if array.ndim not in (1, 2) or array.shape[-1] != 3:
        raise DataError(f"{name} must have shape (3,) or (N, 3), got {array.shape}")
    return array
