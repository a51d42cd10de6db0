"""Reproduce the paper's experiments on the simulated Omni, and go beyond them; write a report.

``teleop-force experiments -o DIR`` writes ``DIR/report.md``, ``DIR/report.json`` and PNG
figures: Table I (rigid-body base parameters against the plant's truth), Tables II and III
(experiment 1: equal / opposite joints 2-3), Table V (experiment 2: independent joints), Table
VI (experiment 3: independent teleoperation test data, CV vs pure WN vs coverage-aware WN),
Fig. 3 (filtered torque against its estimate), Fig. 4 (training and test trajectories in the
qd2-qd3 plane over the coverage map), the network sizes reached, the batch fit against the
Lyapunov adaptation, and a training trajectory generated to fill the test's velocity region.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from time import perf_counter
from typing import Any

import numpy as np

from teleop_force.errors import ConfigurationError, ModelError
from teleop_force.friction.kinds import FrictionKind
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.pipeline import (
    FitReport,
    PreparedRecording,
    evaluate_prepared,
    identify_model,
    prepare,
)
from teleop_force.identification.prepared import wavelet_options_for
from teleop_force.identification.regressor import full_parameters
from teleop_force.identification.training_trajectory import (
    RegionCoverage,
    VelocityRegion,
    region_coverage,
    training_trajectory,
)
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.description import RobotDescription
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description
from teleop_force.simulation import (
    SimulatedSession,
    friction_protocol,
    rigid_body_protocol,
    simulate_session,
    teleoperation_protocol,
)
from teleop_force.simulation.trajectories import Trajectory

#: A base parameter is "well excited" when its share of the filtered torque is at least this.
WELL_EXCITED_SHARE = 0.05


@dataclass(frozen=True)
class ExperimentOptions:
    """Durations and seeds of the simulated experiments."""

    training_duration_s: float = 240.0
    test_duration_s: float = 60.0
    seed: int = 1


class _SampledTrajectory(Trajectory):
    """A trajectory given as samples (linear interpolation)."""

    def __init__(self, t_s: np.ndarray, q_rad: np.ndarray, qd_rad_s: np.ndarray) -> None:
        self._t, self._q, self._qd = t_s, q_rad, qd_rad_s

    @property
    def n_joints(self) -> int:
        return int(self._q.shape[1])

    def sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        q = np.column_stack([np.interp(t, self._t, self._q[:, j]) for j in range(self.n_joints)])
        qd = np.column_stack([np.interp(t, self._t, self._qd[:, j]) for j in range(self.n_joints)])
        if np.ndim(t_s) == 0:
            return q[0], qd[0]
        return q, qd


def _recording(session: SimulatedSession) -> Recording:
    return Recording(session.t_s, session.q_rad, session.tau_nm, session.f_tip_in_base_n)


def _pct(values: np.ndarray) -> list[float]:
    return [round(100.0 * float(v), 2) for v in values]


def _well_excited(model: DynamicModel, prepared: list[PreparedRecording]) -> np.ndarray:
    """Share of each base parameter in the RMS filtered torque of its most affected joint."""
    s = prepared[0].signals
    y = s.rigid_regressor[s.valid]
    torque_rms = np.sqrt(np.mean(s.tau_lowpassed_nm[s.valid] ** 2, axis=0))
    contribution = np.sqrt(np.mean((y * model.base_values[None, None, :]) ** 2, axis=0))
    return np.max(contribution / torque_rms[:, None], axis=0)


@dataclass(frozen=True, eq=False)
class _Fit:
    """A model identified on one session, with its fit report."""

    model: DynamicModel
    report: FitReport


@dataclass(frozen=True)
class _BaseParameterRow:
    """One row of Table I: an identified base parameter against the plant's truth."""

    name: str
    value: float
    std: float
    true: float
    relative_error: float
    torque_share: float

    @property
    def well_excited(self) -> bool:
        """Whether the parameter's share of the filtered torque reaches WELL_EXCITED_SHARE."""
        return self.torque_share >= WELL_EXCITED_SHARE

    def to_json(self) -> dict[str, Any]:
        """Return the row as in ``report.json``."""
        return {
            "name": self.name,
            "value": self.value,
            "std": self.std,
            "true": self.true,
            "relative_error": self.relative_error,
            "torque_share": self.torque_share,
            "well_excited": self.well_excited,
        }


