"""Test-stand logs as labs write them: files missing, replaced where they can be, else named."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from teleop_force.errors import DataError
from teleop_force.io import teststand_logs
from teleop_force.io.recordings import read_recording_with_notes
from teleop_force.io.teststand_logs import (
    NATIVE_FILES,
    read_teststand_folder,
    velocity_from_positions,
)
from tests.shared_data import require


def _write_logs(folder: Path, roles: tuple[str, ...] | None = None) -> None:
    """Small logs, 20 ticks: positions a ramp, every other value a distinct constant."""
    folder.mkdir(exist_ok=True)
    ticks = np.arange(500, 520)
    for role, (name, n_values) in NATIVE_FILES.items():
        if roles is not None and role not in roles:
            continue
        if role == "q":
            values = np.outer(ticks - 500, [0.01, -0.02]) + np.array([0.9, -2.0])
        else:
            values = np.full((ticks.size, n_values), 0.1 * (1 + list(NATIVE_FILES).index(role)))
        lines = [
            f"{t}\t" + "\t".join(repr(float(v)) for v in row)
            for t, row in zip(ticks, values, strict=True)
        ]
        (folder / name).write_text("\n".join(lines) + "\n")


def _copy_shared(tmp_path: Path, drop: tuple[str, ...]) -> Path:
    source = require("teststand")
    folder = tmp_path / "teststand"
    shutil.copytree(source, folder)
    for role in drop:
        (folder / NATIVE_FILES[role][0]).chmod(0o644)
        (folder / NATIVE_FILES[role][0]).unlink()
    return folder


def test_velocities_are_derived_from_positions_without_their_log(tmp_path: Path) -> None:
    _write_logs(tmp_path, ("q", "tau_target", "tau_measured"))
    log = read_teststand_folder(tmp_path)
    assert log.velocity_source == "derived"
    # positions step by (0.01, -0.02) rad per 1 ms tick
    np.testing.assert_allclose(log.qd_rad_s[1:], np.tile([10.0, -20.0], (19, 1)))
    np.testing.assert_allclose(log.qd_rad_s[0], [0.0, 0.0])
    assert "velocities derived from the positions" in log.note()
    assert log.warnings == ()


def test_measured_torques_replace_absent_target_torques_with_one_warning(tmp_path: Path) -> None:
    _write_logs(tmp_path, ("q", "tau_measured", "ati_force"))
    log = read_teststand_folder(tmp_path)
    assert log.torque_source == "measured" and log.tau_target_nm is None
    np.testing.assert_allclose(log.recording.tau_nm, log.tau_measured_nm)
    assert len(log.warnings) == 1 and "joint_target_torques.dat" in log.warnings[0]
    recording, notes = read_recording_with_notes(tmp_path, robot="teststand")
    assert len(notes) == 1 and "warning:" in notes[0] and "measured" in notes[0]
    assert recording.has_force


def test_target_torques_stay_the_default_when_present(tmp_path: Path) -> None:
    _write_logs(tmp_path)
    log = read_teststand_folder(tmp_path)
    assert log.torque_source == "target" and log.velocity_source == "logged"
    assert log.warnings == () and "warning" not in log.note()
    np.testing.assert_allclose(log.recording.tau_nm, log.tau_target_nm)


@pytest.mark.parametrize(
    ("roles", "source", "named"),
    [
        (("tau_target", "tau_measured"), None, "joint_positions.dat"),
        (("q",), None, "joint_target_torques.dat and dg_hopper_teststand-joint_torques.dat"),
        (("q", "tau_measured"), "target", "joint_target_torques.dat"),
        (("q", "tau_target"), "measured", "joint_torques.dat"),
    ],
)
def test_files_nothing_replaces_are_named(
    tmp_path: Path, roles: tuple[str, ...], source: str | None, named: str
) -> None:
    _write_logs(tmp_path, roles)
    with pytest.raises(DataError, match=named):
        read_teststand_folder(tmp_path, source)


def test_a_log_must_carry_the_torques_it_names(tmp_path: Path) -> None:
    _write_logs(tmp_path, ("q", "tau_measured"))
    log = read_teststand_folder(tmp_path)
    with pytest.raises(DataError, match="no target torques"):
        teststand_logs.TeststandLog(
            log.recording, log.ticks, log.qd_rad_s, log.tau_measured_nm, None, None, None,
            None, None, "target",
        )  # fmt: skip


def test_velocity_from_positions_uses_the_tick_intervals() -> None:
    t = np.array([0.0, 0.001, 0.003])
    q = np.array([[0.0], [0.001], [0.005]])
    np.testing.assert_allclose(velocity_from_positions(t, q)[:, 0], [0.0, 1.0, 2.0])


def test_shared_set_without_velocity_and_target_files_reads(tmp_path: Path) -> None:
    """The refused log's case: positions, measured torques and the ATI sensor only."""
    full = read_teststand_folder(require("teststand"), "measured")
    folder = _copy_shared(
        tmp_path, ("qd", "tau_target", "ati_torque", "contact", "height", "lab_estimate")
    )
    log = read_teststand_folder(folder)
    assert log.torque_source == "measured" and log.velocity_source == "derived"
    assert log.recording.has_force and log.lab_estimate_n is None
    # fewer files, fewer trailing ticks dropped: the common ticks start alike
    n = full.recording.n_samples
    assert log.recording.n_samples >= n
    np.testing.assert_allclose(log.recording.q_rad[:n], full.recording.q_rad)
    np.testing.assert_allclose(log.recording.tau_nm[:n], full.tau_measured_nm)
    # the derived velocity follows the lab's logged one (its own filter aside)
    corr = np.corrcoef(log.qd_rad_s[:n, 1], full.qd_rad_s[:, 1])[0, 1]
    assert corr > 0.9
