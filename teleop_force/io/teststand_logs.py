"""The test stand's native logs (whitespace-separated ``.dat`` files): read and aligned on the tick.

Column 0 of every file is the 1 kHz controller tick; the other columns are the values of the
file's role (:data:`NATIVE_FILES`). The robot itself is :mod:`teleop_force.robots.teststand`,
where the sign conventions of the ATI force are given.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from teleop_force.errors import DataError
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.teststand import (
    TICK_S,
)

#: Native files, by role: (file name suffix, number of value columns).
NATIVE_FILES = {
    "q": ("dg_hopper_teststand-joint_positions.dat", 2),
    "qd": ("dg_hopper_teststand-joint_velocities.dat", 2),
    "tau_measured": ("dg_hopper_teststand-joint_torques.dat", 2),
    "tau_target": ("dg_hopper_teststand-joint_target_torques.dat", 2),
    "ati_force": ("dg_hopper_teststand-ati_force.dat", 3),
    "ati_torque": ("dg_hopper_teststand-ati_torque.dat", 3),
    "contact": ("dg_hopper_teststand-contact_sensors.dat", 1),
    "height": ("dg_hopper_teststand-height_sensors.dat", 1),
    "lab_estimate": ("dg_est_f_hopper-sout.dat", 3),
}
#: Roles without which nothing can be read (no other file replaces them).
REQUIRED_ROLES = ("q",)
TORQUE_SOURCES = ("measured", "target")
#: The file of each torque source.
TORQUE_ROLES = {"target": "tau_target", "measured": "tau_measured"}
#: Velocity sources: the lab's velocity log, or the backward difference of the positions.
VELOCITY_SOURCES = ("logged", "derived")


@dataclass(frozen=True, eq=False)
class TeststandLog:
    """The test stand's native logs, aligned on the controller tick.

    Attributes:
        recording: ``t = (tick - first tick) * 1 ms``, joint angles, the chosen joint torques
            and, when the ATI file is there, the ground-truth force of the foot on the ground
            (project convention: the negated ATI force).
        ticks: Controller tick of every sample.
        qd_rad_s: Joint velocities: logged, or (``velocity_source == "derived"``, when
            ``joint_velocities.dat`` is absent) the backward difference of the positions over
            the ticks (0 at the first sample).
        tau_measured_nm: Measured joint torques (motor current x torque constant x gear;
            ``None`` when the file is absent).
        tau_target_nm: Commanded joint torques (``None`` when the file is absent).
        ati_torque_nm: ATI torques as logged (``None`` when absent).
        contact_sensor: Foot contact sensor value (about 1 with the foot in the air, near 0
            on the ground; ``None`` when absent).
        height_m: Slider height sensor (``None`` when absent).
        lab_estimate_n: The lab's force estimate, project convention (``None`` when absent).
        torque_source: ``measured`` or ``target``: which torques ``recording`` carries.
        dropped_ticks: Per file, ticks present in it but not in every file (dropped).
        velocity_source: ``logged`` or ``derived`` (see ``qd_rad_s``).
        warnings: What reading had to replace (a torque source that was asked for by default
            but is absent), one sentence each; :meth:`note` carries them.

    """

    recording: Recording
    ticks: np.ndarray
    qd_rad_s: np.ndarray
    tau_measured_nm: np.ndarray | None
    tau_target_nm: np.ndarray | None
    ati_torque_nm: np.ndarray | None
    contact_sensor: np.ndarray | None
    height_m: np.ndarray | None
    lab_estimate_n: np.ndarray | None
    torque_source: str
    dropped_ticks: dict[str, int] = field(default_factory=dict)
    velocity_source: str = "logged"
    warnings: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        n = self.recording.n_samples
        if self.torque_source not in TORQUE_SOURCES:
            raise DataError(
                f"torque_source must be one of {TORQUE_SOURCES}", path=self.recording.source
            )
        if self.velocity_source not in VELOCITY_SOURCES:
            raise DataError(
                f"velocity_source must be one of {VELOCITY_SOURCES}", path=self.recording.source
            )
        if getattr(self, f"tau_{self.torque_source}_nm") is None:
            raise DataError(f"no {self.torque_source} torques to carry", path=self.recording.source)
        if self.ticks.shape != (n,):
            raise DataError("ticks and samples differ in number", path=self.recording.source)
        for name in (
            "qd_rad_s",
            "tau_measured_nm",
            "tau_target_nm",
            "ati_torque_nm",
            "contact_sensor",
            "height_m",
            "lab_estimate_n",
        ):
            value = getattr(self, name)
            if value is not None and value.shape[0] != n:
                raise DataError(
                    f"{name} has {value.shape[0]} samples, expected {n}", path=self.recording.source
                )

    def note(self) -> str:
        """One line: samples kept, ticks dropped per file, what was derived, any warning."""
        dropped = ", ".join(f"{k} {v}" for k, v in self.dropped_ticks.items() if v)
        derived = (
            f"; velocities derived from the positions (no {NATIVE_FILES['qd'][0]})"
            if self.velocity_source == "derived"
            else ""
        )
        return (
            f"{self.recording.source}: {self.recording.n_samples} samples aligned on the tick "
            f"({self.torque_source} torques)"
            + (f"; ticks dropped: {dropped}" if dropped else "")
            + derived
            + "".join(f"; warning: {w}" for w in self.warnings)
        )


def is_teststand_folder(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a folder holding the test stand's joint-position log."""
    path = Path(path)
    return path.is_dir() and (path / NATIVE_FILES["q"][0]).is_file()


