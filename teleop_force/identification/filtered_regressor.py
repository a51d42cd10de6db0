"""The low-pass filtered regressor of the paper, in momentum form (no accelerations).

Filtering ``tau = d/dt p - C^T qd + N + tau_spring + tau_f`` by ``omega / (s + omega)`` gives::

    tau_L = D_L(Y_p) pi + L(Y_w) pi + L(tau_f)

with ``D_L`` the filtered derivative
(:func:`~teleop_force.lowpass.filtered_derivative_batch`)
and ``L`` the low-pass filter.

``D_L`` is ``omega s / (s + omega)``: its gain tends to ``omega`` at high frequency, so noise in
``p`` is not filtered. With encoder quantization (4e-4 rad at 1 kHz) the backward-difference
velocity carries ~0.16 rad/s of high-frequency noise, which would reach the torque estimate as
~0.01 N m. So every measured signal first passes the same first-order pre-filter ``L_v`` at
``velocity_cutoff_hz``: the angles (``q_v = L_v(q)``, whose backward difference is the
velocity ``qd``) and the motor torque. Every model term is computed on the pre-filtered
trajectory ``(q_v, qd)``; the whole scheme then filters by ``L_v L`` on both sides, and the
lag of ``L_v`` biases nothing (up to second order in the nonlinearity of the terms).

The torque commanded at sample ``k-1`` acts over ``[k-1, k]`` and shows in the motion at ``k``,
so the model at ``k`` is compared with the filtered torque of sample ``k - torque_lag_samples``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np
from msgspec import Meta, Struct

from teleop_force.errors import ConfigurationError, DataError, ModelFileError
from teleop_force.identification.regressor import BaseParameters, RigidBodyRegressor
from teleop_force.lowpass import (
    DEFAULT_CUTOFF_HZ,
    filtered_derivative_batch,
    lowpass_batch,
    sample_intervals,
)
from teleop_force.schema import Finite


@dataclass(frozen=True)
class FilterConfig:
    """How measured signals are filtered before identification and estimation."""

    cutoff_hz: float = DEFAULT_CUTOFF_HZ
    velocity_cutoff_hz: float = 20.0
    torque_lag_samples: int = 1
    warmup_s: float = 0.25

    def __post_init__(self) -> None:
        if not self.cutoff_hz > 0:
            raise ConfigurationError(f"cutoff_hz must be > 0, got {self.cutoff_hz}")
        if not self.velocity_cutoff_hz > 0:
            raise ConfigurationError(
                f"velocity_cutoff_hz must be > 0, got {self.velocity_cutoff_hz}"
            )
        if self.torque_lag_samples not in (0, 1):
            raise ConfigurationError("torque_lag_samples must be 0 or 1")
        if self.warmup_s < 0:
            raise ConfigurationError("warmup_s must be >= 0")


class FilterEntry(Struct, forbid_unknown_fields=True):
    """``filter``: the :class:`FilterConfig` of identification (its defaults when absent)."""

    cutoff_hz: Finite = FilterConfig.cutoff_hz
    velocity_cutoff_hz: Finite = FilterConfig.velocity_cutoff_hz
    torque_lag_samples: Annotated[int, Meta(ge=0, le=1)] = FilterConfig.torque_lag_samples
    warmup_s: Finite = FilterConfig.warmup_s

    def __post_init__(self) -> None:
        self.config()  # FilterConfig's own range checks, named after this entry

    def config(self) -> FilterConfig:
        """Build the :class:`FilterConfig` (ModelFileError when out of range)."""
        try:
            return FilterConfig(
                self.cutoff_hz, self.velocity_cutoff_hz, self.torque_lag_samples, self.warmup_s
            )
        except ConfigurationError as exc:
            raise ModelFileError(str(exc)) from None


def estimate_velocity(t_s: np.ndarray, q_rad: np.ndarray, cutoff_hz: float | None) -> np.ndarray:
    """Backward-difference velocity, low-pass filtered at ``cutoff_hz`` (raw when None)."""
    dt = sample_intervals(t_s)
    qd = np.zeros_like(q_rad, dtype=float)
    qd[1:] = np.diff(q_rad, axis=0) / dt[1:, None]
    return qd if cutoff_hz is None else lowpass_batch(qd, t_s, cutoff_hz)


def lagged(x: np.ndarray, samples: int) -> np.ndarray:
    """``x`` delayed by ``samples`` (the first rows repeat the first sample)."""
    if samples == 0:
        return x
    return np.concatenate((np.repeat(x[:1], samples, axis=0), x[:-samples]), axis=0)


@dataclass(frozen=True, eq=False)
class FilteredSignals:
    """One recording's signals, filtered and ready for identification or evaluation.

    ``y_derivative`` and ``y_lowpassed`` are ``(N, n, r)`` base-parameter regressors (``r = 0``
    for a robot without rigid-body terms); ``y_momentum_lowpassed`` is the low-pass filtered
    momentum regressor used by the adaptive friction identifier.
    """

    t_s: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    tau_lowpassed_nm: np.ndarray
    y_derivative: np.ndarray
    y_lowpassed: np.ndarray
    y_momentum_lowpassed: np.ndarray
    valid: np.ndarray
    config: FilterConfig

    @property
    def rigid_regressor(self) -> np.ndarray:
        """``Y_L``: the filtered rigid-body regressor, ``(N, n, r)``."""
        return self.y_derivative + self.y_lowpassed

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.t_s.size)


def filter_signals(
    t_s: np.ndarray,
    q_rad: np.ndarray,
    tau_nm: np.ndarray,
    regressor: RigidBodyRegressor | None,
    base: BaseParameters | None,
    config: FilterConfig,
) -> FilteredSignals:
    """Compute the filtered regressor and torque of one recording (batch form)."""
    t_s = np.asarray(t_s, dtype=float)
    if t_s.size < 3:
        raise DataError(f"need at least 3 samples, got {t_s.size}")
    q_rad = lowpass_batch(np.asarray(q_rad, dtype=float), t_s, config.velocity_cutoff_hz)
    qd = estimate_velocity(t_s, q_rad, None)
    tau_prefiltered = lowpass_batch(tau_nm, t_s, config.velocity_cutoff_hz)
    tau_l = lagged(lowpass_batch(tau_prefiltered, t_s, config.cutoff_hz), config.torque_lag_samples)
    n = q_rad.shape[1]
    if regressor is not None and base is not None:
        y_p, y_w = regressor.momentum_form_batch(q_rad, qd, base.independent)
        y_derivative = filtered_derivative_batch(y_p, t_s, config.cutoff_hz)
        y_lowpassed = lowpass_batch(y_w, t_s, config.cutoff_hz)
        y_momentum = lowpass_batch(y_p, t_s, config.cutoff_hz)
    else:
        y_derivative = y_lowpassed = y_momentum = np.zeros((t_s.size, n, 0))
    valid = t_s >= t_s[0] + config.warmup_s
    return FilteredSignals(
        t_s, q_rad, qd, tau_l, y_derivative, y_lowpassed, y_momentum, valid, config
    )
