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

import math
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from msgspec import Meta, Struct

from teleop_force.errors import ConfigurationError, DataError, ModelFileError
from teleop_force.estimation.flags import ESTIMATORS
from teleop_force.identification.regressor import BaseParameters, RigidBodyRegressor
from teleop_force.lowpass import (
    DEFAULT_CUTOFF_HZ,
    filtered_derivative_batch,
    lowpass_batch,
    sample_intervals,
)
from teleop_force.schema import Finite

EstimatorName = Literal["filter", "observer"]
#: The default estimator, its bandwidth and the standstill dead band, chosen by the held-out
#: contact-force error on simulated plant family one, seeds 1-3 (the sweep and its figures:
#: docs/results.md, "Force accuracy on unseen data"); family two is reported, never tuned on.
DEFAULT_ESTIMATOR = "observer"
#: The observer at 40 Hz on its own pre-filter of two first-order stages at 40 Hz: the two
#: stages roll off the encoder count's noise that one stage passes flat, and buy the wider
#: band (family one, seeds 1-3: 7.93 % against 9.13 % for the observer at 24 Hz on one stage
#: at ``L_v``, the default until 2026-11-26; 45 Hz stages 7.85 %, a tie). The residual watch
#: does not test these estimates: it makes its own with the 24 Hz estimator it was calibrated
#: on (:mod:`teleop_force.service.watch_residual`), since with the faster one it missed a
#: drifting friction (docs/accuracy/low_speed.md).
DEFAULT_OBSERVER_HZ = 40.0
DEFAULT_STANDSTILL_BAND_RAD_S = 0.02
#: Cutoff [Hz] of each stage of the observer's pre-filter by default (``observer_prefilter_hz``
#: None follows ``velocity_cutoff_hz``: what the observer ran on before it had its own).
DEFAULT_OBSERVER_PREFILTER_HZ = 40.0
DEFAULT_OBSERVER_PREFILTER_STAGES = 2
#: No Butterworth on the observer's output by default. The observer at 400 Hz on two 80 Hz
#: stages with a second-order Butterworth at 40 Hz on its output won on family one (7.48 %
#: against 7.93 %) and held out on family two only by 0.02-0.13 points a seed (and lost there
#: by 0.4-0.6 points once the identification kept a sticking state), while on the
#: dVRK MTM's measured free motion it raised the external torque left by the model (joint 5:
#: 0.573 -> 0.594 of the joint's torque on the loop's trajectory, 0.997 -> 1.007 on the other
#: one): an option (``--observer-output-hz``), docs/accuracy/low_speed.md. 0: none, as the
#: standstill band's 0 is no band.
DEFAULT_OBSERVER_OUTPUT_HZ = 0.0
#: Stages the pre-filter may have.
PREFILTER_STAGES = (1, 2)
#: What a model file without these fields means: written before the observer existed, its
#: estimates were the paper's filtered dynamics, without a dead band.
LEGACY_ESTIMATOR: EstimatorName = "filter"
LEGACY_OBSERVER_HZ = DEFAULT_CUTOFF_HZ
LEGACY_STANDSTILL_BAND_RAD_S = 0.0
#: A model file without the observer's pre-filter fields: its observer ran on ``L_v``.
LEGACY_OBSERVER_PREFILTER_STAGES = 1