def read_dat(path: Path, n_values: int) -> tuple[np.ndarray, np.ndarray]:
    """Read one ``.dat`` log: (ticks, values ``(N, n_values)``); extra columns are ignored.

    Raises:
        DataError: naming the file and the 1-based row for a short, non-numeric or
            non-finite row, a non-integer tick, or ticks that do not increase.

    """
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read file: {exc}", path=path) from None
    rows = []
    for i, line in enumerate(lines):
        cells = line.split()
        if not cells:
            continue
        if len(cells) < 1 + n_values:
            raise DataError(
                f"{len(cells)} columns, expected tick + {n_values} values", path=path, row=i + 1
            )
        try:
            values = [float(c) for c in cells[: 1 + n_values]]
        except ValueError:
            raise DataError(
                f"not a number in {cells[: 1 + n_values]}", path=path, row=i + 1
            ) from None
        if not all(np.isfinite(values)):
            raise DataError("not finite", path=path, row=i + 1)
        if values[0] != round(values[0]):
            raise DataError(
                f"tick {values[0]!r} is not an integer", path=path, row=i + 1, column="tick"
            )
        rows.append(values)
    if not rows:
        raise DataError("no data rows", path=path)
    table = np.asarray(rows)
    ticks = table[:, 0].astype(np.int64)
    bad = np.flatnonzero(np.diff(ticks) <= 0)
    if bad.size:
        raise DataError(
            f"tick {ticks[bad[0] + 1]} does not increase (after {ticks[bad[0]]})",
            path=path,
            row=int(bad[0]) + 2,
            column="tick",
        )
    return ticks, table[:, 1:]


