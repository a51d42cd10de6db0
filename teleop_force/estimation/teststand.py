"""Foot force of the test stand from joint torques: free-phase identification, slider term.

The leg hangs from a base that slides vertically on an unmeasured prismatic joint. A base
accelerating upwards at ``a`` acts on the leg exactly like extra gravity, so the joint
torques are::

    tau = M(q) qdd + C(q, qd) qd + N(q) (1 + a / g) + tau_f(qd) + J(q)^T F

with ``F`` the force of the foot on the ground. With the foot on the ground, the base moves
with the foot's kinematics: ``z_base = -p_z(q) + const``, so ``a = d/dt v_z`` with
``v_z = -J_z(q) qd`` (the *contact kinematics*). In the filtered (momentum) form of the
project no acceleration is differentiated::

    L(N(q) a) = D_L(N(q) v_z) - L(dN/dt v_z)

and ``N(q) = Y_g(q) beta`` is linear in the base parameters, so the slider term is one more
filtered regressor, added to the rigid-body one. When the foot is off the ground the same
kinematics gives the base acceleration up to the foot's own small motion.

Identification uses the samples without contact only (ATI force below a threshold, with a
guard interval for the filters to forget the contact torques), adjusting the nominal (URDF)
parameters by regularised least squares: the free phases are short, so the nominal values
fill the directions they do not excite. The force is then
``F = (J^T)^+ (L(tau) - tau_model_L)`` at every sample (the batch form of
:class:`~teleop_force.estimation.estimator.ForceEstimator`, which has no slider term), the
friction ramped to 0 in the standstill dead band (at rest under load its Coulomb sign is
unknown). The ATI force only tells the phases without contact; it enters no fit. With the
command line's default friction (``wn``) a wavelet network is trained on those phases, its
fallback the coupled CV of the fit: the 0.1 s flights leave it no trained ground, so the
friction is that CV, and the identification says so in one ``warning`` line instead of
refusing. Held-out figures: :mod:`teleop_force.reports.teststand_heldout`.

Sticking (``TeststandOptions.sticking``, CV friction only): the Coulomb term's ``sgn(qd)`` is
replaced by a Dahl state ``z`` of the pre-filtered angle, ``dz/dq = (1 - z sgn(dq)) / phi``
(the sticking state of :mod:`teleop_force.friction.terms`),
which reaches +-1 within the transition angle ``phi`` of motion and keeps its value at rest:
a leg standing under load keeps the friction of its last motion instead of none (the dead band)
or a sign picked by velocity noise. ``phi`` is identified with the rest on the samples without
contact (the fit's own torque residual, minimised over :data:`STICKING_RANGE_RAD`); the force
sensor picks those samples only.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from teleop_force.errors import ConfigurationError, DataError, SingularityError
from teleop_force.friction.base import FrictionModel
from teleop_force.friction.coulomb_viscous import (
    STICKING_RANGE_RAD,
    CoulombViscous,
    CoupledCoulombViscous,
)
from teleop_force.friction.terms import sticking_states
from teleop_force.identification.dynamic_model import DynamicModel, sticking_rad_of
from teleop_force.identification.filtered_regressor import FilterConfig, FilteredSignals
from teleop_force.identification.prepared import PreparedRecording, prepare
from teleop_force.identification.regressor import (
    BaseParameters,
    RigidBodyRegressor,
    full_parameters,
)
from teleop_force.io.interchange_csv import Recording
from teleop_force.lowpass import filtered_derivative_batch, lowpass_batch
from teleop_force.robots.description import Robot, RobotDescription

_DIRECTIONAL_STEP = 1e-5
#: Standstill dead band of the test stand [rad/s]: the 95th percentile (0.040 rad/s, rounded
#: up) of the fastest joint's encoder-derived speed (200 Hz pre-filter) while the leg stands
#: still in the first two thirds of the shared set (0.3-0.6 s), i.e. the velocity noise at
#: rest; chosen without the force sensor. The held-out error moves by under 0.03 N between
#: 0.01 and 0.3 rad/s (docs/results.md).
STANDSTILL_BAND_RAD_S = 0.05
#: Friction models the test stand is identified with.
FRICTION_KINDS = ("cv", "coupled-cv", "wn")


@dataclass(frozen=True)
class TeststandOptions:
    """How the test-stand force is identified and estimated.

    Attributes:
        filter: Filters (the data is 1 kHz and the contact force changes fast) and the
            standstill dead band: :data:`STANDSTILL_BAND_RAD_S` (at rest under load the
            Coulomb sign is unknown; the friction ramps to 0 below it).
        free_force_n: ATI force magnitude below which the foot is off the ground.
        guard_s: Samples closer than this to a contact sample are not used to identify.
        friction: ``cv``, ``coupled-cv`` or ``wn`` (a wavelet network trained on the samples
            without contact, with the coupled CV fitted with the rigid body as its fallback:
            where the short flights leave no trained ground, the friction is that CV).
        prior_weight: Weight of the nominal parameters against the free-phase data, as a
            fraction of the data's column norms (0: plain least squares).
        slider: Whether the model carries the slider-acceleration term.
        sticking: Whether the Coulomb term is the Dahl sticking state (module doc) rather
            than ``sgn(qd)`` with the dead band; ``cv`` friction only.

    """

    filter: FilterConfig = field(
        default_factory=lambda: FilterConfig(
            cutoff_hz=40.0,
            velocity_cutoff_hz=200.0,
            warmup_s=0.05,
            estimator="filter",
            standstill_band_rad_s=STANDSTILL_BAND_RAD_S,
        )
    )
    free_force_n: float = 1.0
    guard_s: float = 0.02
    friction: str = "cv"
    prior_weight: float = 0.3
    slider: bool = False
    sticking: bool = False

    def __post_init__(self) -> None:
        if not self.free_force_n > 0:
            raise ConfigurationError("free_force_n must be > 0")
        if self.guard_s < 0:
            raise ConfigurationError("guard_s must be >= 0")
        if self.friction not in FRICTION_KINDS:
            raise ConfigurationError(
                f"test-stand friction must be one of {', '.join(FRICTION_KINDS)}"
            )
        if self.prior_weight < 0:
            raise ConfigurationError("prior_weight must be >= 0")
        if self.sticking and self.friction != "cv":
            raise ConfigurationError("the sticking friction goes with cv friction")


@dataclass(frozen=True, eq=False)
class TeststandModel:
    """An identified test-stand model and what the slider term needs.

    Attributes:
        model: The project's model (rigid body, friction); the slider term is not part of it.
        slider: Whether estimates add the slider-acceleration term.
        free_samples: Number of samples identification used.
        details: Figures of the friction fit (the wavelet network's sizes, its fraction on
            trained ground) and ``warning``, one line, when the friction is mostly the CV.

    """

    model: DynamicModel
    slider: bool
    free_samples: int
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def sticking_rad(self) -> float:
        """The Dahl transition angle [rad] of the model's Coulomb terms; 0: ``sgn(qd)``."""
        return sticking_rad_of(self.model.friction)