@dataclass(frozen=True)
class FilterConfig:
    """How measured signals are filtered before identification and estimation.

    Attributes:
        cutoff_hz: Cutoff of the second filter ``L`` (identification and the ``filter``
            estimator).
        velocity_cutoff_hz: Cutoff of the pre-filter ``L_v`` of angles and torques.
        torque_lag_samples: Samples the torque is compared late (0 or 1).
        warmup_s: Samples before this are left out of fits and figures.
        estimator: Which estimator turns the model into an external torque: ``filter``
            (``L`` on both sides of the dynamics) or ``observer`` (the momentum observer).
        observer_hz: Bandwidth of the momentum observer [Hz] (``K = 2 pi observer_hz``).
        standstill_band_rad_s: Below this speed of every joint the friction torque, and the
            direction-dependent part of found effects, ramp to 0 (``max_j |qd_j| / band``);
            0: no dead band.
        observer_prefilter_hz: Cutoff of each stage of the observer's pre-filter of angles
            and torques; None: ``velocity_cutoff_hz`` (the ``filter`` estimator always runs on
            ``L_v``, as identification does).
        observer_prefilter_stages: First-order stages of that pre-filter (1 or 2).
        observer_output_hz: Cutoff of a second-order Butterworth low-pass on the observer's
            external torque [Hz]; 0: none (the observer's own first-order lag only).
        count_observer: Estimate from the angles of the encoder count observer
            (:mod:`~teleop_force.estimation.count_observer`: the model carries the angle
            between the counts) instead of the readings.
        count_rad: The encoder count of each joint [rad] the count observer clips to; empty:
            measured on the recording estimated (the smallest step between its readings).

    """

    cutoff_hz: float = DEFAULT_CUTOFF_HZ
    velocity_cutoff_hz: float = 20.0
    torque_lag_samples: int = 1
    warmup_s: float = 0.25
    estimator: str = DEFAULT_ESTIMATOR
    observer_hz: float = DEFAULT_OBSERVER_HZ
    standstill_band_rad_s: float = DEFAULT_STANDSTILL_BAND_RAD_S
    observer_prefilter_hz: float | None = DEFAULT_OBSERVER_PREFILTER_HZ
    observer_prefilter_stages: int = DEFAULT_OBSERVER_PREFILTER_STAGES
    observer_output_hz: float = DEFAULT_OBSERVER_OUTPUT_HZ
    count_observer: bool = False
    count_rad: tuple[float, ...] = ()

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
        if self.estimator not in ESTIMATORS:
            raise ConfigurationError(
                f"estimator must be one of {', '.join(ESTIMATORS)}, got {self.estimator!r}"
            )
        if not (self.observer_hz > 0 and math.isfinite(self.observer_hz)):
            raise ConfigurationError(f"observer_hz must be > 0, got {self.observer_hz}")
        if not (self.standstill_band_rad_s >= 0 and math.isfinite(self.standstill_band_rad_s)):
            raise ConfigurationError(
                f"standstill_band_rad_s must be >= 0, got {self.standstill_band_rad_s}"
            )
        prefilter_hz = self.observer_prefilter_hz
        if prefilter_hz is not None and not (prefilter_hz > 0 and math.isfinite(prefilter_hz)):
            raise ConfigurationError(f"observer_prefilter_hz must be > 0, got {prefilter_hz}")
        if self.observer_prefilter_stages not in PREFILTER_STAGES:
            raise ConfigurationError(
                f"observer_prefilter_stages must be 1 or 2, got {self.observer_prefilter_stages}"
            )
        if not (self.observer_output_hz >= 0 and math.isfinite(self.observer_output_hz)):
            raise ConfigurationError(
                f"observer_output_hz must be >= 0, got {self.observer_output_hz}"
            )
        object.__setattr__(self, "count_rad", tuple(float(c) for c in self.count_rad))
        for j, count in enumerate(self.count_rad):
            if not (count > 0 and math.isfinite(count)):
                raise ConfigurationError(f"count_rad[{j}] must be > 0, got {count}")

    @property
    def observer(self) -> bool:
        """Whether the momentum observer makes the estimates."""
        return self.estimator == "observer"

    @property
    def observer_prefilter_cutoff_hz(self) -> float:
        """Cutoff [Hz] of each stage of the observer's pre-filter (``L_v``'s when not set)."""
        if self.observer_prefilter_hz is None:
            return self.velocity_cutoff_hz
        return self.observer_prefilter_hz

    @property
    def estimator_output_hz(self) -> float:
        """Cutoff [Hz] of the Butterworth on the estimate: the observer's; 0: none."""
        return self.observer_output_hz if self.observer else 0.0

    @property
    def estimator_prefilter(self) -> tuple[float, int]:
        """Cutoff [Hz] and stages of the pre-filter the estimator runs on angles and torques.

        The observer's own (:attr:`observer_prefilter_cutoff_hz`, ``observer_prefilter_stages``);
        for the ``filter`` estimator ``L_v`` (``velocity_cutoff_hz``, one stage), as identified.
        """
        if self.observer:
            return self.observer_prefilter_cutoff_hz, self.observer_prefilter_stages
        return self.velocity_cutoff_hz, 1


class FilterEntry(Struct, forbid_unknown_fields=True):
    """``filter``: the :class:`FilterConfig` of identification (its defaults when absent)."""

    cutoff_hz: Finite = FilterConfig.cutoff_hz
    velocity_cutoff_hz: Finite = FilterConfig.velocity_cutoff_hz
    torque_lag_samples: Annotated[int, Meta(ge=0, le=1)] = FilterConfig.torque_lag_samples
    warmup_s: Finite = FilterConfig.warmup_s
    # absent in files written before the observer: they meant the paper's filter, no band
    estimator: EstimatorName = LEGACY_ESTIMATOR
    observer_hz: Finite = LEGACY_OBSERVER_HZ
    standstill_band_rad_s: Finite = LEGACY_STANDSTILL_BAND_RAD_S
    # absent in files written before the observer had its own pre-filter: it ran on L_v
    observer_prefilter_hz: Finite | None = None
    observer_prefilter_stages: Annotated[int, Meta(ge=1, le=2)] = LEGACY_OBSERVER_PREFILTER_STAGES
    # absent in files written before the output filter: none
    observer_output_hz: Finite = 0.0
    # written only when on / given (older readers keep reading the files that do not use them)
    count_observer: bool = False
    count_rad: tuple[Finite, ...] = ()

    def __post_init__(self) -> None:
        self.config()  # FilterConfig's own range checks, named after this entry

    def config(self) -> FilterConfig:
        """Build the :class:`FilterConfig` (ModelFileError when out of range)."""
        try:
            return FilterConfig(
                self.cutoff_hz, self.velocity_cutoff_hz, self.torque_lag_samples, self.warmup_s,
                estimator=self.estimator, observer_hz=self.observer_hz,
                standstill_band_rad_s=self.standstill_band_rad_s,
                observer_prefilter_hz=self.observer_prefilter_hz,
                observer_prefilter_stages=self.observer_prefilter_stages,
                observer_output_hz=self.observer_output_hz,
                count_observer=self.count_observer, count_rad=self.count_rad,
            )  # fmt: skip
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
