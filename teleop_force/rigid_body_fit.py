"""Offline fit of the rigid-body base parameters, guarded against two biases.

Identification is batch and offline, so it can afford what the 1 kHz estimator cannot:

* **Zero-phase smoothing of the angles.** On closed-loop data the encoder quantization is in
  the regressor (through the differentiated momentum) *and* in the torque (the position
  controller reacts to it), so ordinary least squares is biased: with 4e-4 rad quantization
  and the paper's 8 Hz filter, a gravity parameter of the Omni came out 10 % off although
  everything else was ideal. A second-order Butterworth run forward and backward
  (``smoothing_hz``, default 40 Hz) removes the noise from the angles without delaying them;
  the torque is left alone, so what stays in it is noise the regressor no longer shares.
* **A richer friction basis while the rigid body is fitted.** A Coulomb-viscous friction
  cannot follow a real Stribeck curve; the part it misses correlates with the gravity and
  inertia columns and leaks into them (10-17 % on the same parameter). During the rigid-body
  fit, each joint's friction therefore also gets odd, fixed-shape low-speed terms
  ``sgn(v) exp(-|v| / v_s)`` for a few scales ``v_s`` on each of its friction inputs, and
  ``sgn(qd_j) (1 - exp(-|w| / w_s))`` for the load a coupled input puts on its bearing,
  evaluated on the central-difference velocity of the smoothed angles (no delay) and then
  passed through the torque's own filters: friction acts on the torque before the
  pre-filter does, and a sign taken of a delayed velocity would switch late. Their
  coefficients are nuisance: they are dropped, and the model's own friction (CV or coupled
  CV) is refitted afterwards on the causal signals the estimator sees, with the rigid body
  fixed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, filtfilt

from teleop_force.errors import ConfigurationError
from teleop_force.filtered_regressor import FilterConfig, filter_signals
from teleop_force.friction.base import FrictionModel
from teleop_force.identification import Identification, least_squares
from teleop_force.interchange_csv import Recording
from teleop_force.lowpass import lowpass_batch, sample_intervals
from teleop_force.regressor import BaseParameters, RigidBodyRegressor
from teleop_force.robot import RobotDescription

_SIGN_SMOOTHING_RAD_S = 1e-3


@dataclass(frozen=True)
class RigidBodyFitOptions:
    """How the rigid-body base parameters are fitted.

    Attributes:
        smoothing_hz: Cutoff of the zero-phase smoothing of the angles (None: off). Skipped
            for a recording whose Nyquist frequency is not above it.
        stribeck_scales_rad_s: Scales ``v_s`` of the nuisance low-speed friction terms.
        bearing_scales_rad_s: Scales ``w_s`` of the nuisance bearing-load terms of coupled
            friction inputs.

    """

    smoothing_hz: float | None = 40.0
    stribeck_scales_rad_s: tuple[float, ...] = (0.02, 0.05, 0.1, 0.2, 0.5)
    bearing_scales_rad_s: tuple[float, ...] = (0.2, 1.0)

    def __post_init__(self) -> None:
        if self.smoothing_hz is not None and not (
            math.isfinite(self.smoothing_hz) and self.smoothing_hz > 0
        ):
            raise ConfigurationError(f"smoothing_hz must be > 0 or None, got {self.smoothing_hz}")
        for name in ("stribeck_scales_rad_s", "bearing_scales_rad_s"):
            scales = getattr(self, name)
            if any(not (math.isfinite(s) and s > 0) for s in scales):
                raise ConfigurationError(f"{name} must all be > 0, got {scales}")

    @classmethod
    def plain(cls) -> RigidBodyFitOptions:
        """Ordinary least squares on the causal signals with the model's own friction only."""
        return cls(smoothing_hz=None, stribeck_scales_rad_s=(), bearing_scales_rad_s=())


@dataclass(frozen=True, eq=False)
class RigidBodyFit:
    """Result of :func:`fit_rigid_body`.

    Attributes:
        identification: The whole least-squares fit: base parameters, then each joint's
            friction parameters followed by its nuisance terms (named ``nuisance ...``).
        n_base: Number of base parameters (the first entries of the fit).

    """

    identification: Identification
    n_base: int

    @property
    def base_values(self) -> np.ndarray:
        """Identified base parameters."""
        return self.identification.parameters[: self.n_base]

    @property
    def base_std(self) -> np.ndarray:
        """Their standard deviations."""
        return self.identification.standard_deviations[: self.n_base]