def free_phase_mask(recording: Recording, free_force_n: float, guard_s: float) -> np.ndarray:
    """Return the samples whose ground-truth force is below ``free_force_n``, ``guard_s`` away."""
    if recording.f_tip_in_base_n is None:
        raise DataError(
            "no ground-truth force to tell the phases without contact (the test stand's "
            "dg_hopper_teststand-ati_force.dat)",
            path=recording.source,
        )
    contact = np.linalg.norm(recording.f_tip_in_base_n, axis=1) >= free_force_n
    t = recording.t_s
    contact_times = t[contact]
    if contact_times.size == 0:
        return np.ones(t.size, dtype=bool)
    nearest = np.searchsorted(contact_times, t)
    before = np.abs(t - contact_times[np.clip(nearest - 1, 0, contact_times.size - 1)])
    after = np.abs(contact_times[np.clip(nearest, 0, contact_times.size - 1)] - t)
    return ~contact & (np.minimum(before, after) > guard_s)


def dahl_state(q_rad: np.ndarray, transition_rad: float) -> np.ndarray:
    """Return the Dahl state of every joint, ``(N, n)`` in [-1, 1], from angles ``(N, n)``.

    The sticking state of the friction terms
    (:func:`~teleop_force.friction.terms.sticking_update_into`, ``dz/dq = (1 - z sgn(dq)) /
    phi`` solved over each step) from ``z_0 = 0``: it follows the path, not the time, so it
    holds its value at rest.
    """
    if not transition_rad > 0:
        raise ConfigurationError(f"transition angle must be > 0, got {transition_rad}")
    q = np.ascontiguousarray(np.asarray(q_rad, dtype=float))
    rows = np.eye(q.shape[1])
    return sticking_states(q, rows, 1.0 / transition_rad, np.zeros(q.shape[0], dtype=bool))


