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
arithmetic. So the filters, the coupling ``T`` of motor and model coordinates, the friction
fallback, coverage trust, found effects and the 3 x 3 ``J^-T`` run on Python floats
(:mod:`teleop_force.estimation.kernels`); NumPy is used where arrays are long (the wavelet
network, :meth:`~teleop_force.friction.wavelet_network.WaveletNetwork.torque_one`) and
pinocchio for the rigid body (four calls). See BENCHMARKS.md for the figures.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from teleop_force.errors import DataError, SingularityError
from teleop_force.estimation.kernels import (
    CoverageLookup,
    FrictionKernel,
    compile_linear_map,
    effect_kernel,
    linear_expression,
    linear_friction_kernel,
)
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.regressor import full_parameters
from teleop_force.robots.description import Robot

#: Jacobian singular values below this [m/rad] make the force unobservable: reported, not divided.
DEFAULT_SIGMA_MIN = 5e-3
#: Coverage weight at or above which a joint counts as on trained ground.
TRAINED_GROUND_WEIGHT = 0.5
_TWO_PI = 2.0 * math.pi
_NAN3_LIST = [math.nan] * 3
_UNSET = object()


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


def _compile_rigid_terms(
    robot: Robot, spring_stiffness: np.ndarray
) -> Callable[..., tuple[list[float], list[float]]]:
    """``(q, qd, vm, M, C, g) -> (M qd, -C^T qd + N + tau_spring)`` in motor coordinates, unrolled.

    ``vm = T qd`` and ``M``, ``C``, ``g`` are pinocchio's (model coordinates, upper triangle
    of ``M``); the result is ``T^T M vm + rotor qd`` and ``T^T (g - C^T vm) + springs``.
    """
    n = robot.n
    n_model = robot.model.nv  # > n for a closed chain written as a tree (T is n_model x n)
    tt = robot.coupling.T
    lines = ["def rigid_terms(q, qd, vm, M, C, g):"]
    for i in range(n_model):
        mass = " + ".join(f"M[{min(i, j)}][{max(i, j)}] * vm[{j}]" for j in range(n_model))
        coriolis = " + ".join(f"C[{j}][{i}] * vm[{j}]" for j in range(n_model))
        lines.append(f"    p{i} = {mass}")
        lines.append(f"    w{i} = g[{i}] - ({coriolis})")
    lines.append(f"    p = [{', '.join(f'p{i}' for i in range(n_model))}]")
    lines.append(f"    w = [{', '.join(f'w{i}' for i in range(n_model))}]")
    rotor = robot.description.rotor_inertia_kgm2
    spring: list[list[str]] = [[] for _ in range(n)]
    for s, k in zip(robot.description.springs, spring_stiffness, strict=True):
        spring[s.joint].append(f"{float(k)!r} * (q[{s.joint}] - {float(s.rest_angle_rad)!r})")
    momentum = [
        f"{linear_expression(tt[i], 'p')} + {float(rotor[i])!r} * qd[{i}]" for i in range(n)
    ]
    other = [" + ".join([linear_expression(tt[i], "w"), *spring[i]]) for i in range(n)]
    lines.append(f"    return [{', '.join(momentum)}], [{', '.join(other)}]")
    namespace: dict[str, object] = {}
    exec("\n".join(lines) + "\n", namespace)
    return namespace["rigid_terms"]  # type: ignore[return-value]


class _RigidBody:
    """Momentum, ``-C^T qd + N + tau_spring`` and the tip Jacobian, on Python floats."""

    def __init__(self, robot: Robot, spring_stiffness: np.ndarray) -> None:
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.n = robot.n
        self.to_model = compile_linear_map(robot.coupling)
        self._terms = _compile_rigid_terms(robot, spring_stiffness)
        # J_motor = J_model T: row r of the result is T^T applied to row r of J_model
        self._jacobian_to_motor = compile_linear_map(robot.coupling.T)
        tip_frame = robot.description.tip_frame
        self.tip = None if tip_frame is None else robot.model.getFrameId(tip_frame)
        self._q = np.zeros(robot.model.nv)
        self._v = np.zeros(robot.model.nv)

    def terms(self, q: list[float], qd: list[float]) -> tuple[list[float], list[float]]:
        """``M(q) qd`` and ``-C(q, qd)^T qd + N(q) + tau_spring(q)`` in motor coordinates."""
        model, data = self.model, self.data
        vm = self.to_model(qd)
        self._q[:] = self.to_model(q)
        self._v[:] = vm
        mass = pin.crba(model, data, self._q).tolist()  # upper triangle is valid
        coriolis = pin.computeCoriolisMatrix(model, data, self._q, self._v).tolist()
        gravity = pin.computeGeneralizedGravity(model, data, self._q).tolist()
        return self._terms(q, qd, vm, mass, coriolis, gravity)

    def jacobian(self, q: list[float]) -> list[list[float]]:
        """Return the translational tip Jacobian ``d p / d q_motor`` (3 x n) at angles ``q``."""
        self._q[:] = self.to_model(q)
        j6 = pin.computeFrameJacobian(
            self.model, self.data, self._q, self.tip, pin.LOCAL_WORLD_ALIGNED
        ).tolist()
        convert = self._jacobian_to_motor
        return [convert(j6[0]), convert(j6[1]), convert(j6[2])]

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


