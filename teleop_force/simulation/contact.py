"""Soft-tissue contact with a plane: Hunt-Crossley normal force and viscous sliding drag.

The tissue fills the half-space below a plane through ``point_in_base_m`` with unit normal
``normal_in_base`` (pointing out of the tissue, into free space). With ``d = (p - point) . n``
the signed distance of the tip, ``delta = max(0, -d)`` its penetration and
``delta_dot = -v . n`` the penetration rate, the tissue pushes the tip with::

    f_n     = max(0, k delta (1 + lambda delta_dot))         Hunt-Crossley, exponent 1
    F_env   = f_n n - mu_t f_n v_t                          v_t = v - (v . n) n

Both terms vanish continuously at first touch. The force reported everywhere (docs/conventions.md)
is the force of the tip ON the environment, ``F = -F_env``: pressing down into a horizontal
surface gives ``f_y < 0``. The plant applies ``-J^T F = J^T F_env`` at the joints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError, DataError


@njit_cached()
def plane_contact_force(
    parameters: np.ndarray, px: float, py: float, pz: float, vx: float, vy: float, vz: float
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """Force of the tissue ON THE TIP, ``F_env = -F`` [N], at one tip position and velocity.

    ``parameters`` is :attr:`PlaneContact.kernel_parameters`: the normal ``n``, the surface
    point, ``k``, ``lambda`` and ``mu_t``. The one definition of the force law (compiled), for
    the plant's kernels and :meth:`PlaneContact.environment_force_floats`.
    """
    nx, ny, nz = parameters[0], parameters[1], parameters[2]
    cx, cy, cz = parameters[3], parameters[4], parameters[5]
    distance = (px - cx) * nx + (py - cy) * ny + (pz - cz) * nz
    if distance >= 0.0:
        return 0.0, 0.0, 0.0
    v_normal = vx * nx + vy * ny + vz * nz
    f_n = -parameters[6] * distance * (1.0 - parameters[7] * v_normal)
    if f_n <= 0.0:
        return 0.0, 0.0, 0.0
    drag = parameters[8] * f_n
    tx, ty, tz = vx - v_normal * nx, vy - v_normal * ny, vz - v_normal * nz
    return f_n * nx - drag * tx, f_n * ny - drag * ty, f_n * nz - drag * tz


def _vector3(name: str, value: object) -> tuple[float, float, float]:
    array = np.asarray(value, dtype=float).reshape(-1)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        raise ConfigurationError(f"{name} must be 3 finite numbers, got {value!r}")
    return (float(array[0]), float(array[1]), float(array[2]))


@dataclass(frozen=True)
class PlaneContact:
    """A soft tissue below a plane (see the module docstring for the force law).

    Attributes:
        point_in_base_m: A point of the undeformed surface, base frame [m].
        normal_in_base: Outward normal (normalised on construction).
        stiffness_n_per_m: ``k``, normal stiffness (soft tissue: 200-400 N/m).
        damping_s_per_m: ``lambda``, Hunt-Crossley damping per unit penetration rate [s/m].
        sliding_friction_s_per_m: ``mu_t``, tangential drag per newton of normal force and per
            m/s of sliding velocity [s/m].

    """

    point_in_base_m: tuple[float, float, float] = (0.0, -0.06, 0.0)
    normal_in_base: tuple[float, float, float] = (0.0, 1.0, 0.0)
    stiffness_n_per_m: float = 300.0
    damping_s_per_m: float = 5.0
    sliding_friction_s_per_m: float = 4.0
    _kernel_parameters: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "point_in_base_m", _vector3("point_in_base_m", self.point_in_base_m)
        )
        normal = np.array(_vector3("normal_in_base", self.normal_in_base))
        norm = float(np.linalg.norm(normal))
        if norm < 1e-9:
            raise ConfigurationError("normal_in_base must not be zero")
        object.__setattr__(self, "normal_in_base", _vector3("normal_in_base", normal / norm))
        for name in ("stiffness_n_per_m", "damping_s_per_m", "sliding_friction_s_per_m"):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value < 0.0:
                raise ConfigurationError(f"{name} must be finite and >= 0, got {value}")
            object.__setattr__(self, name, value)
        if self.stiffness_n_per_m == 0.0:
            raise ConfigurationError("stiffness_n_per_m must be > 0")
        packed = np.array(
            [
                *self.normal_in_base,
                *self.point_in_base_m,
                self.stiffness_n_per_m,
                self.damping_s_per_m,
                self.sliding_friction_s_per_m,
            ]
        )
        packed.flags.writeable = False
        object.__setattr__(self, "_kernel_parameters", packed)

    @property
    def kernel_parameters(self) -> np.ndarray:
        """The parameters packed for :func:`plane_contact_force` (read-only, 9 values)."""
        return self._kernel_parameters

    @classmethod
    def horizontal(cls, surface_y_m: float, **parameters: float) -> PlaneContact:
        """Tissue below the horizontal plane ``y = surface_y_m`` (normal +y)."""
        return cls(
            point_in_base_m=(0.0, surface_y_m, 0.0), normal_in_base=(0.0, 1.0, 0.0), **parameters
        )

    @classmethod
    def tilted(
        cls,
        surface_y_m: float,
        tilt_rad: float,
        *,
        centre_z_m: float = 0.12,
        **parameters: float,
    ) -> PlaneContact:
        """Plane through ``(0, surface_y_m, centre_z_m)`` rising by ``tilt_rad`` toward +z.

        The normal is +y rotated about the x axis by ``tilt_rad`` (``|tilt_rad| < pi/2``).
        """
        if not abs(tilt_rad) < math.pi / 2:
            raise ConfigurationError(f"tilt_rad must be in (-pi/2, pi/2), got {tilt_rad}")
        normal = (0.0, math.cos(tilt_rad), -math.sin(tilt_rad))
        return cls(
            point_in_base_m=(0.0, surface_y_m, centre_z_m), normal_in_base=normal, **parameters
        )

    def signed_distance_m(self, p_in_base_m: ArrayLike) -> np.ndarray:
        """Height of the tip above the surface (negative inside), (3,) -> () or (N, 3) -> (N,)."""
        p = _points(p_in_base_m, "p_in_base_m")
        return (p - np.array(self.point_in_base_m)) @ np.array(self.normal_in_base)

    def force_on_environment(self, p_in_base_m: ArrayLike, v_in_base_m_s: ArrayLike) -> np.ndarray:
        """Force of the tip on the tissue ``F`` [N] at tip positions and velocities.

        Shapes (3,) -> (3,) or (N, 3) -> (N, 3); zero above the surface.
        """
        p = _points(p_in_base_m, "p_in_base_m")
        v = _points(v_in_base_m_s, "v_in_base_m_s")
        if p.shape != v.shape:
            raise DataError(f"positions {p.shape} and velocities {v.shape} differ in shape")
        flat_p = p.reshape(-1, 3)
        flat_v = v.reshape(-1, 3)
        out = np.empty_like(flat_p)
        for row, (pk, vk) in enumerate(zip(flat_p, flat_v, strict=True)):
            fx, fy, fz = self.environment_force_floats(*pk, *vk)
            out[row] = (-fx, -fy, -fz)
        return out.reshape(p.shape)

    def environment_force_floats(
        self, px: float, py: float, pz: float, vx: float, vy: float, vz: float
    ) -> tuple[float, float, float]:
        """Scalar path (compiled, :func:`plane_contact_force`): force ON THE TIP, ``F_env = -F``."""
        force: tuple[float, float, float] = plane_contact_force(
            self._kernel_parameters,
            float(px),
            float(py),
            float(pz),
            float(vx),
            float(vy),
            float(vz),
        )
        return force


def _points(value: ArrayLike, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if array.ndim not in (1, 2) or array.shape[-1] != 3:
        raise DataError(f"{name} must have shape (3,) or (N, 3), got {array.shape}")
    return array
