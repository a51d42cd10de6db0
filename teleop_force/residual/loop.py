"""Close the loop: find the residual, trace it to the effect the model lacks, add it, report.

Every decision is made on held-out data (:mod:`teleop_force.residual.scoring`): the valid
samples of each recording are cut into contiguous time blocks dealt to folds, and a candidate
effect (:mod:`teleop_force.residual.candidates`) is scored by blocked cross-validation. An
effect is added only when it lowers the joint's held-out RMS by ``min_rms_gain`` (relative)
and helps in most blocks; the search then repeats until nothing significant is left.

One step of the search (:func:`trace_residual`):

1. Screen (:func:`_screen`): every candidate of every joint, scored against that joint's
   design; one that passes must also pass over the friction controls
   (:mod:`teleop_force.residual.controls`), else friction the model has not learnt would be
   named after a variable that merely correlates with the velocities.
2. Choose (:func:`_choose`): the best candidates, in order, are refitted in the whole model
   (:class:`~teleop_force.residual.scoring.WholeModelCheck`: rigid body, stage-one friction,
   offsets and the effects so far, all joints) on the same blocks, and must keep their gain
   without making an explained joint worse, on time blocks and, for a periodic recording, on
   blocks held out by phase (a pattern of a repeated trajectory's poses fails there). With
   effects at model joints (:class:`~teleop_force.residual.options.EffectPlacement`) the
   model joint is tried first, then the motor joint alone (:mod:`teleop_force.residual.placement`).
3. Accept (:func:`_accept`): the first confirmed candidate joins every design it reaches.

Then the whole model is refitted with the effects on all data
(:mod:`teleop_force.residual.model_fits`). On the dVRK MTM the cable/spring torque of the
wrist platform is found on joint 4 and loads joints 2 and 3 with the cable's ratio
(+-0.6697), instead of being left to the rigid body there. The held-out blocks of one
trajectory score the two placements about equally; a held-out trajectory does not
(docs/robots.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from teleop_force.friction.kinds import FrictionKind
from teleop_force.identification.effects import BasisSpec, variable_values
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.guards import SIMPLER, FitFailure, fit_failure
from teleop_force.io.interchange_csv import Recording
from teleop_force.residual.candidates import (
    candidate_effects,
    friction_change_candidates,
    is_friction_shaped,
)
from teleop_force.residual.controls import control_design, control_gain
from teleop_force.residual.model_fits import Baseline, fit_baseline, fitted_model
from teleop_force.residual.options import EffectPlacement, ResidualOptions
from teleop_force.residual.payload import PayloadCandidate, confirm_payload
from teleop_force.residual.placement import effect_reaches, placed_columns
from teleop_force.residual.report import EffectPlot, ResidualReport, TracedEffect, TracedPayload
from teleop_force.residual.samples import (
    SelectedSamples,
    filtered_columns,
    joint_base,
    select_samples,
    selected_friction_regressor,
    whole_model_check,
)
from teleop_force.residual.scoring import (
    Confirmation,
    JointDesign,
    WholeModelCheck,
    confirm,
    held_out_gain,
)
from teleop_force.robots.description import RobotDescription

__all__ = ["trace_residual"]


@dataclass(frozen=True, eq=False)
class Scorers:
    """The held-out scorers of the search; effects are added to them as they are accepted."""

    #: Per joint: its design (own rigid-body copy, friction reaching it, offset, effects).
    designs: tuple[JointDesign, ...]
    #: Per joint: its design with the friction controls (None: nothing to control for).
    controls: tuple[JointDesign | None, ...]
    #: The whole model on the time blocks, and on the phase blocks (None: not periodic).
    check: WholeModelCheck
    veto: WholeModelCheck | None
    #: Per joint: the velocities its friction maps beyond its own (not offered as effects).
    covered: tuple[tuple[int, ...], ...]
    #: Per joint: the reach of an effect at its model joint (None: the joint alone).
    reaches: tuple[np.ndarray | None, ...]
    #: Where effects act, ``auto`` resolved.
    placement: EffectPlacement
    #: The last link's inertial parameters as a candidate (a model in hand only).
    payload: PayloadCandidate | None = None
    #: Offer changes of each joint's own friction, exempt from the friction controls (a
    #: model in hand: its friction is fixed, so a change of it is an effect to name).
    friction_changes: bool = False


@dataclass(frozen=True, eq=False)
class Candidate:
    """A candidate effect that passed the screening of its joint."""

    joint: int
    spec: BasisSpec
    #: Its filtered columns at the scored samples.
    columns: np.ndarray
    #: Held-out squared error per fold with it in the joint's design.
    errors: np.ndarray
    #: Relative drop of the joint's held-out RMS, and the same over the friction controls.
    gain: float
    control_gain: float

    def history_entry(self) -> dict[str, Any]:
        """Return the :attr:`ResidualReport.history` entry of this effect."""
        return {
            "effect": self.spec.describe(),
            "kind": self.spec.kind,
            "gain": self.gain,
            "control_gain": self.control_gain,
        }


@dataclass(frozen=True)
class ControlRejection:
    """A candidate that lowered its joint's error but not over the friction controls."""

    effect: str
    gain: float
    control_gain: float

    def to_dict(self) -> dict[str, Any]:
        """Return the :attr:`ResidualReport.rejected` entry."""
        return {"effect": self.effect, "gain": self.gain, "control_gain": self.control_gain}