class _Friction:
    """Friction torque and coverage weight of a model at one sample, on Python floats."""

    def __init__(self, model: DynamicModel) -> None:
        self.model = model
        self.friction = model.friction
        self.n = model.n_joints
        self._ones = [1.0] * self.n
        self._linear = linear_friction_kernel(self.friction)
        self._network = self.friction if type(self.friction) is WaveletNetwork else None
        self._fallback: object = _UNSET  # what the kernels below were built for
        self._fallback_kernel: FrictionKernel | None = None
        self._coverage: object = _UNSET
        self._trust: Callable[[list[float]], list[float]] | None = None

    def _refresh(self, network: WaveletNetwork) -> None:
        """(Re)build the kernels of the network's fallback and coverage map."""
        fallback = network.fallback
        if fallback is None:
            network.blended_torque(np.zeros((1, self.n)))  # raises the model error
        assert fallback is not None
        kernel = linear_friction_kernel(fallback)
        if kernel is None:
            kernel = lambda qd: fallback.torque(np.asarray([qd]))[0].tolist()  # noqa: E731
        self._fallback, self._fallback_kernel = fallback, kernel
        coverage = network.coverage
        self._coverage = coverage
        self._trust = None if coverage is None else CoverageLookup(coverage).trust

    def __call__(self, qd: list[float]) -> tuple[list[float], list[float]]:
        """``(friction torque, coverage weight)`` per joint at ``qd``."""
        network = self._network
        if network is not None:
            if network.fallback is not self._fallback or network.coverage is not self._coverage:
                self._refresh(network)
            trust = self._trust
            weight = self._ones if trust is None else trust(qd)
            wn = network.torque_one(qd).tolist()
            fb = self._fallback_kernel(qd)  # type: ignore[misc]
            blended = [w * a + (1.0 - w) * b for w, a, b in zip(weight, wn, fb, strict=True)]
            return blended, weight
        if self._linear is not None:
            return self._linear(qd), self._ones
        row = np.asarray([qd])
        torque = self.model.friction_torque(row)[0].tolist()
        return torque, self.friction.coverage_weight(row)[0].tolist()


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
        self._friction = _Friction(model)
        # ((joint, weight), ...), kernel) or an effect with .torque()
        self._effects: list[Any] = []
        for effect in model.effects:
            kernel = effect_kernel(effect, self.n)
            if kernel is None:
                self._effects.append(effect)
                continue
            weights = effect.weights(self.n)
            reach = tuple((j, float(w)) for j, w in enumerate(weights) if w != 0.0)
            self._effects.append((reach, kernel[1]))
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

    def _add_effects(
        self, other: list[float], t: float, q: list[float], qd: list[float], load: list[float]
    ) -> None:
        """Add the found effects' torques to ``other`` (in place); ``load`` feeds ``tau<j>``."""
        for entry in self._effects:
            if type(entry) is tuple:
                reach, kernel = entry
                value = kernel(t, q, qd, load)
                for joint, weight in reach:
                    other[joint] += weight * value
            else:
                row = entry.torque(
                    np.asarray([t]), np.asarray([q]), np.asarray([qd]), np.asarray([load])
                )[0].tolist()
                for j, value in enumerate(row):
                    other[j] += value

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
        friction, weight = self._friction(qd)
        other = [f + o for f, o in zip(friction, self.model.offsets_nm.tolist(), strict=True)]

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
        if self._effects:
            self._add_effects(other, t_s - self._t_first, q, qd, load)
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