def slider_regressor(
    description: RobotDescription,
    signals: FilteredSignals,
    base: BaseParameters,
    base_velocity_mps: np.ndarray | None = None,
) -> np.ndarray:
    """``L(Y_g(q) a / g)``, the filtered slider-term regressor ``(N, n, r)`` (see module doc).

    The base's vertical velocity is ``base_velocity_mps`` when given (e.g. from the height
    sensor), else the contact kinematics' ``-J_z(q) qd``.
    """
    regressor = RigidBodyRegressor(description)
    robot = Robot(description)
    cols = base.independent
    g = float(np.linalg.norm(description.model.gravity.linear))  # type: ignore[union-attr]
    q, qd = signals.q_rad, signals.qd_rad_s
    n_samples, n = q.shape
    zero = np.zeros(n)
    momentum = np.empty((n_samples, n, cols.size))
    drift = np.empty_like(momentum)
    for k in range(n_samples):
        if base_velocity_mps is None:
            v_z = -(robot.tip_jacobian_in_base(q[k])[2] @ qd[k])
        else:
            v_z = float(base_velocity_mps[k])
        y_g = regressor.coriolis_gravity(q[k], zero)[:, cols]
        momentum[k] = y_g * v_z / g
        speed = float(np.linalg.norm(qd[k]))
        if speed > 0:
            h = _DIRECTIONAL_STEP / speed
            ahead = regressor.coriolis_gravity(q[k] + h * qd[k], zero)[:, cols]
            behind = regressor.coriolis_gravity(q[k] - h * qd[k], zero)[:, cols]
            drift[k] = (ahead - behind) / (2 * h) * v_z / g
        else:
            drift[k] = 0.0
    cutoff = signals.config.cutoff_hz
    return filtered_derivative_batch(momentum, signals.t_s, cutoff) - lowpass_batch(
        drift, signals.t_s, cutoff
    )


def _friction(kind: str, description: RobotDescription) -> FrictionModel:
    """Return the friction fitted with the rigid body (``wn``: its coupled-CV fallback)."""
    if kind == "cv":
        return CoulombViscous(description.n_joints)
    return CoupledCoulombViscous(description.n_joints, description.friction_inputs)


def _design(
    description: RobotDescription,
    recording: Recording,
    options: TeststandOptions,
    base: BaseParameters | None,
    base_velocity_mps: np.ndarray | None = None,
) -> tuple[PreparedRecording, BaseParameters, np.ndarray, np.ndarray, FrictionModel]:
    prepared, found = prepare([recording], description, options.filter, base)
    if found is None:
        raise ConfigurationError(f"{description.name}: no rigid body to identify")
    base = found
    signals = prepared[0].signals
    rigid = signals.rigid_regressor
    if options.slider:
        rigid = rigid + slider_regressor(description, signals, base, base_velocity_mps)
    friction = _friction(options.friction, description)
    n = description.n_joints
    p_f = int(sum(friction.parameter_counts()))
    fric = np.zeros((signals.n_samples, n, p_f))
    for j in range(n):
        basis = lowpass_batch(
            friction.basis(j, signals.qd_rad_s), signals.t_s, options.filter.cutoff_hz
        )
        fric[:, j, friction.joint_slice(j)] = basis
    return prepared[0], base, rigid, fric, friction