@dataclass(frozen=True, eq=False)
class _RigidBodyExperiment:
    """Table I: rigid body and coupled CV identified on the rigid-body session."""

    fit: _Fit
    parameters: tuple[_BaseParameterRow, ...]

    @property
    def max_error_well_excited(self) -> float:
        """Largest relative error of the well-excited base parameters."""
        return max(row.relative_error for row in self.parameters if row.well_excited)


@dataclass(frozen=True, eq=False)
class _FrictionSession:
    """One friction-protocol session and the CV, coupled-CV and WN models trained on it."""

    session: SimulatedSession
    cv: _Fit
    coupled_cv: _Fit
    wn: _Fit

    def fit(self, kind: FrictionKind) -> _Fit:
        """Return the model of friction ``kind`` (cv, coupled-cv or wn)."""
        match kind:
            case FrictionKind.CV:
                return self.cv
            case FrictionKind.COUPLED_CV:
                return self.coupled_cv
            case FrictionKind.WN:
                return self.wn
        raise ConfigurationError(f"no {kind} model in the friction experiments")


#: The paper's network: the whole friction (not added to the coupled CV), so "pure" means it.
_PAPER_WN = wavelet_options_for("alone")

#: The friction models each friction session trains, in the report's order.
_SESSION_FRICTIONS: tuple[FrictionKind, ...] = (
    FrictionKind.CV,
    FrictionKind.COUPLED_CV,
    FrictionKind.WN,
)


@dataclass(frozen=True, eq=False)
class _FrictionExperiments:
    """Experiments 1 (equal / opposite joints 2-3) and 2 (independent joints)."""

    equal: _FrictionSession
    opposite: _FrictionSession
    independent: _FrictionSession

    def by_mode(self) -> tuple[tuple[str, _FrictionSession], ...]:
        """Return the sessions with their protocol mode, in the order they were simulated."""
        return (
            ("equal", self.equal),
            ("opposite", self.opposite),
            ("independent", self.independent),
        )


@dataclass(frozen=True, eq=False)
class _TeleoperationTest:
    """Experiment 3: the independent teleoperation session and the models evaluated on it.

    ``prepared`` is the test recording filtered with the experiment-2 WN model's filter and
    base; the ``*_rms`` are relative RMS per joint (fractions), ``coverage`` the fraction of
    test samples on the WN's trained ground and ``rigid_body_rms`` the Table I model's.
    """

    recording: Recording
    prepared: list[PreparedRecording]
    cv_rms: np.ndarray
    coupled_cv_rms: np.ndarray
    wn_pure_rms: np.ndarray
    wn_rms: np.ndarray
    coverage: np.ndarray
    rigid_body_rms: np.ndarray

    def table_six(self) -> dict[str, list[float]]:
        """Table VI: relative RMS % per joint by column."""
        return {
            "CV": _pct(self.cv_rms),
            "coupled CV": _pct(self.coupled_cv_rms),
            "WN (pure, as the paper)": _pct(self.wn_pure_rms),
            "WN coverage-aware": _pct(self.wn_rms),
        }


@dataclass(frozen=True, eq=False)
class _GeneratedTraining:
    """Beyond the paper: models trained on a trajectory filling the test's velocity region."""

    cover_before: RegionCoverage
    cover_after: RegionCoverage
    cv_rms: np.ndarray
    wn_pure_rms: np.ndarray
    wn_rms: np.ndarray
    coverage: np.ndarray


@dataclass(frozen=True)
class _MethodRun:
    """One WN training method on the experiment-2 data, evaluated on the test session."""

    method: str
    train_pct: list[float]
    test_pct: list[float]
    sizes: list[int]
    identify_wall_s: float
    details: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        """Return the run as in ``report.json``."""
        return {
            "train": self.train_pct,
            "test": self.test_pct,
            "sizes": self.sizes,
            "identify_wall_s": self.identify_wall_s,
            "details": self.details,
        }


