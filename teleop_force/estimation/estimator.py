"""Streaming contact-force estimation: one call per 1 kHz sample, no accelerations.

The identified base parameters are turned into an equivalent full parameter set (exact for
every motion, see :meth:`~teleop_force.identification.regressor.BaseParameters.representative`) so
the rigid
body terms come straight from pinocchio (``crba``, Coriolis matrix, gravity) instead of a
regressor. Per sample::

    q_v, qd     = L_v(q), backward difference of q_v      (pre-filter, see filtered_regressor)
    tau_model_L = D_L(M(q_v) qd) + L(-C^T qd + N + tau_spring + tau_f(qd) + offsets + effects)
    tau_ext_L   = L(L_v(tau))[k - lag] - tau_model_L
    F           = J(q)^-T tau_ext_L        (base frame, force of the tip on the environment)

which is, sample for sample, the batch computation of
:meth:`~teleop_force.identification.dynamic_model.DynamicModel.predict_filtered_torque`. Found
effects read
``tau<j>`` as the filtered rigid-body model torque ``D_L(M qd) + L(-C^T qd + N + tau_spring)``
of the same sample (as the batch does) and ``t`` as the time since the stream's first sample
(the batch: since the recording's).

Speed: one sample is three-vectors, where NumPy's per-call overhead (~1 µs) dwarfs the
arithmetic. So the filters and the 3 x 3 ``J^-T`` run on Python floats, and the model's terms
run compiled (numba, :mod:`teleop_force.estimation.kernels`): friction (Coulomb-viscous
terms, or the wavelet network blended with its fallback by the coverage trust), offsets and
found effects in one call per sample, with the single definitions the batch fit uses
(:mod:`teleop_force.friction.terms`, :mod:`teleop_force.identification.effect_terms`); the
coupling and the rigid-body terms around pinocchio's four calls in two more. See
BENCHMARKS.md for the figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from teleop_force.errors import DataError, SingularityError
from teleop_force.estimation.kernels import (
    ModelTerms,
    linear_map_into,
    rigid_terms_into,
    spring_table,
)
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.regressor import full_parameters
from teleop_force.robots.description import Robot

#: Jacobian singular values below this [m/rad] make the force unobservable: reported, not divided.
DEFAULT_SIGMA_MIN = 5e-3
#: Coverage weight at or above which a joint counts as on trained ground.
TRAINED_GROUND_WEIGHT = 0.5
_TWO_PI = 2.0 * math.pi
_NAN3_LIST = [math.nan] * 3


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


class _RigidBody:
    """Momentum, ``-C^T qd + N + tau_spring`` and the tip Jacobian at one sample (compiled)."""

    def __init__(self, robot: Robot, spring_stiffness: np.ndarray) -> None:
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.n = n = robot.n
        n_model = robot.model.nv  # > n for a closed chain written as a tree (T is n_model x n)
        self.coupling = np.ascontiguousarray(robot.coupling, dtype=float)
        self._identity = n_model == n and bool(np.array_equal(self.coupling, np.eye(n)))
        self.rotor = np.ascontiguousarray(robot.description.rotor_inertia_kgm2, dtype=float)
        springs = robot.description.springs
        self.springs = spring_table(
            [s.joint for s in springs], spring_stiffness, [s.rest_angle_rad for s in springs]
        )
        #: ``[q (n), qd (n), momentum (n), other (n)]``
        self._state = np.zeros(4 * n)
        self._out = slice(2 * n, 4 * n)
        identity = self._identity
        # pinocchio's angles and velocities in model coordinates (views of the state for T = I)
        self._q_model = self._state[:n] if identity else np.zeros(n_model)
        self._v_model = self._state[n : 2 * n] if identity else np.zeros(n_model)
        self._q_motor = np.zeros(n)
        self._q_jacobian = self._q_motor if identity else np.zeros(n_model)
        tip_frame = robot.description.tip_frame
        self.tip = None if tip_frame is None else robot.model.getFrameId(tip_frame)

    def terms(self, q: list[float], qd: list[float]) -> tuple[list[float], list[float]]:
        """``M(q) qd`` and ``-C(q, qd)^T qd + N(q) + tau_spring(q)`` in motor coordinates."""
        model, data, state, n = self.model, self.data, self._state, self.n
        state[: 2 * n] = q + qd
        q_model, v_model = self._q_model, self._v_model
        if not self._identity:
            linear_map_into(self.coupling, state[:n], q_model)
            linear_map_into(self.coupling, state[n : 2 * n], v_model)
        mass = pin.crba(model, data, q_model)  # upper triangle is valid
        coriolis = pin.computeCoriolisMatrix(model, data, q_model, v_model)
        gravity = pin.computeGeneralizedGravity(model, data, q_model)
        rigid_terms_into(
            state, v_model, mass, coriolis, gravity, self.coupling, self.rotor, self.springs
        )
        out = state[self._out].tolist()
        return out[:n], out[n:]

    def jacobian(self, q: list[float]) -> list[list[float]]:
        """Return the translational tip Jacobian ``d p / d q_motor`` (3 x n) at angles ``q``."""
        self._q_motor[:] = q
        if not self._identity:
            linear_map_into(self.coupling, self._q_motor, self._q_jacobian)
        j6 = pin.computeFrameJacobian(
            self.model, self.data, self._q_jacobian, self.tip, pin.LOCAL_WORLD_ALIGNED
        )
        # J_motor = J_model T
        return (j6[:3] if self._identity else j6[:3] @ self.coupling).tolist()

    def tip_force(self, q: list[float], tau_ext: list[float], sigma_min: float) -> list[float]:
        """``F`` with ``J^T F = tau_ext`` for three joints (raise SingularityError)."""
        j = self.jacobian(q)
        (a, b, c), (d, e, f), (g, h, i) = j
        # first row of cofactors of J
        c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g
        det = a * c00 + b * c01 + c * c02
        frob = a * a + b * b + c * c + d * d + e * e + f * f + g * g + h * h + i * i
        # sigma_min >= |det| / sigma_max^2 >= |det| / ||J||_F^2: only near a singularity
        # are the singular values needed (LAPACK, as Robot.tip_force_from_joint_torque)
        if not abs(det) > sigma_min * frob:
            smallest = float(np.linalg.svd(np.asarray(j), compute_uv=False)[-1])
            if smallest < sigma_min or det == 0.0:
                raise SingularityError(smallest, sigma_min)
        t0, t1, t2 = tau_ext
        # F = (J^T)^-1 tau = (J^-1)^T tau = cof(J) tau / det J
        return [
            (c00 * t0 + c01 * t1 + c02 * t2) / det,
            ((c * h - b * i) * t0 + (a * i - c * g) * t1 + (b * g - a * h) * t2) / det,
            ((b * f - c * e) * t0 + (c * d - a * f) * t1 + (a * e - b * d) * t2) / det,
        ]


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
            n_links = 10 * description.n_links
            # pinocchio's composite inertias need positive subtree masses
            full = model.base.representative_with_masses(
                model.base_values, nominal, range(0, n_links, 10)
            )
            equivalent = description.with_link_parameters(full[:n_links]).with_rotor_inertia(
                full[n_links : n_links + self.n]
            )
            self.spring_stiffness = full[n_links + self.n :]
            self.robot = Robot(equivalent)
        self._rigid = None if self.robot is None else _RigidBody(self.robot, self.spring_stiffness)
        self._has_tip = self.robot is not None and self.robot.description.tip_frame is not None
        self._terms = ModelTerms(model)
        config = model.filter_config
        self._lag = config.torque_lag_samples
        self._omega_v = _TWO_PI * config.velocity_cutoff_hz
        self._omega = _TWO_PI * config.cutoff_hz
        self.reset()

    def reset(self) -> None:
        """Forget all filter state (start of a new stream)."""
        self._t_prev: float | None = None
        self._t_first = 0.0
        self._stage1: list[float] = []  # L_v(q), L_v(tau)
        self._stage2: list[float] = []  # L of M qd, -C^T qd + N + springs, the rest, L_v(tau)

    def update(self, t_s: float, q_rad: np.ndarray, tau_nm: np.ndarray) -> ForceEstimate:
        """Feed one sample (time, measured angles, commanded motor torques)."""
        n = self.n
        q_arr = np.asarray(q_rad, dtype=float)
        tau_arr = np.asarray(tau_nm, dtype=float)
        if q_arr.shape != (n,) or tau_arr.shape != (n,):
            raise DataError(f"expected {n} joint angles and torques")
        q_raw = q_arr.tolist()
        tau = tau_arr.tolist()
        t_s = float(t_s)
        if not math.isfinite(sum(q_raw) + sum(tau) + t_s) and not (
            all(map(math.isfinite, q_raw)) and all(map(math.isfinite, tau)) and math.isfinite(t_s)
        ):
            raise DataError("non-finite joint angle, torque or time")
        # stage 1: the pre-filter L_v of the angles and torques; velocity of the filtered angles
        t_prev = self._t_prev
        first = t_prev is None
        if first:
            dt = 1e-3
            stage1 = q_raw + tau
            qd = [0.0] * n
            self._t_first = t_s
        else:
            dt = t_s - t_prev  # type: ignore[operator]
            if not dt > 0:
                raise DataError(f"time does not increase ({t_s} after {t_prev})")
            a = math.exp(-self._omega_v * dt)
            b = 1.0 - a
            previous = self._stage1
            stage1 = [a * s + b * x for s, x in zip(previous, q_raw + tau, strict=True)]
            qd = [(stage1[i] - previous[i]) / dt for i in range(n)]
        self._t_prev = t_s
        self._stage1 = stage1
        q = stage1[:n]
        tau_v = stage1[n:]

        # the model's terms at this sample
        rigid = self._rigid
        if rigid is not None:
            momentum, terms = rigid.terms(q, qd)
        else:
            momentum = terms = [0.0] * n

        # stage 2: the filter L of [M qd, -C^T qd + N + springs, other terms, L_v(tau)];
        # D_L(M qd) + L(-C^T qd + N + springs) is the filtered rigid-body torque, the load
        # that found effects on ``tau<j>`` read (DynamicModel.predict_filtered_torque)
        if first:
            head = momentum + terms
            derivative = [0.0] * n
        else:
            a = math.exp(-self._omega * dt)
            b = 1.0 - a
            previous = self._stage2
            x_head = momentum + terms
            head = [a * s + b * x for s, x in zip(previous[: 2 * n], x_head, strict=True)]
            derivative = [(head[i] - previous[i]) / dt for i in range(n)]
        load = [derivative[i] + head[n + i] for i in range(n)]
        # friction + offsets + found effects (which read the load) in one compiled call
        other, weight = self._terms(t_s - self._t_first, q, qd, load)
        if first:
            tail = other + tau_v
            tau_filtered = tau_v
        else:
            x_tail = other + tau_v
            tail = [a * s + b * x for s, x in zip(previous[2 * n :], x_tail, strict=True)]
            tau_filtered = tail[n:] if self._lag == 0 else previous[3 * n :]
        self._stage2 = head + tail
        tau_model = [load[i] + tail[i] for i in range(n)]
        tau_ext = [x - m for x, m in zip(tau_filtered, tau_model, strict=True)]

        force: list[float] | np.ndarray = _NAN3_LIST
        singular = False
        if self._has_tip:
            assert rigid is not None and self.robot is not None
            try:
                if n == 3:
                    force = rigid.tip_force(q_raw, tau_ext, self.sigma_min)
                else:
                    force = self.robot.tip_force_from_joint_torque(
                        q_arr, np.asarray(tau_ext), self.sigma_min
                    )
            except SingularityError:
                singular = True
        if n == 3:
            block = np.array((tau_ext, tau_filtered, tau_model, weight, force))
            force_row = block[4]
        else:
            block = np.array((tau_ext, tau_filtered, tau_model, weight))
            force_row = np.array(force, dtype=float)
        coverage = block[3]
        return ForceEstimate(
            t_s,
            force_row,
            block[0],
            block[1],
            block[2],
            coverage,
            coverage >= TRAINED_GROUND_WEIGHT,
            singular,
        )