def identify_teststand(
    recording: Recording,
    description: RobotDescription,
    options: TeststandOptions | None = None,
    base_velocity_mps: np.ndarray | None = None,
) -> TeststandModel:
    """Identify the leg on the samples without contact (see the module docstring).

    ``base_velocity_mps``: the slider's vertical velocity for the slider term (default: the
    contact kinematics, which off the ground holds only while the foot stays low).
    """
    options = options or TeststandOptions()
    prepared, base, rigid, fric, friction = _design(
        description, recording, options, None, base_velocity_mps
    )
    signals = prepared.signals
    free = free_phase_mask(recording, options.free_force_n, options.guard_s) & signals.valid
    if int(free.sum()) < 10:
        raise DataError(
            f"only {int(free.sum())} samples without contact to identify from",
            path=recording.source,
        )
    torque = signals.tau_lowpassed_nm[free]
    nominal = np.concatenate(
        (base.project(full_parameters(description, np.zeros(0))), np.zeros(fric.shape[2]))
    )
    sticking_rad = 0.0
    if options.sticking:
        sticking_rad, fric = _identify_sticking(
            signals, rigid, fric, friction, free, nominal, options.prior_weight
        )
    regressor = np.concatenate((rigid, fric), axis=2)[free]
    theta = _regularised_fit(regressor, torque, nominal, options.prior_weight)
    r = base.count
    friction.parameters = theta[r:].copy()
    if sticking_rad > 0.0 and isinstance(friction, CoulombViscous):
        friction.set_sticking(sticking_rad)  # the model file carries it: `estimate` runs it
    details: dict[str, Any] = {}
    if options.friction == "wn":
        friction, details = _train_network(
            prepared, description, theta[:r], friction, free, options.slider
        )
    model = DynamicModel(
        robot=description.name,
        n_joints=description.n_joints,
        filter_config=options.filter,
        base=base,
        base_values=theta[:r],
        base_std=np.zeros(r),
        friction=friction,
        offsets_nm=np.zeros(description.n_joints),
        notes={
            "sources": [str(recording.source)],
            "identified_on": f"{int(free.sum())} samples without contact",
            "slider_term": options.slider,
            "prior_weight": options.prior_weight,
            "sticking_rad": sticking_rad,
        },
    )
    return TeststandModel(model, options.slider, int(free.sum()), details)


def _sticking_basis(
    signals: FilteredSignals, fric: np.ndarray, friction: FrictionModel, transition_rad: float
) -> np.ndarray:
    """``fric`` with every joint's filtered ``sgn(qd)`` column replaced by its Dahl state."""
    state = lowpass_batch(
        dahl_state(signals.q_rad, transition_rad), signals.t_s, signals.config.cutoff_hz
    )
    out = fric.copy()
    for j in range(state.shape[1]):
        out[:, j, friction.joint_slice(j).start] = state[:, j]
    return out


def _identify_sticking(
    signals: FilteredSignals,
    rigid: np.ndarray,
    fric: np.ndarray,
    friction: FrictionModel,
    free: np.ndarray,
    nominal: np.ndarray,
    prior_weight: float,
) -> tuple[float, np.ndarray]:
    """Return the transition angle whose fit leaves the least residual without contact."""
    from scipy.optimize import minimize_scalar  # lazy: scipy.optimize is slow to import

    torque = signals.tau_lowpassed_nm[free]

    def residual(log_rad: float) -> float:
        basis = _sticking_basis(signals, fric, friction, 10.0**log_rad)
        regressor = np.concatenate((rigid, basis), axis=2)[free]
        theta = _regularised_fit(regressor, torque, nominal, prior_weight)
        return float(np.sum((torque - np.einsum("kjp,p->kj", regressor, theta)) ** 2))

    low, high = np.log10(STICKING_RANGE_RAD)
    found = minimize_scalar(residual, bounds=(low, high), method="bounded", options={"xatol": 0.01})
    transition_rad = float(10.0**found.x)
    return transition_rad, _sticking_basis(signals, fric, friction, transition_rad)


def _train_network(
    prepared: PreparedRecording,
    description: RobotDescription,
    base_values: np.ndarray,
    fallback: FrictionModel,
    free: np.ndarray,
    slider: bool,
) -> tuple[FrictionModel, dict[str, Any]]:
    """Train a wavelet network on the samples without contact, ``fallback`` inside it."""
    from teleop_force.identification.prepared import WaveletOptions
    from teleop_force.identification.wavelet_training import train_wavelet_network

    if not isinstance(fallback, CoupledCoulombViscous):
        raise ConfigurationError("the wavelet network's fallback must be a coupled CV model")
    if slider:
        raise ConfigurationError("the slider term goes with cv or coupled-cv friction")
    network, details = train_wavelet_network(
        [prepared],
        description,
        base_values,
        np.zeros(description.n_joints),
        fallback,
        WaveletOptions(method="batch"),
        sample_masks=[free],
    )
    return network, details


