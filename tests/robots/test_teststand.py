from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from teleop_force.errors import DataError
from teleop_force.estimation.teststand import free_phase_mask
from teleop_force.io.interchange_csv import Recording
from teleop_force.io.recordings import read_recording_with_notes
from teleop_force.io.teststand_logs import NATIVE_FILES, read_teststand_folder
from teleop_force.robots.teststand import build_teststand_model
from tests.shared_data import require


def _write_logs(folder: Path, ticks_by_role: dict[str, np.ndarray] | None = None) -> None:
    folder.mkdir(exist_ok=True)
    for role, (name, n_values) in NATIVE_FILES.items():
        ticks = (ticks_by_role or {}).get(role, np.arange(1000, 1010))
        values = np.outer(ticks - 1000, np.arange(1, n_values + 1)) * 0.01 + 0.5
        lines = [
            f"{t}\t\t" + "\t".join(repr(float(v)) for v in row)
            for t, row in zip(ticks, values, strict=True)
        ]
        (folder / name).write_text("\n".join(lines) + "\n")


def test_logs_are_aligned_on_the_tick(tmp_path):
    _write_logs(
        tmp_path,
        {
            "q": np.arange(1000, 1012),
            "ati_force": np.arange(1000, 1009),
            "contact": np.arange(1001, 1010),
        },
    )
    log = read_teststand_folder(tmp_path)
    np.testing.assert_array_equal(log.ticks, np.arange(1001, 1009))
    np.testing.assert_allclose(log.recording.t_s, np.arange(8) * 1e-3)
    # same tick, same row in every file: positions of tick 1001 are 0.01 * (1, 2) + 0.5
    np.testing.assert_allclose(log.recording.q_rad[0], [0.51, 0.52])
    assert log.dropped_ticks["q"] == 4 and log.dropped_ticks["ati_force"] == 1


def test_force_signs_are_converted_to_the_project_convention(tmp_path):
    _write_logs(tmp_path)
    log = read_teststand_folder(tmp_path)
    raw = np.array([0.5, 0.5, 0.5]) + 0.01 * np.arange(1, 4) * 3  # tick 1003
    np.testing.assert_allclose(log.recording.f_tip_in_base_n[3], -raw)
    np.testing.assert_allclose(log.lab_estimate_n[3], -raw)
    assert log.torque_source == "target"
    measured = read_teststand_folder(tmp_path, "measured")
    np.testing.assert_allclose(measured.recording.tau_nm, measured.tau_measured_nm)


def test_missing_or_bad_logs_name_the_file_and_row(tmp_path):
    _write_logs(tmp_path)
    (tmp_path / NATIVE_FILES["q"][0]).unlink()
    with pytest.raises(DataError, match="joint_positions"):
        read_teststand_folder(tmp_path)
    _write_logs(tmp_path)
    path = tmp_path / NATIVE_FILES["q"][0]
    lines = path.read_text().splitlines()
    lines[4], lines[5] = lines[5], lines[4]
    path.write_text("\n".join(lines))
    with pytest.raises(DataError, match="row 6"):
        read_teststand_folder(tmp_path)
    lines[4] = "1004\t\tx\t1.0"
    path.write_text("\n".join(lines))
    with pytest.raises(DataError, match="row 5"):
        read_teststand_folder(tmp_path)


def test_read_recording_reads_a_log_folder(tmp_path):
    _write_logs(tmp_path)
    recording, notes = read_recording_with_notes(tmp_path, robot="teststand")
    assert recording.n_joints == 2 and recording.has_force and "aligned on the tick" in notes[0]
    with pytest.raises(DataError, match="--robot teststand"):
        read_recording_with_notes(tmp_path, robot="omni")


def test_free_phase_mask_keeps_a_guard_from_contact():
    t = np.arange(100) * 1e-3
    force = np.zeros((100, 3))
    force[:40, 2] = -5.0
    recording = Recording(t, np.zeros((100, 2)), np.zeros((100, 2)), force)
    mask = free_phase_mask(recording, 1.0, 0.010)
    assert not mask[:49].any() and mask[51:].all()


def test_model_in_code_matches_the_published_urdf():
    urdf = require("teststand", "teststand.urdf")
    full = pin.buildModelFromUrdf(str(urdf))
    reference = pin.buildReducedModel(full, [full.getJointId("joint_z")], np.zeros(full.nq))
    model = build_teststand_model()
    data, ref_data = model.createData(), reference.createData()
    rng = np.random.default_rng(1)
    for _ in range(5):
        q, v, a = rng.normal(size=(3, 2))
        np.testing.assert_allclose(
            pin.rnea(model, data, q, v, a), pin.rnea(reference, ref_data, q, v, a), atol=1e-12
        )
        pin.framesForwardKinematics(model, data, q)
        pin.framesForwardKinematics(reference, ref_data, q)
        np.testing.assert_allclose(
            data.oMf[model.getFrameId("contact")].translation,
            ref_data.oMf[reference.getFrameId("contact")].translation,
            atol=1e-12,
        )


def test_shared_data_force_estimate_beats_the_lab_estimator():
    from teleop_force.estimation.teststand import estimate_forces, identify_teststand
    from teleop_force.robots.teststand import teststand_description

    log = read_teststand_folder(require("teststand"))
    recording = log.recording
    truth = recording.f_tip_in_base_n
    lab_fz = np.sqrt(np.mean((log.lab_estimate_n[:, 2] - truth[:, 2]) ** 2))
    assert lab_fz == pytest.approx(1.98, abs=0.01)
    assert np.sqrt(np.mean(truth[:, 2] ** 2)) == pytest.approx(5.5, abs=0.05)
    description = teststand_description()
    identified = identify_teststand(recording, description)
    forces = estimate_forces(identified, recording, description)
    fz = np.sqrt(np.nanmean((forces[:, 2] - truth[:, 2]) ** 2))
    assert fz < 0.6 * lab_fz
