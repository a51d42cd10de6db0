"""A discrete joint-space PID position controller (the paper's "PID controller", 1 kHz).

Per joint, with ``e = q_ref - q_measured``::

    v[k]   = a v[k-1] + (1 - a) (q[k] - q[k-1]) / dt      derivative on measurement, low-passed
    u[k]   = kp e + I[k] + kd (qd_ref - v[k])             qd_ref = 0 if not given
    tau[k] = clip(u[k], -limit, limit)
    I[k+1] = clip(I[k] + ki e dt, -I_max, I_max)          not updated while saturated and the
                                                          error pushes further (anti-windup)

``a = exp(-2 pi f_c dt)``. The derivative acts on the measurement (never on the reference, so
steps in the reference do not kick), and the reference velocity, when given, enters as a
damping target. State is explicit (:attr:`PID.integral_nm`, :attr:`PID.velocity_rad_s`) and
:meth:`PID.reset` clears it or presets the integral (bumpless start).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError, DataError


def _positive_vector(name: str, value: object, *, allow_zero: bool = True) -> np.ndarray:
    array = np.array(value, dtype=float).reshape(-1)
    bad = array < 0.0 if allow_zero else array <= 0.0
    if array.size == 0 or not np.all(np.isfinite(array)) or np.any(bad):
        raise ConfigurationError(
            f"{name} must be finite and {'>=' if allow_zero else '>'} 0, got {value!r}"
        )
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class PIDGains:
    """Gains of :class:`PID`, one value per joint (or one for all).

    Attributes:
        kp_nm_per_rad: Proportional gains.
        ki_nm_per_rad_s: Integral gains.
        kd_nms_per_rad: Derivative gains.
        derivative_cutoff_hz: Cut-off of the first-order filter on the measured velocity.
        integral_limit_nm: Bound of the integral term.
        torque_limit_nm: Output saturation.

    """

    kp_nm_per_rad: np.ndarray
    ki_nm_per_rad_s: np.ndarray
    kd_nms_per_rad: np.ndarray
    derivative_cutoff_hz: float = 40.0
    integral_limit_nm: np.ndarray | float = 0.4
    torque_limit_nm: np.ndarray | float = 0.6

    def __post_init__(self) -> None:
        for name in ("kp_nm_per_rad", "ki_nm_per_rad_s", "kd_nms_per_rad"):
            object.__setattr__(self, name, _positive_vector(name, getattr(self, name)))
        for name in ("integral_limit_nm", "torque_limit_nm"):
            object.__setattr__(
                self, name, _positive_vector(name, getattr(self, name), allow_zero=False)
            )
        cutoff = float(self.derivative_cutoff_hz)
        if not (math.isfinite(cutoff) and cutoff > 0.0):
            raise ConfigurationError(f"derivative_cutoff_hz must be > 0, got {cutoff}")
        object.__setattr__(self, "derivative_cutoff_hz", cutoff)

    @classmethod
    def omni(cls) -> PIDGains:
        """Gains tuned for the simulated Omni at 1 kHz (closed-loop bandwidth ~12-15 Hz).

        On the rigid-body protocol (0.5-2 Hz, ~0.24 rad RMS per joint) the RMS tracking error
        is 2-4 mrad, about 1 % of the motion, and encoder quantization leaves ~5 mN m of
        high-frequency torque noise (the derivative filter's 30 Hz cut-off trades the two).
        """
        return cls(
            kp_nm_per_rad=np.array([18.0, 21.0, 9.0]),
            ki_nm_per_rad_s=np.array([180.0, 210.0, 90.0]),
            kd_nms_per_rad=np.array([0.12, 0.14, 0.06]),
            derivative_cutoff_hz=30.0,
        )


@njit_cached()
def _pid_update(
    constants: np.ndarray,
    a: float,
    gain: float,
    has_previous: bool,
    integral: np.ndarray,
    velocity: np.ndarray,
    q_previous: np.ndarray,
    q_ref: np.ndarray,
    q: np.ndarray,
    qd_ref: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """One update (module docstring): ``out`` rows are tau, the new integral, velocity and q.

    ``constants`` rows are ``kp, ki dt, kd, I_max, u_max``; ``gain = (1 - a) / dt``.
    """
    for j in range(q.size):
        v = velocity[j]
        if has_previous:
            v = a * v + gain * (q[j] - q_previous[j])
        error = q_ref[j] - q[j]
        u = constants[0, j] * error + integral[j] + constants[2, j] * (qd_ref[j] - v)
        u_max = constants[4, j]
        tau = u_max if u > u_max else (-u_max if u < -u_max else u)
        increment = constants[1, j] * error
        i_next = integral[j]
        if tau == u or increment * u <= 0.0:  # anti-windup: freeze while pushing the limit
            i_max = constants[3, j]
            i_next = min(i_max, max(-i_max, i_next + increment))
        out[0, j] = tau
        out[1, j] = i_next
        out[2, j] = v
        out[3, j] = q[j]


class PID:
    """Streaming joint-space PID (formula in the module docstring; the update is compiled)."""

    def __init__(self, gains: PIDGains, n_joints: int = 3, control_period_s: float = 1e-3) -> None:
        """Create a controller for ``n_joints`` joints sampled every ``control_period_s``."""
        if n_joints < 1:
            raise ConfigurationError(f"n_joints must be >= 1, got {n_joints}")
        if not (math.isfinite(control_period_s) and control_period_s > 0.0):
            raise ConfigurationError(f"control_period_s must be > 0, got {control_period_s}")
        self.gains = gains
        self.n_joints = n_joints
        self.control_period_s = float(control_period_s)
        shape = (n_joints,)
        try:
            self._kp = np.broadcast_to(gains.kp_nm_per_rad, shape).copy()
            self._ki = np.broadcast_to(gains.ki_nm_per_rad_s, shape).copy()
            self._kd = np.broadcast_to(gains.kd_nms_per_rad, shape).copy()
            self._i_max = np.broadcast_to(gains.integral_limit_nm, shape).copy()
            self._u_max = np.broadcast_to(gains.torque_limit_nm, shape).copy()
        except ValueError as error:
            raise ConfigurationError(f"PID gains do not fit {n_joints} joints: {error}") from error
        self._a = math.exp(-2.0 * math.pi * gains.derivative_cutoff_hz * self.control_period_s)
        self._gain = (1.0 - self._a) / self.control_period_s
        # Per-joint constants for the compiled update: kp, ki dt, kd, I_max, u_max.
        self._constants = np.stack(
            [self._kp, self._ki * self.control_period_s, self._kd, self._i_max, self._u_max]
        )
        self._zeros = np.zeros(shape)
        self._warm_up()
        self.integral_nm = np.zeros(shape)
        self.velocity_rad_s = np.zeros(shape)
        self.q_previous_rad: np.ndarray | None = None

    def _warm_up(self) -> None:
        # Compile (or load from numba's cache) the update for writable and read-only measured
        # angles (a DeviceReading's), here rather than in the first control tick.
        scratch = np.zeros(self.n_joints)
        frozen = scratch.copy()
        frozen.flags.writeable = False
        out = np.empty((4, self.n_joints))
        for q in (scratch, frozen):
            _pid_update(
                self._constants,
                self._a,
                self._gain,
                True,
                scratch,
                scratch,
                scratch,
                scratch,
                q,
                scratch,
                out,
            )

    def reset(self, integral_nm: np.ndarray | None = None) -> None:
        """Clear the state; optionally preset the integral term (e.g. the holding torque)."""
        self.integral_nm = np.zeros(self.n_joints)
        if integral_nm is not None:
            preset = np.asarray(integral_nm, dtype=float)
            if preset.shape != (self.n_joints,):
                raise DataError(f"integral preset needs {self.n_joints} values, got {preset.shape}")
            self.integral_nm = np.clip(preset, -self._i_max, self._i_max)
        self.velocity_rad_s = np.zeros(self.n_joints)
        self.q_previous_rad = None

    def update(
        self,
        q_ref_rad: np.ndarray,
        q_measured_rad: np.ndarray,
        qd_ref_rad_s: np.ndarray | None = None,
    ) -> np.ndarray:
        """Feed one sample; return the (saturated) torque command [N m]."""
        n = self.n_joints
        q = np.asarray(q_measured_rad, dtype=float)
        q_ref = np.asarray(q_ref_rad, dtype=float)
        if q.shape != (n,) or q_ref.shape != (n,):
            raise DataError(
                f"expected {n} reference and measured angles, got {q_ref.shape}, {q.shape}"
            )
        if qd_ref_rad_s is None:
            qd_ref = self._zeros
        else:
            qd_ref = np.asarray(qd_ref_rad_s, dtype=float)
            if qd_ref.shape != (n,):
                raise DataError(f"expected {n} reference velocities, got {qd_ref.shape}")
        previous = self.q_previous_rad
        out = np.empty((4, n))
        _pid_update(
            self._constants,
            self._a,
            self._gain,
            previous is not None,
            np.asarray(self.integral_nm, dtype=float),
            np.asarray(self.velocity_rad_s, dtype=float),
            self._zeros if previous is None else np.asarray(previous, dtype=float),
            q_ref,
            q,
            qd_ref,
            out,
        )
        self.integral_nm = out[1]
        self.velocity_rad_s = out[2]
        self.q_previous_rad = out[3]
        return out[0]