@dataclass(frozen=True)
class _Section:
    """A part of the report: its markdown lines and the entries it adds to ``report.json``."""

    markdown: list[str]
    figures: dict[str, Any]


def _rigid_body_experiment(
    description: RobotDescription, options: ExperimentOptions, log: Callable[[str], None]
) -> _RigidBodyExperiment:
    """Simulate the rigid-body session and identify Table I's model on it."""
    started = perf_counter()
    session = rigid_body_protocol(options.training_duration_s, options.seed)
    log(f"rigid-body session simulated in {perf_counter() - started:.1f} s")
    model, report = identify_model([_recording(session)], description, FrictionKind.COUPLED_CV)
    prepared, _ = prepare([_recording(session)], description, model.filter_config, model.base)
    if model.base is None:
        raise ModelError("the Omni's model has no rigid-body base parameters")
    truth = model.base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    share = _well_excited(model, prepared)
    rows = tuple(
        _BaseParameterRow(
            name=name,
            value=float(model.base_values[i]),
            std=float(model.base_std[i]),
            true=float(truth[i]),
            relative_error=float(abs(model.base_values[i] - truth[i]) / max(abs(truth[i]), 1e-12)),
            torque_share=float(share[i]),
        )
        for i, name in enumerate(model.base.names())
    )
    return _RigidBodyExperiment(_Fit(model, report), rows)


def _friction_experiments(
    description: RobotDescription, options: ExperimentOptions, log: Callable[[str], None]
) -> _FrictionExperiments:
    """Simulate the three friction sessions and train CV, coupled CV and WN on each."""

    def session(mode: str) -> _FrictionSession:
        started = perf_counter()
        simulated = friction_protocol(mode, options.training_duration_s, options.seed)
        log(f"friction session {mode} simulated in {perf_counter() - started:.1f} s")
        cv, coupled_cv, wn = (
            _Fit(*identify_model([_recording(simulated)], description, kind, wavelet=_PAPER_WN))
            for kind in _SESSION_FRICTIONS
        )
        return _FrictionSession(simulated, cv, coupled_cv, wn)

    return _FrictionExperiments(session("equal"), session("opposite"), session("independent"))


def _teleoperation_test(
    description: RobotDescription,
    options: ExperimentOptions,
    rigid: _RigidBodyExperiment,
    friction: _FrictionExperiments,
    log: Callable[[str], None],
) -> _TeleoperationTest:
    """Simulate the teleoperation test session and evaluate the trained models on it."""
    started = perf_counter()
    test_session = teleoperation_protocol(options.test_duration_s, options.seed + 100)
    log(f"teleoperation test session simulated in {perf_counter() - started:.1f} s")
    recording = _recording(test_session)
    independent = friction.independent
    wn_model, cv_model = independent.wn.model, independent.cv.model
    prepared, _ = prepare([recording], description, wn_model.filter_config, wn_model.base)
    cv_prepared = prepare([recording], description, wn_model.filter_config, cv_model.base)[0]
    cv = evaluate_prepared(cv_model, cv_prepared)
    coupled_cv = evaluate_prepared(independent.coupled_cv.model, prepared)
    wn_pure = evaluate_prepared(wn_model, prepared, blend=False)
    wn = evaluate_prepared(wn_model, prepared, blend=True)
    rigid_model = rigid.fit.model
    rigid_prepared = prepare([recording], description, rigid_model.filter_config, rigid_model.base)
    rigid_body = evaluate_prepared(rigid_model, rigid_prepared[0])
    return _TeleoperationTest(
        recording=recording,
        prepared=prepared,
        cv_rms=cv["relative_rms"],
        coupled_cv_rms=coupled_cv["relative_rms"],
        wn_pure_rms=wn_pure["relative_rms"],
        wn_rms=wn["relative_rms"],
        coverage=wn["coverage"],
        rigid_body_rms=rigid_body["relative_rms"],
    )


