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
REQUIRED_ROLES = ("q", "qd", "tau_measured")
TORQUE_SOURCES = ("measured", "target")


@dataclass(frozen=True, eq=False)
class TeststandLog:
    """The test stand's native logs, aligned on the controller tick.

    Attributes:
        recording: ``t = (tick - first tick) * 1 ms``, joint angles, the chosen joint torques
            and, when the ATI file is there, the ground-truth force of the foot on the ground
            (project convention: the negated ATI force).
        ticks: Controller tick of every sample.
        qd_rad_s: Measured joint velocities.
        tau_measured_nm: Measured joint torques (motor current x torque constant x gear).
        tau_target_nm: Commanded joint torques (``None`` when the file is absent).
        ati_torque_nm: ATI torques as logged (``None`` when absent).
        contact_sensor: Foot contact sensor value (about 1 with the foot in the air, near 0
            on the ground; ``None`` when absent).
        height_m: Slider height sensor (``None`` when absent).
        lab_estimate_n: The lab's force estimate, project convention (``None`` when absent).
        torque_source: ``measured`` or ``target``: which torques ``recording`` carries.
        dropped_ticks: Per file, ticks present in it but not in every file (dropped).

    """

    recording: Recording
    ticks: np.ndarray
    qd_rad_s: np.ndarray
    tau_measured_nm: np.ndarray
    tau_target_nm: np.ndarray | None
    ati_torque_nm: np.ndarray | None
    contact_sensor: np.ndarray | None
    height_m: np.ndarray | None
    lab_estimate_n: np.ndarray | None
    torque_source: str
    dropped_ticks: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = self.recording.n_samples
        if self.torque_source not in TORQUE_SOURCES:
            raise DataError(
                f"torque_source must be one of {TORQUE_SOURCES}", path=self.recording.source
            )
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
        """One line: samples kept, ticks dropped per file."""
        dropped = ", ".join(f"{k} {v}" for k, v in self.dropped_ticks.items() if v)
        return (
            f"{self.recording.source}: {self.recording.n_samples} samples aligned on the tick "
            f"({self.torque_source} torques)" + (f"; ticks dropped: {dropped}" if dropped else "")
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
    folder: str | os.PathLike[str], torque_source: str = "target"
) -> TeststandLog:
    """Read the test stand's ``.dat`` logs from ``folder`` and align them on the tick.

    Only ticks present in every file that is there are kept (the files start together but
    end at slightly different ticks). ``torque_source`` chooses the torques the recording
    carries: ``target`` (the default: the torques sent to the motor drivers, the project's
    convention of a commanded torque acting over the next sample, and the one a sensorless
    estimator always has) or ``measured`` (motor current x torque constant x gear: the same
    signal plus current-sensing noise; on the published set it gives a slightly larger force
    error, see ``docs/robots.md``).
    """
    folder = Path(folder)
    if torque_source not in TORQUE_SOURCES:
        raise DataError(
            f"torque source must be one of {', '.join(TORQUE_SOURCES)}, got {torque_source!r}"
        )
    if not folder.is_dir():
        raise DataError("not a folder of test-stand logs", path=folder)
    logs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for role, (name, n_values) in NATIVE_FILES.items():
        path = folder / name
        if path.is_file():
            logs[role] = read_dat(path, n_values)
        elif role in REQUIRED_ROLES or (role == "tau_target" and torque_source == "target"):
            raise DataError(f"missing test-stand log {name}", path=folder)
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
    tau = aligned["tau_measured"] if torque_source == "measured" else aligned["tau_target"]
    force = -aligned["ati_force"] if "ati_force" in aligned else None
    recording = Recording(
        t_s=(common - common[0]) * TICK_S,
        q_rad=aligned["q"],
        tau_nm=tau,
        f_tip_in_base_n=force,
        source=folder,
    )
    return TeststandLog(
        recording=recording,
        ticks=common,
        qd_rad_s=aligned["qd"],
        tau_measured_nm=aligned["tau_measured"],
        tau_target_nm=aligned.get("tau_target"),
        ati_torque_nm=aligned.get("ati_torque"),
        contact_sensor=aligned["contact"][:, 0] if "contact" in aligned else None,
        height_m=aligned["height"][:, 0] if "height" in aligned else None,
        lab_estimate_n=-aligned["lab_estimate"] if "lab_estimate" in aligned else None,
        torque_source=torque_source,
        dropped_ticks=dropped,
    )