@dataclass(frozen=True, eq=False)
class WholeModelRejection:
    """A candidate the whole model refuted (:func:`~teleop_force.residual.scoring.confirm`)."""

    candidate: Candidate
    confirmation: Confirmation
    #: Whole-model held-out relative RMS per joint before it.
    whole_before: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        """Return the :attr:`ResidualReport.rejected` entry."""
        return {
            "effect": self.candidate.spec.describe(),
            "gain": self.candidate.gain,
            "whole_model_gain": self.confirmation.gain,
            "whole_model_worse_joints": list(self.confirmation.worse_joints),
            "whole_model_before": list(self.whole_before),
            "whole_model_after": list(self.confirmation.after),
        }


@dataclass(frozen=True, eq=False)
class Screening:
    """Outcome of screening every joint's candidates (:func:`_screen`)."""

    #: Candidates that passed, best gain first.
    passing: tuple[Candidate, ...]
    rejected: tuple[ControlRejection, ...]


@dataclass(frozen=True, eq=False)
class Choice:
    """Outcome of confirming the best candidates in the whole model (:func:`_choose`)."""

    #: The first confirmed candidate (None: none was).
    candidate: Candidate | None
    #: Its placement (None: on its joint alone).
    reach: np.ndarray | None
    #: The candidates refuted before it.
    rejected: tuple[WholeModelRejection, ...]


@dataclass(frozen=True, eq=False)
class Accepted:
    """An accepted effect (:func:`_accept`)."""

    effect: TracedEffect
    plot: EffectPlot


@dataclass(frozen=True, eq=False)
class Search:
    """Outcome of the search (:func:`_search`)."""

    #: Held-out relative RMS per joint before and after the effects.
    before: np.ndarray
    after: np.ndarray
    accepted: tuple[TracedEffect, ...]
    history: tuple[dict[str, Any], ...]
    rejected: tuple[dict[str, Any], ...]
    plots: tuple[EffectPlot, ...]
    #: The payload, when one was offered and confirmed.
    payload: TracedPayload | None = None


def trace_residual(
    recordings: Sequence[Recording],
    description: RobotDescription,
    options: ResidualOptions | None = None,
    config: FilterConfig | None = None,
) -> ResidualReport:
    """Fit, find what the model lacks on held-out data, add it, refit, report before and after."""
    return traced_with_baseline(recordings, description, options, config)[0]


