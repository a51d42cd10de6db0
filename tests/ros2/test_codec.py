"""CDR payloads against the real ROS 2 serializer (rclpy, rmw_fastrtps): decoded values agree.

Fast CDR leaves padding bytes uninitialised, so the tests compare decoded values, not bytes.
"""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.errors import MessageError
from teleop_force.ros2 import codec
from teleop_force.ros2.topics import BASE_FRAME, OMNI_MODEL_JOINT_NAMES
from teleop_force.transport import messages as m

serialization = pytest.importorskip("rclpy.serialization")
sensor_msgs = pytest.importorskip("sensor_msgs.msg")
geometry_msgs = pytest.importorskip("geometry_msgs.msg")

T_NS = 1_764_158_400_123_456_789
FINITE = st.floats(allow_nan=False, allow_infinity=False, width=64)
NAMES = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"),
                max_size=12)  # fmt: skip


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def test_joint_state_to_rclpy():
    msg = m.JointState(7, T_NS, (0.1, -0.2, 0.3), (1.0, 2.0, 3.0), (0.01, 0.02, -0.03))
    payload = codec.encode_joint_state(msg, OMNI_MODEL_JOINT_NAMES)
    ros = serialization.deserialize_message(payload, sensor_msgs.JointState)
    assert stamp_ns(ros.header) == T_NS
    assert list(ros.name) == list(OMNI_MODEL_JOINT_NAMES)
    assert tuple(ros.position) == msg.q_rad
    assert tuple(ros.velocity) == msg.qd_rad_s
    assert tuple(ros.effort) == msg.effort_nm


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 8).flatmap(
    lambda n: st.tuples(st.lists(NAMES, min_size=n, max_size=n),
                        *[st.lists(FINITE, min_size=n, max_size=n) for _ in range(3)])),
    st.integers(-(2**31) * 10**9, (2**31 - 1) * 10**9 + 999_999_999))  # fmt: skip
def test_joint_state_round_trips_through_rclpy(arrays, t_ns):
    names, q, qd, effort = arrays
    msg = m.JointState(1, t_ns, q, qd, effort)
    ros = serialization.deserialize_message(
        codec.encode_joint_state(msg, names), sensor_msgs.JointState
    )
    assert list(ros.name) == names and tuple(ros.position) == msg.q_rad
    assert tuple(ros.velocity) == msg.qd_rad_s and tuple(ros.effort) == msg.effort_nm
    assert stamp_ns(ros.header) == t_ns
    back, named = codec.decode_joint_state(serialization.serialize_message(ros), seq=1)
    assert back == msg
    assert named.names == tuple(names)


def test_rclpy_joint_state_is_decoded():
    ros = sensor_msgs.JointState()
    ros.header.stamp.sec, ros.header.stamp.nanosec = 1_764_158_400, 5
    ros.header.frame_id = BASE_FRAME
    ros.name = ["waist", "shoulder", "elbow"]
    ros.position, ros.velocity, ros.effort = [0.1, 0.2, 0.3], [0.0, 0.0, 0.0], [1.0, 2.0, 3.0]
    msg, named = codec.decode_joint_state(serialization.serialize_message(ros), seq=42)
    assert msg == m.JointState(42, 1_764_158_400_000_000_005, (0.1, 0.2, 0.3), (0.0,) * 3,
                               (1.0, 2.0, 3.0))  # fmt: skip
    assert named == codec.NamedJoints(("waist", "shoulder", "elbow"), BASE_FRAME)


def test_a_joint_state_without_velocities_is_not_a_measured_state_but_a_setpoint():
    ros = sensor_msgs.JointState()
    ros.name, ros.position = ["model_q1"], [0.5]
    payload = serialization.serialize_message(ros)
    with pytest.raises(MessageError, match="velocities"):
        codec.decode_joint_state(payload, seq=1)
    setpoint, _ = codec.decode_joint_setpoint(payload, seq=1)
    assert setpoint.q_rad == (0.5,)


