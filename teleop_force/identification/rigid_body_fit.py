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
  pre-filter does, and a sign taken of a delayed velocity would switch late. A friction in
  model coordinates (:class:`~teleop_force.friction.model_coordinates.ModelCoordinateFriction`)
  gets them where it acts instead: ``sgn(w) exp(-|w| / v_s)`` on each of its axes'
  velocities ``w``, reaching the motors through the coupling like the friction itself
  (per-motor terms would absorb the part of its Coulomb torque that the coupling's fixed
  ratios carry to other joints, and bias the rigid body: measured on the dVRK MTM, joint 3
  held out 24 % with the axis terms, 31 % with per-motor ones). Their coefficients are
  nuisance: they are dropped, and the model's own friction is refitted afterwards on the
  causal signals the estimator sees, with the rigid body fixed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, filtfilt

from teleop_force.errors import ConfigurationError, ModelError
from teleop_force.friction.base import FrictionModel
from teleop_force.friction.model_coordinates import ModelCoordinateFriction
from teleop_force.identification.filtered_regressor import FilterConfig, filter_signals
from teleop_force.identification.least_squares import Identification, least_squares
from teleop_force.identification.regressor import BaseParameters, RigidBodyRegressor
from teleop_force.io.interchange_csv import Recording
from teleop_force.lowpass import lowpass_batch, sample_intervals
from teleop_force.robots.description import RobotDescription

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
        identification: The whole least-squares fit: base parameters, then the friction's
            parameters, the nuisance terms (named ``nuisance ...``) and any offsets.
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


def axis_nuisance_regressor(
    friction: ModelCoordinateFriction, qd_rad_s: np.ndarray, options: RigidBodyFitOptions
) -> tuple[np.ndarray, list[str]]:
    """Nuisance low-speed terms on the axes of a model-coordinate friction, ``(N, n, p)``.

    ``sgn(w_a) exp(-|w_a| / v_s)`` for each axis velocity ``w_a`` and scale ``v_s``, mapped to
    the motors by the axis's coupling row, as the friction itself is.
    """
    w = friction.axis_velocities(qd_rad_s)
    scales = options.stribeck_scales_rad_s
    if not scales:
        return np.zeros((w.shape[0], friction.n_joints, 0)), []
    shapes = np.stack(
        [np.tanh(w / _SIGN_SMOOTHING_RAD_S) * np.exp(-np.abs(w) / v) for v in scales], axis=2
    )
    out = np.einsum("aj,kas->kjas", friction.axes, shapes)
    names = [
        f"nuisance {friction.axis_label(a)}: stribeck {v:g}"
        for a in range(friction.n_axes)
        for v in scales
    ]
    return out.reshape(w.shape[0], friction.n_joints, len(names)), names


def _nuisance_regressor(
    friction: FrictionModel,
    qd_rad_s: np.ndarray,
    description: RobotDescription,
    options: RigidBodyFitOptions,
) -> tuple[np.ndarray, list[str]]:
    """Return the nuisance terms that go with ``friction`` (``(N, n, p)``) and their names."""
    if isinstance(friction, ModelCoordinateFriction):
        return axis_nuisance_regressor(friction, qd_rad_s, options)
    if not friction.block_diagonal:
        raise ModelError(f"no nuisance friction terms for a {friction.kind} model")
    per_joint, names = [], []
    for j in range(description.n_joints):
        columns, joint_names = nuisance_friction_basis(
            qd_rad_s, j, description.friction_inputs, options
        )
        per_joint.append(columns)
        names += joint_names
    return _block_diagonal(per_joint), names


def fit_rigid_body(
    recordings: Sequence[Recording],
    description: RobotDescription,
    base: BaseParameters,
    friction: FrictionModel,
    config: FilterConfig,
    options: RigidBodyFitOptions,
    offsets: bool = False,
) -> RigidBodyFit:
    """Fit the base parameters by least squares with ``friction`` and the nuisance terms.

    With ``offsets``, a constant torque per joint is fitted too. Returns the fit (base
    parameters, friction, nuisance terms, offsets); ``friction.parameters`` is not touched
    (refit it on the causal signals).
    """
    regressor = RigidBodyRegressor(description)
    n = description.n_joints
    blocks, torques = [], []
    nuisance_names: list[str] = []
    for rec in recordings:
        q = rec.q_rad
        if options.smoothing_hz is not None:
            q = zero_phase_smoothed(rec.t_s, q, options.smoothing_hz)
        signals = filter_signals(rec.t_s, q, rec.tau_nm, regressor, base, config)
        qd = np.gradient(q, rec.t_s, axis=0)
        nuisance, nuisance_names = _nuisance_regressor(friction, qd, description, options)
        columns = np.concatenate((friction.regressor(qd), nuisance), axis=2)
        filtered = _as_torque(columns.reshape(columns.shape[0], -1), rec.t_s, config)
        parts = [
            signals.rigid_regressor[signals.valid],
            filtered.reshape(columns.shape)[signals.valid],
        ]
        if offsets:
            parts.append(np.broadcast_to(np.eye(n), (int(signals.valid.sum()), n, n)))
        blocks.append(np.concatenate(parts, axis=2))
        torques.append(signals.tau_lowpassed_nm[signals.valid])
    names = list(base.names()) + friction.all_parameter_names() + nuisance_names
    if offsets:
        names += [f"offset_{j + 1}" for j in range(n)]
    fit = least_squares(np.concatenate(blocks), np.concatenate(torques), names)
    return RigidBodyFit(fit, base.count)
