"""From recordings to a :class:`DynamicModel`, and back to figures.

Identification runs in two stages, as in the paper: the rigid-body base parameters are fitted
together with a Coulomb-viscous (or coupled) friction that absorbs friction "noise" (with the
guards of :mod:`teleop_force.identification.rigid_body_fit`: zero-phase smoothed angles and nuisance
low-speed friction terms, then the CV friction refitted on the causal signals with the rigid
body fixed); a wavelet-network friction is then trained on what the rigid-body model leaves
(the filtered friction torque), with the stage-one coupled CV kept as its off-ground fallback.
Identification with the network never refuses for lack of data: where its coverage map has
no trained ground the model's friction is that fitted CV, and ``FitReport.details["warning"]``
says so in one line (the command line prints it as ``warning: ...``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from teleop_force.errors import ConfigurationError
from teleop_force.friction.base import FrictionModel
from teleop_force.friction.coulomb_viscous import (
    STICKING_RANGE_RAD,
    CoulombViscous,
    CoupledCoulombViscous,
    TermTableFriction,
)
from teleop_force.friction.kinds import FrictionKind
from teleop_force.friction.model_coordinates import ModelCoordinateFriction
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.encoder_count import measured_count_rad, with_count_observer
from teleop_force.identification.filtered_regressor import (
    FilterConfig,
    FilteredSignals,
)
from teleop_force.identification.least_squares import Identification, least_squares, relative_rms
from teleop_force.identification.prepared import PreparedRecording, WaveletOptions, prepare
from teleop_force.identification.regressor import BaseParameters, RigidBodyRegressor
from teleop_force.identification.rigid_body_fit import RigidBodyFitOptions, fit_rigid_body
from teleop_force.io.interchange_csv import Recording
from teleop_force.lowpass import lowpass_batch
from teleop_force.robots.description import RobotDescription


@dataclass(frozen=True, eq=False)
class FitReport:
    """What identification produced besides the model.

    ``rigid`` is the rigid-body fit (base parameters first); ``stage_one`` the fit of the
    stage-one CV friction (and offsets) with the rigid body fixed, None when both were fitted
    together (no rigid body, or :meth:`RigidBodyFitOptions.plain`).
    """

    rigid: Identification
    friction_relative_rms: np.ndarray
    details: dict[str, Any] = field(default_factory=dict)
    stage_one: Identification | None = None


def stage_one_friction(friction_kind: FrictionKind, description: RobotDescription) -> FrictionModel:
    """Return the friction fitted with the rigid body.

    CV (``cv``), friction in model coordinates through the description's coupling
    (``model-cv``), or else (``coupled-cv``, and ``wn``'s fallback) the coupled CV.
    """
    match friction_kind:
        case FrictionKind.CV:
            return CoulombViscous(description.n_joints)
        case FrictionKind.MODEL_CV:
            return ModelCoordinateFriction(description.coupling)
        case _:
            return CoupledCoulombViscous(description.n_joints, description.friction_inputs)


#: How much lower (relative) the friction fit's mean squared relative residual must be with a
#: sticking state than with ``sgn(w)`` for ``identify_model(sticking=True)`` to keep it.
STICKING_MIN_GAIN = 0.1


def _friction_regressor(friction: FrictionModel, signals: FilteredSignals) -> np.ndarray:
    """Return the filtered friction regressor ``(N, n, p_f)`` of a recording (along its path)."""
    raw = (
        friction.path_regressor(signals.q_rad, signals.qd_rad_s)
        if isinstance(friction, TermTableFriction)
        else friction.regressor(signals.qd_rad_s)
    )
    flat = lowpass_batch(raw.reshape(raw.shape[0], -1), signals.t_s, signals.config.cutoff_hz)
    return flat.reshape(raw.shape)


def _friction_columns(
    item: PreparedRecording, friction: FrictionModel, with_offsets: bool
) -> np.ndarray:
    """Friction (and offset) columns ``(N_valid, n, p_f [+ n])`` of one recording."""
    s = item.signals
    fric = _friction_regressor(friction, s)[s.valid]
    if not with_offsets:
        return fric
    n = friction.n_joints
    return np.concatenate((fric, np.broadcast_to(np.eye(n), (fric.shape[0], n, n))), axis=2)


def _stack_regressor(
    prepared: Sequence[PreparedRecording], friction: FrictionModel, with_offsets: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Joint regressor ``(N, n, r + p_f [+ n])`` and filtered torque over the valid samples."""
    blocks = [
        np.concatenate(
            (item.signals.rigid_regressor[item.signals.valid],
             _friction_columns(item, friction, with_offsets)),
            axis=2,
        )
        for item in prepared
    ]  # fmt: skip
    torques = [item.signals.tau_lowpassed_nm[item.signals.valid] for item in prepared]
    return np.concatenate(blocks), np.concatenate(torques)


def _friction_block(
    prepared: Sequence[PreparedRecording], friction: FrictionModel, with_offsets: bool
) -> np.ndarray:
    """Return the friction (and offset) columns of :func:`_stack_regressor` alone."""
    return np.concatenate([_friction_columns(item, friction, with_offsets) for item in prepared])


def choose_sticking(
    prepared: Sequence[PreparedRecording],
    friction: TermTableFriction,
    friction_torque: np.ndarray,
    names: list[str],
    with_offsets: bool,
) -> tuple[float, Identification, dict[str, float]]:
    """Pick the Coulomb terms' sticking transition angle on the identification's own motion.

    Fits the friction (and offsets) to ``friction_torque`` (the stacked valid samples' torque
    less the rigid body) with ``sgn(w)`` and with the Dahl state of every transition angle in
    :data:`STICKING_RANGE_RAD` (bounded search on its logarithm), scored by the mean over the
    joints of the squared relative residual. Keeps the best angle if it scores
    :data:`STICKING_MIN_GAIN` lower than ``sgn(w)``, else 0. Returns the angle (also set on
    ``friction``), that fit and the two scores.
    """
    from scipy.optimize import minimize_scalar  # lazy: scipy.optimize is slow to import

    def fit(transition_rad: float) -> tuple[float, Identification]:
        friction.set_sticking(transition_rad)
        result = least_squares(
            _friction_block(prepared, friction, with_offsets), friction_torque, names
        )
        return float(np.mean(result.relative_rms**2)), result

    sign_score, sign_fit = fit(0.0)
    low, high = np.log10(STICKING_RANGE_RAD)
    found = minimize_scalar(
        lambda x: fit(10.0**x)[0], bounds=(low, high), method="bounded", options={"xatol": 0.02}
    )
    transition_rad = float(10.0**found.x)
    score, result = fit(transition_rad)
    scores = {"sign": sign_score, "sticking": score, "transition_rad": transition_rad}
    if score <= (1.0 - STICKING_MIN_GAIN) * sign_score:
        return transition_rad, result, scores
    friction.set_sticking(0.0)
    return 0.0, sign_fit, scores


def identify_model(
    recordings: Sequence[Recording],
    description: RobotDescription,
    friction_kind: FrictionKind = FrictionKind.WN,
    config: FilterConfig | None = None,
    wavelet: WaveletOptions | None = None,
    rigid_body: RigidBodyFitOptions | None = None,
    offsets: bool | None = None,
    sticking: bool = False,
    count_observer: bool = False,
) -> tuple[DynamicModel, FitReport]:
    """Identify rigid-body parameters and friction from recordings.

    ``offsets``: fit a constant torque per joint with the friction (the data authors'
    Coulomb + viscous + offset); None fits them only without rigid-body terms. A
    ``friction_kind`` given by its name is parsed (:class:`ConfigurationError` if unknown).
    ``sticking``: give the Coulomb terms of the stage-one CV (``wn``: the network's fallback,
    chosen before the network is trained on what it leaves) a sticking state if the motion
    says so (:func:`choose_sticking`, the friction refitted with the rigid body held);
    ConfigurationError with ``model-cv``. ``count_observer``: the model estimates on the
    count observer's angles, with the encoder count measured on the recordings and the
    estimator that goes with it (:func:`~teleop_force.identification.encoder_count.
    with_count_observer`); ConfigurationError without rigid-body terms.
    """
    friction_kind = FrictionKind.parse(friction_kind)
    if count_observer and not description.has_rigid_body:
        raise ConfigurationError("the count observer needs a robot with rigid-body terms")
    if sticking and friction_kind is FrictionKind.MODEL_CV:
        raise ConfigurationError("a sticking state goes with cv, coupled-cv or wn friction")
    config = config or FilterConfig()
    rigid_body = rigid_body or RigidBodyFitOptions()
    prepared, base = prepare(recordings, description, config)
    stage_one = stage_one_friction(friction_kind, description)
    with_offsets = not description.has_rigid_body if offsets is None else offsets
    regressor, torque = _stack_regressor(prepared, stage_one, with_offsets)
    names = list(base.names() if base is not None else [])
    names += stage_one.all_parameter_names()
    if with_offsets:
        names += [f"offset_{j + 1}" for j in range(description.n_joints)]
    r = 0 if base is None else base.count
    p_f = stage_one.parameters.size
    stage_one_fit: Identification | None = None
    if base is not None and rigid_body != RigidBodyFitOptions.plain():
        rigid = fit_rigid_body(
            recordings, description, base, stage_one, config, rigid_body, with_offsets
        )
        rigid_fit = rigid.identification
        base_values, base_std = rigid.base_values.copy(), rigid.base_std.copy()
        friction_torque = torque - np.einsum("kjp,p->kj", regressor[:, :, :r], base_values)
        stage_one_fit = least_squares(regressor[:, :, r:], friction_torque, names[r:])
        friction_values = stage_one_fit.parameters
    else:
        rigid_fit = least_squares(regressor, torque, names)
        base_values = rigid_fit.parameters[:r]
        base_std = rigid_fit.standard_deviations[:r]
        friction_values = rigid_fit.parameters[r:]
    stage_one.parameters = friction_values[:p_f].copy()
    offsets_nm = friction_values[p_f:] if with_offsets else np.zeros(description.n_joints)
    details: dict[str, Any] = {"stage_one_friction": stage_one.kind}
    if sticking and isinstance(stage_one, TermTableFriction):
        rest = torque - np.einsum("kjp,p->kj", regressor[:, :, :r], base_values)
        transition, stage_one_fit, scores = choose_sticking(
            prepared, stage_one, rest, names[r:], with_offsets
        )
        stage_one.parameters = stage_one_fit.parameters[:p_f].copy()
        if with_offsets:
            offsets_nm = stage_one_fit.parameters[p_f:]
        details["sticking_rad"] = transition
        details["sticking_scores"] = scores
    friction: FrictionModel = stage_one
    if friction_kind is FrictionKind.WN:
        from teleop_force.identification.wavelet_training import train_wavelet_network

        if not isinstance(stage_one, CoupledCoulombViscous):
            raise ConfigurationError("the wavelet network's fallback must be a coupled CV model")
        friction, wn_details = train_wavelet_network(
            prepared,
            description,
            base_values,
            offsets_nm,
            stage_one,
            wavelet or WaveletOptions(),
            typical_inertia(prepared, description, base, base_values),
        )
        details.update(wn_details)
    model = DynamicModel(
        robot=description.name,
        n_joints=description.n_joints,
        filter_config=config,
        base=base,
        base_values=base_values,
        base_std=base_std,
        friction=friction,
        offsets_nm=np.asarray(offsets_nm, dtype=float),
        notes={
            "sources": [str(p.recording.source) for p in prepared],
            "training_relative_rms": rigid_fit.relative_rms.tolist(),
            "condition_number": rigid_fit.condition_number,
        },
    )
    training = evaluate_prepared(model, prepared)
    if count_observer:
        counts = measured_count_rad([p.recording.q_rad for p in prepared])
        details["count_rad"] = counts.tolist()
        model = dataclasses.replace(
            model, filter_config=with_count_observer(config, counts.tolist())
        )
    return model, FitReport(rigid_fit, training["relative_rms"], details, stage_one_fit)


def typical_inertia(
    prepared: Sequence[PreparedRecording],
    description: RobotDescription,
    base: BaseParameters | None,
    base_values: np.ndarray,
) -> np.ndarray | None:
    """Diagonal of the identified ``M(q)`` at the median pose of the data (None without one)."""
    if base is None or not description.has_rigid_body:
        return None
    q_median = np.median(np.concatenate([p.signals.q_rad for p in prepared]), axis=0)
    regressor = RigidBodyRegressor(description)
    n = description.n_joints
    diag = np.array(
        [
            regressor.momentum(q_median, np.eye(n)[j])[j, base.independent] @ base_values
            for j in range(n)
        ]
    )
    return np.clip(diag, 1e-6, None)


def evaluate_prepared(
    model: DynamicModel, prepared: Sequence[PreparedRecording], blend: bool = True
) -> dict[str, Any]:
    """Relative RMS per joint of the reverse torque computation, adaptation off.

    ``blend=False`` evaluates a wavelet network alone, without falling back to its coupled
    CV off the trained ground (the paper's pure WN).
    """
    measured, estimated, qd = [], [], []
    for item in prepared:
        s = item.signals
        tau_hat = model.predict_filtered_torque(s, item.recording.tau_nm, blend=blend)
        measured.append(s.tau_lowpassed_nm[s.valid])
        estimated.append(tau_hat[s.valid])
        qd.append(s.qd_rad_s[s.valid])
    m, e, v = np.concatenate(measured), np.concatenate(estimated), np.concatenate(qd)
    coverage = model.friction.coverage_weight(v)
    return {
        "relative_rms": relative_rms(m, e),
        "samples": int(m.shape[0]),
        "coverage": (coverage >= 0.5).mean(axis=0),
        "measured": m,
        "estimated": e,
    }


def evaluate_model(
    model: DynamicModel, recordings: Sequence[Recording], blend: bool = True
) -> dict[str, Any]:
    """Evaluate ``model`` on recordings (the ``evaluate`` command)."""
    prepared, _ = prepare(recordings, model.description(), model.filter_config, model.base)
    return evaluate_prepared(model, prepared, blend)
