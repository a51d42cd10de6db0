"""Streaming contact-force estimation: one call per 1 kHz sample, no accelerations.

The identified base parameters are turned into an equivalent full parameter set (exact for
every motion, see :meth:`~teleop_force.regressor.BaseParameters.representative`) so the rigid
body terms come straight from pinocchio (``crba``, Coriolis matrix, gravity) instead of a
regressor. Per sample::

    q_v, qd     = L_v(q), backward difference of q_v      (pre-filter, see filtered_regressor)
    tau_model_L = D_L(M(q_v) qd) + L(-C^T qd + N + tau_spring + tau_f(qd) + offsets + effects)
    tau_ext_L   = L(L_v(tau))[k - lag] - tau_model_L
    F           = J(q)^-T tau_ext_L        (base frame, force of the tip on the environment)

which is, sample for sample, the batch computation of
:meth:`~teleop_force.dynamic_model.DynamicModel.predict_filtered_torque`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop_force.dynamic_model import DynamicModel
from teleop_force.errors import DataError, SingularityError
from teleop_force.lowpass import FilteredDerivative, LowPass
from teleop_force.regressor import full_parameters
from teleop_force.robot import Robot

#: Jacobian singular values below this [m/rad] make the force unobservable: reported, not divided.
DEFAULT_SIGMA_MIN = 5e-3
#: Coverage weight at or above which a joint counts as on trained ground.
TRAINED_GROUND_WEIGHT = 0.5


@dataclass(frozen=True)
class ForceEstimate:
    """The estimate at one sample.

    Attributes:
        t_s: Sample time.
        force_tip_in_base_n: Force of the tip on the environment, base frame [N] (NaN when
            the Jacobian is near singular).
        tau_external_nm: External joint torques ``tau_L - tau_model_L`` [N m].
        tau_motor_filtered_nm: Low-pass filtered motor torque [N m].
        tau_model_filtered_nm: Low-pass filtered model torque [N m].
        coverage_weight: Per joint, how much the friction estimate rests on training data.
        on_trained_ground: Per joint, ``coverage_weight >= 0.5``.
        singular: Whether the Jacobian was too close to singular for a force.
    """

    t_s: float
    force_tip_in_base_n: np.ndarray
    tau_external_nm: np.ndarray
    tau_motor_filtered_nm: np.ndarray
    tau_model_filtered_nm: np.ndarray
    coverage_weight: np.ndarray
    on_trained_ground: np.ndarray
    singular: bool


class ForceEstimator:
    """Streaming estimator of the tip contact force from joint angles and motor torques."""

    def __init__(self, model: DynamicModel, sigma_min: float = DEFAULT_SIGMA_MIN) -> None:
        """Build the equivalent rigid-body model and the filters."""
        self.model = model
        description = model.description()
        self.n = model.n_joints
        self.sigma_min = sigma_min
        self.robot: Robot | None = None
        self.spring_stiffness = np.zeros(len(description.springs))
        if description.has_rigid_body and model.base is not None:
            nominal = full_parameters(description, np.zeros(len(description.springs)))
            full = model.base.representative(model.base_values, nominal)
            n_links = 10 * description.n_links
            equivalent = description.with_link_parameters(full[:n_links]).with_rotor_inertia(
                full[n_links : n_links + self.n]
            )
            self.spring_stiffness = full[n_links + self.n :]
            self.robot = Robot(equivalent)
        config = model.filter_config
        self._lag = config.torque_lag_samples
        self._angle = LowPass(config.velocity_cutoff_hz)
        self._momentum = FilteredDerivative(config.cutoff_hz)
        self._other = LowPass(config.cutoff_hz)
        self._torque_prefilter = LowPass(config.velocity_cutoff_hz)
        self._torque = LowPass(config.cutoff_hz)
        self._t_prev: float | None = None
        self._q_prev = np.zeros(self.n)

    def reset(self) -> None:
        """Forget all filter state (start of a new stream)."""
        for f in (self._angle, self._momentum, self._other, self._torque_prefilter, self._torque):
            f.reset()
        self._t_prev = None

    def update(self, t_s: float, q_rad: np.ndarray, tau_nm: np.ndarray) -> ForceEstimate:
        """Feed one sample (time, measured angles, commanded motor torques)."""
        q = np.asarray(q_rad, dtype=float)
        tau = np.asarray(tau_nm, dtype=float)
        if q.shape != (self.n,) or tau.shape != (self.n,):
            raise DataError(f"expected {self.n} joint angles and torques")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(tau)) and np.isfinite(t_s)):
            raise DataError("non-finite joint angle, torque or time")
        q_raw = q
        if self._t_prev is None:
            dt = 1e-3
            q = self._angle.update(q_raw, dt).copy()
            qd = np.zeros(self.n)
        else:
            dt = t_s - self._t_prev
            if not dt > 0:
                raise DataError(f"time does not increase ({t_s} after {self._t_prev})")
            q = self._angle.update(q_raw, dt).copy()
            qd = (q - self._q_prev) / dt
        self._t_prev = t_s
        self._q_prev = q
        model = self.model
        other = model.friction_torque(qd[None, :])[0] + model.offsets_nm
        if model.effects:
            other = other + model.effects_torque(
                np.array([t_s]), q[None, :], qd[None, :], tau[None, :]
            )[0]
        robot = self.robot
        if robot is not None:
            momentum = robot.momentum(q, qd)
            other = other + robot.coriolis_transpose_gravity(q, qd)
            other = other + robot.spring_torque(q, self.spring_stiffness)
            tau_model = self._momentum.update(momentum, dt) + self._other.update(other, dt)
        else:
            tau_model = self._other.update(other, dt).copy()
        previous_torque = self._torque.state
        tau_now = self._torque.update(self._torque_prefilter.update(tau, dt), dt)
        tau_filtered = tau_now.copy() if (self._lag == 0 or previous_torque is None) else previous_torque
        tau_ext = tau_filtered - tau_model
        weight = model.friction.coverage_weight(qd[None, :])[0]
        force = np.full(3, np.nan)
        singular = False
        if robot is not None and robot.description.tip_frame is not None:
            try:
                force = robot.tip_force_from_joint_torque(q_raw, tau_ext, self.sigma_min)
            except SingularityError:
                singular = True
        return ForceEstimate(
            t_s,
            force,
            tau_ext,
            tau_filtered,
            tau_model,
            weight,
            weight >= TRAINED_GROUND_WEIGHT,
            singular,
        )
