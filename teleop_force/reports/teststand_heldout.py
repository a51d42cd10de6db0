"""The test stand held out in time: identify on the first part of a log, score on the rest.

``teleop-force teststand-heldout FOLDER`` (docs/cli.md). The model is identified on the first
``train_fraction`` of the samples (the ATI force only picks the phases without contact there;
it never enters the fit) and the force is estimated over the whole log with causal filters
(the estimator runs on as it would live), then scored against the ATI sensor on the held-out
rest only. The model's Coulomb term is the sticking (Dahl) state, its transition angle
identified with the rest on the phases without contact
(:mod:`teleop_force.estimation.teststand`); the same identification with ``sgn(qd)`` and the
standstill dead band instead (the model before the sticking state) is scored beside it. The
baseline is the URDF rigid body with ``J^-T`` and no friction, through the same filters, on
the same samples.

The f_z error is split (issue 19): ``lag`` is the RMS of the true force filtered like the
estimate minus the true force (what the filters' delay alone costs), ``bias`` the mean of the
estimate minus that filtered force, ``spread`` the RMS of the rest; ``rms^2 ~ lag^2 + bias^2
+ spread^2`` up to the cross terms. Errors are also given at standstill (every joint slower
than 0.01 rad/s, pre-filtered velocity), while moving, and as the false force where the ATI
reads no contact.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.estimation.teststand import (
    TeststandOptions,
    estimate_forces,
    free_phase_mask,
    identify_teststand,
    nominal_teststand_model,
)
from teleop_force.identification.filtered_regressor import filter_signals, lagged
from teleop_force.io.interchange_csv import Recording
from teleop_force.io.teststand_logs import read_teststand_folder
from teleop_force.lowpass import lowpass_batch
from teleop_force.robots.teststand import teststand_description

#: The issue's goal: held-out RMS f_z error at most this fraction of the URDF-``J^-T`` one.
GOAL_RATIO = 2.0 / 3.0
#: Every joint slower than this [rad/s]: standstill (issue 19).
STANDSTILL_RAD_S = 0.01
#: The text's name of each estimate of ``HeldOutReport.first_part_contact_n``.
_ROW_NAMES = {"urdf": "URDF", "ours": "identified", "dead_band": "with dead band"}


@dataclass(frozen=True)
class ForceErrors:
    """f_z errors of one estimate against the ATI sensor on a set of samples [N].

    Attributes:
        rms_n: RMS error.
        lag_n: RMS of the sensor force filtered like the estimate minus the sensor force.
        bias_n: Mean of the estimate minus the filtered sensor force.
        spread_n: RMS of the estimate minus the filtered sensor force, bias removed.
        standstill_rms_n: RMS error at standstill (NaN without such samples).
        moving_rms_n: RMS error while moving (NaN without such samples).
        free_false_force_n: RMS estimated f_z where the ATI reads no contact (NaN if none).

    """

    rms_n: float
    lag_n: float
    bias_n: float
    spread_n: float
    standstill_rms_n: float
    moving_rms_n: float
    free_false_force_n: float

    def __post_init__(self) -> None:
        if not np.isfinite(self.rms_n):
            raise DataError("no finite estimate to score")


@dataclass(frozen=True)
class HeldOutReport:
    """Held-out and in-sample figures of the test stand (see the module docstring).

    Attributes:
        source: The log folder.
        torque_source: ``target`` or ``measured``.
        train_samples: Samples of the first part (identification).
        test_samples: Samples of the held-out part.
        free_samples: Samples without contact the fit used.
        standstill_samples: Held-out samples at standstill.
        rms_truth_fz_n: RMS of the sensor's f_z on the held-out part.
        urdf: The URDF rigid body with ``J^-T``, no friction, held out.
        ours: The identified model, held out.
        lab: The lab's own estimate, held out (None without its file); its filters are its
            own, so its split is against the raw sensor force (``lag`` 0).
        dead_band: The same identification with ``sgn(qd)`` and the dead band in place of
            the sticking state, held out (None when ``ours`` has no sticking state).
        first_part_contact_n: RMS f_z error on the first part's samples in contact (after
            the filters' warm-up), per estimate (``urdf``, ``ours``, ``dead_band``): samples
            no fit used, but from the part the model was identified on, so not held out.
        in_sample_ours_n: RMS f_z error of a model identified on the whole log, scored on
            the whole log (in-sample; the old headline).
        in_sample_urdf_n: The URDF's RMS f_z error on the whole log.
        ratio: ``ours.rms_n / urdf.rms_n``.
        options: Filter, dead band, prior weight, friction of the identified model.

    """

    source: str
    torque_source: str
    train_samples: int
    test_samples: int
    free_samples: int
    standstill_samples: int
    rms_truth_fz_n: float
    urdf: ForceErrors
    ours: ForceErrors
    lab: ForceErrors | None
    dead_band: ForceErrors | None
    first_part_contact_n: dict[str, float]
    in_sample_ours_n: float
    in_sample_urdf_n: float
    ratio: float
    options: dict[str, Any]

    @property
    def goal_met(self) -> bool:
        """Whether the held-out error is at most :data:`GOAL_RATIO` of the URDF's."""
        return self.ratio <= GOAL_RATIO

    def to_json(self) -> dict[str, Any]:
        """Return the report as JSON-compatible values (NaN as None)."""
        payload = asdict(self)
        payload["goal_ratio"] = GOAL_RATIO
        payload["goal_met"] = self.goal_met
        return _finite_or_none(payload)

    def lines(self) -> list[str]:
        """Return the report as text lines."""
        fit, held = ("last", "first") if self.options.get("reverse") else ("first", "last")
        out = [
            f"{self.source} ({self.torque_source} torques): identified on the {fit} "
            f"{self.train_samples} samples ({self.free_samples} without contact), "
            f"held out: the {held} {self.test_samples} "
            f"({self.standstill_samples} at standstill); RMS f_z {self.rms_truth_fz_n:.2f} N",
            "held out, f_z [N]       rms   lag   bias  spread  standstill  moving",
        ]
        rows = [("URDF + J^-T", self.urdf), ("identified", self.ours)]
        if self.dead_band is not None:
            rows.append(("  with dead band", self.dead_band))
        if self.lab is not None:
            rows.append(("lab estimator", self.lab))
        for name, e in rows:
            out.append(
                f"  {name:20s} {e.rms_n:5.3f} {e.lag_n:5.3f} {e.bias_n:+6.3f} {e.spread_n:6.3f}"
                f"  {e.standstill_rms_n:10.3f}  {e.moving_rms_n:6.3f}"
            )
        free = self.ours.free_false_force_n
        out.append(
            "false force where the ATI reads no contact: "
            + (
                "no such sample in the held-out part"
                if not np.isfinite(free)
                else f"identified {free:.3f} N, URDF {self.urdf.free_false_force_n:.3f} N RMS"
            )
        )
        sticking = float(self.options.get("sticking_rad", 0.0))
        if sticking > 0.0:
            out.append(
                f"identified: sticking Coulomb term, transition angle {sticking:.2g} rad "
                "(identified without contact)"
            )
        verdict = "met" if self.goal_met else "NOT met"
        out.append(f"identified / URDF = {self.ratio:.2f} (goal <= {GOAL_RATIO:.2f}: {verdict})")
        first = self.first_part_contact_n  # the identification's part, in either direction
        out.append(
            f"{fit} part, samples in contact (in no fit, not held out): "
            + ", ".join(f"{_ROW_NAMES[name]} {value:.3f} N" for name, value in first.items())
        )
        out.append(
            f"in-sample (identified and scored on the whole log): identified "
            f"{self.in_sample_ours_n:.3f} N, URDF {self.in_sample_urdf_n:.3f} N"
        )
        return out


