"""The streaming estimator's numbers for a whole recording at once (fixed model).

:class:`BatchEstimator` returns, for arrays of samples, what
:meth:`~teleop_force.estimation.estimator.ForceEstimator.update` returns sample by sample
(equal to rounding, tested to 1e-9), one stream after the other: a stream begins at the first
sample and at every index of ``stream_starts``, where the streaming estimator would be reset
(the force service's restarts, :mod:`teleop_force.service.stream_clock`). Per stream, the same
recursions in the same order::

    q_v, qd     = L_v(q), backward difference of q_v      first sample: q, 0
    tau_model_L = D_L(M(q_v) qd) + L(-C^T qd + N + tau_spring + tau_f(qd) + offsets + effects)
    tau_ext_L   = L(L_v(tau))[k - lag] - tau_model_L
    F           = J(q)^-T tau_ext_L    (raw q; NaN and ``singular`` below ``sigma_min``)

or, for a model whose filter configuration names the ``observer``, ``tau_ext`` the momentum
observer's residual (:func:`~teleop_force.estimation.momentum_observer.observer_update_into`,
the streaming step's own function, in a compiled loop) and ``tau_model_L = tau_L - tau_ext``;
friction ramped to 0 in the standstill band as the streaming estimator ramps it.

The work is done in passes over all samples rather than sample by sample: the filters are
compiled loops (their sample intervals vary, so no ``lfilter``); the rigid-body terms and the
tip Jacobian come from :mod:`teleop_force.estimation.rigid_chain` (pinocchio per sample for a
joint type it does not encode); friction with its coverage blend, offsets and found effects
from the streaming estimator's own compiled kernel
(:func:`~teleop_force.estimation.kernels.add_model_terms`, the single definitions of
:mod:`teleop_force.friction.terms` and :mod:`teleop_force.identification.effect_terms`) in a
compiled loop. Found effects read ``t`` as the time since their stream's first sample.

The model is fixed: online adaptation (the wavelet network's Lyapunov law) changes the
parameters at every sample, which only the streaming estimator follows.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from teleop_force.compiled import njit_cached
from teleop_force.errors import ConfigurationError, DataError
from teleop_force.estimation.count_observer import observe_counts, observer_tables
from teleop_force.estimation.estimator import (
    DEFAULT_SIGMA_MIN,
    TRAINED_GROUND_WEIGHT,
    equivalent_rigid_body,
)
from teleop_force.estimation.kernels import ModelTerms, add_model_terms, first_prefilter_stage
from teleop_force.estimation.momentum_observer import (
    BUTTERWORTH_STATES,
    butterworth_step_into,
    observer_update_into,
)
from teleop_force.estimation.rigid_chain import (
    ChainTables,
    chain_jacobian_batch,
    chain_tables,
    chain_terms_batch,
)
from teleop_force.friction.terms import standstill_factors, sticking_states
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.encoder_count import measured_count_rad
from teleop_force.identification.least_squares import relative_rms
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.description import Robot

_TWO_PI = 2.0 * math.pi
#: Threads the friction and effects of a recording are computed on, at most.
MAX_THREADS = 2
#: Fewer samples than this per thread are computed on one thread.
_MIN_SAMPLES_PER_THREAD = 50_000
#: The interval the first sample of a stream is given (unused by the recursions).
_FIRST_DT_S = 1e-3


@dataclass(frozen=True, eq=False)
class BatchEstimates:
    """The estimates of every sample (the fields of ``ForceEstimate``, stacked).

    Attributes:
        t_s: Sample times as given [s] (N,).
        force_tip_in_base_n: Force of the tip on the environment, base frame [N] (N, 3);
            NaN where the Jacobian is near singular or the robot has no tip.
        tau_external_nm: External joint torques ``tau_L - tau_model_L`` [N m] (N, n).
        tau_motor_filtered_nm: Low-pass filtered motor torque [N m] (N, n).
        tau_model_filtered_nm: Low-pass filtered model torque [N m] (N, n).
        coverage_weight: How much each joint's friction rests on training data (N, n).
        on_trained_ground: ``coverage_weight >= 0.5`` (N, n).
        singular: Whether the Jacobian was too close to singular for a force (N,).

    """

    t_s: np.ndarray
    force_tip_in_base_n: np.ndarray
    tau_external_nm: np.ndarray
    tau_motor_filtered_nm: np.ndarray
    tau_model_filtered_nm: np.ndarray
    coverage_weight: np.ndarray
    on_trained_ground: np.ndarray
    singular: np.ndarray

    def __post_init__(self) -> None:
        """Check every array has one row per sample."""
        n_samples = self.t_s.shape[0]
        for name in (
            "force_tip_in_base_n", "tau_external_nm", "tau_motor_filtered_nm",
            "tau_model_filtered_nm", "coverage_weight", "on_trained_ground", "singular",
        ):  # fmt: skip
            if getattr(self, name).shape[0] != n_samples:
                raise DataError(f"{name} has {getattr(self, name).shape[0]} rows, not {n_samples}")

    def __len__(self) -> int:
        """Return the number of samples."""
        return int(self.t_s.shape[0])

    def rows(self, selection: slice) -> BatchEstimates:
        """Return the estimates of the samples ``selection`` picks (every field alike)."""
        return BatchEstimates(
            *(getattr(self, name)[selection] for name in BatchEstimates.__dataclass_fields__)
        )


def stream_times_s(t_ns: np.ndarray, stream_starts: np.ndarray | None = None) -> np.ndarray:
    """Return the times [s] the service runs its estimator on: ``(t_ns - t0_ns) * 1e-9``.

    ``t0_ns`` is the stamp of the sample's stream's first sample (index 0 and every index of
    ``stream_starts``), the difference taken in integer nanoseconds.
    """
    stamps = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    starts = _start_mask(stamps.size, stream_starts)
    origin = stamps[np.maximum.accumulate(np.where(starts, np.arange(stamps.size), 0))]
    return (stamps - origin) * 1e-9


class BatchEstimator:
    """What :class:`~teleop_force.estimation.estimator.ForceEstimator` gives, for arrays."""

    def __init__(self, model: DynamicModel, sigma_min: float = DEFAULT_SIGMA_MIN) -> None:
        """Build the equivalent rigid body (as the streaming estimator) and its tables."""
        self.model = model
        self.n = model.n_joints
        self.sigma_min = float(sigma_min)
        self.robot, spring_stiffness = equivalent_rigid_body(model)
        config = model.filter_config
        self._lag = int(config.torque_lag_samples)
        prefilter_hz, self._prefilter_stages = config.estimator_prefilter
        self._omega_v = _TWO_PI * prefilter_hz
        self._omega = _TWO_PI * config.cutoff_hz
        self._observer = config.observer
        self._omega_observer = _TWO_PI * config.observer_hz
        self._omega_output = _TWO_PI * config.estimator_output_hz
        self._band = float(config.standstill_band_rad_s)
        robot = self.robot
        n = self.n
        self._tables: ChainTables | None = None
        self._identity = True
        self._has_tip = robot is not None and robot.description.tip_frame is not None
        if robot is None:
            self._coupling = np.eye(n)
            self._rotor = np.zeros(n)
            self._springs = np.zeros((0, 3))
            return
        description = robot.description
        self._coupling = np.ascontiguousarray(robot.coupling, dtype=float)
        self._identity = self._coupling.shape[0] == n and bool(
            np.array_equal(self._coupling, np.eye(n))
        )
        self._rotor = np.ascontiguousarray(description.rotor_inertia_kgm2, dtype=float)
        self._springs = np.array(
            [
                (float(s.joint), float(k), float(s.rest_angle_rad))
                for s, k in zip(description.springs, spring_stiffness, strict=True)
            ],
            dtype=float,
        ).reshape(-1, 3)
        self._tables = chain_tables(robot.model, description.tip_frame)

    def estimate(
        self,
        t_s: np.ndarray,
        q_rad: np.ndarray,
        tau_nm: np.ndarray,
        stream_starts: np.ndarray | None = None,
        *,
        stream_time_s: np.ndarray | None = None,
    ) -> BatchEstimates:
        """Estimate on every sample; a stream begins at sample 0 and at ``stream_starts``.

        ``stream_time_s``: each sample's time since its stream began [s], what found effects
        that drift are evaluated at (default: since the stream's first sample given here; a
        caller that estimates a long stream in pieces passes its own). Raises DataError for a
        non-finite value, a shape that does not fit the model, or a time that does not
        increase within a stream (the row is 1-based, as in a file).
        """
        t, q, tau = self._check(t_s, q_rad, tau_nm)
        starts = _start_mask(t.size, stream_starts)
        steps = np.flatnonzero(~starts[1:] & ~(t[1:] > t[:-1])) + 1
        if steps.size:
            k = int(steps[0])
            raise DataError(f"time does not increase ({t[k]} after {t[k - 1]})", row=k + 1)
        if self.model.filter_config.count_observer:
            q = self._observe_counts(t, q, tau, starts)
        with ThreadPoolExecutor(_threads()) as pool:
            # the tip Jacobian reads the raw angles only: computed meanwhile
            jacobian = pool.submit(self._jacobians, q)
            q_v, tau_v, qd, dt = _prefilter(
                t, q, tau, starts, self._omega_v, self._prefilter_stages
            )
            momentum, rigid_other = self._rigid_terms(q_v, qd)
            load = _rigid_load(momentum, rigid_other, dt, starts, self._omega)
            if stream_time_s is None:
                t_first = t[np.maximum.accumulate(np.where(starts, np.arange(t.size), 0))]
                since_start = t - t_first
            else:
                since_start = np.ascontiguousarray(stream_time_s, dtype=float).reshape(-1)
                if since_start.shape != t.shape:
                    raise DataError(f"stream_time_s must have {t.size} values")
            other, weight = self._model_terms(since_start, q_v, qd, load, pool, starts)
            tau_filtered, tau_model, tau_ext = _output_filter(
                other, tau_v, load, dt, starts, self._omega, self._lag,
            )  # fmt: skip
            if self._observer:
                tau_ext = _observer_loop(
                    momentum, tau_v, rigid_other, other, dt, starts, self._omega_observer,
                    self._lag,
                )  # fmt: skip
                if self._omega_output > 0.0:
                    output_filter_loop(tau_ext, dt, starts, self._omega_output)
                tau_model = tau_filtered - tau_ext
            force, singular = self._tip_forces(jacobian.result(), tau_ext)
        return BatchEstimates(
            t, force, tau_ext, tau_filtered, tau_model, weight,
            weight >= TRAINED_GROUND_WEIGHT, singular,
        )  # fmt: skip

    def _observe_counts(
        self, t: np.ndarray, q: np.ndarray, tau: np.ndarray, starts: np.ndarray
    ) -> np.ndarray:
        """Return the count observer's angles (:mod:`~teleop_force.estimation.count_observer`).

        The counts are the model's, or measured on these readings when it has none.
        ConfigurationError for a model without rigid-body terms (the observer predicts with
        them).
        """
        if self._tables is None:
            raise ConfigurationError(
                f"{self.model.robot}: the count observer needs a model with rigid-body terms"
            )
        floats, ints, scratch = observer_tables(
            self._count_rad(q), self._tables, self._coupling, self._rotor, self._springs,
            ModelTerms(self.model),
        )  # fmt: skip
        return np.asarray(observe_counts(t, q, tau, starts, floats, ints, scratch))

    def _count_rad(self, q: np.ndarray) -> np.ndarray:
        """Return the model's encoder counts, else those measured on ``q``."""
        given = self.model.filter_config.count_rad
        return np.array(given, dtype=float) if given else measured_count_rad(q)

    def _check(
        self, t_s: np.ndarray, q_rad: np.ndarray, tau_nm: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.n
        t = np.ascontiguousarray(t_s, dtype=float).reshape(-1)
        q = np.ascontiguousarray(q_rad, dtype=float)
        tau = np.ascontiguousarray(tau_nm, dtype=float)
        if q.shape != (t.size, n) or tau.shape != (t.size, n):
            raise DataError(
                f"expected {t.size} samples of {n} joint angles and torques, got "
                f"{q.shape} and {tau.shape}"
            )
        finite = np.isfinite(t) & np.isfinite(q).all(axis=1) & np.isfinite(tau).all(axis=1)
        if not finite.all():
            k = int(np.argmin(finite))
            raise DataError("non-finite joint angle, torque or time", row=k + 1)
        return t, q, tau

    def _model_terms(
        self,
        t_s: np.ndarray,
        q_v: np.ndarray,
        qd: np.ndarray,
        load: np.ndarray,
        pool: ThreadPoolExecutor,
        starts: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Friction (coverage blend) + offsets + found effects, and the coverage weight.

        The streaming estimator's own per-sample kernel
        (:func:`~teleop_force.estimation.kernels.add_model_terms`) in a compiled loop, in
        blocks on the ``pool``'s threads (each with its own scratch; the kernel releases the
        GIL); a friction without a term encoding by its batch methods, added as the estimator
        adds it. A sticking state (it follows the path) is run first, sequentially, over
        every stream (``starts``), as the streaming estimator advances it.
        """
        n_samples = t_s.size
        blocks = max(1, min(_threads(), n_samples // _MIN_SAMPLES_PER_THREAD))
        bounds = np.linspace(0, n_samples, blocks + 1).astype(int)
        # the kernel's arguments are made here, once per block (the coverage grids are
        # smoothed on first use), not by the threads
        terms = [ModelTerms(self.model) for _ in range(blocks)]
        jobs = [
            (slice(a, b), block.work, block.arguments())
            for (a, b), block in zip(itertools.pairwise(bounds.tolist()), terms, strict=True)
        ]
        sticking = np.zeros((n_samples, 0))
        if terms[0].sticking_inv_rad > 0.0:
            inv_rad, rows = terms[0].sticking_inv_rad, terms[0].sticking_rows
            sticking = sticking_states(np.ascontiguousarray(q_v), rows, inv_rad, starts)

        def run(job: tuple[slice, np.ndarray, tuple[Any, ...]]) -> tuple[np.ndarray, np.ndarray]:
            rows, work, arguments = job
            return _terms_loop(
                t_s[rows], q_v[rows], qd[rows], load[rows], sticking[rows], work, arguments
            )

        if blocks == 1:
            other, weight = run(jobs[0])
        else:
            parts = list(pool.map(run, jobs))
            other = np.concatenate([p[0] for p in parts])
            weight = np.concatenate([p[1] for p in parts])
        if terms[0].python_friction:
            torque = self.model.friction_torque(qd)
            if self._band > 0.0:
                torque = torque * standstill_factors(np.ascontiguousarray(qd), self._band)[:, None]
            other = other + torque
            weight = np.ascontiguousarray(self.model.friction.coverage_weight(qd), dtype=float)
        return other, weight

    def _rigid_terms(self, q_v: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``M qd`` (rotor included) and ``-C^T qd + N + springs``, motor coordinates."""
        robot = self.robot
        if robot is None:
            return np.zeros_like(q_v), np.zeros_like(q_v)
        q_model, v_model = self._to_model(q_v), self._to_model(qd)
        tables = self._tables
        if tables is not None:
            p_model, w_model = chain_terms_batch(q_model, v_model, *tables.arrays())
        else:
            p_model, w_model = _pinocchio_terms(robot, q_model, v_model)
        return _motor_terms(q_v, qd, p_model, w_model, self._coupling, self._rotor, self._springs)

    def _to_model(self, x: np.ndarray) -> np.ndarray:
        """``T x`` of every sample (the motor-to-model coupling)."""
        return x if self._identity else _couple(self._coupling, x)

    def _jacobians(self, q: np.ndarray) -> np.ndarray | None:
        """Return the tip Jacobian ``d p / d q_motor`` (N, 3, n); None without a tip."""
        robot = self.robot
        if not self._has_tip or robot is None:
            return None
        q_model = self._to_model(q)
        tables = self._tables
        if tables is not None:
            jacobian = chain_jacobian_batch(
                q_model, *tables.arrays()[:6], tables.tip_body, tables.tip_translation,
                tables.tip_support,
            )  # fmt: skip
        else:
            jacobian = _pinocchio_jacobian(robot, q_model)
        if self._identity:
            return jacobian
        return np.ascontiguousarray(jacobian @ self._coupling)  # J_motor = J_model T

    def _tip_forces(
        self, jacobian: np.ndarray | None, tau_ext: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``F`` with ``J^T F = tau_ext`` per sample, and where it is singular."""
        n_samples = tau_ext.shape[0]
        force = np.full((n_samples, 3), math.nan)
        singular = np.zeros(n_samples, dtype=bool)
        if jacobian is None:
            return force, singular
        sigma_min = self.sigma_min
        if self.n == 3:
            force, det, check = _cofactor_solve(jacobian, tau_ext, sigma_min)
            near = np.flatnonzero(check)
            if near.size:
                smallest = np.linalg.svd(jacobian[near], compute_uv=False)[:, -1]
                bad = near[(smallest < sigma_min) | (det[near] == 0.0)]
                force[bad] = math.nan
                singular[bad] = True
            return force, singular
        # least squares, as Robot.tip_force_from_joint_torque
        u, s, vt = np.linalg.svd(np.swapaxes(jacobian, 1, 2), full_matrices=False)
        singular = s[:, -1] < sigma_min
        good = np.flatnonzero(~singular)
        projected = np.einsum("kji,kj->ki", u[good], tau_ext[good]) / s[good]
        force[good] = np.einsum("kij,ki->kj", vt[good], projected)
        return force, singular


def evaluate_recordings(
    model: DynamicModel, recordings: Sequence[Recording], sigma_min: float = DEFAULT_SIGMA_MIN
) -> dict[str, Any]:
    """Return the ``evaluate`` figures of ``model`` on recordings, from the batch estimator.

    As :func:`~teleop_force.identification.pipeline.evaluate_model` (adaptation off, the
    friction blended by its coverage): per joint, the relative RMS of the filtered model torque
    against the filtered motor torque and the fraction of samples on trained ground, over the
    samples past each recording's ``warmup_s``; ``measured`` and ``estimated`` are those
    samples' torques. Raise DataError naming a recording whose joint count does not fit.
    """
    estimator = BatchEstimator(model, sigma_min)
    warmup_s = model.filter_config.warmup_s
    measured, estimated, on_ground = [], [], []
    for recording in recordings:
        t = np.asarray(recording.t_s, dtype=float)
        n_joints = recording.q_rad.shape[1]
        if n_joints != model.n_joints:
            raise DataError(
                f"has {n_joints} joints, the model ({model.robot!r}) has {model.n_joints}",
                path=recording.source,
            )
        if t.size < 3:
            raise DataError(f"need at least 3 samples, got {t.size}", path=recording.source)
        estimates = estimator.estimate(t, recording.q_rad, recording.tau_nm)
        valid = t >= t[0] + warmup_s
        measured.append(estimates.tau_motor_filtered_nm[valid])
        estimated.append(estimates.tau_model_filtered_nm[valid])
        on_ground.append(estimates.on_trained_ground[valid])
    m, e = np.concatenate(measured), np.concatenate(estimated)
    return {
        "relative_rms": relative_rms(m, e),
        "samples": int(m.shape[0]),
        "coverage": np.concatenate(on_ground).mean(axis=0),
        "measured": m,
        "estimated": e,
    }


def _threads() -> int:
    """Threads to use: :data:`MAX_THREADS`, or fewer if the process may use fewer cores."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(MAX_THREADS, cores))


def _start_mask(n_samples: int, stream_starts: np.ndarray | None) -> np.ndarray:
    """Boolean mask of the samples that begin a stream (sample 0 always does)."""
    starts = np.zeros(n_samples, dtype=bool)
    if n_samples:
        starts[0] = True
    if stream_starts is not None:
        index = np.asarray(stream_starts, dtype=np.int64).reshape(-1)
        if index.size and (index.min() < 0 or index.max() >= n_samples):
            raise DataError(f"stream starts must lie in 0..{n_samples - 1}")
        starts[index] = True
    return starts


def _pinocchio_terms(
    robot: Robot, q_model: np.ndarray, v_model: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``M v`` and ``g - C^T v`` by pinocchio, sample by sample (joints the chain lacks)."""
    model, data = robot.model, robot.model.createData()
    momentum = np.empty_like(q_model)
    other = np.empty_like(q_model)
    for k in range(q_model.shape[0]):
        mass = pin.crba(model, data, q_model[k])
        mass = np.triu(mass) + np.triu(mass, 1).T
        coriolis = pin.computeCoriolisMatrix(model, data, q_model[k], v_model[k])
        gravity = pin.computeGeneralizedGravity(model, data, q_model[k])
        momentum[k] = mass @ v_model[k]
        other[k] = gravity - coriolis.T @ v_model[k]
    return momentum, other


def _pinocchio_jacobian(robot: Robot, q_model: np.ndarray) -> np.ndarray:
    """Return the tip's translational Jacobian by pinocchio, sample by sample."""
    model, data = robot.model, robot.model.createData()
    tip = model.getFrameId(robot.description.tip_frame)
    out = np.empty((q_model.shape[0], 3, q_model.shape[1]))
    for k in range(q_model.shape[0]):
        out[k] = pin.computeFrameJacobian(model, data, q_model[k], tip, pin.LOCAL_WORLD_ALIGNED)[:3]
    return out


@njit_cached()
def _prefilter(
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray,
    starts: np.ndarray,
    omega_v: float,
    stages: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Return the pre-filtered angles and torques, the angles' backward difference and ``dt``.

    ``stages`` (1 or 2) first-order low-passes at ``omega_v`` in cascade, as
    :func:`~teleop_force.estimation.kernels.prefilter_step` per sample.
    """
    n_samples, n = q.shape
    q_v = np.empty((n_samples, n))
    tau_v = np.empty((n_samples, n))
    qd = np.empty((n_samples, n))
    dt = np.empty(n_samples)
    inner = np.empty(2 * n)
    for k in range(n_samples):
        if starts[k]:
            dt[k] = _FIRST_DT_S
            for i in range(n):
                q_v[k, i] = q[k, i]
                tau_v[k, i] = tau[k, i]
                qd[k, i] = 0.0
                inner[i] = q[k, i]
                inner[n + i] = tau[k, i]
            continue
        step = t[k] - t[k - 1]
        dt[k] = step
        a = math.exp(-omega_v * step)
        b = 1.0 - a
        for i in range(n):
            value = first_prefilter_stage(q[k, i], inner, i, a, b, stages)
            previous = q_v[k - 1, i]
            filtered = a * previous + b * value
            q_v[k, i] = filtered
            qd[k, i] = (filtered - previous) / step
        for i in range(n):
            value = first_prefilter_stage(tau[k, i], inner, n + i, a, b, stages)
            tau_v[k, i] = a * tau_v[k - 1, i] + b * value
    return q_v, tau_v, qd, dt


@njit_cached()
def _terms_loop(
    t: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray,
    load: np.ndarray,
    sticking: np.ndarray,
    work: np.ndarray,
    arguments: tuple[Any, ...],
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """:func:`~teleop_force.estimation.kernels.add_model_terms` at every sample.

    ``sticking``: the sticking states of every sample (N, T), or (N, 0) without.
    """
    n_samples, n = q.shape
    other = np.empty((n_samples, n))
    weight = np.empty((n_samples, n))
    network = np.empty(n)
    for k in range(n_samples):
        add_model_terms(
            t[k], q[k], qd[k], load[k], other[k], weight[k], network, work, sticking[k],
            *arguments,
        )  # fmt: skip
    return other, weight


@njit_cached()
def _rigid_load(
    momentum: np.ndarray, other: np.ndarray, dt: np.ndarray, starts: np.ndarray, omega: float
) -> np.ndarray:  # pragma: no cover - compiled
    """``D_L(M qd) + L(-C^T qd + N + springs)``: the filtered rigid-body torque per sample."""
    n_samples, n = momentum.shape
    load = np.empty((n_samples, n))
    head_p = np.empty(n)
    head_w = np.empty(n)
    for k in range(n_samples):
        if starts[k]:
            for i in range(n):
                head_p[i] = momentum[k, i]
                head_w[i] = other[k, i]
                load[k, i] = 0.0 + head_w[i]
            continue
        step = dt[k]
        a = math.exp(-omega * step)
        b = 1.0 - a
        for i in range(n):
            previous = head_p[i]
            value = a * previous + b * momentum[k, i]
            head_p[i] = value
            head_w[i] = a * head_w[i] + b * other[k, i]
            load[k, i] = (value - previous) / step + head_w[i]
    return load


@njit_cached()
def _output_filter(
    other: np.ndarray,
    tau_v: np.ndarray,
    load: np.ndarray,
    dt: np.ndarray,
    starts: np.ndarray,
    omega: float,
    lag: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """``L(L_v(tau))`` (``lag`` samples late), ``tau_model_L`` and ``tau_ext_L`` per sample."""
    n_samples, n = other.shape
    tau_filtered = np.empty((n_samples, n))
    tau_model = np.empty((n_samples, n))
    tau_ext = np.empty((n_samples, n))
    tail_o = np.empty(n)
    tail_t = np.empty(n)
    for k in range(n_samples):
        if starts[k]:
            for i in range(n):
                tail_o[i] = other[k, i]
                tail_t[i] = tau_v[k, i]
                tau_filtered[k, i] = tau_v[k, i]
        else:
            a = math.exp(-omega * dt[k])
            b = 1.0 - a
            for i in range(n):
                tail_o[i] = a * tail_o[i] + b * other[k, i]
                previous = tail_t[i]
                tail_t[i] = a * previous + b * tau_v[k, i]
                tau_filtered[k, i] = tail_t[i] if lag == 0 else previous
        for i in range(n):
            model = load[k, i] + tail_o[i]
            tau_model[k, i] = model
            tau_ext[k, i] = tau_filtered[k, i] - model
    return tau_filtered, tau_model, tau_ext


@njit_cached()
def _observer_loop(
    momentum: np.ndarray,
    tau_v: np.ndarray,
    beta: np.ndarray,
    other: np.ndarray,
    dt: np.ndarray,
    starts: np.ndarray,
    omega: float,
    lag: int,
) -> np.ndarray:  # pragma: no cover - compiled
    """Return the momentum observer's residual (the external torque) per sample, per stream.

    :func:`~teleop_force.estimation.momentum_observer.observer_update_into` at every sample,
    on ``p = M qd``, ``L_v(tau)``, ``beta = g - C^T qd + springs`` and friction + offsets +
    effects, as the streaming estimator calls it.
    """
    n_samples, n = momentum.shape
    residual = np.empty((n_samples, n))
    p_hat = np.zeros(n)
    drive = np.zeros(n)
    for k in range(n_samples):
        observer_update_into(
            momentum[k], tau_v[k], beta[k], other[k], dt[k], omega, lag, starts[k], p_hat, drive,
            residual[k],
        )  # fmt: skip
    return residual


@njit_cached()
def output_filter_loop(
    values: np.ndarray, dt: np.ndarray, starts: np.ndarray, omega: float
) -> None:  # pragma: no cover - compiled
    """Run the observer's output Butterworth at ``omega`` [rad/s] over every sample, in place.

    :func:`~teleop_force.estimation.momentum_observer.butterworth_step_into` per sample, its
    state restarting with each stream, as the streaming step runs it.
    """
    n_samples, n = values.shape
    state = np.zeros(BUTTERWORTH_STATES * n)
    for k in range(n_samples):
        butterworth_step_into(values[k], state, omega, dt[k], starts[k])


@njit_cached()
def _couple(coupling: np.ndarray, x: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``coupling @ x[k]`` of every sample, over the coupling's nonzero entries."""
    n_samples = x.shape[0]
    n_model, n = coupling.shape
    out = np.empty((n_samples, n_model))
    for k in range(n_samples):
        for i in range(n_model):
            w = 0.0
            for j in range(n):
                c = coupling[i, j]
                if c != 0.0:
                    w += c * x[k, j]
            out[k, i] = w
    return out


@njit_cached()
def _motor_terms(
    q: np.ndarray,
    qd: np.ndarray,
    p_model: np.ndarray,
    w_model: np.ndarray,
    coupling: np.ndarray,
    rotor: np.ndarray,
    springs: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """``T^T p + rotor qd`` and ``T^T w + springs`` of every sample (motor coordinates)."""
    n_samples, n = q.shape
    n_model = coupling.shape[0]
    momentum = np.empty((n_samples, n))
    other = np.empty((n_samples, n))
    for k in range(n_samples):
        for j in range(n):
            momentum[k, j] = rotor[j] * qd[k, j]
            other[k, j] = 0.0
        for i in range(n_model):
            p = p_model[k, i]
            w = w_model[k, i]
            for j in range(n):
                c = coupling[i, j]
                if c == 1.0:
                    momentum[k, j] += p
                    other[k, j] += w
                elif c != 0.0:
                    momentum[k, j] += c * p
                    other[k, j] += c * w
        for s in range(springs.shape[0]):
            j = int(springs[s, 0])
            other[k, j] += springs[s, 1] * (q[k, j] - springs[s, 2])
    return momentum, other


@njit_cached()
def _cofactor_solve(
    jacobian: np.ndarray, tau: np.ndarray, sigma_min: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """``F = cof(J) tau / det J`` per sample (3 joints), ``det J``, and where to check ``J``.

    ``sigma_min >= |det| / ||J||_F^2``: only where ``|det| <= sigma_min ||J||_F^2`` can the
    smallest singular value be below ``sigma_min``; those samples are flagged for an SVD.
    """
    n_samples = jacobian.shape[0]
    force = np.empty((n_samples, 3))
    det_out = np.empty(n_samples)
    check = np.zeros(n_samples, dtype=np.bool_)
    for k in range(n_samples):
        j = jacobian[k]
        a, b, c = j[0, 0], j[0, 1], j[0, 2]
        d, e, f = j[1, 0], j[1, 1], j[1, 2]
        g, h, i = j[2, 0], j[2, 1], j[2, 2]
        c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g
        det = a * c00 + b * c01 + c * c02
        frob = a * a + b * b + c * c + d * d + e * e + f * f + g * g + h * h + i * i
        det_out[k] = det
        if not abs(det) > sigma_min * frob:
            check[k] = True
        if det == 0.0:
            force[k, 0] = force[k, 1] = force[k, 2] = math.nan
            continue
        t0, t1, t2 = tau[k, 0], tau[k, 1], tau[k, 2]
        force[k, 0] = (c00 * t0 + c01 * t1 + c02 * t2) / det
        force[k, 1] = ((c * h - b * i) * t0 + (a * i - c * g) * t1 + (b * g - a * h) * t2) / det
        force[k, 2] = ((b * f - c * e) * t0 + (c * d - a * f) * t1 + (a * e - b * d) * t2) / det
    return force, det_out, check