def test_setpoint_to_rclpy_has_positions_only():
    msg = m.JointSetpoint(3, T_NS, (0.4, 0.5, 0.6))
    ros = serialization.deserialize_message(
        codec.encode_joint_setpoint(msg, OMNI_MODEL_JOINT_NAMES), sensor_msgs.JointState
    )
    assert tuple(ros.position) == msg.q_rad
    assert len(ros.velocity) == 0 and len(ros.effort) == 0


@pytest.mark.parametrize("force", [(1.5, -2.0, 0.25), (math.nan, math.nan, math.nan)])
def test_wrench_both_ways(force):
    payload = codec.encode_wrench(T_NS, force, BASE_FRAME)
    ros = serialization.deserialize_message(payload, geometry_msgs.WrenchStamped)
    got = (ros.wrench.force.x, ros.wrench.force.y, ros.wrench.force.z)
    assert got == pytest.approx(force, nan_ok=True, abs=0.0, rel=0.0)
    assert (ros.wrench.torque.x, ros.wrench.torque.y, ros.wrench.torque.z) == (0.0, 0.0, 0.0)
    assert ros.header.frame_id == BASE_FRAME and stamp_ns(ros.header) == T_NS
    back = codec.decode_wrench(serialization.serialize_message(ros))
    assert back.force_n == pytest.approx(force, nan_ok=True, abs=0.0, rel=0.0)
    assert (back.t_ns, back.frame_id) == (T_NS, BASE_FRAME)


def test_true_force_must_be_finite():
    payload = codec.encode_wrench(T_NS, (math.nan, 0.0, 0.0), BASE_FRAME)
    with pytest.raises(MessageError):
        codec.decode_contact_force(payload, seq=1)
    assert codec.decode_contact_force(
        codec.encode_contact_force(m.ContactForce(2, T_NS, (0.0, -1.8, 0.1)), BASE_FRAME), seq=2
    ) == m.ContactForce(2, T_NS, (0.0, -1.8, 0.1))


ESTIMATE = m.ForceEstimateMessage(
    seq=9, t_ns=T_NS, source_seq=8, f_n=(0.1, math.nan, 0.3), tau_ext_nm=(0.01, 0.02, 0.03),
    on_trained_ground=(True, False, True), coverage_weight=(1.0, 0.2, 0.9),
    tau_motor_filtered_nm=(0.1, 0.2, 0.3), tau_model_filtered_nm=(0.09, 0.18, 0.27),
)  # fmt: skip


def test_estimate_is_a_wrench_and_diagnostics_with_one_stamp():
    wrench, diagnostics = codec.encode_estimate(ESTIMATE, OMNI_MODEL_JOINT_NAMES, BASE_FRAME)
    ros = serialization.deserialize_message(wrench, geometry_msgs.WrenchStamped)
    assert ros.wrench.force.x == 0.1 and math.isnan(ros.wrench.force.y)
    d = codec.decode_estimate_diagnostics(diagnostics)
    assert d.names == OMNI_MODEL_JOINT_NAMES and d.source_sequence == 8
    back = codec.estimate_message(9, codec.decode_wrench(wrench), d)
    assert back.tau_ext_nm == ESTIMATE.tau_ext_nm
    assert back.on_trained_ground == ESTIMATE.on_trained_ground
    assert back.coverage_weight == ESTIMATE.coverage_weight
    assert back.tau_model_filtered_nm == ESTIMATE.tau_model_filtered_nm
    assert math.isnan(back.f_n[1]) and back.f_n[0] == 0.1


def test_estimate_halves_of_different_samples_are_refused():
    _, diagnostics = codec.encode_estimate(ESTIMATE, OMNI_MODEL_JOINT_NAMES, BASE_FRAME)
    other = codec.encode_wrench(T_NS + 1, (0.0, 0.0, 0.0), BASE_FRAME)
    with pytest.raises(MessageError, match="differ"):
        codec.estimate_message(9, codec.decode_wrench(other),
                               codec.decode_estimate_diagnostics(diagnostics))  # fmt: skip


