"""The simulated Omni's true joint friction: smooth, nonlinear and coupled through the cable.

Deliberately *not* shaped like any model the project fits (not sign + viscous, not a sum of
Mexican hats). With ``w = qd2 - qd3`` the relative velocity of the cable over the joint-2
pulley and ``sigma(v) = tanh(v / v_t)`` a smoothed sign::

    L_i(v)   = Fc_i + (Fs_i - Fc_i) exp(-(v / vs_i)^2)              Stribeck level, joint i
    c_i(v)   = L_i(v) sigma(v)                                      dry friction, joint i
    g(w)     = (Fcc + (Fsc - Fcc) exp(-(w / vsc)^2)) sigma(w) + bc w   cable friction
    kappa(w) = 1 + gamma w^2 / (w^2 + w0^2)                         cable load on the bearings

    tau_f1 = c_1(qd1) + b_1 qd1
    tau_f2 = kappa(w) c_2(qd2) + b_2 qd2 + g(w)
    tau_f3 = kappa(w) c_3(qd3) + b_3 qd3 - g(w)

The cable term acts with opposite signs on joints 2 and 3 (it resists the *relative* motion),
so the friction is passive: ``tau_f . qd >= 0`` for any velocity. The defaults reproduce the
paper's Table III: apparent Coulomb ~0.02 N m and viscous ~5e-3 N m s/rad on joints 2 and 3
when they move together, rising to ~0.023 N m and ~1.1e-2 N m s/rad when they move opposite.

Torques follow docs/conventions.md: ``tau_f`` is on the left of ``M qdd + ... + tau_f = tau``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError, DataError

_Triple = tuple[float, float, float]


@njit_cached()
def true_friction_floats(
    parameters: np.ndarray, qd1: float, qd2: float, qd3: float
) -> tuple[float, float, float, float, float, float, float, float]:  # pragma: no cover
    """Return the friction torques and their non-zero velocity derivatives at one velocity.

    ``parameters`` is :attr:`TrueFriction.kernel_parameters`: ``1/v_t``, ``Fc_1..3, Fcc``,
    ``Fs - Fc`` (joints 1-3, cable), ``1/vs`` (joints 1-3, cable), ``b_1..3, bc``, ``w0^2``,
    ``gamma``. Returns ``(tau1, tau2, tau3, d11, d22, d23, d32, d33)`` with
    ``d_ij = d tau_i / d qd_j``; the one definition the plant's kernels and
    :meth:`TrueFriction.evaluate_floats` use.
    """
    ivt = parameters[0]
    fc1, fc2, fc3, fcc = parameters[1], parameters[2], parameters[3], parameters[4]
    h1, h2, h3, hc = parameters[5], parameters[6], parameters[7], parameters[8]
    iv1, iv2, iv3, ivc = parameters[9], parameters[10], parameters[11], parameters[12]
    b1, b2, b3, bc = parameters[13], parameters[14], parameters[15], parameters[16]
    w0_sq, gain = parameters[17], parameters[18]
    x = qd1 * iv1
    hump = h1 * math.exp(-x * x)
    s = math.tanh(qd1 * ivt)
    c1 = (fc1 + hump) * s
    dc1 = (fc1 + hump) * (1.0 - s * s) * ivt - 2.0 * x * iv1 * hump * s
    x = qd2 * iv2
    hump = h2 * math.exp(-x * x)
    s = math.tanh(qd2 * ivt)
    c2 = (fc2 + hump) * s
    dc2 = (fc2 + hump) * (1.0 - s * s) * ivt - 2.0 * x * iv2 * hump * s
    x = qd3 * iv3
    hump = h3 * math.exp(-x * x)
    s = math.tanh(qd3 * ivt)
    c3 = (fc3 + hump) * s
    dc3 = (fc3 + hump) * (1.0 - s * s) * ivt - 2.0 * x * iv3 * hump * s
    w = qd2 - qd3
    x = w * ivc
    hump = hc * math.exp(-x * x)
    s = math.tanh(w * ivt)
    g = (fcc + hump) * s + bc * w
    dg = (fcc + hump) * (1.0 - s * s) * ivt - 2.0 * x * ivc * hump * s + bc
    denominator = w * w + w0_sq
    kappa = 1.0 + gain * w * w / denominator
    dkappa = gain * 2.0 * w * w0_sq / (denominator * denominator)
    return (
        c1 + b1 * qd1,
        kappa * c2 + b2 * qd2 + g,
        kappa * c3 + b3 * qd3 - g,
        dc1 + b1,
        kappa * dc2 + b2 + dkappa * c2 + dg,
        -dkappa * c2 - dg,
        dkappa * c3 - dg,
        kappa * dc3 + b3 - dkappa * c3 + dg,
    )


def _check_triple(name: str, value: Any, *, positive: bool) -> _Triple:
    values = tuple(float(v) for v in np.asarray(value, dtype=float).reshape(-1))
    if len(values) != 3:
        raise ConfigurationError(f"{name} needs 3 values (one per joint), got {len(values)}")
    if any(not math.isfinite(v) or v < 0.0 or (positive and v == 0.0) for v in values):
        raise ConfigurationError(f"{name} must be {'> 0' if positive else '>= 0'}, got {values}")
    return values[0], values[1], values[2]


def _check_scalar(name: str, value: float, *, positive: bool) -> float:
    value = float(value)
    if not math.isfinite(value) or value < 0.0 or (positive and value == 0.0):
        raise ConfigurationError(f"{name} must be {'> 0' if positive else '>= 0'}, got {value}")
    return value


@dataclass(frozen=True)
class TrueFriction:
    """Ground-truth friction of the simulated 3-joint Omni (formula in the module docstring).

    Attributes:
        coulomb_nm: ``Fc_i``, kinetic dry friction per joint.
        static_nm: ``Fs_i``, breakaway (Stribeck peak) level per joint.
        stribeck_velocity_rad_s: ``vs_i``, width of the Stribeck peak.
        viscous_nms_per_rad: ``b_i``, viscous coefficient per joint.
        cable_coulomb_nm: ``Fcc``, kinetic dry friction of the cable over the pulley.
        cable_static_nm: ``Fsc``, its breakaway level.
        cable_stribeck_velocity_rad_s: ``vsc``.
        cable_viscous_nms_per_rad: ``bc``.
        interaction_gain: ``gamma``, relative rise of joints 2-3 dry friction at large ``|w|``.
        interaction_velocity_rad_s: ``w0``, relative velocity where half of the rise is reached.
        smoothing_velocity_rad_s: ``v_t``, width of the smoothed sign.

    """

    coulomb_nm: _Triple = (0.0195, 0.0195, 0.0165)
    static_nm: _Triple = (0.026, 0.026, 0.022)
    stribeck_velocity_rad_s: _Triple = (0.04, 0.05, 0.05)
    viscous_nms_per_rad: _Triple = (1.7e-3, 5.0e-3, 5.6e-3)
    cable_coulomb_nm: float = 0.0025
    cable_static_nm: float = 0.004
    cable_stribeck_velocity_rad_s: float = 0.08
    cable_viscous_nms_per_rad: float = 3.0e-3
    interaction_gain: float = 0.15
    interaction_velocity_rad_s: float = 0.5
    smoothing_velocity_rad_s: float = 0.005
    _kernel_parameters: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("coulomb_nm", "static_nm", "viscous_nms_per_rad"):
            object.__setattr__(self, name, _check_triple(name, getattr(self, name), positive=False))
        vs = _check_triple("stribeck_velocity_rad_s", self.stribeck_velocity_rad_s, positive=True)
        object.__setattr__(self, "stribeck_velocity_rad_s", vs)
        for name in (
            "cable_coulomb_nm",
            "cable_static_nm",
            "cable_viscous_nms_per_rad",
            "interaction_gain",
        ):
            object.__setattr__(self, name, _check_scalar(name, getattr(self, name), positive=False))
        for name in (
            "cable_stribeck_velocity_rad_s",
            "interaction_velocity_rad_s",
            "smoothing_velocity_rad_s",
        ):
            object.__setattr__(self, name, _check_scalar(name, getattr(self, name), positive=True))
        fc = (*self.coulomb_nm, self.cable_coulomb_nm)
        fs = (*self.static_nm, self.cable_static_nm)
        widths = (*self.stribeck_velocity_rad_s, self.cable_stribeck_velocity_rad_s)
        packed = np.array(
            [
                1.0 / self.smoothing_velocity_rad_s,
                *fc,
                *(s - c for s, c in zip(fs, fc, strict=True)),
                *(1.0 / v for v in widths),
                *self.viscous_nms_per_rad,
                self.cable_viscous_nms_per_rad,
                self.interaction_velocity_rad_s**2,
                self.interaction_gain,
            ]
        )
        packed.flags.writeable = False
        object.__setattr__(self, "_kernel_parameters", packed)

    @property
    def n_joints(self) -> int:
        """Always 3: the formula is the Omni's."""
        return 3

    @property
    def kernel_parameters(self) -> np.ndarray:
        """The parameters packed for :func:`true_friction_floats` (read-only, 19 values)."""
        return self._kernel_parameters

    def scaled(self, factor: float) -> TrueFriction:
        """Return a copy with every torque coefficient multiplied by ``factor`` (>= 0)."""
        factor = _check_scalar("factor", factor, positive=False)
        return TrueFriction(
            coulomb_nm=tuple(factor * v for v in self.coulomb_nm),  # type: ignore[arg-type]
            static_nm=tuple(factor * v for v in self.static_nm),  # type: ignore[arg-type]
            stribeck_velocity_rad_s=self.stribeck_velocity_rad_s,
            viscous_nms_per_rad=tuple(factor * v for v in self.viscous_nms_per_rad),  # type: ignore[arg-type]
            cable_coulomb_nm=factor * self.cable_coulomb_nm,
            cable_static_nm=factor * self.cable_static_nm,
            cable_stribeck_velocity_rad_s=self.cable_stribeck_velocity_rad_s,
            cable_viscous_nms_per_rad=factor * self.cable_viscous_nms_per_rad,
            interaction_gain=self.interaction_gain,
            interaction_velocity_rad_s=self.interaction_velocity_rad_s,
            smoothing_velocity_rad_s=self.smoothing_velocity_rad_s,
        )

    def torque(self, qd_rad_s: np.ndarray) -> np.ndarray:
        """Friction torque [N m] at motor velocities ``qd`` ((3,) -> (3,), or (N, 3) -> (N, 3))."""
        qd = self._check_velocities(qd_rad_s)
        tau1, tau2, tau3, *_ = self._evaluate(qd[..., 0], qd[..., 1], qd[..., 2], np.tanh, np.exp)
        return np.stack(np.broadcast_arrays(tau1, tau2, tau3), axis=-1)

    def jacobian(self, qd_rad_s: np.ndarray) -> np.ndarray:
        """``d tau_f / d qd`` at ``qd`` ((3,) -> (3, 3), or (N, 3) -> (N, 3, 3))."""
        qd = self._check_velocities(qd_rad_s)
        _, _, _, d11, d22, d23, d32, d33 = self._evaluate(
            qd[..., 0], qd[..., 1], qd[..., 2], np.tanh, np.exp
        )
        d11, d22, d23, d32, d33 = np.broadcast_arrays(d11, d22, d23, d32, d33)
        out = np.zeros((*qd.shape[:-1], 3, 3))
        out[..., 0, 0] = d11
        out[..., 1, 1] = d22
        out[..., 1, 2] = d23
        out[..., 2, 1] = d32
        out[..., 2, 2] = d33
        return out

    def cable_torque(self, qd_rad_s: np.ndarray) -> np.ndarray:
        """Return the cable part ``g(qd2 - qd3)`` alone (added to joint 2, subtracted from 3)."""
        qd = self._check_velocities(qd_rad_s)
        w = qd[..., 1] - qd[..., 2]
        level = self.cable_coulomb_nm + (self.cable_static_nm - self.cable_coulomb_nm) * np.exp(
            -((w / self.cable_stribeck_velocity_rad_s) ** 2)
        )
        return (
            level * np.tanh(w / self.smoothing_velocity_rad_s) + self.cable_viscous_nms_per_rad * w
        )

    def evaluate_floats(
        self, qd1: float, qd2: float, qd3: float
    ) -> tuple[float, float, float, float, float, float, float, float]:
        """Scalar path, compiled (:func:`true_friction_floats`; same numbers as :meth:`torque`).

        Returns ``(tau1, tau2, tau3, d11, d22, d23, d32, d33)``: the torques and the non-zero
        entries ``d_ij = d tau_i / d qd_j`` of the Jacobian.
        """
        result: tuple[float, float, float, float, float, float, float, float] = (
            true_friction_floats(self._kernel_parameters, float(qd1), float(qd2), float(qd3))
        )
        return result

    @staticmethod
    def _check_velocities(qd_rad_s: np.ndarray) -> np.ndarray:
        qd = np.asarray(qd_rad_s, dtype=float)
        if qd.ndim not in (1, 2) or qd.shape[-1] != 3:
            raise DataError(f"expected velocities of shape (3,) or (N, 3), got {qd.shape}")
        return qd

    def _evaluate(
        self,
        qd1: Any,
        qd2: Any,
        qd3: Any,
        tanh: Callable[[Any], Any],
        exp: Callable[[Any], Any],
    ) -> tuple[Any, Any, Any, Any, Any, Any, Any, Any]:
        # One formula for floats (math) and arrays (numpy): the simulator and the tests share it.
        vt = self.smoothing_velocity_rad_s
        fc1, fc2, fc3 = self.coulomb_nm
        fs1, fs2, fs3 = self.static_nm
        vs1, vs2, vs3 = self.stribeck_velocity_rad_s
        b1, b2, b3 = self.viscous_nms_per_rad

        def dry(v: Any, fc: float, fs: float, vs: float) -> tuple[Any, Any]:
            hump = (fs - fc) * exp(-((v / vs) ** 2))
            level = fc + hump
            s = tanh(v / vt)
            slope = level * (1.0 - s * s) / vt - 2.0 * v / (vs * vs) * hump * s
            return level * s, slope

        c1, dc1 = dry(qd1, fc1, fs1, vs1)
        c2, dc2 = dry(qd2, fc2, fs2, vs2)
        c3, dc3 = dry(qd3, fc3, fs3, vs3)
        w = qd2 - qd3
        g, dg = dry(
            w, self.cable_coulomb_nm, self.cable_static_nm, self.cable_stribeck_velocity_rad_s
        )
        g = g + self.cable_viscous_nms_per_rad * w
        dg = dg + self.cable_viscous_nms_per_rad
        w0_sq = self.interaction_velocity_rad_s**2
        denominator = w * w + w0_sq
        kappa = 1.0 + self.interaction_gain * w * w / denominator
        dkappa = self.interaction_gain * 2.0 * w * w0_sq / (denominator * denominator)

        tau1 = c1 + b1 * qd1
        tau2 = kappa * c2 + b2 * qd2 + g
        tau3 = kappa * c3 + b3 * qd3 - g
        d11 = dc1 + b1
        d22 = kappa * dc2 + b2 + dkappa * c2 + dg
        d23 = -dkappa * c2 - dg
        d32 = dkappa * c3 - dg
        d33 = kappa * dc3 + b3 - dkappa * c3 + dg
        return tau1, tau2, tau3, d11, d22, d23, d32, d33