def held_out_study(
    folder: str | os.PathLike[str],
    train_fraction: float = 2.0 / 3.0,
    torque_source: str | None = None,
    options: TeststandOptions | None = None,
    reverse: bool = False,
) -> HeldOutReport:
    """Identify on the first ``train_fraction`` of the log, score on the rest (module doc).

    ``reverse``: identify on the last ``train_fraction``, score on the first samples (the
    check in the other direction).
    """
    if not 0.0 < train_fraction < 1.0:
        raise ConfigurationError(f"train_fraction must be in (0, 1), got {train_fraction}")
    options = options or TeststandOptions(sticking=True)
    log = read_teststand_folder(folder, torque_source)
    recording = log.recording
    truth = recording.f_tip_in_base_n
    if truth is None:
        raise DataError(
            "no ATI force (dg_hopper_teststand-ati_force.dat) to score against",
            path=recording.source,
        )
    n = recording.n_samples
    cut = round(train_fraction * n)
    if cut < 3 or n - cut < 3:
        raise DataError(
            f"{n} samples cannot be split at {train_fraction:.2f}", path=recording.source
        )
    description = teststand_description()
    head = _tail(recording, n - cut) if reverse else _head(recording, cut)
    identified = identify_teststand(head, description, options)
    nominal = nominal_teststand_model(description, options)
    ours = estimate_forces(identified, recording, description)
    dead_band = (
        estimate_forces(
            identify_teststand(head, description, replace(options, sticking=False)),
            recording,
            description,
        )
        if options.sticking
        else None
    )
    urdf = estimate_forces(nominal, recording, description, with_friction=False)
    whole = identify_teststand(recording, description, options)
    in_sample = estimate_forces(whole, recording, description)

    config = options.filter
    filtered_truth = lagged(
        lowpass_batch(
            lowpass_batch(truth, recording.t_s, config.velocity_cutoff_hz),
            recording.t_s,
            config.cutoff_hz,
        ),
        config.torque_lag_samples,
    )
    qd = filter_signals(
        recording.t_s, recording.q_rad, recording.tau_nm, None, None, config
    ).qd_rad_s
    test = np.arange(n) < n - cut if reverse else np.arange(n) >= cut
    still = np.all(np.abs(qd) < STANDSTILL_RAD_S, axis=1)
    free = free_phase_mask(recording, options.free_force_n, 0.0)
    sets = _SampleSets(test, test & still, test & ~still, test & free)

    def errors(forces: np.ndarray) -> ForceErrors:
        return _errors(forces[:, 2], truth[:, 2], filtered_truth[:, 2], sets)

    # the lab's estimate has filters of its own: its error is split against the raw force
    lab = (
        None
        if log.lab_estimate_n is None
        else _errors(log.lab_estimate_n[:, 2], truth[:, 2], truth[:, 2], sets)
    )
    urdf_errors, our_errors = errors(urdf), errors(ours)
    first_contact = ~test & ~free & (recording.t_s >= recording.t_s[0] + config.warmup_s)
    estimates = {"urdf": urdf, "ours": ours}
    if dead_band is not None:
        estimates["dead_band"] = dead_band
    first_part_contact = {
        name: _rms(forces[first_contact, 2] - truth[first_contact, 2])
        for name, forces in estimates.items()
    }
    return HeldOutReport(
        source=str(recording.source),
        torque_source=log.torque_source,
        train_samples=cut,
        test_samples=n - cut,
        free_samples=identified.free_samples,
        standstill_samples=int(sets.standstill.sum()),
        rms_truth_fz_n=_rms(truth[test, 2]),
        urdf=urdf_errors,
        ours=our_errors,
        lab=lab,
        dead_band=None if dead_band is None else errors(dead_band),
        first_part_contact_n=first_part_contact,
        in_sample_ours_n=_rms(in_sample[:, 2] - truth[:, 2]),
        in_sample_urdf_n=_rms(urdf[:, 2] - truth[:, 2]),
        ratio=our_errors.rms_n / urdf_errors.rms_n,
        options={
            "cutoff_hz": config.cutoff_hz,
            "prefilter_hz": config.velocity_cutoff_hz,
            "standstill_band_rad_s": float(getattr(config, "standstill_band_rad_s", 0.0)),
            "prior_weight": options.prior_weight,
            "friction": options.friction,
            "sticking_rad": identified.sticking_rad,
            "free_force_n": options.free_force_n,
            "guard_s": options.guard_s,
            "train_fraction": train_fraction,
            "reverse": reverse,
        },
    )