def _generated_training(
    description: RobotDescription,
    options: ExperimentOptions,
    friction: _FrictionExperiments,
    test: _TeleoperationTest,
    log: Callable[[str], None],
) -> _GeneratedTraining:
    """Generate a training trajectory filling the test's velocity region; train and test on it."""
    duration, seed = options.training_duration_s, options.seed
    qd_test = test.prepared[0].signals.qd_rad_s
    lo, hi = np.percentile(qd_test, 1, axis=0), np.percentile(qd_test, 99, axis=0)
    region = VelocityRegion((lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2]))
    generated = training_trajectory(region, duration, seed=seed)
    started = perf_counter()
    filled = simulate_session(
        _SampledTrajectory(generated.t_s, generated.q_rad, generated.qd_rad_s),
        duration,
        seed,
        name="filled",
    )
    log(f"generated-training session simulated in {perf_counter() - started:.1f} s")
    filled_rec = _recording(filled)
    cv_model = identify_model([filled_rec], description, FrictionKind.CV)[0]
    wn_model = identify_model([filled_rec], description, FrictionKind.WN, wavelet=_PAPER_WN)[0]
    filter_config = friction.independent.wn.model.filter_config
    cv = evaluate_prepared(
        cv_model, prepare([test.recording], description, filter_config, cv_model.base)[0]
    )
    wn_prepared = prepare([test.recording], description, filter_config, wn_model.base)[0]
    wn_pure = evaluate_prepared(wn_model, wn_prepared, blend=False)
    wn = evaluate_prepared(wn_model, wn_prepared, blend=True)
    return _GeneratedTraining(
        cover_before=region_coverage(friction.independent.session.qd_true_rad_s, region),
        cover_after=region_coverage(filled.qd_true_rad_s, region),
        cv_rms=cv["relative_rms"],
        wn_pure_rms=wn_pure["relative_rms"],
        wn_rms=wn["relative_rms"],
        coverage=wn["coverage"],
    )


def _method_comparison(
    description: RobotDescription, friction: _FrictionExperiments, test: _TeleoperationTest
) -> tuple[_MethodRun, ...]:
    """Train the WN on experiment 2's data by batch fit and by Lyapunov adaptation."""
    recording = _recording(friction.independent.session)
    runs = []
    for method in ("batch", "adaptive"):
        started = perf_counter()
        model, report = identify_model(
            [recording],
            description,
            FrictionKind.WN,
            wavelet=wavelet_options_for("alone", method),
        )
        elapsed = perf_counter() - started
        prepared = prepare([test.recording], description, model.filter_config, model.base)[0]
        evaluation = evaluate_prepared(model, prepared)
        runs.append(
            _MethodRun(
                method=method,
                train_pct=_pct(report.friction_relative_rms),
                test_pct=_pct(evaluation["relative_rms"]),
                sizes=list(model.friction.parameter_counts()),
                identify_wall_s=round(elapsed, 1),
                details={k: v for k, v in report.details.items() if k != "wn_sizes_history"},
            )
        )
    return tuple(runs)


def _header_section(options: ExperimentOptions) -> _Section:
    """Title and protocol paragraph."""
    return _Section(
        [
            "# Experiments on the simulated PHANTOM Omni",
            "",
            f"Training sessions {options.training_duration_s:.0f} s,"
            f" test session {options.test_duration_s:.0f} s, 1 kHz,",
            "encoder quantization 4e-4 rad, torque noise, a true friction coupled and nonlinear in",
            "(qd2, qd3) that no fitted model shares. Relative RMS of the filtered torque"
            " (paper eq. 10),",
            "adaptation off. Regenerate with `teleop-force experiments -o DIR`.",
            "",
        ],
        {},
    )


