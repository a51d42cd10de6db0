"""Tables and plots of the two real-robot datasets, regenerated from ``../shared/datasets``.

``teleop-force report-robots -o FOLDER`` (or ``python -m teleop_force.reports.robots FOLDER``)
writes ``robots.md``, ``robots.json`` and PNG plots:

* dVRK MTM: identify on ``mtm_traj_one``, evaluate on ``mtm_traj_two`` (relative RMS per joint
  of the filtered motor torque) for CV, coupled CV, the wavelet network, friction in model
  coordinates through the coupling (without and with offsets) and the residual loop's found
  effects, and CV on the serial chain without the parallelogram for comparison; the share
  of the measured torque above 3 Hz (beyond the excitation); the gravity-direction check;
* test stand: the foot force from joint torques against the ATI sensor, with the error broken
  down into rigid-body model, friction and slider motion, against the lab's own estimator.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from teleop_force.errors import DataError, TeleopForceError
from teleop_force.identification.effects import describe_reach

if TYPE_CHECKING:
    from teleop_force.estimation.teststand import TeststandModel, TeststandOptions
    from teleop_force.io.interchange_csv import Recording
    from teleop_force.robots.description import RobotDescription

#: The data authors' figure: relative motor-torque error below this for MTM joints 1-3.
MTM_PUBLISHED_RELATIVE_ERROR = 0.163
#: The lab's online estimator: Fz error [N] RMS over the 3 s set.
TESTSTAND_LAB_FZ_RMS_N = 1.98
#: Frequency above which the filtered MTM torque is counted as beyond the excitation [Hz] (the
#: Fourier excitation is below 1 Hz: under 1 % of the angles' variance is above 1 Hz).
MTM_FLOOR_HZ = 3.0
#: Label of the comparison row: CV on the serial DH chain, without the parallelogram links.
MTM_SERIAL_ROW = "CV, serial chain (no parallelogram)"
#: Rows with the friction in model coordinates (``tau_f = T^T f(T qd)``), without and with a
#: constant torque per joint (the data authors' Coulomb + viscous + offset).
MTM_MODEL_CV_ROW = "model-coordinate CV (through the coupling)"
MTM_MODEL_CV_OFFSETS_ROW = "model-coordinate CV + offsets"
#: The residual loop's rows on the model-coordinate CV + offsets baseline: effects placed by
#: the loop's default (``either``: at the model joint if the whole model confirms it, else on
#: the motor joint), and, for comparison, on the motor joints only.
MTM_MODEL_CV_EFFECTS_ROW = "model-coordinate CV + offsets + found effects"
MTM_MOTOR_EFFECTS_ROW = "model-coordinate CV + offsets + found effects on the motor joints"
_AXIS_GRAVITIES = {
    "-z": (0.0, 0.0, -9.81),
    "+z": (0.0, 0.0, 9.81),
    "-y": (0.0, -9.81, 0.0),
    "+y": (0.0, 9.81, 0.0),
    "-x": (-9.81, 0.0, 0.0),
    "+x": (9.81, 0.0, 0.0),
}


def default_datasets_dir() -> Path:
    """``<repo>/../shared/datasets``, where the shared real-robot data lives."""
    return Path(__file__).resolve().parents[2].parent / "shared" / "datasets"


def _pct(values: Sequence[float]) -> list[str]:
    return [f"{100 * v:.1f} %" if np.isfinite(v) else "n/a" for v in values]


def _rms(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.nanmean(x**2)))


# --------------------------------------------------------------------------- dVRK MTM


def mtm_study(
    folder: Path, out: Path, residual: bool, log: Callable[[str], None]
) -> dict[str, Any]:
    """Identify on trajectory one, evaluate on trajectory two; return the figures."""
    from teleop_force.friction.kinds import FrictionKind
    from teleop_force.identification.pipeline import (
        evaluate_model,
        evaluate_prepared,
        identify_model,
        prepare,
    )
    from teleop_force.io.dvrk_mtm_csv import read_mtm_csv
    from teleop_force.robots.dvrk_mtm import dvrk_mtm_description

    train = read_mtm_csv(folder / "mtm_traj_one_results.csv")
    test = read_mtm_csv(folder / "mtm_traj_two_results.csv")
    for item in (train, test):
        log(item.note())
    description = dvrk_mtm_description()
    serial = dvrk_mtm_description(parallelogram=False)
    rows: dict[str, dict[str, Any]] = {}
    for kind, candidate, friction, offsets in (
        ("cv", description, FrictionKind.CV, None),
        ("coupled-cv", description, FrictionKind.COUPLED_CV, None),
        ("wn", description, FrictionKind.WN, None),
        (MTM_SERIAL_ROW, serial, FrictionKind.CV, None),
        (MTM_MODEL_CV_ROW, description, FrictionKind.MODEL_CV, None),
        (MTM_MODEL_CV_OFFSETS_ROW, description, FrictionKind.MODEL_CV, True),
    ):
        start = time.perf_counter()
        try:
            model, report = identify_model([train.recording], candidate, friction, offsets=offsets)
            result = evaluate_model(model, [test.recording])
        except (
            TeleopForceError,
            ImportError,
            NotImplementedError,
            AttributeError,
            TypeError,
        ) as exc:
            log(f"MTM {kind}: not done ({type(exc).__name__}: {exc})")
            rows[kind] = {"done": False, "reason": f"{type(exc).__name__}: {exc}"}
            continue
        rows[kind] = _mtm_row(report.friction_relative_rms, result, start)
        log(f"MTM {kind}: test {', '.join(_pct(result['relative_rms']))}")
    effects: dict[str, list[dict[str, Any]]] = {}
    if residual:
        from teleop_force.residual.loop import trace_residual
        from teleop_force.residual.options import EffectPlacement, ResidualOptions

        model_cv = FrictionKind.MODEL_CV
        for label, options in (
            ("wn + found effects", ResidualOptions(friction=FrictionKind.WN, offsets=False)),
            (MTM_MODEL_CV_EFFECTS_ROW, ResidualOptions(friction=model_cv, offsets=True)),
            (
                MTM_MOTOR_EFFECTS_ROW,
                ResidualOptions(
                    friction=model_cv, offsets=True, effect_placement=EffectPlacement.MOTOR
                ),
            ),
        ):
            start = time.perf_counter()
            traced = trace_residual([train.recording], description, options)
            result = evaluate_model(traced.model, [test.recording])
            rows[label] = _mtm_row(traced.after, result, start)
            rows[label]["held_out_before"] = traced.before.tolist()
            effects[label] = [e.to_json() for e in traced.effects]
            log(
                f"MTM residual loop ({label}): {len(effects[label])} effects; "
                f"test {', '.join(_pct(result['relative_rms']))}"
            )
    gravity = {}
    for label, vector in _AXIS_GRAVITIES.items():
        candidate = dvrk_mtm_description(vector)
        model, report = identify_model([train.recording], candidate, FrictionKind.CV)
        prepared, _ = prepare([test.recording], candidate, model.filter_config, model.base)
        gravity[label] = {
            "train": report.friction_relative_rms.tolist(),
            "test": evaluate_prepared(model, prepared)["relative_rms"].tolist(),
        }
    floor = (
        _share_above(rows["cv"]["measured"], MTM_FLOOR_HZ).tolist()
        if rows.get("cv", {}).get("done")
        else []
    )
    _plot_mtm(rows, description.joint_names, out)
    return {
        "files": {"train": train.note(), "test": test.note()},
        "coupling_shape": list(description.coupling.shape),
        "torque_above_floor_hz": {"hz": MTM_FLOOR_HZ, "relative_rms": floor},
        "rows": {
            k: {kk: vv for kk, vv in v.items() if kk not in ("measured", "estimated")}
            for k, v in rows.items()
        },
        "effects": effects,
        "gravity": gravity,
        "joint_names": list(description.joint_names),
    }


def _mtm_row(train: np.ndarray, result: dict[str, Any], start: float) -> dict[str, Any]:
    """One model's row: training and test relative RMS, both metrics, and its time."""
    return {
        "done": True,
        "train": np.asarray(train).tolist(),
        "test": result["relative_rms"].tolist(),
        "test_zero_phase": _zero_phase_relative_rms(
            result["measured"], result["estimated"], MTM_FLOOR_HZ
        ).tolist(),
        "seconds": time.perf_counter() - start,
        "measured": result["measured"],
        "estimated": result["estimated"],
    }