def traced_with_baseline(
    recordings: Sequence[Recording],
    description: RobotDescription,
    options: ResidualOptions | None = None,
    config: FilterConfig | None = None,
) -> tuple[ResidualReport, Baseline]:
    """:func:`trace_residual`, and the baseline the residual was taken from.

    A failed baseline (held-out error above 100 % or not finite on a joint, the loop's own
    blocks: :func:`~teleop_force.identification.guards.fit_failure`) is refused and the
    next simpler friction fitted (``wn -> coupled-cv -> cv``); the report lists every
    fallback, and names the cause in ``failed`` if even the simplest fails.
    """
    options = (options or ResidualOptions()).for_robot(description.name, description.has_rigid_body)
    config = config or FilterConfig()
    offsets = bool(options.offsets)
    kind: FrictionKind = options.friction or FrictionKind.WN
    fallbacks: list[FitFailure] = []
    while True:
        baseline = fit_baseline(recordings, description, kind, offsets, config)
        samples = select_samples(baseline.prepared, options, baseline.rigid_values)
        scorers = _scorers(samples, baseline, description, options)
        before = np.array([d.relative_rms(d.held_out_errors()) for d in scorers.designs])
        cause = fit_failure(before)
        simpler = SIMPLER[kind]
        if cause is None or simpler is None:
            break
        fallbacks.append(FitFailure(kind.value, cause))
        kind = simpler
    search = _search(samples, scorers, options, offsets)
    model = fitted_model(baseline, description, config, search.accepted, options.ridge)
    report = ResidualReport(
        before=search.before,
        after=search.after,
        effects=search.accepted,
        model=model,
        samples=int(samples.folds.size),
        history=search.history,
        effect_plots=search.plots,
        rejected=search.rejected,
        friction=kind.value,
        fallbacks=tuple(f.to_dict() for f in fallbacks),
        failed=None if cause is None else f"{kind.value}: {cause}",
    )
    return report, baseline


def _scorers(
    samples: SelectedSamples,
    baseline: Baseline,
    description: RobotDescription,
    options: ResidualOptions,
) -> Scorers:
    """Build every joint's design and controls and the whole-model checks."""
    n = description.n_joints
    friction_l = selected_friction_regressor(samples, baseline.friction)
    designs = []
    for j in range(n):
        columns, y = joint_base(samples, friction_l, j, baseline.offsets, baseline.network)
        designs.append(JointDesign(columns, y, samples.folds, options.folds, options.ridge))
    # The velocities the friction maps beyond each joint's own: the network's inputs, or the
    # model-coordinate laws that reach the joint through the coupling.
    maps_inputs = baseline.network is not None or not baseline.friction.block_diagonal
    covered = description.friction_inputs if maps_inputs else tuple(() for _ in range(n))
    controls = tuple(
        control_design(samples, design, j, covered[j], description, options)
        for j, design in enumerate(designs)
    )
    placement = options.placement
    reaches = effect_reaches(description) if placement is not EffectPlacement.MOTOR else [None] * n
    check = whole_model_check(samples, friction_l, baseline.offsets, options, samples.folds)
    veto = None
    holdout = samples.holdout_folds
    if holdout is not None:
        veto = whole_model_check(samples, friction_l, baseline.offsets, options, *holdout)
    return Scorers(tuple(designs), controls, check, veto, covered, tuple(reaches), placement)