def test_status_round_trip():
    status = m.Status(4, T_NS, m.SafetyState.HOLDING, "master lost: no setpoint for 50 ms")
    assert codec.decode_status(codec.encode_status(status), seq=4) == status


DIAGNOSTICS = m.ServiceDiagnostics(
    seq=83, t_ns=T_NS, device="slave", state="dependence", stream_s=83.0,
    baseline_complete=True, rms_torque_nm=(0.0205, 0.0284, 0.0205),
    checks=(m.DiagnosticCheck(1, 128, None, math.nan, math.nan, 0),
            m.DiagnosticCheck(2, 128, "t", 2.4e-13, 0.296, 5)),
    finding=m.DiagnosticFinding(2, "t", 0.296, 0.0084, 2.4e-13, 80.0, True),
    command="teleop-force residual RECORDING --model /abs/omni_sim.json",
)  # fmt: skip


def test_service_diagnostics_round_trip():
    back = codec.decode_service_diagnostics(codec.encode_service_diagnostics(DIAGNOSTICS), 83)
    assert back.to_json_dict() == DIAGNOSTICS.to_json_dict()
    quiet = m.ServiceDiagnostics(1, T_NS, "slave", "baseline", 1.0, False, (), (), None, "")
    assert codec.decode_service_diagnostics(codec.encode_service_diagnostics(quiet), 1) == quiet


@pytest.mark.parametrize(
    ("payload", "decode"),
    [
        (codec.encode_joint_state(m.JointState(1, T_NS, (0.1,), (0.2,), (0.3,)), ["a"]),
         lambda p: codec.decode_joint_state(p, seq=1)),
        (codec.encode_wrench(T_NS, (1.0, 2.0, 3.0), BASE_FRAME), codec.decode_wrench),
        (codec.encode_estimate(ESTIMATE, OMNI_MODEL_JOINT_NAMES, BASE_FRAME)[1],
         codec.decode_estimate_diagnostics),
        (codec.encode_status(m.Status(1, T_NS, m.SafetyState.FOLLOWING, "ok")),
         lambda p: codec.decode_status(p, seq=1)),
        (codec.encode_service_diagnostics(DIAGNOSTICS),
         lambda p: codec.decode_service_diagnostics(p, 1)),
    ],
)  # fmt: skip
def test_every_truncation_raises_message_error(payload, decode):
    for cut in range(len(payload) - 3):  # CDR may end in up to 3 bytes of padding
        with pytest.raises(MessageError):
            decode(payload[:cut])


def test_unknown_status_state_raises():
    payload = bytearray(codec.encode_status(m.Status(1, T_NS, m.SafetyState.STOPPED, "")))
    payload[16] = 9  # the state byte, after encapsulation (4) and header (stamp 8, frame 4)
    with pytest.raises(MessageError):
        codec.decode_status(bytes(payload), seq=1)


def test_pose_stamped_and_empty_round_trip_as_rosbags_reads_them():
    from teleop_force.ros2 import interfaces

    store = interfaces.typestore()
    payload = codec.encode_pose(1_500_000_123, (0.1, -0.02, 0.3), "base")
    raw = store.deserialize_cdr(payload, interfaces.POSE_STAMPED)
    assert (raw.header.stamp.sec, raw.header.stamp.nanosec) == (1, 500_000_123)
    assert (raw.pose.position.x, raw.pose.position.y, raw.pose.position.z) == (0.1, -0.02, 0.3)
    pose = codec.decode_pose(payload)
    assert pose.frame_id == "base" and pose.orientation_xyzw == (0.0, 0.0, 0.0, 1.0)
    assert pose.position_m == (0.1, -0.02, 0.3) and pose.t_ns == 1_500_000_123
    empty = codec.encode_empty()
    assert store.deserialize_cdr(empty, interfaces.EMPTY).structure_needs_at_least_one_member == 0
    codec.decode_empty(empty)
    with pytest.raises(MessageError):
        codec.decode_empty(b"\x00\x01")
