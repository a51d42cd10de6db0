"""Friction controls: stand-ins for friction the model may still miss.

With a wavelet network mapping a joint's velocities (or friction in model coordinates), a
candidate on another variable must also lower the held-out error with friction-shaped
stand-ins in the model: smooth functions of the mapped velocities, Stribeck and bearing-load
terms, and the transients after a motion reversal (:func:`reversal_transient_basis`). On a
periodic trajectory every variable correlates with the velocities, and friction the static
velocity map cannot follow (the velocity estimate lags the true velocity at a reversal, where
dry friction flips) would otherwise be named after the joint angle at which the reversals
happen.
"""

from __future__ import annotations

import numpy as np

from teleop_force.identification.effects import BasisSpec
from teleop_force.identification.rigid_body_fit import RigidBodyFitOptions, nuisance_friction_basis
from teleop_force.lowpass import lowpass_batch
from teleop_force.residual.options import ResidualOptions
from teleop_force.residual.samples import SelectedSamples, filtered_columns
from teleop_force.residual.scoring import JointDesign, held_out_gain
from teleop_force.robots.description import RobotDescription

#: Displacements since the last reversal [rad] at which the reversal stand-ins decay.
REVERSAL_DISPLACEMENTS_RAD: tuple[float, ...] = (0.003, 0.01, 0.03, 0.1)
#: Times since the last reversal [s] at which the reversal stand-ins decay.
REVERSAL_TIMES_S: tuple[float, ...] = (0.02, 0.05, 0.15, 0.4)
#: A joint's direction of motion changes when its velocity passes this far beyond zero [rad/s].
REVERSAL_DEAD_BAND_RAD_S = 0.005


def reversal_transient_basis(
    t_s: np.ndarray, q_rad: np.ndarray, qd_rad_s: np.ndarray
) -> np.ndarray:
    """Friction-shaped transients after each motion reversal of one joint: (N,) -> (N, 16).

    The direction of motion is the sign of ``qd_rad_s`` held through the dead band
    (:data:`REVERSAL_DEAD_BAND_RAD_S`); it changes at a reversal. Columns: ``exp(-|q - q_r| / x)``
    for each displacement scale ``x`` and ``exp(-(t - t_r) / T)`` for each time scale ``T``
    (``q_r``, ``t_r``: angle and time of the last reversal), each times the smoothed direction
    ``tanh(qd / dead band)`` and alone. Every column is 1 (or +-1) at a reversal and decays
    as the joint moves away from it: presliding and a velocity estimate that lags the true
    velocity where dry friction flips.
    """
    t_s = np.asarray(t_s, dtype=float)
    q_rad = np.asarray(q_rad, dtype=float)
    v = np.asarray(qd_rad_s, dtype=float)
    index = np.arange(v.size)
    band = REVERSAL_DEAD_BAND_RAD_S
    moving = np.where(v > band, 1.0, np.where(v < -band, -1.0, 0.0))
    direction = moving[np.maximum.accumulate(np.where(moving != 0.0, index, 0))]
    changed = np.r_[True, direction[1:] != direction[:-1]] if v.size else np.zeros(0, dtype=bool)
    last = np.maximum.accumulate(np.where(changed, index, 0))
    moved = np.abs(q_rad - q_rad[last])[:, None] / np.asarray(REVERSAL_DISPLACEMENTS_RAD)
    waited = (t_s - t_s[last])[:, None] / np.asarray(REVERSAL_TIMES_S)
    decay = np.concatenate((np.exp(-moved), np.exp(-waited)), axis=1)
    sign = np.tanh(v / REVERSAL_DEAD_BAND_RAD_S)[:, None]
    return np.concatenate((decay * sign, decay), axis=1)


