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

from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.pipeline import (
    FitReport,
    PreparedRecording,
    WaveletOptions,
    evaluate_prepared,
    identify_model,
    prepare,
)
from teleop_force.identification.regressor import full_parameters
from teleop_force.identification.training_trajectory import (
    VelocityRegion,
    region_coverage,
    training_trajectory,
)
from teleop_force.io.interchange_csv import Recording
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


def run_experiments(
    folder: Path, options: ExperimentOptions | None = None, log: Callable[[str], None] = print
) -> dict[str, Any]:
    """Run every experiment, write the report into ``folder`` and return its figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    options = options or ExperimentOptions()
    folder.mkdir(parents=True, exist_ok=True)
    description = omni_description()
    duration, seed = options.training_duration_s, options.seed
    results: dict[str, Any] = {"options": options.__dict__}
    md: list[str] = ["# Experiments on the simulated PHANTOM Omni", ""]
    md += [
        f"Training sessions {duration:.0f} s, test session {options.test_duration_s:.0f} s, 1 kHz,",
        "encoder quantization 4e-4 rad, torque noise, a true friction coupled and nonlinear in",
        "(qd2, qd3) that no fitted model shares. Relative RMS of the filtered torque"
        " (paper eq. 10),",
        "adaptation off. Regenerate with `teleop-force experiments -o DIR`.",
        "",
    ]

    # --- Table I ------------------------------------------------------------------------------
    started = perf_counter()
    session = rigid_body_protocol(duration, seed)
    log(f"rigid-body session simulated in {perf_counter() - started:.1f} s")
    model, report = identify_model([_recording(session)], description, "coupled-cv")
    prepared, _ = prepare([_recording(session)], description, model.filter_config, model.base)
    assert model.base is not None
    truth = model.base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    share = _well_excited(model, prepared)
    names = model.base.names()
    md += [f"## Table I: rigid-body base parameters ({duration:.0f} s protocol of IV-A)", ""]
    md += [
        "| a | base parameter | identified +- std | true | error | torque share |",
        "|---|---|---|---|---|---|",
    ]
    table_one: list[dict[str, Any]] = []
    for i, name in enumerate(names):
        err = abs(model.base_values[i] - truth[i]) / max(abs(truth[i]), 1e-12)
        excited = share[i] >= WELL_EXCITED_SHARE
        table_one.append(
            {
                "name": name,
                "value": float(model.base_values[i]),
                "std": float(model.base_std[i]),
                "true": float(truth[i]),
                "relative_error": float(err),
                "torque_share": float(share[i]),
                "well_excited": bool(excited),
            }
        )
        mark = "**" if excited else ""
        md.append(
            f"| a{i + 1} | `{name}` | {model.base_values[i]:.4e} +- {model.base_std[i]:.1e}"
            f" | {truth[i]:.4e} | {mark}{err:.1%}{mark} | {share[i]:.1%} |"
        )
    excited_errors = [r["relative_error"] for r in table_one if r["well_excited"]]
    md += [
        "",
        f"Well excited (torque share >= {WELL_EXCITED_SHARE:.0%}, in bold):"
        f" {len(excited_errors)} of {len(names)}, largest error {max(excited_errors):.1%}."
        f" Condition number {report.rigid.condition_number:.1f}; training relative RMS"
        f" {_pct(report.rigid.relative_rms)} %.",
        "",
    ]
    results["table_I"] = {
        "parameters": table_one,
        "max_error_well_excited": max(excited_errors),
        "condition_number": report.rigid.condition_number,
    }

    # --- Experiments 1 and 2 --------------------------------------------------------------------
    trained: dict[str, tuple[DynamicModel, FitReport]] = {}
    sessions: dict[str, SimulatedSession] = {}
    for mode in ("equal", "opposite", "independent"):
        started = perf_counter()
        sessions[mode] = friction_protocol(mode, duration, seed)
        log(f"friction session {mode} simulated in {perf_counter() - started:.1f} s")
        for kind in ("cv", "coupled-cv", "wn"):
            trained[f"{mode}/{kind}"] = identify_model(
                [_recording(sessions[mode])], description, kind
            )
    md += ["## Table II: experiment 1 (relative RMS %, training data)", ""]
    md += [
        "| joint | small qd23: CV | WN | diff. | large qd23: CV | WN | diff. |",
        "|---|---|---|---|---|---|---|",
    ]
    table_two = {}
    for mode in ("equal", "opposite"):
        table_two[mode] = {
            "cv": _pct(trained[f"{mode}/cv"][1].friction_relative_rms),
            "wn": _pct(trained[f"{mode}/wn"][1].friction_relative_rms),
        }
    for j in range(3):
        row = [f"| {j + 1} "]
        for mode in ("equal", "opposite"):
            cv, wn = table_two[mode]["cv"][j], table_two[mode]["wn"][j]
            row.append(f"| {cv:.2f} | {wn:.2f} | {cv - wn:.2f} ")
        md.append("".join(row) + "|")
    results["table_II"] = table_two
    md += ["", "## Table III: Coulomb + viscous parameters, experiment 1", ""]
    md += ["| parameter | small qd23 | large qd23 |", "|---|---|---|"]
    table_three = {}
    for mode in ("equal", "opposite"):
        cv_model = trained[f"{mode}/cv"][0]
        cv_report = trained[f"{mode}/cv"][1]
        fit = cv_report.stage_one or cv_report.rigid
        r = 0 if cv_report.stage_one is not None or cv_model.base is None else cv_model.base.count
        table_three[mode] = [
            (
                fit.parameter_names[r + i],
                float(fit.parameters[r + i]),
                float(fit.standard_deviations[r + i]),
            )
            for i in range(6)
        ]
    for i in range(6):
        name = table_three["equal"][i][0]
        cells = [
            f"({v:.3e} +- {s:.1e})"
            for _, v, s in (table_three["equal"][i], table_three["opposite"][i])
        ]
        md.append(f"| {name} | {cells[0]} | {cells[1]} |")
    results["table_III"] = table_three
    md += [
        "",
        "## Table V: experiment 2 (independent joints 2 and 3; relative RMS %, training data)",
        "",
    ]
    md += ["| joint | CV | coupled CV | WN | CV - WN |", "|---|---|---|---|---|"]
    table_five = {
        k: _pct(trained[f"independent/{k}"][1].friction_relative_rms)
        for k in ("cv", "coupled-cv", "wn")
    }
    for j in range(3):
        md.append(
            f"| {j + 1} | {table_five['cv'][j]:.2f} | {table_five['coupled-cv'][j]:.2f} |"
            f" {table_five['wn'][j]:.2f} | {table_five['cv'][j] - table_five['wn'][j]:.2f} |"
        )
    results["table_V"] = table_five
    sizes = {
        k: list(trained[k][0].friction.parameter_counts()) for k in trained if k.endswith("/wn")
    }
    md += [
        "",
        "Network sizes reached (wavelets per joint): "
        + "; ".join(f"{k.split('/')[0]}: {v}" for k, v in sizes.items()),
        "",
    ]
    results["network_sizes"] = sizes

    # --- Experiment 3 ---------------------------------------------------------------------------
    started = perf_counter()
    test_session = teleoperation_protocol(options.test_duration_s, seed + 100)
    log(f"teleoperation test session simulated in {perf_counter() - started:.1f} s")
    test_rec = _recording(test_session)
    wn_model = trained["independent/wn"][0]
    test_prepared, _ = prepare([test_rec], description, wn_model.filter_config, wn_model.base)
    rows = {
        "CV": evaluate_prepared(
            trained["independent/cv"][0],
            prepare(
                [test_rec], description, wn_model.filter_config, trained["independent/cv"][0].base
            )[0],
        ),
        "coupled CV": evaluate_prepared(trained["independent/coupled-cv"][0], test_prepared),
        "WN (pure, as the paper)": evaluate_prepared(wn_model, test_prepared, blend=False),
        "WN coverage-aware": evaluate_prepared(wn_model, test_prepared, blend=True),
    }
    md += ["## Table VI: experiment 3, independent teleoperation data (relative RMS %)", ""]
    md += [
        "| joint | " + " | ".join(rows) + " | CV - WN coverage-aware |",
        "|---" * (len(rows) + 2) + "|",
    ]
    table_six = {k: _pct(v["relative_rms"]) for k, v in rows.items()}
    for j in range(3):
        md.append(
            f"| {j + 1} | "
            + " | ".join(f"{table_six[k][j]:.2f}" for k in rows)
            + f" | {table_six['CV'][j] - table_six['WN coverage-aware'][j]:.2f} |"
        )
    coverage = rows["WN coverage-aware"]["coverage"]
    md += [
        "",
        "Test samples on trained ground (coverage weight >= 0.5): "
        + ", ".join(f"joint {j + 1} {100 * c:.1f} %" for j, c in enumerate(coverage)),
        "",
    ]
    results["table_VI"] = table_six
    results["test_coverage"] = [float(c) for c in coverage]
    table_one_test = evaluate_prepared(
        model, prepare([test_rec], description, model.filter_config, model.base)[0]
    )
    reverse = {
        "train": _pct(report.friction_relative_rms),
        "test": _pct(table_one_test["relative_rms"]),
    }
    md += [
        "Reverse torque computation of the Table I model (rigid body + coupled CV, fitted on the",
        f"rigid-body session): relative RMS per joint {reverse['train']} %"
        " on its training session,",
        f"{reverse['test']} % on this independent teleoperation session.",
        "",
    ]
    results["table_I"]["reverse_torque_relative_rms_pct"] = reverse

    # --- Beyond the paper: a training trajectory that fills the test's velocity region ------------
    qd_test = test_prepared[0].signals.qd_rad_s
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
    filled_models = {k: identify_model([filled_rec], description, k)[0] for k in ("cv", "wn")}
    filled_cv = evaluate_prepared(
        filled_models["cv"],
        prepare([test_rec], description, wn_model.filter_config, filled_models["cv"].base)[0],
    )
    filled_prep = prepare(
        [test_rec], description, wn_model.filter_config, filled_models["wn"].base
    )[0]
    filled_pure = evaluate_prepared(filled_models["wn"], filled_prep, blend=False)
    filled_wn = evaluate_prepared(filled_models["wn"], filled_prep, blend=True)
    cover_before = region_coverage(sessions["independent"].qd_true_rad_s, region)
    cover_after = region_coverage(filled.qd_true_rad_s, region)
    md += [
        "## Beyond the paper: train where you will work",
        "",
        "`teleop_force.identification.training_trajectory` generated a training trajectory"
        " filling the test's",
        "velocity region (1st-99th percentile). Region cells visited by the training:"
        f" qd2-qd3 plane {cover_before.qd23_fraction:.0%} (experiment 2)"
        f" -> {cover_after.qd23_fraction:.0%} (generated).",
        "",
        "| joint | CV | WN pure | WN coverage-aware | test on trained ground |",
        "|---|---|---|---|---|",
    ]
    for j in range(3):
        md.append(
            f"| {j + 1} | {100 * filled_cv['relative_rms'][j]:.2f}"
            f" | {100 * filled_pure['relative_rms'][j]:.2f}"
            f" | {100 * filled_wn['relative_rms'][j]:.2f}"
            f" | {100 * filled_wn['coverage'][j]:.1f} % |"
        )
    results["generated_training"] = {
        "cv": _pct(filled_cv["relative_rms"]),
        "wn_pure": _pct(filled_pure["relative_rms"]),
        "wn_coverage_aware": _pct(filled_wn["relative_rms"]),
        "coverage": [float(c) for c in filled_wn["coverage"]],
        "region_cells_qd23": [cover_before.qd23_fraction, cover_after.qd23_fraction],
    }

    # --- Batch fit against the Lyapunov adaptation ------------------------------------------------
    rec_independent = _recording(sessions["independent"])
    comparison = {}
    for method in ("batch", "adaptive"):
        started = perf_counter()
        m, rep = identify_model(
            [rec_independent], description, "wn", wavelet=WaveletOptions(method=method)
        )
        elapsed = perf_counter() - started
        ev = evaluate_prepared(m, prepare([test_rec], description, m.filter_config, m.base)[0])
        comparison[method] = {
            "train": _pct(rep.friction_relative_rms),
            "test": _pct(ev["relative_rms"]),
            "sizes": list(m.friction.parameter_counts()),
            "identify_wall_s": round(elapsed, 1),
            "details": {k: v for k, v in rep.details.items() if k != "wn_sizes_history"},
        }
    md += [
        "",
        "## WN training: batch ridge fit against the Lyapunov adaptation (experiment 2 data)",
        "",
        "| method | train RMS % | test RMS % (coverage-aware) | wavelets | identify wall time |",
        "|---|---|---|---|---|",
    ]
    for method, c in comparison.items():
        md.append(
            f"| {method} | {c['train']} | {c['test']} | {c['sizes']} | {c['identify_wall_s']} s |"
        )
    results["wn_method_comparison"] = comparison

    # --- Figures ----------------------------------------------------------------------------------
    s = test_prepared[0].signals
    tau_hat = wn_model.predict_filtered_torque(s, test_rec.tau_nm)
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
    train_qd = sessions["independent"].qd_true_rad_s
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
    md += ["", "![Fig. 3](fig3_torque_estimate.png)", "", "![Fig. 4](fig4_velocity_plane.png)", ""]
    (folder / "report.md").write_text("\n".join(md))
    (folder / "report.json").write_text(json.dumps(results, indent=1, default=float))
    return results
