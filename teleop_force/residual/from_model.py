"""Close the loop from a model in hand: what today's data show that the model lacks.

:func:`trace_from_model` keeps every identified parameter of the model (rigid body, friction,
offsets, its effects), takes the residual of the new recordings against it (the filtered
motor torque minus the model's filtered torque, as ``evaluate`` computes it) and runs the
search of :mod:`teleop_force.residual.loop` on that residual alone: nothing the model knew
is refitted, so an effect present in all of today's data cannot hide in the model's own
parameters. Besides the loop's candidates, a change of each joint's own friction (viscous,
Coulomb) is offered, and on a robot with a body a payload: a change of the last link's
inertial parameters (:mod:`teleop_force.residual.payload`).

Before: the model as given, on all the selected samples (it was not fitted on them). After:
the found effects by blocked cross-validation, as in the loop. The extended model is the
given one with the payload's base-parameter change and the new effects, their coefficients
fitted together on all valid samples of the residual.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from teleop_force.friction.kinds import FrictionKind
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import FoundEffect
from teleop_force.identification.least_squares import least_squares
from teleop_force.identification.prepared import PreparedRecording, prepare
from teleop_force.io.interchange_csv import Recording
from teleop_force.lowpass import lowpass_batch
from teleop_force.residual.controls import friction_stand_in_columns, velocity_controls
from teleop_force.residual.options import EffectPlacement, ResidualOptions
from teleop_force.residual.payload import PayloadCandidate, payload_candidate
from teleop_force.residual.placement import effect_reaches, placed_columns
from teleop_force.residual.report import ResidualReport, TracedEffect, TracedPayload
from teleop_force.residual.samples import SelectedSamples, filtered_columns, select_samples
from teleop_force.residual.scoring import JointDesign, WholeModelCheck
from teleop_force.robots.description import RobotDescription

__all__ = ["trace_from_model"]


@dataclass(frozen=True, eq=False)
class ModelResidual:
    """The residual of the selected samples against the model, and the torque it is of."""

    #: Filtered motor torque minus the model's filtered torque, ``(rows, n)``.
    residual_nm: np.ndarray
    #: Sum of squares of the filtered motor torque per joint (relative RMS divides by it).
    torque_energy: np.ndarray


def trace_from_model(
    recordings: Sequence[Recording],
    model: DynamicModel,
    options: ResidualOptions | None = None,
    model_path: str | None = None,
) -> ResidualReport:
    """Find what ``model`` lacks on ``recordings``, add it, report before and after.

    ``options.friction`` and ``options.offsets`` are not used (the model's are kept);
    ``model_path`` is reported as the baseline model.
    """
    from teleop_force.residual.loop import Scorers, _search

    options = options or ResidualOptions()
    description = model.description()
    prepared, _ = prepare(recordings, description, model.filter_config, model.base)
    samples = select_samples(prepared, options, model.base_values)
    known = model_residual(samples, model)
    designs = _joint_designs(known, samples, options)
    scorers = Scorers(
        designs=tuple(designs),
        controls=tuple(
            _control_design(samples, design, j, description, options)
            for j, design in enumerate(designs)
        ),
        check=_whole_check(known, samples.folds, options.folds, options),
        veto=None
        if samples.holdout_folds is None
        else _whole_check(known, *samples.holdout_folds, options),
        covered=tuple(() for _ in range(model.n_joints)),
        reaches=tuple(_reaches(model, description, options)),
        placement=_placement(model, options),
        payload=payload_candidate(samples, model.base, description),
        friction_changes=True,
    )
    search = _search(samples, scorers, options, offsets=False)
    extended, payload = extended_model(
        model, prepared, search.accepted, search.payload, scorers.payload
    )
    return ResidualReport(
        before=search.before,
        after=search.after,
        effects=search.accepted,
        model=extended,
        samples=int(samples.folds.size),
        history=search.history,
        effect_plots=search.plots,
        rejected=search.rejected,
        payload=payload,
        baseline_model=model_path or "<model>",
    )


def model_residual(samples: SelectedSamples, model: DynamicModel) -> ModelResidual:
    """Residual of the selected samples against ``model`` (its parameters as identified)."""
    residuals, energy = [], np.zeros(model.n_joints)
    for item, idx in zip(samples.prepared, samples.rows, strict=True):
        s = item.signals
        predicted = model.predict_filtered_torque(s, item.recording.tau_nm)
        residuals.append(s.tau_lowpassed_nm[idx] - predicted[idx])
        energy += np.sum(s.tau_lowpassed_nm[idx] ** 2, axis=0)
    return ModelResidual(np.concatenate(residuals), energy)


def _joint_designs(
    known: ModelResidual, samples: SelectedSamples, options: ResidualOptions
) -> list[JointDesign]:
    """Per joint: nothing fitted yet, the residual to explain, the torque as the reference."""
    rows, n = known.residual_nm.shape
    return [
        JointDesign(
            np.zeros((rows, 0)),
            known.residual_nm[:, j],
            samples.folds,
            options.folds,
            options.ridge,
            reference_energy=float(known.torque_energy[j]),
        )
        for j in range(n)
    ]


def _control_design(
    samples: SelectedSamples,
    design: JointDesign,
    joint: int,
    description: RobotDescription,
    options: ResidualOptions,
) -> JointDesign:
    """Return the joint's design with friction stand-ins: a changed friction is no pose."""
    specs = velocity_controls(samples, joint, (joint,))
    extra = np.concatenate(
        [filtered_columns(samples, spec) for spec in specs]
        + [friction_stand_in_columns(samples, joint, description)],
        axis=1,
    )
    return design.with_columns(extra)


def _whole_check(
    known: ModelResidual, folds: np.ndarray, n_folds: int, options: ResidualOptions
) -> WholeModelCheck:
    """Return the whole model's check on the residual: nothing fitted until effects join."""
    rows, n = known.residual_nm.shape
    return WholeModelCheck(
        np.zeros((rows, n, 0)),
        known.residual_nm,
        folds,
        n_folds,
        options.ridge,
        reference_energy=known.torque_energy,
    )


def _placement(model: DynamicModel, options: ResidualOptions) -> EffectPlacement:
    """Where effects act, ``auto`` resolved with the model's friction."""
    try:
        kind = FrictionKind(model.friction.kind)
    except ValueError:
        kind = FrictionKind.WN
    return options.effect_placement.resolved(kind)


def _reaches(
    model: DynamicModel, description: RobotDescription, options: ResidualOptions
) -> list[np.ndarray | None]:
    """Per joint, the reach of an effect at its model joint (None: the joint alone)."""
    if _placement(model, options) is EffectPlacement.MOTOR:
        return [None] * model.n_joints
    return effect_reaches(description)


def extended_model(
    model: DynamicModel,
    prepared: Sequence[PreparedRecording],
    accepted: Sequence[TracedEffect],
    payload: TracedPayload | None,
    candidate: PayloadCandidate | None,
) -> tuple[DynamicModel, TracedPayload | None]:
    """Return the model with the payload and the effects, fitted on every valid sample.

    Only the new terms are fitted (least squares on the residual against ``model``); the
    model's own parameters are kept. Returns the model and the payload with its change of
    the base parameters.
    """
    if not accepted and payload is None:
        return model, None
    n = model.n_joints
    directions = np.zeros((model.base_values.size, 0))
    if payload is not None and candidate is not None:
        directions = candidate.directions
    k = directions.shape[1]
    total = k + int(sum(e.spec.size for e in accepted))
    blocks, targets = [], []
    for item in prepared:
        s = item.signals
        v = s.valid
        a = np.zeros((int(v.sum()), n, total))
        if k:
            a[:, :, :k] = np.einsum("kjp,pc->kjc", s.rigid_regressor[v], directions)
        load = np.einsum("kjp,p->kj", s.rigid_regressor, model.base_values)
        col = k
        for traced in accepted:
            spec = traced.spec
            phi = spec.basis(s.t_s, s.q_rad, s.qd_rad_s, load)
            filtered = lowpass_batch(phi, s.t_s, model.filter_config.cutoff_hz)[v]
            reach = None if traced.reach is None else np.asarray(traced.reach)
            a[:, :, col : col + spec.size] = placed_columns(filtered, spec.joint, reach, n)
            col += spec.size
        blocks.append(a)
        predicted = model.predict_filtered_torque(s, item.recording.tau_nm)
        targets.append((s.tau_lowpassed_nm - predicted)[v])
    names = [f"payload[{i}]" for i in range(k)]
    for e, traced in enumerate(accepted):
        names += [f"effect{e + 1}[{i}]" for i in range(traced.spec.size)]
    theta = least_squares(
        np.concatenate(blocks), np.concatenate(targets), names, ridge=1e-8
    ).parameters
    base_values = model.base_values
    if payload is not None and k:
        change = directions @ theta[:k]
        base_values = base_values + change
        payload = replace(payload, base_change=tuple(float(x) for x in change))
    effects = list(model.effects)
    col = k
    for traced in accepted:
        spec = traced.spec
        reach = None if traced.reach is None else np.asarray(traced.reach)
        effects.append(FoundEffect(spec, theta[col : col + spec.size], traced.explained, reach))
        col += spec.size
    notes = dict(model.notes)
    notes["residual_from_model"] = {
        "sources": [str(p.recording.source) for p in prepared],
        "effects_added": len(accepted) + (payload is not None),
    }
    return replace(model, base_values=base_values, effects=tuple(effects), notes=notes), payload