def _share_above(measured: np.ndarray, cutoff_hz: float, rate_hz: float = 200.0) -> np.ndarray:
    """Per joint, RMS of the part of ``measured`` above ``cutoff_hz`` over RMS of ``measured``.

    The part below is a 4th-order Butterworth run forward and backward (no phase shift); what
    is above it is beyond the excitation, where the smoothed angles carry little motion.
    """
    from scipy.signal import butter, filtfilt

    b, a = butter(4, cutoff_hz / (rate_hz / 2))
    padding = min(measured.shape[0] - 1, int(rate_hz))
    low = filtfilt(b, a, measured, axis=0, padlen=padding)
    return np.sqrt(np.mean((measured - low) ** 2, axis=0)) / np.sqrt(np.mean(measured**2, axis=0))


def _zero_phase_relative_rms(
    measured: np.ndarray, estimated: np.ndarray, cutoff_hz: float, rate_hz: float = 200.0
) -> np.ndarray:
    """Per joint, relative RMS after both torques pass a 6th-order zero-phase low-pass.

    The data authors' torque filter type (a sixth-order Butterworth run forward and
    backward), at ``cutoff_hz``: it removes the band above the excitation that the project's
    first-order filter keeps (see ``torque_above_floor_hz``).
    """
    from scipy.signal import butter, filtfilt

    from teleop_force.identification.least_squares import relative_rms

    b, a = butter(6, cutoff_hz / (rate_hz / 2))
    padding = min(measured.shape[0] - 1, int(rate_hz))
    low = [filtfilt(b, a, x, axis=0, padlen=padding) for x in (measured, estimated)]
    return relative_rms(low[0], low[1])