def velocity_controls(
    samples: SelectedSamples, joint: int, covered: tuple[int, ...]
) -> list[BasisSpec]:
    """Friction-shaped stand-ins for what the friction model may still miss on ``joint``.

    Velocities the wavelet network maps are not offered as effects; these shapes of them
    (smooth in each covered velocity, alone and times ``sgn(qd_joint)``, and low-speed
    Stribeck terms) only serve as a control: a candidate on another variable must still
    lower the held-out error with them in the model, so that friction the network has not
    learnt is not named after a variable that merely correlates with the velocities (on a
    periodic trajectory, every variable does).
    """
    specs = []
    for k in covered:
        x = samples.qd_rad_s[:, k]
        lo, hi = np.percentile(x, [0.5, 99.5])
        if hi - lo < 1e-3:
            continue
        specs.append(BasisSpec(joint, f"qd{k + 1}", "smooth", "none", float(lo), float(hi), 8))
        specs.append(BasisSpec(joint, f"qd{k + 1}", "smooth", "sign", float(lo), float(hi), 8))
    if joint in covered:
        specs.append(
            BasisSpec(joint, f"qd{joint + 1}", "stribeck", "sign", scales=(0.03, 0.1, 0.3))
        )
    return specs


def friction_stand_in_columns(
    samples: SelectedSamples, joint: int, description: RobotDescription
) -> np.ndarray:
    """Return ``joint``'s filtered friction stand-ins at the selected rows.

    The rigid-body fit's nuisance friction terms (coupled inputs too), then the transients
    after the joint's motion reversals (:func:`reversal_transient_basis`).
    """
    out = []
    for item, idx in zip(samples.prepared, samples.rows, strict=True):
        s = item.signals
        nuisance, _ = nuisance_friction_basis(
            s.qd_rad_s, joint, description.friction_inputs, RigidBodyFitOptions()
        )
        reversal = reversal_transient_basis(s.t_s, s.q_rad[:, joint], s.qd_rad_s[:, joint])
        phi = np.concatenate((nuisance, reversal), axis=1)
        out.append(lowpass_batch(phi, s.t_s, s.config.cutoff_hz)[idx])
    return np.concatenate(out)


def inertia_stand_in_columns(samples: SelectedSamples) -> np.ndarray:
    """Every joint's filtered acceleration at the selected rows, ``(rows, n)``.

    A robot without a rigid body (``none``) has no inertia in its model, and on a periodic
    trajectory the accelerations are functions of the angles (``q̈ = -w^2 q`` for one
    sinusoid): a pose effect would stand in for the inertia on that trajectory and fail on
    the next. A candidate must also lower the error with these in the model.
    """
    out = []
    for item, idx in zip(samples.prepared, samples.rows, strict=True):
        s = item.signals
        velocity = lowpass_batch(s.qd_rad_s, s.t_s, s.config.cutoff_hz)
        out.append(np.gradient(velocity, s.t_s, axis=0)[idx])
    return np.concatenate(out)


def control_design(
    samples: SelectedSamples,
    design: JointDesign,
    joint: int,
    covered: tuple[int, ...],
    description: RobotDescription,
    options: ResidualOptions,
) -> JointDesign | None:
    """Return ``joint``'s design with its friction controls added.

    Without a rigid body also the inertia stand-ins (:func:`inertia_stand_in_columns`) and
    the friction stand-ins of the joint's own velocity. None when the friction maps nothing
    beyond the joint's own velocity and the robot has a body.
    """
    bodiless = not description.has_rigid_body
    specs = velocity_controls(samples, joint, (joint,) if bodiless and not covered else covered)
    if not specs:
        return None
    parts = [filtered_columns(samples, spec) for spec in specs]
    parts.append(friction_stand_in_columns(samples, joint, description))
    if bodiless:
        parts.append(inertia_stand_in_columns(samples))
    extra = np.concatenate(parts, axis=1)
    return design.with_columns(extra)


def control_gain(control: JointDesign | None, cols: np.ndarray) -> float:
    """Held-out RMS gain of ``cols`` over the design with the friction controls (1 without)."""
    if control is None:
        return 1.0
    return held_out_gain(control.held_out_errors(), control.held_out_errors(cols))