def _table_one_section(
    rigid: _RigidBodyExperiment, test: _TeleoperationTest, options: ExperimentOptions
) -> _Section:
    """Table I, with the reverse torque computation of its model on the test session."""
    report = rigid.fit.report
    md = [
        f"## Table I: rigid-body base parameters ({options.training_duration_s:.0f} s protocol"
        " of IV-A)",
        "",
        "| a | base parameter | identified +- std | true | error | torque share |",
        "|---|---|---|---|---|---|",
    ]
    for i, row in enumerate(rigid.parameters):
        mark = "**" if row.well_excited else ""
        md.append(
            f"| a{i + 1} | `{row.name}` | {row.value:.4e} +- {row.std:.1e}"
            f" | {row.true:.4e} | {mark}{row.relative_error:.1%}{mark} | {row.torque_share:.1%} |"
        )
    excited = sum(row.well_excited for row in rigid.parameters)
    md += [
        "",
        f"Well excited (torque share >= {WELL_EXCITED_SHARE:.0%}, in bold):"
        f" {excited} of {len(rigid.parameters)}, largest error"
        f" {rigid.max_error_well_excited:.1%}."
        f" Condition number {report.rigid.condition_number:.1f}; training relative RMS"
        f" {_pct(report.rigid.relative_rms)} %.",
        "",
    ]
    table_one = {
        "parameters": [row.to_json() for row in rigid.parameters],
        "max_error_well_excited": rigid.max_error_well_excited,
        "condition_number": report.rigid.condition_number,
        "reverse_torque_relative_rms_pct": {
            "train": _pct(report.friction_relative_rms),
            "test": _pct(test.rigid_body_rms),
        },
    }
    return _Section(md, {"table_I": table_one})


def _friction_tables_section(friction: _FrictionExperiments) -> _Section:
    """Tables II, III and V and the network sizes reached."""
    md = ["## Table II: experiment 1 (relative RMS %, training data)", ""]
    md += [
        "| joint | small qd23: CV | WN | diff. | large qd23: CV | WN | diff. |",
        "|---|---|---|---|---|---|---|",
    ]
    experiment_one = (("equal", friction.equal), ("opposite", friction.opposite))
    table_two = {
        mode: {
            "cv": _pct(s.cv.report.friction_relative_rms),
            "wn": _pct(s.wn.report.friction_relative_rms),
        }
        for mode, s in experiment_one
    }
    for j in range(3):
        row = [f"| {j + 1} "]
        for mode, _ in experiment_one:
            cv, wn = table_two[mode]["cv"][j], table_two[mode]["wn"][j]
            row.append(f"| {cv:.2f} | {wn:.2f} | {cv - wn:.2f} ")
        md.append("".join(row) + "|")
    md += ["", "## Table III: Coulomb + viscous parameters, experiment 1", ""]
    md += ["| parameter | small qd23 | large qd23 |", "|---|---|---|"]
    table_three = {mode: _cv_parameters(s.cv) for mode, s in experiment_one}
    for i in range(6):
        name = table_three["equal"][i][0]
        cells = [
            f"({v:.3e} +- {s:.1e})"
            for _, v, s in (table_three["equal"][i], table_three["opposite"][i])
        ]
        md.append(f"| {name} | {cells[0]} | {cells[1]} |")
    md += [
        "",
        "## Table V: experiment 2 (independent joints 2 and 3; relative RMS %, training data)",
        "",
    ]
    md += ["| joint | CV | coupled CV | WN | CV - WN |", "|---|---|---|---|---|"]
    table_five = {
        kind.value: _pct(friction.independent.fit(kind).report.friction_relative_rms)
        for kind in _SESSION_FRICTIONS
    }
    for j in range(3):
        md.append(
            f"| {j + 1} | {table_five['cv'][j]:.2f} | {table_five['coupled-cv'][j]:.2f} |"
            f" {table_five['wn'][j]:.2f} | {table_five['cv'][j] - table_five['wn'][j]:.2f} |"
        )
    sizes = {
        f"{mode}/wn": list(s.wn.model.friction.parameter_counts()) for mode, s in friction.by_mode()
    }
    md += [
        "",
        "Network sizes reached (wavelets per joint): "
        + "; ".join(f"{k.split('/')[0]}: {v}" for k, v in sizes.items()),
        "",
    ]
    return _Section(
        md,
        {
            "table_II": table_two,
            "table_III": table_three,
            "table_V": table_five,
            "network_sizes": sizes,
        },
    )