def read_teststand_folder(
    folder: str | os.PathLike[str], torque_source: str | None = None
) -> TeststandLog:
    """Read the test stand's ``.dat`` logs from ``folder`` and align them on the tick.

    Only ticks present in every file that is there are kept (the files start together but
    end at slightly different ticks). ``torque_source`` chooses the torques the recording
    carries: ``target`` (the torques sent to the motor drivers, the project's convention of a
    commanded torque acting over the next sample, and the one a sensorless estimator always
    has) or ``measured`` (motor current x torque constant x gear: the same signal plus
    current-sensing noise; on the published set it gives a slightly larger force error, see
    ``docs/robots.md``). ``None`` (the default) takes ``target`` when its file is there, else
    ``measured`` with a warning (:attr:`TeststandLog.warnings`, in :meth:`TeststandLog.note`).

    Logs as labs write them: without ``joint_velocities.dat`` the velocities are derived from
    the positions; the ATI, contact, height and lab-estimate files are optional.

    Raises:
        DataError: naming the missing file when the positions, the torque source asked for,
            or both torque files are absent, and naming file and row for a bad row.

    """
    folder = Path(folder)
    if torque_source is not None and torque_source not in TORQUE_SOURCES:
        raise DataError(
            f"torque source must be one of {', '.join(TORQUE_SOURCES)}, got {torque_source!r}"
        )
    if not folder.is_dir():
        raise DataError("not a folder of test-stand logs", path=folder)
    present = {role for role, (name, _) in NATIVE_FILES.items() if (folder / name).is_file()}
    for role in REQUIRED_ROLES:
        if role not in present:
            raise DataError(f"missing test-stand log {NATIVE_FILES[role][0]}", path=folder)
    source, warnings = _torque_source(folder, present, torque_source)
    logs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for role, (name, n_values) in NATIVE_FILES.items():
        if role in present:
            logs[role] = read_dat(folder / name, n_values)
    common = logs["q"][0]
    for ticks, _ in logs.values():
        common = np.intersect1d(common, ticks)
    if common.size < 3:
        raise DataError(f"only {common.size} ticks common to every log", path=folder)
    aligned = {}
    dropped = {}
    for role, (ticks, values) in logs.items():
        aligned[role] = values[np.searchsorted(ticks, common)]
        dropped[role] = int(ticks.size - common.size)
    force = -aligned["ati_force"] if "ati_force" in aligned else None
    t_s = (common - common[0]) * TICK_S
    recording = Recording(
        t_s=t_s,
        q_rad=aligned["q"],
        tau_nm=aligned[TORQUE_ROLES[source]],
        f_tip_in_base_n=force,
        source=folder,
    )
    qd = aligned["qd"] if "qd" in aligned else velocity_from_positions(t_s, aligned["q"])
    return TeststandLog(
        recording=recording,
        ticks=common,
        qd_rad_s=qd,
        tau_measured_nm=aligned.get("tau_measured"),
        tau_target_nm=aligned.get("tau_target"),
        ati_torque_nm=aligned.get("ati_torque"),
        contact_sensor=aligned["contact"][:, 0] if "contact" in aligned else None,
        height_m=aligned["height"][:, 0] if "height" in aligned else None,
        lab_estimate_n=-aligned["lab_estimate"] if "lab_estimate" in aligned else None,
        torque_source=source,
        dropped_ticks=dropped,
        velocity_source="logged" if "qd" in aligned else "derived",
        warnings=warnings,
    )


def velocity_from_positions(t_s: np.ndarray, q_rad: np.ndarray) -> np.ndarray:
    """Backward-difference velocity ``(q[k] - q[k-1]) / (t[k] - t[k-1])``, 0 at the first sample.

    The same velocity the project's filters compute from the positions (before their
    low-pass): the model never reads the lab's velocity log, only ``TeststandLog.qd_rad_s``.
    """
    qd = np.zeros_like(q_rad, dtype=float)
    qd[1:] = np.diff(q_rad, axis=0) / np.diff(t_s)[:, None]
    return qd


def _torque_source(
    folder: Path, present: set[str], asked: str | None
) -> tuple[str, tuple[str, ...]]:
    """Return the torque source to read, and the warning when it is not the default one."""
    if asked is not None:
        if TORQUE_ROLES[asked] not in present:
            name = NATIVE_FILES[TORQUE_ROLES[asked]][0]
            raise DataError(f"missing test-stand log {name} ({asked} torques)", path=folder)
        return asked, ()
    if TORQUE_ROLES["target"] in present:
        return "target", ()
    target, measured = (NATIVE_FILES[TORQUE_ROLES[k]][0] for k in ("target", "measured"))
    if TORQUE_ROLES["measured"] not in present:
        raise DataError(
            f"missing test-stand logs {target} and {measured}: no joint torques", path=folder
        )
    return "measured", (f"no {target}: the torques are the measured ones ({measured})",)