def _search(
    samples: SelectedSamples, scorers: Scorers, options: ResidualOptions, offsets: bool
) -> Search:
    """Add the best confirmed effect, step by step, until none is left or ``max_effects``.

    BLAS runs on one thread: the search solves thousands of small systems, on which
    OpenBLAS's busy-waiting workers only cost: on a 2-core machine under load, the dVRK MTM's
    loop had not finished after 35 min with BLAS threads; on one thread it took 80 s.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _search_steps(samples, scorers, options, offsets)


def _search_steps(
    samples: SelectedSamples, scorers: Scorers, options: ResidualOptions, offsets: bool
) -> Search:
    designs = scorers.designs
    before = np.array([d.relative_rms(d.held_out_errors()) for d in designs])
    current = before.copy()
    accepted: list[Accepted] = []
    history: list[dict[str, Any]] = []
    rejected: list[dict[str, Any]] = []
    refuted: set[tuple[int, BasisSpec]] = set()
    payload = None
    if scorers.payload is not None:
        payload, entry = _try_payload(scorers, scorers.payload, current, options)
        (history if payload is not None else rejected).append(entry)
    for _ in range(options.max_effects - (payload is not None)):
        screening = _screen(samples, scorers, options, offsets, refuted)
        rejected += [r.to_dict() for r in screening.rejected]
        choice = _choose(scorers, screening.passing, options)
        refuted.update((r.candidate.joint, r.candidate.spec) for r in choice.rejected)
        rejected += [r.to_dict() for r in choice.rejected]
        if choice.candidate is None:
            break
        j = choice.candidate.joint
        step = _accept(samples, scorers, choice.candidate, choice.reach, float(current[j]))
        accepted.append(step)
        history.append(choice.candidate.history_entry())
        current[j] = step.effect.joint_rms_after
    return Search(
        before,
        current,
        tuple(a.effect for a in accepted),
        tuple(history),
        tuple(rejected),
        tuple(a.plot for a in accepted),
        payload,
    )


def _try_payload(
    scorers: Scorers, payload: PayloadCandidate, current: np.ndarray, options: ResidualOptions
) -> tuple[TracedPayload | None, dict[str, Any]]:
    """Confirm the payload in the whole model; if it is, add it to every design it reaches.

    Updates ``current`` (held-out relative RMS per joint) in place. Returns the payload (None:
    refuted) and its history or rejection entry.
    """
    checked = confirm_payload(scorers.check, scorers.veto, payload, options)
    entry: dict[str, Any] = {
        "effect": f"link {payload.link}: inertial parameters",
        "kind": "payload",
        "gain": checked.gain,
        "control_gain": checked.gain,
        "holdout_gain": checked.holdout_gain,
        "whole_model_worse_joints": list(checked.worse_joints),
    }
    if not checked.confirmed:
        return None, entry
    scorers.check.add(payload.columns)
    if scorers.veto is not None:
        scorers.veto.add(payload.columns)
    j = checked.joint
    design = scorers.designs[j]
    base_errors = design.held_out_errors()
    for k in payload.reached:
        scorers.designs[k].add(payload.columns[:, k, :])
        control = scorers.controls[k]
        if control is not None:
            control.add(payload.columns[:, k, :])
    for k in range(len(current)):
        d = scorers.designs[k]
        current[k] = d.relative_rms(d.held_out_errors())
    after_errors = design.held_out_errors()
    explained = 1.0 - after_errors.sum() / max(base_errors.sum(), 1e-300)
    traced = TracedPayload(
        payload.link,
        j,
        payload.reached,
        payload.depends_on,
        float(explained),
        design.relative_rms(base_errors),
        float(current[j]),
    )
    return traced, entry


def _screen(
    samples: SelectedSamples,
    scorers: Scorers,
    options: ResidualOptions,
    offsets: bool,
    refuted: set[tuple[int, BasisSpec]],
) -> Screening:
    """Score every joint's candidates on held-out blocks, then over the friction controls."""
    n = len(scorers.designs)
    passing: list[Candidate] = []
    rejected: list[ControlRejection] = []
    for j, design in enumerate(scorers.designs):
        base_errors = design.held_out_errors()
        residual = design.residual()
        specs = candidate_effects(samples, j, n, residual, options, offsets, scorers.covered[j])
        if scorers.friction_changes:
            specs += friction_change_candidates(j)
        for spec in specs:
            if (j, spec) in refuted:
                continue
            cols = filtered_columns(samples, spec)
            if not np.all(np.isfinite(cols)):
                continue
            errors = design.held_out_errors(cols)
            gain = held_out_gain(base_errors, errors)
            wins = float(np.mean(errors < base_errors))
            if not (gain >= options.min_rms_gain and wins >= options.min_fold_wins):
                continue
            # the joint's own friction shape is named as such: its stand-ins are its controls
            exempt = is_friction_shaped(spec)
            over_controls = 1.0 if exempt else control_gain(scorers.controls[j], cols)
            if over_controls < options.min_control_gain:
                rejected.append(ControlRejection(spec.describe(), gain, over_controls))
                continue
            passing.append(Candidate(j, spec, cols, errors, gain, over_controls))
    return Screening(_simplest_first(passing, options.parsimony), tuple(rejected))