def _cv_parameters(fit: _Fit) -> list[tuple[str, float, float]]:
    """Table III column: the six CV parameters (name, value, std) of a CV fit."""
    report, model = fit.report, fit.model
    identification = report.stage_one or report.rigid
    r = 0 if report.stage_one is not None or model.base is None else model.base.count
    return [
        (
            identification.parameter_names[r + i],
            float(identification.parameters[r + i]),
            float(identification.standard_deviations[r + i]),
        )
        for i in range(6)
    ]


def _table_six_section(test: _TeleoperationTest, rigid: _RigidBodyExperiment) -> _Section:
    """Table VI, the test's trained-ground share and Table I's model on the test session."""
    table_six = test.table_six()
    md = ["## Table VI: experiment 3, independent teleoperation data (relative RMS %)", ""]
    md += [
        "| joint | " + " | ".join(table_six) + " | CV - WN coverage-aware |",
        "|---" * (len(table_six) + 2) + "|",
    ]
    for j in range(3):
        md.append(
            f"| {j + 1} | "
            + " | ".join(f"{table_six[k][j]:.2f}" for k in table_six)
            + f" | {table_six['CV'][j] - table_six['WN coverage-aware'][j]:.2f} |"
        )
    md += [
        "",
        "Test samples on trained ground (coverage weight >= 0.5): "
        + ", ".join(f"joint {j + 1} {100 * c:.1f} %" for j, c in enumerate(test.coverage)),
        "",
    ]
    training_rms = _pct(rigid.fit.report.friction_relative_rms)
    md += [
        "Reverse torque computation of the Table I model (rigid body + coupled CV, fitted on the",
        f"rigid-body session): relative RMS per joint {training_rms} % on its training session,",
        f"{_pct(test.rigid_body_rms)} % on this independent teleoperation session.",
        "",
    ]
    return _Section(md, {"table_VI": table_six, "test_coverage": [float(c) for c in test.coverage]})


def _generated_section(generated: _GeneratedTraining) -> _Section:
    """Beyond the paper: train where you will work."""
    md = [
        "## Beyond the paper: train where you will work",
        "",
        "`teleop_force.identification.training_trajectory` generated a training trajectory"
        " filling the test's",
        "velocity region (1st-99th percentile). Region cells visited by the training:"
        f" qd2-qd3 plane {generated.cover_before.qd23_fraction:.0%} (experiment 2)"
        f" -> {generated.cover_after.qd23_fraction:.0%} (generated).",
        "",
        "| joint | CV | WN pure | WN coverage-aware | test on trained ground |",
        "|---|---|---|---|---|",
    ]
    for j in range(3):
        md.append(
            f"| {j + 1} | {100 * generated.cv_rms[j]:.2f}"
            f" | {100 * generated.wn_pure_rms[j]:.2f}"
            f" | {100 * generated.wn_rms[j]:.2f}"
            f" | {100 * generated.coverage[j]:.1f} % |"
        )
    figures = {
        "cv": _pct(generated.cv_rms),
        "wn_pure": _pct(generated.wn_pure_rms),
        "wn_coverage_aware": _pct(generated.wn_rms),
        "coverage": [float(c) for c in generated.coverage],
        "region_cells_qd23": [
            generated.cover_before.qd23_fraction,
            generated.cover_after.qd23_fraction,
        ],
    }
    return _Section(md, {"generated_training": figures})


def _method_section(runs: tuple[_MethodRun, ...]) -> _Section:
    """WN training: batch ridge fit against the Lyapunov adaptation."""
    md = [
        "",
        "## WN training: batch ridge fit against the Lyapunov adaptation (experiment 2 data)",
        "",
        "| method | train RMS % | test RMS % (coverage-aware) | wavelets | identify wall time |",
        "|---|---|---|---|---|",
    ]
    for run in runs:
        md.append(
            f"| {run.method} | {run.train_pct} | {run.test_pct} | {run.sizes}"
            f" | {run.identify_wall_s} s |"
        )
    return _Section(md, {"wn_method_comparison": {run.method: run.to_json() for run in runs}})


