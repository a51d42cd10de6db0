from pathlib import Path

import numpy as np
import pytest
from shared_data import require

from teleop_force.dvrk_mtm import (
    CABLE_RATIO,
    N_JOINTS,
    SAMPLE_RATE_HZ,
    dvrk_mtm_description,
    mtm_coupling,
    read_mtm_csv,
)
from teleop_force.errors import DataError
from teleop_force.recordings import read_recording, read_recording_with_notes
from teleop_force.robot import Robot


def _native_rows(n: int = 60) -> np.ndarray:
    t = np.arange(n) / SAMPLE_RATE_HZ
    q = 0.3 * np.sin(2 * np.pi * 0.5 * t[:, None] + np.arange(N_JOINTS))
    qd = np.gradient(q, t, axis=0)
    tau = 0.1 * np.cos(2 * np.pi * 0.5 * t[:, None] + np.arange(N_JOINTS))
    return np.hstack((q, qd, tau))


def _write(path: Path, table: np.ndarray) -> Path:
    path.write_text("\n".join(",".join(repr(float(x)) for x in row) for row in table) + "\n")
    return path


def test_repeated_rows_are_dropped_counted_and_bridged(tmp_path):
    table = _native_rows()
    table[5] = table[4]  # a stale sample
    table[6] = table[4]  # and another one
    table[20, 14:] += 1.0  # tau changed, state repeated: still a stale state
    table[20, :14] = table[19, :14]
    path = _write(tmp_path / "traj.csv", table)
    trajectory = read_mtm_csv(path, smoothing_hz=None)
    assert trajectory.total_rows == 60
    assert trajectory.repeated_rows == 3
    assert "dropped 3 of 60 rows" in trajectory.note()
    recording = trajectory.recording
    # uniform grid t = row / 200, values of the distinct rows kept exactly
    np.testing.assert_allclose(recording.t_s, np.arange(60) / SAMPLE_RATE_HZ)
    kept = trajectory.kept_rows
    np.testing.assert_array_equal(kept, np.setdiff1d(np.arange(60), [5, 6, 20]))
    np.testing.assert_allclose(recording.q_rad[kept], table[kept, :7])
    np.testing.assert_allclose(recording.tau_nm[kept], table[kept, 14:])
    # the dropped rows are linear in time between their distinct neighbours
    np.testing.assert_allclose(recording.q_rad[5], table[4, :7] + (table[7, :7] - table[4, :7]) / 3)


def test_smoothing_is_zero_phase_on_the_motion(tmp_path):
    rng = np.random.default_rng(0)
    table = _native_rows(400)
    clean = table[:, :7].copy()
    table[:, :7] += rng.normal(scale=1e-3, size=clean.shape)
    recording = read_mtm_csv(_write(tmp_path / "t.csv", table)).recording
    error = recording.q_rad - clean
    assert np.sqrt(np.mean(error[50:-50] ** 2)) < 4e-4  # noise reduced, no lag on a 0.5 Hz motion


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda lines: lines.__setitem__(3, lines[3] + ",1.0"), "row 4"),
        (
            lambda lines: lines.__setitem__(2, lines[2].replace(lines[2].split(",")[15], "abc", 1)),
            "tau2",
        ),
        (
            lambda lines: lines.__setitem__(1, lines[1].replace(lines[1].split(",")[0], "nan", 1)),
            "column 'q1'",
        ),
    ],
)
def test_bad_native_rows_name_the_row_and_column(tmp_path, edit, match):
    lines = [",".join(repr(float(x)) for x in row) for row in _native_rows()]
    edit(lines)
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines))
    with pytest.raises(DataError, match=match):
        read_mtm_csv(path)


def test_read_recording_recognises_native_files(tmp_path):
    path = _write(tmp_path / "traj.csv", _native_rows())
    recording, notes = read_recording_with_notes(path, robot="dvrk-mtm")
    assert recording.n_joints == 7 and "dropped 0 of 60" in notes[0]
    assert read_recording(path).n_joints == 7
    with pytest.raises(DataError, match="--robot dvrk-mtm"):
        read_recording(path, robot="omni")


def test_coupling_maps_file_to_dvrk_coordinates():
    coupling = mtm_coupling()
    q_file = np.array([0.1, 0.2, 0.5, 0.3, 0.0, 0.0, 0.0])
    q_dvrk = coupling @ q_file
    assert q_dvrk[2] == pytest.approx(0.5 - 0.2)  # relative elbow
    assert q_dvrk[3] == pytest.approx(CABLE_RATIO * (0.2 - 0.5) + 0.3)  # cable-coupled platform
    desc = dvrk_mtm_description()
    assert desc.friction_inputs[3] == (1, 2, 3)
    np.testing.assert_allclose(desc.model.gravity.linear, [0, 0, -9.81])
    robot = Robot(desc)
    tau_dvrk = np.arange(1.0, 8.0)
    assert robot.coupling.T @ tau_dvrk == pytest.approx(coupling.T @ tau_dvrk)


def test_shared_trajectories_read_with_their_repeated_rows():
    folder = require("dvrk_mtm")
    one = read_mtm_csv(folder / "mtm_traj_one_results.csv")
    assert (one.total_rows, one.repeated_rows) == (5999, 869)
    assert one.recording.n_samples == 5999
    assert np.ptp(one.q_file_rad[:, 6]) > 2 * np.pi  # joint 7 turns more than once


def _first(recording, n):
    from teleop_force.interchange_csv import Recording

    return Recording(
        recording.t_s[:n], recording.q_rad[:n], recording.tau_nm[:n], source=recording.source
    )


def test_shared_data_cv_model_beats_the_published_error_on_joint_1():
    from teleop_force.model_fitting import evaluate_model, identify_model

    folder = require("dvrk_mtm")
    train = _first(read_mtm_csv(folder / "mtm_traj_one_results.csv").recording, 4000)
    test = _first(read_mtm_csv(folder / "mtm_traj_two_results.csv").recording, 2000)
    model, _ = identify_model([train], dvrk_mtm_description(), "cv")
    result = evaluate_model(model, [test])
    assert result["relative_rms"][0] < 0.163
    assert np.all(result["relative_rms"][:3] < 0.5)