def nominal_teststand_model(
    description: RobotDescription, options: TeststandOptions | None = None
) -> TeststandModel:
    """Return the URDF (nominal) rigid body without friction: the model before identification."""
    options = options or TeststandOptions()
    regressor = RigidBodyRegressor(description)
    base = regressor.find_base_parameters()
    values = base.project(full_parameters(description, np.zeros(0)))
    friction = _friction(options.friction, description)
    model = DynamicModel(
        robot=description.name,
        n_joints=description.n_joints,
        filter_config=options.filter,
        base=base,
        base_values=values,
        base_std=np.zeros(base.count),
        friction=friction,
        offsets_nm=np.zeros(description.n_joints),
        notes={"nominal": "URDF inertias, no friction"},
    )
    return TeststandModel(model, options.slider, 0)


def _regularised_fit(
    regressor: np.ndarray, torque: np.ndarray, nominal: np.ndarray, weight: float
) -> np.ndarray:
    """Least squares pulled towards ``nominal`` (ridge on the column-scaled parameters)."""
    n_params = regressor.shape[2]
    a = regressor.reshape(-1, n_params)
    b = torque.reshape(-1)
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0.0] = 1.0
    a_scaled = a / scale
    penalty = weight * np.eye(n_params)
    lhs = np.vstack((a_scaled, penalty))
    rhs = np.concatenate((b, penalty @ (nominal * scale)))
    theta_scaled = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return theta_scaled / scale


def estimate_forces(
    identified: TeststandModel,
    recording: Recording,
    description: RobotDescription,
    with_friction: bool = True,
    sigma_min: float = 5e-3,
) -> np.ndarray:
    """Force of the foot on the ground at every sample, base frame (N x 3, NaN if singular)."""
    model = identified.model
    observer = getattr(model.filter_config, "observer", False)
    if observer and not identified.slider:
        from teleop_force.estimation.batch import BatchEstimator

        estimates = BatchEstimator(model).estimate(recording.t_s, recording.q_rad, recording.tau_nm)
        return estimates.force_tip_in_base_n
    options = TeststandOptions(filter=model.filter_config, slider=identified.slider)
    prepared, _, rigid, _, _ = _design(description, recording, options, model.base)
    signals = prepared.signals
    tau_model = np.einsum("kjp,p->kj", rigid, model.base_values)
    if with_friction:
        friction_nm = (
            model.path_friction_torque(signals.q_rad, signals.qd_rad_s)
            if identified.sticking_rad > 0.0
            else _friction_torque(model, signals.qd_rad_s)
        )
        tau_model = tau_model + lowpass_batch(
            friction_nm, signals.t_s, model.filter_config.cutoff_hz
        )
    tau_external = signals.tau_lowpassed_nm - tau_model
    robot = Robot(description)
    forces = np.full((recording.n_samples, 3), np.nan)
    for k in range(recording.n_samples):
        try:
            forces[k] = robot.tip_force_from_joint_torque(
                recording.q_rad[k], tau_external[k], sigma_min
            )
        except SingularityError:
            continue
    return forces


def _friction_torque(model: DynamicModel, qd_rad_s: np.ndarray) -> np.ndarray:
    """Return the friction torque (coverage-blended), ramped to 0 in the standstill band."""
    torque = model.friction_torque(qd_rad_s)
    band = float(getattr(model.filter_config, "standstill_band_rad_s", 0.0))
    if band > 0.0:
        from teleop_force.friction.terms import standstill_factors

        torque = torque * standstill_factors(np.ascontiguousarray(qd_rad_s), band)[:, None]
    return torque


def identify_teststand_command(
    recordings: list[Recording],
    description: RobotDescription,
    friction_kind: str,
    output: str | os.PathLike[str],
    log: Callable[[str], None],
    *,
    sticking: bool = False,
) -> int:
    """``teleop-force identify --robot teststand``: identify on the free phases, save the model.

    ``sticking``: the Coulomb term's sticking state (``TeststandOptions.sticking``, ``cv``).
    """
    if len(recordings) != 1:
        raise ConfigurationError("the test stand is identified from one log folder at a time")
    if friction_kind not in FRICTION_KINDS:
        raise ConfigurationError(
            f"teststand: friction {friction_kind} is not one of {', '.join(FRICTION_KINDS)}"
        )
    identified = identify_teststand(
        recordings[0], description, TeststandOptions(friction=friction_kind, sticking=sticking)
    )
    identified.model.save(Path(output))
    log(f"identified on {identified.free_samples} samples without contact (|F| < 1 N)")
    for key, value in identified.details.items():
        log(f"{key}: {value}")
    log(f"model written to {output}")
    return 0