def _plot_mtm(rows: dict[str, dict[str, Any]], joint_names: Sequence[str], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    done = {k: v for k, v in rows.items() if v.get("done")}
    n = len(joint_names)
    fig, ax = plt.subplots(figsize=(8, 3.8))
    width = 0.8 / max(len(done), 1)
    for i, (name, row) in enumerate(done.items()):
        ax.bar(
            np.arange(n) + i * width - 0.4 + width / 2,
            100 * np.asarray(row["test"]),
            width,
            label=name,
        )
    ax.axhline(
        100 * MTM_PUBLISHED_RELATIVE_ERROR, color="k", ls="--", lw=1, label="published, joints 1-3"
    )
    ax.set_xticks(np.arange(n), [f"j{j + 1}" for j in range(n)])
    ax.set_ylabel("test relative RMS [%]")
    ax.set_ylim(0, 110)
    ax.legend(fontsize=7)
    ax.set_title("dVRK MTM: identified on trajectory one, evaluated on trajectory two")
    fig.tight_layout()
    fig.savefig(out / "mtm_relative_rms.png", dpi=110)
    plt.close(fig)
    best_name = min(done, key=lambda k: float(np.mean(done[k]["test"][:3])))
    best = done[best_name]
    fig, axes = plt.subplots(3, 1, figsize=(9, 6), sharex=True)
    t = np.arange(best["measured"].shape[0]) / 200.0
    for j, axis in enumerate(axes):
        axis.plot(t, best["measured"][:, j], lw=0.8, label="measured (filtered)")
        axis.plot(t, best["estimated"][:, j], lw=0.8, label=f"model ({best_name})")
        axis.set_ylabel(f"tau{j + 1} [N m]")
    axes[0].legend(fontsize=7)
    axes[-1].set_xlabel("t [s] (trajectory two)")
    fig.tight_layout()
    fig.savefig(out / "mtm_torque_test.png", dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------- test stand


@dataclass(frozen=True)
class _TeststandData:
    """The test stand's log (commanded torques) and what every estimate is judged against.

    Attributes:
        note: The log's one-line description.
        recording: The aligned log.
        truth: The ATI sensor's force (negated: the foot's force on the ground) [N].
        lab_estimate: The lab's online estimate of the same force [N].
        contact: Samples in contact (outside the free phase).

    """

    note: str
    recording: Recording
    truth: np.ndarray
    lab_estimate: np.ndarray
    contact: np.ndarray

    def errors(self, forces: np.ndarray) -> dict[str, float]:
        """Return the RMS errors of ``forces`` against the sensor: f_z, f_x, f_z in contact."""
        error = forces - self.truth
        return {
            "fz_rms_n": _rms(error[:, 2]),
            "fx_rms_n": _rms(error[:, 0]),
            "fz_rms_contact_n": _rms(error[self.contact, 2]),
        }


@dataclass(frozen=True)
class _TeststandRows:
    """The estimates' errors, and the identified model they single out.

    Attributes:
        rows: Errors per estimate (see :meth:`_TeststandData.errors`), in the report's order.
        identified: The model identified on the commanded torques.
        best_forces: Its forces with friction, the headline estimate [N].
        slider_term_rms_n: RMS of the slider term's contribution to f_z [N].

    """

    rows: dict[str, dict[str, float]]
    identified: TeststandModel
    best_forces: np.ndarray
    slider_term_rms_n: float


def teststand_study(folder: Path, out: Path, log: Callable[[str], None]) -> dict[str, Any]:
    """Foot force from joint torques vs the ATI sensor; the error broken down."""
    from teleop_force.estimation.teststand import TeststandOptions
    from teleop_force.robots.teststand import teststand_description

    options = TeststandOptions()
    data = _read_teststand(folder, options, log)
    description = teststand_description()
    found = _teststand_rows(folder, data, description, options)
    sensitivity = _teststand_sensitivity(data, description)
    _save_teststand_model(found.identified, out)
    _plot_teststand(data.recording.t_s, data.truth, data.lab_estimate, found.best_forces, out)
    return {
        "file": data.note,
        "samples": data.recording.n_samples,
        "free_samples": found.identified.free_samples,
        "slider_term_rms_n": found.slider_term_rms_n,
        "rms_fz_n": _rms(data.truth[:, 2]),
        "rows": found.rows,
        "sensitivity": sensitivity,
        "options": {
            "cutoff_hz": options.filter.cutoff_hz,
            "prefilter_hz": options.filter.velocity_cutoff_hz,
            "prior_weight": options.prior_weight,
            "free_force_n": options.free_force_n,
            "guard_s": options.guard_s,
            "friction": options.friction,
        },
        "friction_parameters": found.identified.model.friction.parameters.tolist(),
    }


def _read_teststand(
    folder: Path, options: TeststandOptions, log: Callable[[str], None]
) -> _TeststandData:
    """Read the log with commanded torques; it needs the sensor's force and the lab's."""
    from teleop_force.estimation.teststand import free_phase_mask
    from teleop_force.io.teststand_logs import read_teststand_folder

    log_measured = read_teststand_folder(folder, "target")
    log(log_measured.note())
    recording = log_measured.recording
    truth = recording.f_tip_in_base_n
    if truth is None or log_measured.lab_estimate_n is None:
        raise DataError(
            "the test-stand folder needs the ATI force and the lab's estimate", path=folder
        )
    contact = ~free_phase_mask(recording, options.free_force_n, 0.0)
    return _TeststandData(
        log_measured.note(), recording, truth, log_measured.lab_estimate_n, contact
    )


def _teststand_rows(
    folder: Path,
    data: _TeststandData,
    description: RobotDescription,
    options: TeststandOptions,
) -> _TeststandRows:
    """Errors of the lab's estimate, the URDF and identified models, and the streaming path."""
    from teleop_force.estimation.estimator import ForceEstimator
    from teleop_force.estimation.teststand import (
        TeststandModel,
        estimate_forces,
        identify_teststand,
        nominal_teststand_model,
    )
    from teleop_force.io.teststand_logs import read_teststand_folder

    recording, errors = data.recording, data.errors
    rows = {"lab estimator (baseline)": errors(data.lab_estimate)}
    nominal = nominal_teststand_model(description, options)
    rows["URDF rigid body only"] = errors(estimate_forces(nominal, recording, description, False))
    with_slider = TeststandModel(nominal.model, True, 0)
    rows["URDF rigid body + slider term"] = errors(
        estimate_forces(with_slider, recording, description, False)
    )
    identified = identify_teststand(recording, description, options)
    rows["identified rigid body, no friction"] = errors(
        estimate_forces(identified, recording, description, False)
    )
    best_forces = estimate_forces(identified, recording, description)
    rows["identified rigid body + friction"] = errors(best_forces)
    slider = TeststandModel(identified.model, True, identified.free_samples)
    slider_forces = estimate_forces(slider, recording, description)
    rows["identified + friction + slider term"] = errors(slider_forces)
    nominal_friction = TeststandModel(
        replace(nominal.model, friction=identified.model.friction), False, 0
    )
    rows["URDF rigid body + identified friction"] = errors(
        estimate_forces(nominal_friction, recording, description)
    )
    log_other = read_teststand_folder(folder, "measured")
    identified_other = identify_teststand(log_other.recording, description, options)
    rows["identified + friction, measured torques"] = errors(
        estimate_forces(identified_other, log_other.recording, description)
    )
    rows["streaming ForceEstimator (same model)"] = errors(
        _stream(ForceEstimator(identified.model), recording)
    )
    slider_term_rms_n = _rms(slider_forces[:, 2] - best_forces[:, 2])
    return _TeststandRows(rows, identified, best_forces, slider_term_rms_n)


def _teststand_sensitivity(
    data: _TeststandData, description: RobotDescription
) -> dict[str, dict[str, float]]:
    """Errors of the headline estimate identified with other filters and prior weights."""
    from teleop_force.estimation.teststand import (
        STANDSTILL_BAND_RAD_S,
        TeststandOptions,
        estimate_forces,
        identify_teststand,
    )
    from teleop_force.identification.filtered_regressor import FilterConfig

    sensitivity = {}
    for cutoff in (20.0, 40.0):
        for weight in (0.1, 0.3, 1.0):
            variant = TeststandOptions(
                filter=FilterConfig(
                    cutoff_hz=cutoff,
                    velocity_cutoff_hz=5 * cutoff,
                    warmup_s=0.05,
                    estimator="filter",
                    standstill_band_rad_s=STANDSTILL_BAND_RAD_S,
                ),
                prior_weight=weight,
            )
            model = identify_teststand(data.recording, description, variant)
            sensitivity[f"{cutoff:g} Hz, prior {weight:g}"] = data.errors(
                estimate_forces(model, data.recording, description)
            )
    return sensitivity


def _save_teststand_model(identified: TeststandModel, out: Path) -> None:
    """Save the identified model as ``teststand_model.json`` and check that it reads back."""
    from teleop_force.identification.dynamic_model import DynamicModel

    saved = out / "teststand_model.json"
    identified.model.save(saved)
    DynamicModel.load(saved)  # the saved model reads back


def _stream(estimator: Any, recording: Any) -> np.ndarray:
    forces = np.empty((recording.n_samples, 3))
    for k in range(recording.n_samples):
        update = estimator.update(recording.t_s[k], recording.q_rad[k], recording.tau_nm[k])
        forces[k] = update.force_tip_in_base_n
    return forces


def _plot_teststand(
    t: np.ndarray, truth: np.ndarray, lab: np.ndarray, ours: np.ndarray, out: Path
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for axis, column, name in ((axes[0], 2, "f_z"), (axes[1], 0, "f_x")):
        axis.plot(t, truth[:, column], lw=1.0, color="k", label="ATI sensor (negated)")
        axis.plot(t, lab[:, column], lw=0.9, label="lab estimator")
        axis.plot(t, ours[:, column], lw=0.9, label="teleop-force (identified + friction)")
        axis.set_ylabel(f"{name} [N]")
    axes[0].legend(fontsize=7)
    axes[0].set_title("Test stand: force of the foot on the ground (world frame, z up)")
    axes[1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(out / "teststand_force.png", dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------- markdown


def _verdict(joint: int, published: float, value: float) -> str:
    """``j2 beats it by 6.2 points (10.1 %)``; level when it rounds to the published figure."""
    margin = 100 * (published - value)
    if round(100 * value, 1) == round(100 * published, 1):
        return f"j{joint + 1} is level with it ({100 * value:.2f} %)"
    word = "beats" if margin > 0 else "misses"
    return f"j{joint + 1} {word} it by {abs(margin):.1f} points ({100 * value:.1f} %)"


def _mtm_markdown(mtm: dict[str, Any]) -> list[str]:
    """Return the dVRK MTM section of ``robots.md`` from the study's figures."""
    rows = mtm["rows"]
    joints = len(mtm["joint_names"])
    lines = _mtm_test_table(mtm["files"], rows, joints)
    lines += _mtm_train_table(rows, joints)
    lines += _mtm_zero_phase_table(rows, joints)
    lines += _mtm_floor_note(mtm.get("torque_above_floor_hz", {}))
    lines += _mtm_verdicts(rows)
    lines += _mtm_effect_tables(mtm["effects"])
    lines += _mtm_gravity_table(mtm["gravity"])
    lines += [
        "",
        "![relative RMS](mtm_relative_rms.png)",
        "",
        "![torques](mtm_torque_test.png)",
        "",
    ]
    return lines


def _joints_head(joints: int, mean: bool) -> list[str]:
    """Return the head of a per-joint table (with a ``mean j1-3`` column if ``mean``)."""
    extra = 1 if mean else 0
    return [
        "| model | " + " | ".join(f"j{j + 1}" for j in range(joints))
        + (" | mean j1-3 |" if mean else " |"),
        "|---|" + "---|" * (joints + extra),
    ]  # fmt: skip


def _mean_row(name: str, values: Sequence[float]) -> str:
    """Return a table row of per-joint percentages and their mean over joints 1-3."""
    return f"| {name} | " + " | ".join(_pct(values)) + f" | {100 * np.mean(values[:3]):.1f} % |"


def _mtm_test_table(
    files: dict[str, str], rows: dict[str, dict[str, Any]], joints: int
) -> list[str]:
    """Return the section's heading and the test-trajectory table (the paper's metric)."""
    lines = [
        "## dVRK MTM: identified on trajectory one, evaluated on trajectory two",
        "",
        f"- {files['train']}",
        f"- {files['test']}",
        "",
        "Relative RMS of the filtered motor torque per joint on the independent test trajectory"
        " (the paper's metric; training figures in `robots.json`).",
        "",
        *_joints_head(joints, mean=True),
    ]
    for name, row in rows.items():
        if not row.get("done"):
            lines.append(f"| {name} | not done: {row['reason']} |" + " |" * joints)
            continue
        lines.append(_mean_row(name, row["test"]))
    return lines


def _mtm_train_table(rows: dict[str, dict[str, Any]], joints: int) -> list[str]:
    """Return the training-trajectory table (same metric, on the fit data)."""
    lines = ["", "Training trajectory (same metric, fit data):", "", *_joints_head(joints, False)]
    for name, row in rows.items():
        if row.get("done"):
            lines.append(f"| {name} | " + " | ".join(_pct(row["train"])) + " |")
    return lines


def _mtm_zero_phase_table(rows: dict[str, dict[str, Any]], joints: int) -> list[str]:
    """Return the test table under the data authors' zero-phase filter, and their figure."""
    lines = [
        "",
        f"Test trajectory, both torques through a sixth-order zero-phase {MTM_FLOOR_HZ:g} Hz"
        " low-pass (the data authors' filter type) instead of the first-order 8 Hz filter:",
        "",
        *_joints_head(joints, mean=True),
    ]
    for name, row in rows.items():
        if row.get("test_zero_phase"):
            lines.append(_mean_row(name, row["test_zero_phase"]))
    published = f"{100 * MTM_PUBLISHED_RELATIVE_ERROR:.1f} % for joints 1-3."
    lines += ["", f"Published (data authors): below {published}", ""]
    return lines


def _mtm_floor_note(floor: dict[str, Any]) -> list[str]:
    """Return the share of the test torque above the floor frequency (nothing if not done)."""
    if not floor.get("relative_rms"):
        return []
    return [
        f"Share of the filtered test torque above {floor['hz']:g} Hz (the excitation is below"
        " 1 Hz; the smoothed angles carry little motion there, so models explain little"
        " of it): "
        + ", ".join(f"j{j + 1} {v}" for j, v in enumerate(_pct(floor["relative_rms"][:3])))
        + ".",
        "",
    ]


def _mtm_verdicts(rows: dict[str, dict[str, Any]]) -> list[str]:
    """Return, per model done, how joints 1-3 compare with the published figure."""
    lines = [f"Against the published {100 * MTM_PUBLISHED_RELATIVE_ERROR:.1f} %:", ""]
    metrics = (("8 Hz", "test"), (f"{MTM_FLOOR_HZ:g} Hz zero-phase", "test_zero_phase"))
    for name, row in rows.items():
        if not row.get("done"):
            continue
        verdicts = [
            f"{metric}: "
            + ", ".join(
                _verdict(j, MTM_PUBLISHED_RELATIVE_ERROR, v) for j, v in enumerate(row[key][:3])
            )
            for metric, key in metrics
            if row.get(key)
        ]
        lines.append(f"- {name}: {'; '.join(verdicts)}")
    return lines


def _mtm_effect_tables(found: dict[str, list[dict[str, Any]]]) -> list[str]:
    """Return one table per residual-loop run of the effects it found (none if it found none)."""
    lines: list[str] = []
    for label, traced in found.items():
        if traced:
            lines += _mtm_effect_table(label, traced)
    return lines


def _mtm_effect_table(label: str, traced: list[dict[str, Any]]) -> list[str]:
    """Return the table of the effects one residual-loop run found."""
    lines = [
        "",
        f"Effects the residual loop found ({label}; fit on trajectory one: held-out time"
        " blocks decide, each effect confirmed on the whole model and vetoed if it raises"
        " an explained joint's error on blocks held out by phase; RMS columns: the"
        " joint's own held-out design):",
        "",
        "| # | joint | acts on (motor torque per unit) | depends on | kind | explained"
        " | joint RMS before | after |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for k, e in enumerate(traced):
        acts = describe_reach(e["joint"], e.get("reach"))
        lines.append(
            f"| {k + 1} | {e['joint']} | {acts} | {', '.join(e['depends_on'])} | {e['kind']} |"
            f" {e['explained']:.1%} |"
            f" {e['joint_rms_before']:.1%} | {e['joint_rms_after']:.1%} |"
        )
    return lines


def _mtm_gravity_table(gravity: dict[str, dict[str, list[float]]]) -> list[str]:
    """Return the table of the gravity-direction check (relative RMS, joints 1-3)."""
    lines = [
        "",
        "Gravity direction in the MTM base frame (CV friction; relative RMS joints 1-3):",
        "",
        "| gravity along | train j1 | j2 | j3 | test j1 | j2 | j3 |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, fig in gravity.items():
        lines.append(f"| {label} | " + " | ".join(_pct(fig["train"][:3] + fig["test"][:3])) + " |")
    return lines


def _teststand_markdown(ts: dict[str, Any]) -> list[str]:
    opts = ts["options"]
    lines = [
        "## Test stand: foot force from joint torques vs the ATI sensor",
        "",
        f"- {ts['file']}",
        "- commanded (target) joint torques unless the row says otherwise.",
        f"- RMS of the sensor's f_z: {ts['rms_fz_n']:.2f} N over {ts['samples']} samples;"
        f" identified on {ts['free_samples']} samples without contact"
        f" (|F| < {opts['free_force_n']:g} N,"
        f" {1000 * opts['guard_s']:.0f} ms guard); filter {opts['cutoff_hz']:g} Hz"
        f" (pre-filter {opts['prefilter_hz']:g} Hz), prior weight {opts['prior_weight']:g},"
        f" {opts['friction']} friction.",
        "",
        "| estimate | f_z RMS error | f_x RMS error | f_z RMS error in contact |",
        "|---|---|---|---|",
    ]
    for name, fig in ts["rows"].items():
        lines.append(
            f"| {name} | {fig['fz_rms_n']:.2f} N | {fig['fx_rms_n']:.2f} N |"
            f" {fig['fz_rms_contact_n']:.2f} N |"
        )
    best = ts["rows"]["identified rigid body + friction"]["fz_rms_n"]
    lab = ts["rows"]["lab estimator (baseline)"]["fz_rms_n"]
    lines += [
        "",
        f"f_z error {best:.2f} N against the lab's {lab:.2f} N:"
        f" {100 * (1 - best / lab):.0f} % lower.",
        "",
        "Sensitivity of the headline row to the filter and the prior weight:",
        "",
        "| filter, prior | f_z RMS error | f_x RMS error |",
        "|---|---|---|",
    ]
    for name, fig in ts["sensitivity"].items():
        lines.append(f"| {name} | {fig['fz_rms_n']:.2f} N | {fig['fx_rms_n']:.2f} N |")
    lines += [
        "",
        f"The slider term itself (its f_z contribution) is {ts['slider_term_rms_n']:.2f} N RMS.",
        "",
        "![force](teststand_force.png)",
        "",
    ]
    return lines


def run_robot_reports(
    out: Path,
    datasets: Path | None = None,
    residual: bool = True,
    log: Callable[[str], None] = lambda message: print(message, file=sys.stderr),
) -> Path:
    """Run both studies from the shared data; write ``robots.md``, ``robots.json`` and plots."""
    datasets = datasets or default_datasets_dir()
    if not datasets.is_dir():
        raise DataError(
            "no shared datasets folder (expected <repo>/../shared/datasets)", path=datasets
        )
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    mtm = mtm_study(datasets / "dvrk_mtm", out, residual, log)
    teststand = teststand_study(datasets / "teststand", out, log)
    payload = {"dvrk_mtm": mtm, "teststand": teststand, "seconds": time.perf_counter() - start}
    (out / "robots.json").write_text(json.dumps(payload, indent=1))
    lines = [
        "# Measured data from real robots",
        "",
        "Regenerated by `teleop-force report-robots` from `../shared/datasets`"
        f" in {payload['seconds']:.0f} s.",
        "",
    ]
    lines += _mtm_markdown(mtm) + _teststand_markdown(teststand)
    path = out / "robots.md"
    path.write_text("\n".join(lines))
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m teleop_force.reports.robots [FOLDER] [--skip-residual]``."""
    args = list(sys.argv[1:] if argv is None else argv)
    residual = "--skip-residual" not in args
    folders = [a for a in args if not a.startswith("--")]
    out = Path(folders[0]) if folders else Path("reports/robots")
    try:
        path = run_robot_reports(out, residual=residual)
    except TeleopForceError as exc:
        print(f"report-robots: {exc}", file=sys.stderr)
        return 2
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