def _simplest_first(passing: list[Candidate], parsimony: float) -> tuple[Candidate, ...]:
    """Order candidates: those within ``parsimony`` of the best gain first, simplest first.

    Then the rest, best gain first.

    A load-dependent friction ``|tau2| sgn(qd2)`` is, on a gravity-loaded joint, also a
    function of the angles times the direction; sixteen bumps fit it a little better
    held out than its one parameter. The simpler name that explains nearly as much is the
    one the physics has.
    """
    passing = sorted(passing, key=lambda candidate: -candidate.gain)
    if not passing:
        return ()
    bar = parsimony * passing[0].gain
    near = sorted((c for c in passing if c.gain >= bar), key=lambda c: (c.spec.size, -c.gain))
    return tuple(near + [c for c in passing if c.gain < bar])


def _choose(scorers: Scorers, passing: Sequence[Candidate], options: ResidualOptions) -> Choice:
    """Confirm the best ``confirm_candidates`` in the whole model, in order; take the first."""
    whole_before = scorers.check.relative_rms()
    alone_too = scorers.placement is EffectPlacement.EITHER
    rejected: list[WholeModelRejection] = []
    for candidate in passing[: options.confirm_candidates]:
        j = candidate.joint
        checked = confirm(
            scorers.check,
            scorers.veto,
            whole_before,
            candidate.columns,
            j,
            scorers.reaches[j],
            alone_too,
            options,
        )
        if checked.confirmed:
            return Choice(candidate, checked.reach, tuple(rejected))
        rejected.append(WholeModelRejection(candidate, checked, tuple(whole_before.tolist())))
    return Choice(None, None, tuple(rejected))


def _accept(
    samples: SelectedSamples,
    scorers: Scorers,
    candidate: Candidate,
    reach: np.ndarray | None,
    joint_rms_before: float,
) -> Accepted:
    """Add ``candidate`` at ``reach`` to the whole model and to every design it reaches."""
    j, spec, cols = candidate.joint, candidate.spec, candidate.columns
    placed = placed_columns(cols, j, reach, len(scorers.designs))
    scorers.check.add(placed)
    if scorers.veto is not None:
        scorers.veto.add(placed)
    design = scorers.designs[j]
    base_errors = design.held_out_errors()
    explained = 1.0 - candidate.errors.sum() / max(base_errors.sum(), 1e-300)
    effect = TracedEffect(
        spec,
        float(explained),
        joint_rms_before,
        design.relative_rms(candidate.errors),
        None if reach is None else tuple(float(w) for w in reach),
    )
    plot = _effect_plot(samples, design, spec, cols)
    # The effect's share on the other joints it reaches is part of their models from now
    # on (free columns of each joint's design, as every column there is).
    for k in (j,) if reach is None else np.flatnonzero(reach):
        scorers.designs[k].add(cols)
        control = scorers.controls[k]
        if control is not None:
            control.add(cols)
    return Accepted(effect, plot)


def _effect_plot(
    samples: SelectedSamples, design: JointDesign, spec: BasisSpec, cols: np.ndarray
) -> EffectPlot:
    """Residual of the joint against the traced variable, before and after adding ``spec``."""
    variable = spec.variable if spec.shape != "constant" else "t"
    x = variable_values(variable, samples.t_s, samples.q_rad, samples.qd_rad_s, samples.load_nm)
    both = np.concatenate((design.base, cols), axis=1)
    theta = np.linalg.lstsq(both, design.y, rcond=None)[0]
    return EffectPlot(spec, x[samples.stacked_rows], design.residual(), design.y - both @ theta)
