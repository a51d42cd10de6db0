"""Sessions recorded through a driver: its JointStates converted once on reading."""

from __future__ import annotations

import json

import numpy as np
import pytest

from teleop_force.errors import DataError
from teleop_force.io.driver_session import (
    METADATA_DRIVER_DESCRIPTION,
    driver_metadata,
    session_driver,
)
from teleop_force.io.mcap_session import SessionWriter, read_session_with_notes
from teleop_force.io.recordings import read_recording_with_notes
from teleop_force.robots.file import driver_document, driver_interface_from_document
from teleop_force.robots.registry import builtin_driver
from teleop_force.ros2 import fast_cdr, interfaces
from teleop_force.simulation.sensable_driver import JOINT_NAMES, driver_joint_state

TOPIC = "/arm/measured_js"
T0_NS = 1_700_000_000_000_000_000


def _angles(n: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * 0.002
    q = np.column_stack([0.3 * np.sin(t), 0.8 + 0.2 * np.cos(2 * t), 0.1 + 0.3 * np.sin(3 * t)])
    tau = np.column_stack([0.01 * np.cos(t), 0.05 + 0.0 * t, -0.02 * np.sin(t)])
    return q, tau


def _write(path, n=200, *, metadata=None, efforts=True, stamps=True) -> tuple[np.ndarray, ...]:
    """A session of the simulated driver's JointStates (500 Hz, mN m, no velocity)."""
    interface = builtin_driver("sensable-phantom")
    layout = fast_cdr.JointStateLayout(JOINT_NAMES, velocities=False, efforts=efforts)
    q, tau = _angles(n)
    with SessionWriter(path, metadata or {}, profile="ros2") as writer:
        for k in range(n):
            position, effort = driver_joint_state(interface, q[k], tau[k])
            t_ns = T0_NS + k * 2_000_000
            payload = layout.pack(t_ns if stamps else 0, position, (), effort if efforts else ())
            writer.write_ros2(TOPIC, interfaces.JOINT_STATE, payload, k, t_ns, t_ns)
    return q, tau


def test_a_session_naming_its_driver_is_converted_to_the_model(tmp_path):
    path = tmp_path / "excited.mcap"
    metadata = {"primary_device": "arm", **driver_metadata(builtin_driver("sensable-phantom"))}
    q, tau = _write(path, metadata=metadata)
    recording, notes = read_recording_with_notes(path)
    np.testing.assert_allclose(recording.q_rad, q, atol=1e-12)
    np.testing.assert_allclose(recording.tau_nm, tau, atol=1e-12)  # mN m -> N m
    np.testing.assert_allclose(recording.t_s, np.arange(len(q)) * 0.002, atol=1e-12)
    assert "sawSensablePhantom" in notes[0] and "velocities derived" in notes[0]


def test_without_a_description_the_error_names_the_topic_and_the_flag(tmp_path):
    path = tmp_path / "rosbag.mcap"
    _write(path)
    with pytest.raises(DataError) as raised:
        read_recording_with_notes(path)
    message = str(raised.value)
    assert str(path) in message and TOPIC in message and "--driver" in message
    recording, _ = read_recording_with_notes(path, driver=builtin_driver("sensable-phantom"))
    assert recording.q_rad.shape == (200, 3)


def test_joint_states_without_efforts_are_refused_by_name(tmp_path):
    path = tmp_path / "no_efforts.mcap"
    _write(path, n=5, efforts=False)
    with pytest.raises(DataError, match="efforts") as raised:
        read_session_with_notes(path, driver=builtin_driver("sensable-phantom"))
    assert raised.value.column == TOPIC and raised.value.path == str(path)


def test_a_driver_that_does_not_stamp_is_timed_by_the_source_times(tmp_path):
    path = tmp_path / "unstamped.mcap"
    _write(path, n=50, stamps=False)
    recording, notes = read_session_with_notes(path, driver=builtin_driver("sensable-phantom"))
    np.testing.assert_allclose(recording.t_s, np.arange(50) * 0.002, atol=1e-12)
    assert "no header stamps" in notes[0]


def test_a_driver_description_goes_through_json_unchanged():
    interface = builtin_driver("sensable-phantom")
    document = json.loads(json.dumps(driver_document(interface)))
    again = driver_interface_from_document(document, "<test>")
    for attr in ("name", "base_frame", "rate_hz", "publishes_velocity", "effort_unit",
                 "positions", "efforts"):  # fmt: skip
        assert getattr(again, attr) == getattr(interface, attr)
    np.testing.assert_array_equal(again.position_matrix, interface.position_matrix)
    np.testing.assert_array_equal(again.effort_matrix, interface.effort_matrix)


def test_a_broken_description_in_the_metadata_is_named(tmp_path):
    bad = json.loads(
        driver_metadata(builtin_driver("sensable-phantom"))[METADATA_DRIVER_DESCRIPTION]
    )
    bad["driver"]["effort_unit"] = "furlongs"
    with pytest.raises(DataError, match="effort_unit"):
        session_driver({METADATA_DRIVER_DESCRIPTION: json.dumps(bad)}, tmp_path / "x.mcap")
    with pytest.raises(DataError, match="not JSON"):
        session_driver({METADATA_DRIVER_DESCRIPTION: "{"}, tmp_path / "x.mcap")


def test_a_driver_applies_to_sessions_only(tmp_path):
    path = tmp_path / "data.csv"
    path.write_text("t,q1,tau1\n0,0,0\n")
    with pytest.raises(DataError, match=r"\.mcap sessions only"):
        read_recording_with_notes(path, driver=builtin_driver("sensable-phantom"))