def _plot_figures(
    folder: Path, friction: _FrictionExperiments, test: _TeleoperationTest
) -> _Section:
    """Fig. 3 (filtered torque and its estimate) and Fig. 4 (velocity plane); write the PNGs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    wn_model = friction.independent.wn.model
    s = test.prepared[0].signals
    tau_hat = wn_model.predict_filtered_torque(s, test.recording.tau_nm)
    window = (s.t_s >= s.t_s[0] + 5.0) & (s.t_s < s.t_s[0] + 15.0)
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for j, ax in enumerate(axes):
        ax.plot(s.t_s[window], s.tau_lowpassed_nm[window, j], label="filtered motor torque")
        ax.plot(s.t_s[window], tau_hat[window, j], "--", label="estimate (coverage-aware WN)")
        ax.set_ylabel(f"joint {j + 1} [N m]")
    axes[0].legend(loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("Fig. 3: low-pass filtered torque and its estimate (test data)")
    fig.tight_layout()
    fig.savefig(folder / "fig3_torque_estimate.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 6))
    coverage_map = getattr(wn_model.friction, "coverage", None)
    if coverage_map is not None:
        density = coverage_map.density_grid(1)
        spec = wn_model.friction.specs[1]  # type: ignore[attr-defined]
        extent = (
            spec.x_min_rad_s[0],
            spec.x_max_rad_s[0],
            spec.x_min_rad_s[1],
            spec.x_max_rad_s[1],
        )
        ax.imshow(
            np.log1p(density.T),
            origin="lower",
            extent=extent,
            cmap="Greens",
            alpha=0.7,
            aspect="auto",
        )
    train_qd = friction.independent.session.qd_true_rad_s
    ax.plot(
        train_qd[::20, 1],
        train_qd[::20, 2],
        ".",
        ms=1,
        color="0.4",
        label="training (experiment 2)",
    )
    ax.plot(
        s.qd_rad_s[:, 1],
        s.qd_rad_s[:, 2],
        "-",
        lw=1.5,
        color="tab:red",
        label="test (teleoperation)",
    )
    ax.set_xlabel("qd2 [rad/s]")
    ax.set_ylabel("qd3 [rad/s]")
    ax.legend(loc="upper left")
    ax.set_title("Fig. 4: trained (green: coverage) and tested velocities")
    fig.tight_layout()
    fig.savefig(folder / "fig4_velocity_plane.png", dpi=110)
    plt.close(fig)
    md = ["", "![Fig. 3](fig3_torque_estimate.png)", "", "![Fig. 4](fig4_velocity_plane.png)", ""]
    return _Section(md, {})


def run_experiments(
    folder: Path, options: ExperimentOptions | None = None, log: Callable[[str], None] = print
) -> dict[str, Any]:
    """Run every experiment, write the report into ``folder`` and return its figures."""
    options = options or ExperimentOptions()
    folder.mkdir(parents=True, exist_ok=True)
    description = omni_description()
    rigid = _rigid_body_experiment(description, options, log)
    friction = _friction_experiments(description, options, log)
    test = _teleoperation_test(description, options, rigid, friction, log)
    generated = _generated_training(description, options, friction, test, log)
    methods = _method_comparison(description, friction, test)
    sections = (
        _header_section(options),
        _table_one_section(rigid, test, options),
        _friction_tables_section(friction),
        _table_six_section(test, rigid),
        _generated_section(generated),
        _method_section(methods),
        _plot_figures(folder, friction, test),
    )
    results: dict[str, Any] = {"options": options.__dict__}
    for section in sections:
        results.update(section.figures)
    markdown = [line for section in sections for line in section.markdown]
    (folder / "report.md").write_text("\n".join(markdown))
    (folder / "report.json").write_text(json.dumps(results, indent=1, default=float))
    return results
