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

or, with the model's ``estimator`` ``observer``, ``tau_ext`` the residual of the
generalised-momentum observer (:mod:`teleop_force.estimation.momentum_observer`) on
``p = M(q_v) qd``, ``beta``, friction and the pre-filtered torque, and
``tau_model_L = tau_L - tau_ext``; the observer's pre-filter is its own
(:attr:`~teleop_force.identification.filtered_regressor.FilterConfig.estimator_prefilter`:
one or two first-order stages in cascade; by default one at ``L_v``'s cutoff, as before it).
Below the model's standstill band every friction torque is ramped to 0
(:func:`~teleop_force.friction.terms.standstill_factor`). The filter form is, sample for
sample, the batch computation of
:meth:`~teleop_force.identification.dynamic_model.DynamicModel.predict_filtered_torque`. Found
effects read
``tau<j>`` as the filtered rigid-body model torque ``D_L(M qd) + L(-C^T qd + N + tau_spring)``
of the same sample (as the batch does) and ``t`` as the time since the stream's first sample
(the batch: since the recording's).

Speed: one sample is three-vectors, where NumPy's per-call overhead (~1 µs) dwarfs the
arithmetic. So a sample crosses into compiled code twice (numba,
:mod:`teleop_force.estimation.kernels`), around pinocchio's four calls (``crba``, Coriolis
matrix, gravity, tip Jacobian): :func:`~teleop_force.estimation.kernels.prefilter_step`
(checks, ``L_v``, the velocity) and :func:`~teleop_force.estimation.kernels.finish_step`
(rigid body, ``L``, friction with the coverage blend, offsets, found effects, ``J^-T``), on
preallocated arrays, with the single definitions the batch fit uses
(:mod:`teleop_force.friction.terms`, :mod:`teleop_force.identification.effect_terms`).
:meth:`ForceEstimator.step` returns the output array itself (the service encodes from it);
:meth:`ForceEstimator.update` wraps it in a :class:`ForceEstimate`. See BENCHMARKS.md for the
figures.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from teleop_force.errors import ConfigurationError, DataError, ModelError, SingularityError
from teleop_force.estimation.count_observer import count_observer_step, observer_tables
from teleop_force.estimation.count_observer import state_size as count_state_size
from teleop_force.estimation.fused_step import StepTables, fused_step
from teleop_force.estimation.kernels import (
    RIGID_MATRICES,
    RIGID_NONE,
    STATE_HEAD,
    STEP_NON_FINITE,
    STEP_OK,
    ModelTerms,
    finish_step,
    output_size,
    prefilter_step,
    spring_table,
    state_size,
)
from teleop_force.estimation.rigid_chain import chain_tables
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.regressor import full_parameters
from teleop_force.robots.description import Robot

#: Jacobian singular values below this [m/rad] make the force unobservable: reported, not divided.
DEFAULT_SIGMA_MIN = 5e-3
#: Coverage weight at or above which a joint counts as on trained ground.
TRAINED_GROUND_WEIGHT = 0.5
_TWO_PI = 2.0 * math.pi
_NO_MATRIX = np.zeros((0, 0))
_NO_VECTOR = np.zeros(0)


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


def with_estimator(
    model: DynamicModel,
    estimator: str | None = None,
    observer_hz: float | None = None,
    standstill_band_rad_s: float | None = None,
    *,
    observer_prefilter_hz: float | None = None,
    observer_prefilter_stages: int | None = None,
    observer_output_hz: float | None = None,
    count_observer: bool | None = None,
    count_rad: Sequence[float] | None = None,
) -> DynamicModel:
    """Return ``model`` with its filter configuration's estimator choice overridden.

    ``None`` keeps the model's own value; the result is ``model`` itself when nothing changes.
    Its ``to_dict`` records the estimator that made the estimates. Raises ConfigurationError
    for an unknown estimator or a bandwidth, band or number of stages out of range.
    """
    config = model.filter_config
    wanted: dict[str, Any] = {
        "estimator": estimator,
        "observer_hz": None if observer_hz is None else float(observer_hz),
        "standstill_band_rad_s": (
            None if standstill_band_rad_s is None else float(standstill_band_rad_s)
        ),
        "observer_prefilter_hz": (
            None if observer_prefilter_hz is None else float(observer_prefilter_hz)
        ),
        "observer_prefilter_stages": observer_prefilter_stages,
        "observer_output_hz": None if observer_output_hz is None else float(observer_output_hz),
        "count_observer": None if count_observer is None else bool(count_observer),
        "count_rad": None if count_rad is None else tuple(float(c) for c in count_rad),
    }
    changes = {
        name: value
        for name, value in wanted.items()
        if value is not None and value != getattr(config, name)
    }
    if not changes:
        return model
    return dataclasses.replace(model, filter_config=dataclasses.replace(config, **changes))


def estimator_from_args(model: DynamicModel, args: argparse.Namespace) -> DynamicModel:
    """Return ``model`` with the estimator flags (:mod:`teleop_force.estimation.flags`) applied."""
    return with_estimator(
        model, args.estimator, args.observer_hz,
        observer_prefilter_hz=args.observer_prefilter_hz,
        observer_prefilter_stages=args.observer_prefilter_stages,
        observer_output_hz=args.observer_output_hz, count_observer=args.count_observer,
    )  # fmt: skip


#: The estimator choice a recording's metadata carries (all strings).
_RECORDED_NUMBERS = (
    "observer_hz",
    "standstill_band_rad_s",
    "observer_prefilter_hz",
    "observer_prefilter_stages",
    "observer_output_hz",
)


def estimator_metadata(model: DynamicModel) -> dict[str, str]:
    """Return the estimator choice of ``model`` as recording metadata (strings)."""
    config = model.filter_config
    return {
        "estimator": config.estimator,
        "observer_hz": repr(float(config.observer_hz)),
        "standstill_band_rad_s": repr(float(config.standstill_band_rad_s)),
        "observer_prefilter_hz": repr(float(config.observer_prefilter_cutoff_hz)),
        "observer_prefilter_stages": str(int(config.observer_prefilter_stages)),
        "observer_output_hz": repr(float(config.observer_output_hz)),
        "count_observer": "1" if config.count_observer else "0",
        "count_rad": " ".join(repr(float(c)) for c in config.count_rad),
    }


def with_recorded_estimator(model: DynamicModel, metadata: dict[str, str]) -> DynamicModel:
    """Return ``model`` with the estimator choice a recording's metadata names (if it does).

    A recording made before the observer had its own pre-filter names none: its observer ran
    on ``L_v`` (the model's ``velocity_cutoff_hz``, one stage); one made before the output
    filter names none either: it had none (``observer_output_hz`` 0). Raises
    ConfigurationError for metadata that is not a valid choice.
    """
    numbers: dict[str, float | None] = {}
    for key in _RECORDED_NUMBERS:
        text = metadata.get(key)
        try:
            numbers[key] = None if not text else float(text)
        except ValueError:
            raise ConfigurationError(f"recording metadata {key}={text!r} is not a number") from None
    stages = numbers["observer_prefilter_stages"]
    prefilter_hz = numbers["observer_prefilter_hz"]
    if metadata.get("estimator") and prefilter_hz is None:  # recorded before the field
        prefilter_hz = model.filter_config.velocity_cutoff_hz
        stages = 1.0
    output_hz = numbers["observer_output_hz"]
    if metadata.get("estimator") and output_hz is None:  # recorded before the field
        output_hz = 0.0
    if stages is not None and stages not in (1.0, 2.0):
        raise ConfigurationError(f"recording metadata observer_prefilter_stages={stages!r}")
    count_observer, count_rad = _recorded_counts(metadata)
    return with_estimator(
        model, metadata.get("estimator") or None, numbers["observer_hz"],
        numbers["standstill_band_rad_s"], observer_prefilter_hz=prefilter_hz,
        observer_prefilter_stages=None if stages is None else int(stages),
        observer_output_hz=output_hz, count_observer=count_observer, count_rad=count_rad,
    )  # fmt: skip


def _recorded_counts(metadata: dict[str, str]) -> tuple[bool | None, tuple[float, ...] | None]:
    """Return the count observer a recording's metadata names (off if recorded before it)."""
    flag = metadata.get("count_observer")
    if flag is None:
        return (False, None) if metadata.get("estimator") else (None, None)
    if flag not in ("0", "1"):
        raise ConfigurationError(f"recording metadata count_observer={flag!r} is not 0 or 1")
    text = metadata.get("count_rad", "")
    try:
        counts = tuple(float(c) for c in text.split())
    except ValueError:
        raise ConfigurationError(f"recording metadata count_rad={text!r}") from None
    return flag == "1", counts or None


def equivalent_rigid_body(model: DynamicModel) -> tuple[Robot | None, np.ndarray]:
    """Return the robot whose full parameters represent the model's base ones, and its springs.

    What :class:`ForceEstimator` and the batch form run: ``None`` (and no springs) for a model
    without rigid-body terms.
    """
    description = model.description()
    if not (description.has_rigid_body and model.base is not None):
        return None, np.zeros(len(description.springs))
    n = model.n_joints
    nominal = full_parameters(description, np.zeros(len(description.springs)))
    n_links = 10 * description.n_links
    # pinocchio's composite inertias need positive subtree masses
    full = model.base.representative_with_masses(model.base_values, nominal, range(0, n_links, 10))
    equivalent = description.with_link_parameters(full[:n_links]).with_rotor_inertia(
        full[n_links : n_links + n]
    )
    return Robot(equivalent), full[n_links + n :]


class _PinocchioTerms:
    """The pinocchio model and data of the equivalent rigid body, and the tip frame."""

    def __init__(self, robot: Robot) -> None:
        self.model = robot.model
        self.data = robot.model.createData()
        tip_frame = robot.description.tip_frame
        self.tip = -1 if tip_frame is None else robot.model.getFrameId(tip_frame)


@dataclass(frozen=True, eq=False)
class _CountObserver:
    """The count observer's state, output and arguments in a :class:`ForceEstimator`."""

    state: np.ndarray
    out: np.ndarray
    arguments: tuple[Any, ...]

    @staticmethod
    def create(estimator: ForceEstimator) -> _CountObserver:
        """Build it for ``estimator``'s model (ConfigurationError without counts or a body)."""
        model, n, robot = estimator.model, estimator.n, estimator.robot
        counts = model.filter_config.count_rad
        if robot is None:
            raise ConfigurationError(
                f"{model.robot}: the count observer needs a model with rigid-body terms"
            )
        if len(counts) != n:
            raise ConfigurationError(
                f"the count observer needs the filter's count_rad, one per joint (got {counts})"
            )
        chain = estimator._chain
        if chain is None:
            raise ConfigurationError(
                f"{model.robot}: the count observer needs a chain of revolute or prismatic joints"
            )
        out = np.zeros(n)
        floats, ints, scratch = observer_tables(
            np.array(counts), chain, estimator._coupling, estimator._rotor, estimator._springs,
            estimator._terms,
        )  # fmt: skip
        arguments = (floats, ints, scratch, out)
        return _CountObserver(np.zeros(count_state_size(n)), out, arguments)


class ForceEstimator:
    """Streaming estimator of the tip contact force from joint angles and motor torques."""

    def __init__(
        self, model: DynamicModel, sigma_min: float = DEFAULT_SIGMA_MIN, *, fused: bool = True
    ) -> None:
        """Build the equivalent rigid-body model and the filters.

        ``fused``: run each sample in one compiled call (:mod:`~teleop_force.estimation.
        fused_step`) where the model allows it (a rigid body its kinematic chain encodes, a
        friction with a term encoding); False: always the two halves around pinocchio (the
        reference the fused step is tested against). With the model's count observer
        (:mod:`~teleop_force.estimation.count_observer`) every sample's angles are the
        observer's; ConfigurationError if the model gives no ``count_rad`` or no rigid body.
        """
        self.model = model
        self.n = model.n_joints
        self.sigma_min = sigma_min
        self.robot, self.spring_stiffness = equivalent_rigid_body(model)
        self._rigid = None if self.robot is None else _PinocchioTerms(self.robot)
        self._has_tip = self.robot is not None and self.robot.description.tip_frame is not None
        #: whether the compiled step computes ``F`` (three joints); else :class:`Robot` does
        self._tip_kernel = self._has_tip and self.n == 3
        self._terms = ModelTerms(model)
        config = model.filter_config
        self._lag = int(config.torque_lag_samples)
        prefilter_hz, self._prefilter_stages = config.estimator_prefilter
        self._omega_v = _TWO_PI * prefilter_hz
        self._omega = _TWO_PI * config.cutoff_hz
        self._observer = config.observer
        self._omega_observer = _TWO_PI * config.observer_hz
        self._omega_output = _TWO_PI * config.estimator_output_hz
        self._allocate()
        robot = self.robot
        #: The kinematic chain in arrays (None without a body, or for joints it does not encode)
        self._chain = (
            None if robot is None else chain_tables(robot.model, robot.description.tip_frame)
        )
        self._counts = _CountObserver.create(self) if config.count_observer else None
        self._tables = self._fused_tables() if fused else None
        #: The fused step's table arguments and, after them, its full argument tail (kept
        #: until the tables are repacked: no tuple built per sample).
        self._call_arguments: tuple[Any, tuple[Any, ...]] = (None, ())
        self.reset()

    @property
    def fused(self) -> bool:
        """Whether :meth:`step` runs the one-call compiled step."""
        return self._tables is not None

    def _fused_tables(self) -> StepTables | None:
        robot = self.robot
        if robot is None:
            return None
        try:
            self._terms.arguments()
        except ModelError:  # e.g. a network without fallback: raised by step, as the halves do
            return None
        return StepTables.create(
            self._terms, self._chain,
            coupling=self._coupling, rotor=self._rotor, springs=self._springs,
            omega_v=self._omega_v, prefilter_stages=self._prefilter_stages, omega=self._omega,
            omega_observer=self._omega_observer, omega_output=self._omega_output,
            observer=self._observer, lag=self._lag,
            sigma_min=self.sigma_min, tip=self._tip_kernel,
        )  # fmt: skip

    def _allocate(self) -> None:
        """Preallocate the step's state, inputs, pinocchio inputs and outputs."""
        n = self.n
        robot = self.robot
        coupling = np.eye(n) if robot is None else robot.coupling
        self._coupling = np.ascontiguousarray(coupling, dtype=float)
        n_model = self._coupling.shape[0]
        self._rotor = (
            np.zeros(n)
            if robot is None
            else np.ascontiguousarray(robot.description.rotor_inertia_kgm2, dtype=float)
        )
        springs = [] if robot is None else robot.description.springs
        self._springs = spring_table(
            [s.joint for s in springs], self.spring_stiffness, [s.rest_angle_rad for s in springs]
        )
        self._state = np.zeros(state_size(n, self._terms.sticking_terms))
        self._qd_slice = slice(STATE_HEAD + 7 * n, STATE_HEAD + 8 * n)
        self._sample = np.zeros(1 + 2 * n)
        self._q_model = np.zeros(n_model)
        self._v_model = np.zeros(n_model)
        self._q_jacobian = np.zeros(n_model)
        self._jacobian_motor = np.zeros((3, 3))
        self._scratch = np.zeros(7 * n + self._terms.work.size)
        self._out = np.zeros(output_size(n))

    def reset(self) -> None:
        """Forget all filter state (start of a new stream)."""
        self._state[:] = 0.0
        if self._counts is not None:
            self._counts.state[:] = 0.0

    def step(
        self, t_s: float, q_rad: Sequence[float] | np.ndarray, tau_nm: Sequence[float] | np.ndarray
    ) -> np.ndarray:
        """Feed one sample; return the step's output array (overwritten by the next call).

        ``[F (3), tau_ext (n), tau_motor_filtered (n), tau_model_filtered (n), coverage
        weight (n), singular (0/1)]``: the fields of :class:`ForceEstimate` without copies, for
        callers at 1 kHz (the service). Raises DataError on a bad sample (state untouched).
        ``q_rad`` and ``tau_nm``: arrays or tuples of floats (the fastest), or sequences.
        """
        counts = self._counts
        if counts is not None:  # the count observer's angles replace the readings
            self._compiled(count_observer_step, counts.state, t_s, q_rad, tau_nm, counts.arguments)
            q_rad = counts.out
        return self._step_on_angles(t_s, q_rad, tau_nm)

    def warm_up(self, part: str = "all") -> None:
        """Compile (or load from numba's cache) what :meth:`step` runs on tuples, then reset.

        The service's samples are tuples of floats, and numba compiles one specialisation per
        argument type: this runs exactly those. ``part``: ``"all"``, ``"observer"`` (the count
        observer alone) or ``"step"`` (the rest), so that two processes can compile them in
        parallel (:mod:`teleop_force.process.warm_up`). ConfigurationError for another part.
        """
        if part not in ("all", "observer", "step"):
            raise ConfigurationError(f"warm_up: part is all, observer or step, got {part!r}")
        rest = (0.0,) * self.n
        counts = self._counts
        with contextlib.suppress(DataError):  # at q = 0 the Jacobian may be singular: no matter
            for k in range(2):
                if part == "all":
                    self.step(k * 1e-3, rest, rest)
                elif part == "observer" and counts is not None:
                    self._compiled(
                        count_observer_step, counts.state, k * 1e-3, rest, rest, counts.arguments
                    )
                elif part == "step":
                    self._step_on_angles(k * 1e-3, rest if counts is None else counts.out, rest)
        self.reset()

    def _step_on_angles(
        self, t_s: float, q_rad: Sequence[float] | np.ndarray, tau_nm: Sequence[float] | np.ndarray
    ) -> np.ndarray:
        """:meth:`step` after the count observer (``q_rad``: the angles the step runs on)."""
        tables = self._tables
        if tables is not None:
            return self._fused_step(tables, t_s, q_rad, tau_nm)
        n = self.n
        sample = self._sample
        try:
            sample[0] = t_s
            sample[1 : 1 + n] = q_rad
            sample[1 + n :] = tau_nm
        except (TypeError, ValueError) as exc:
            raise DataError(f"expected {n} joint angles and torques: {exc}") from exc
        code = prefilter_step(
            self._state, sample, self._omega_v, self._prefilter_stages, self._coupling,
            self._q_model, self._v_model, self._q_jacobian,
        )  # fmt: skip
        if code != STEP_OK:
            raise self._step_error(code, t_s)
        rigid = self._rigid
        if rigid is not None:
            model, data = rigid.model, rigid.data
            mass = pin.crba(model, data, self._q_model)  # upper triangle is valid
            coriolis = pin.computeCoriolisMatrix(model, data, self._q_model, self._v_model)
            gravity = pin.computeGeneralizedGravity(model, data, self._q_model)
            jacobian = (
                pin.computeFrameJacobian(
                    model, data, self._q_jacobian, rigid.tip, pin.LOCAL_WORLD_ALIGNED
                )
                if self._tip_kernel
                else _NO_MATRIX
            )
        else:
            mass = coriolis = jacobian = _NO_MATRIX
            gravity = _NO_VECTOR
        terms = self._terms
        extra = _NO_VECTOR
        if terms.python_friction:
            qd = self._state[self._qd_slice]
            torque, weight = terms.python_terms(qd)
            extra = np.concatenate((torque, weight))
        out = self._out
        finish_step(
            self._state, sample, self._omega, self._lag, self._observer, self._omega_observer,
            self._omega_output, RIGID_NONE if rigid is None else RIGID_MATRICES, self._v_model,
            mass, coriolis, gravity, self._coupling, self._rotor, self._springs,
            self._tip_kernel, jacobian, self._jacobian_motor, self.sigma_min, extra,
            self._scratch, out, *terms.arguments(),
        )  # fmt: skip
        if self._has_tip and not self._tip_kernel:
            self._tip_force_python(q_rad, out)
        return out

    def _fused_step(
        self,
        tables: StepTables,
        t_s: float,
        q_rad: Sequence[float] | np.ndarray,
        tau_nm: Sequence[float] | np.ndarray,
    ) -> np.ndarray:
        """:meth:`step` in one compiled call."""
        tables.refresh()
        arguments = self._call_arguments
        if arguments[0] is not tables.call_arguments:  # the tables were repacked
            arguments = self._call_arguments = (
                tables.call_arguments,
                (*tables.call_arguments, self._out),
            )
        q_rad = self._compiled(fused_step, self._state, t_s, q_rad, tau_nm, arguments[1])
        if self._has_tip and not self._tip_kernel:
            self._tip_force_python(q_rad, self._out)
        return self._out

    def _compiled(
        self,
        kernel: Any,
        state: np.ndarray,
        t_s: float,
        q_rad: Sequence[float] | np.ndarray,
        tau_nm: Sequence[float] | np.ndarray,
        arguments: tuple[Any, ...],
    ) -> Sequence[float] | np.ndarray:
        """Run a compiled step on one sample; return the angles as it took them.

        Arrays and tuples of floats go in as they are (the service's tuples: no conversion at
        1 kHz); anything else, or a tuple the kernel refuses, is converted first. DataError
        for a wrong number of joints or a bad sample (the kernel leaves its state untouched).
        """
        if not isinstance(q_rad, (tuple, np.ndarray)) or not isinstance(
            tau_nm, (tuple, np.ndarray)
        ):
            q_rad, tau_nm = self._as_arrays(q_rad, tau_nm)
        try:
            code = kernel(state, t_s, q_rad, tau_nm, *arguments)
        except ValueError as exc:  # a wrong number of joints
            raise DataError(f"expected {self.n} joint angles and torques: {exc}") from exc
        except Exception:  # e.g. a tuple holding something other than floats
            q_rad, tau_nm = self._as_arrays(q_rad, tau_nm)
            code = kernel(state, t_s, q_rad, tau_nm, *arguments)
        if code != STEP_OK:
            raise self._step_error(code, t_s)
        return q_rad

    def _as_arrays(
        self, q_rad: Sequence[float] | np.ndarray, tau_nm: Sequence[float] | np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Float arrays of one sample's angles and torques (DataError for anything else)."""
        try:
            q = np.asarray(q_rad, dtype=float).reshape(-1)
            tau = np.asarray(tau_nm, dtype=float).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise DataError(f"expected {self.n} joint angles and torques: {exc}") from exc
        if q.size != self.n or tau.size != self.n:
            raise DataError(f"expected {self.n} joint angles and torques")
        return q, tau

    def _step_error(self, code: int, t_s: float) -> DataError:
        if code == STEP_NON_FINITE:
            return DataError("non-finite joint angle, torque or time")
        return DataError(f"time does not increase ({t_s} after {self._state[1]})")

    def _tip_force_python(self, q_rad: Sequence[float] | np.ndarray, out: np.ndarray) -> None:
        """``F`` of a robot other than three joints (least squares, :class:`Robot`)."""
        n = self.n
        assert self.robot is not None
        try:
            out[:3] = self.robot.tip_force_from_joint_torque(
                np.asarray(q_rad, dtype=float), out[3 : 3 + n].copy(), self.sigma_min
            )
            out[3 + 4 * n] = 0.0
        except SingularityError:
            out[:3] = math.nan
            out[3 + 4 * n] = 1.0

    def update(self, t_s: float, q_rad: np.ndarray, tau_nm: np.ndarray) -> ForceEstimate:
        """Feed one sample (time, measured angles, commanded motor torques)."""
        n = self.n
        q_arr = np.asarray(q_rad, dtype=float)
        tau_arr = np.asarray(tau_nm, dtype=float)
        if q_arr.shape != (n,) or tau_arr.shape != (n,):
            raise DataError(f"expected {n} joint angles and torques")
        out = self.step(float(t_s), q_arr, tau_arr).copy()
        coverage = out[3 + 3 * n : 3 + 4 * n]
        return ForceEstimate(
            float(t_s),
            out[:3],
            out[3 : 3 + n],
            out[3 + n : 3 + 2 * n],
            out[3 + 2 * n : 3 + 3 * n],
            coverage,
            coverage >= TRAINED_GROUND_WEIGHT,
            bool(out[3 + 4 * n]),
        )