def zero_phase_smoothed(t_s: np.ndarray, q_rad: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """Angles smoothed by a 2nd-order Butterworth forward and backward (no delay).

    The sample rate is taken from the median interval; a recording too short to pad, or
    sampled too slowly for ``cutoff_hz``, is returned unchanged.
    """
    dt = float(np.median(sample_intervals(t_s)))
    normalised = 2.0 * cutoff_hz * dt
    q_rad = np.asarray(q_rad, dtype=float)
    if normalised >= 0.9 or q_rad.shape[0] <= 15:
        return q_rad
    b, a = butter(2, normalised)
    return filtfilt(b, a, q_rad, axis=0)


def nuisance_friction_basis(
    qd_rad_s: np.ndarray,
    joint: int,
    friction_inputs: Sequence[Sequence[int]],
    options: RigidBodyFitOptions,
) -> tuple[np.ndarray, list[str]]:
    """Fixed-shape odd friction terms of ``joint`` (module docstring), ``(N, p)``, and names."""
    v_own = qd_rad_s[:, joint]
    sign_own = np.tanh(v_own / _SIGN_SMOOTHING_RAD_S)
    inputs = [("", v_own)] + [
        (f"{joint + 1}-{k + 1}", v_own - qd_rad_s[:, k])
        for k in friction_inputs[joint]
        if k != joint
    ]
    columns, names = [], []
    for label, v in inputs:
        sign = np.tanh(v / _SIGN_SMOOTHING_RAD_S)
        for scale in options.stribeck_scales_rad_s:
            columns.append(sign * np.exp(-np.abs(v) / scale))
            names.append(f"nuisance {joint + 1}: stribeck qd{label or joint + 1} {scale:g}")
        if label:
            for scale in options.bearing_scales_rad_s:
                columns.append(sign_own * (1.0 - np.exp(-np.abs(v) / scale)))
                names.append(f"nuisance {joint + 1}: bearing load qd{label} {scale:g}")
    if not columns:
        return np.zeros((qd_rad_s.shape[0], 0)), []
    return np.stack(columns, axis=1), names


def _as_torque(columns: np.ndarray, t_s: np.ndarray, config: FilterConfig) -> np.ndarray:
    """Friction columns through the torque's own filters (pre-filter, then the low-pass)."""
    prefiltered = lowpass_batch(columns, t_s, config.velocity_cutoff_hz)
    return lowpass_batch(prefiltered, t_s, config.cutoff_hz)


def _block_diagonal(per_joint: Sequence[np.ndarray]) -> np.ndarray:
    """Each joint's columns ``(m, p_j)`` in its row of an ``(m, n, sum p_j)`` regressor."""
    widths = [cols.shape[1] for cols in per_joint]
    out = np.zeros((per_joint[0].shape[0], len(per_joint), sum(widths)))
    start = 0
    for j, cols in enumerate(per_joint):
        out[:, j, start : start + widths[j]] = cols
        start += widths[j]
    return out


def fit_rigid_body(
    recordings: Sequence[Recording],
    description: RobotDescription,
    base: BaseParameters,
    friction: FrictionModel,
    config: FilterConfig,
    options: RigidBodyFitOptions,
) -> RigidBodyFit:
    """Least squares of the base parameters with ``friction`` and the nuisance terms.

    Returns the fit; ``friction.parameters`` is not touched (refit it on the causal signals).
    """
    regressor = RigidBodyRegressor(description)
    joints = range(description.n_joints)
    blocks, torques = [], []
    for rec in recordings:
        q = rec.q_rad
        if options.smoothing_hz is not None:
            q = zero_phase_smoothed(rec.t_s, q, options.smoothing_hz)
        signals = filter_signals(rec.t_s, q, rec.tau_nm, regressor, base, config)
        qd = np.gradient(q, rec.t_s, axis=0)
        per_joint = []
        for j in joints:
            nuisance, _ = nuisance_friction_basis(qd, j, description.friction_inputs, options)
            columns = np.concatenate((friction.basis(j, qd), nuisance), axis=1)
            per_joint.append(_as_torque(columns, rec.t_s, config)[signals.valid])
        blocks.append(
            np.concatenate(
                [signals.rigid_regressor[signals.valid], _block_diagonal(per_joint)], axis=2
            )
        )
        torques.append(signals.tau_lowpassed_nm[signals.valid])
    names = list(base.names())
    for j in joints:
        empty = np.zeros((1, description.n_joints))
        names += friction.parameter_names(j)
        names += nuisance_friction_basis(empty, j, description.friction_inputs, options)[1]
    fit = least_squares(np.concatenate(blocks), np.concatenate(torques), names)
    return RigidBodyFit(fit, base.count)