@dataclass(frozen=True)
class _SampleSets:
    """Boolean masks of the held-out samples: all, at standstill, moving, without contact."""

    test: np.ndarray
    standstill: np.ndarray
    moving: np.ndarray
    free: np.ndarray


def _head(recording: Recording, cut: int) -> Recording:
    """Return the first ``cut`` samples of ``recording``."""
    force = recording.f_tip_in_base_n
    return Recording(
        recording.t_s[:cut],
        recording.q_rad[:cut],
        recording.tau_nm[:cut],
        None if force is None else force[:cut],
        source=recording.source,
    )


def _tail(recording: Recording, start: int) -> Recording:
    """Return the samples of ``recording`` from ``start`` on."""
    force = recording.f_tip_in_base_n
    return Recording(
        recording.t_s[start:],
        recording.q_rad[start:],
        recording.tau_nm[start:],
        None if force is None else force[start:],
        source=recording.source,
    )


def _errors(
    estimate: np.ndarray, truth: np.ndarray, filtered_truth: np.ndarray, sets: _SampleSets
) -> ForceErrors:
    test = sets.test
    model_error = estimate[test] - filtered_truth[test]
    bias = float(np.nanmean(model_error))
    return ForceErrors(
        rms_n=_rms(estimate[test] - truth[test]),
        lag_n=_rms(filtered_truth[test] - truth[test]),
        bias_n=bias,
        spread_n=_rms(model_error - bias),
        standstill_rms_n=_rms(estimate[sets.standstill] - truth[sets.standstill]),
        moving_rms_n=_rms(estimate[sets.moving] - truth[sets.moving]),
        free_false_force_n=_rms(estimate[sets.free]),
    )


def _rms(x: np.ndarray) -> float:
    """RMS over the finite entries (NaN when there are none)."""
    finite = np.asarray(x, dtype=float)
    finite = finite[np.isfinite(finite)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def write_report(report: HeldOutReport, path: Path) -> Path:
    """Write ``report``'s text lines to ``path`` (a ``.md`` code block) and return it."""
    path.write_text("```\n" + "\n".join(report.lines()) + "\n```\n", encoding="utf-8")
    return path
