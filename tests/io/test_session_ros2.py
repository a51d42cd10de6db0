"""ROS 2 messages in a session: recorded as received, read back by MCAP's own reader."""

import pytest
from mcap.reader import make_reader

from teleop_force.errors import DataError
from teleop_force.io.mcap_session import SessionReader, SessionWriter
from teleop_force.ros2 import codec, interfaces
from teleop_force.ros2.topics import BASE_FRAME, OMNI_MODEL_JOINT_NAMES
from teleop_force.transport import keys
from teleop_force.transport import messages as m

T_NS = 1_764_158_400_000_000_000


def joint_state_payload(k):
    msg = m.JointState(0, T_NS + k, (0.1 * k, 0.2, 0.3), (0.0,) * 3, (0.01, 0.02, 0.03))
    return codec.encode_joint_state(msg, OMNI_MODEL_JOINT_NAMES) + b"\xab" * (k % 3)  # slack


def test_ros2_messages_are_recorded_as_received_with_the_attachments_seq_and_time(tmp_path):
    path = tmp_path / "s.mcap"
    payloads = [joint_state_payload(k) for k in range(5)]
    with SessionWriter(path, {"primary_device": "slave"}, profile="ros2") as writer:
        for k, payload in enumerate(payloads):
            writer.write_ros2("/slave/measured_js", interfaces.JOINT_STATE, payload, k + 1,
                              T_NS + k, T_NS + 10 + k)  # fmt: skip
        wrench = codec.encode_wrench(T_NS, (1.0, 2.0, 3.0), BASE_FRAME)
        writer.write_ros2("/slave/estimated_cf", interfaces.WRENCH_STAMPED, wrench, 2**32 + 7,
                          -1, T_NS + 20)  # fmt: skip
        writer.write(keys.measured_js("slave"), m.JointState(3, T_NS, (0.1,) * 3, (0.0,) * 3,
                                                             (0.0,) * 3), T_NS)  # fmt: skip
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        got = [(schema, channel, message) for schema, channel, message in reader.iter_messages()]
    ros = [(s, c, msg) for s, c, msg in got if c.topic.startswith("/")]
    js = [(s, c, msg) for s, c, msg in ros if c.topic == "/slave/measured_js"]
    assert [msg.data for _, _, msg in js] == payloads  # the bytes as they arrived
    assert [msg.sequence for _, _, msg in js] == [1, 2, 3, 4, 5]
    assert [msg.publish_time for _, _, msg in js] == [T_NS + k for k in range(5)]
    assert [msg.log_time for _, _, msg in js] == [T_NS + 10 + k for k in range(5)]
    schema, channel, _ = js[0]
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        interfaces.JOINT_STATE, "ros2msg", "cdr")  # fmt: skip
    assert schema.data.decode() == interfaces.schema_text(interfaces.JOINT_STATE)
    ((_, _, estimate),) = [(s, c, msg) for s, c, msg in ros if c.topic == "/slave/estimated_cf"]
    assert estimate.sequence == 7 and estimate.publish_time == T_NS + 20  # mod 2**32; log time
    session = SessionReader(path)  # the project's reader: its own channels as before
    assert session.devices() == ["slave"]
    assert session.message_counts["/slave/measured_js"] == 5
    decoded = [msg for topic, _, msg in session.messages() if topic == keys.measured_js("slave")]
    assert len(decoded) == 1 and isinstance(decoded[0], m.JointState)


def test_bad_ros2_channels_are_refused(tmp_path):
    with SessionWriter(tmp_path / "s.mcap", profile="ros2") as writer:
        payload = joint_state_payload(0)
        writer.write_ros2("/slave/measured_js", interfaces.JOINT_STATE, payload, 1, T_NS, T_NS)
        with pytest.raises(DataError, match="carries"):
            writer.write_ros2("/slave/measured_js", interfaces.WRENCH_STAMPED, payload, 2, T_NS,
                              T_NS)  # fmt: skip
        with pytest.raises(DataError, match="ROS 2 channel"):
            writer.write_ros2("slave/measured_js", interfaces.JOINT_STATE, payload, 2, T_NS, T_NS)
        with pytest.raises(DataError):
            writer.write_ros2("/x", "nobody_msgs/msg/Unknown", payload, 2, T_NS, T_NS)


# --------------------------------------------------------------------------- reading


def _write_session(path, n=50, *, names=OMNI_MODEL_JOINT_NAMES, chunk_size_bytes=1 << 20):
    """A ROS 2 session of the demo's streams: joint states, true forces, estimates, status."""
    with SessionWriter(path, {"primary_device": "slave"}, profile="ros2",
                       chunk_size_bytes=chunk_size_bytes) as writer:  # fmt: skip
        for k in range(n):
            t = T_NS + k * 1_000_000
            js = m.JointState(0, t, (0.01 * k, 0.2, 0.3), (0.1, 0.0, 0.0), (0.0, 0.5, 0.0))
            chosen = names[k % len(names)] if isinstance(names, list) else names
            payload = codec.encode_joint_state(js, chosen)
            writer.write_ros2("/slave/measured_js", interfaces.JOINT_STATE, payload, k + 1, t + 3,
                              t + 10)  # fmt: skip
            force = m.ContactForce(0, t, (0.0, 0.0, float(k)))
            payload = codec.encode_contact_force(force, BASE_FRAME)
            writer.write_ros2("/slave/true_cf", interfaces.WRENCH_STAMPED, payload, k + 1, t,
                              t + 11)  # fmt: skip
            estimate = m.ForceEstimateMessage(0, t + 5, k + 1, (0.0, 0.0, k + 0.5), (0.1,) * 3,
                                              (True, False, True), (1.0,) * 3, (0.2,) * 3,
                                              (0.3,) * 3)  # fmt: skip
            wrench, diagnostics = codec.encode_estimate(estimate, OMNI_MODEL_JOINT_NAMES,
                                                        BASE_FRAME)  # fmt: skip
            halves = [("/slave/estimated_cf", interfaces.WRENCH_STAMPED, wrench),
                      ("/slave/estimate_diagnostics", interfaces.ESTIMATE_DIAGNOSTICS,
                       diagnostics)]  # fmt: skip
            if k % 2:
                halves.reverse()  # the diagnostics may arrive first
            for i, (topic, ros_type, payload) in enumerate(halves):
                writer.write_ros2(topic, ros_type, payload, 100 + k, t + 5, t + 12 + i)
            if k % 10 == 0:
                status = m.Status(0, t, m.SafetyState.FOLLOWING, "ok")
                writer.write_ros2("/slave/status", interfaces.STATUS, codec.encode_status(status),
                                  k // 10 + 1, t, t + 13)  # fmt: skip


def test_a_ros2_session_reads_as_the_projects_messages(tmp_path):
    from teleop_force.io.cdr_columns import read_joint_state_arrays
    from teleop_force.io.mcap_session import (
        ESTIMATED_CF,
        MEASURED_JS,
        TRUE_CF,
        Stream,
        read_session_as_recording,
    )

    path = tmp_path / "s.mcap"
    _write_session(path)
    reader = SessionReader(path)
    assert reader.ros2 and reader.devices() == ["slave"]
    assert reader.stream_topic("slave", MEASURED_JS) == "/slave/measured_js"
    assert reader.stream_count("slave", TRUE_CF) == 50
    assert Stream("slave", ESTIMATED_CF) in reader.streams
    states = [js for _, _, js in reader.messages(["/slave/measured_js"])]
    assert [js.seq for js in states] == list(range(1, 51))  # the MCAP sequence
    assert [js.q_rad[0] for js in states] == [0.01 * k for k in range(50)]
    estimates = [e for _, _, e in reader.messages(["/slave/estimated_cf"])]
    assert [e.seq for e in estimates] == [100 + k for k in range(50)]
    assert [e.f_n[2] for e in estimates] == [k + 0.5 for k in range(50)]
    assert all(e.on_trained_ground == (True, False, True) for e in estimates)
    assert [e.source_seq for e in estimates] == list(range(1, 51))
    kinds = {type(x).__name__ for _, _, x in reader.messages()}
    assert kinds == {"JointState", "ContactForce", "ForceEstimateMessage", "Status"}
    arrays = read_joint_state_arrays(path, "/slave/measured_js")
    assert arrays.seq.tolist() == list(range(1, 51))
    assert arrays.t_ns.tolist() == [T_NS + k * 1_000_000 for k in range(50)]  # header stamp
    assert arrays.log_time_ns.tolist() == [T_NS + k * 1_000_000 + 10 for k in range(50)]
    recording = read_session_as_recording(path)
    assert recording.f_tip_in_base_n[:, 2].tolist() == [float(k) for k in range(50)]
    assert recording.tau_nm[:, 1].tolist() == [0.5] * 50


def _estimate_halves(k, stamp_ns):
    estimate = m.ForceEstimateMessage(0, stamp_ns, k + 1, (0.0, 0.0, k + 0.5), (0.1,) * 3,
                                      (True, False, True), (1.0,) * 3, (0.2,) * 3,
                                      (0.3,) * 3)  # fmt: skip
    return codec.encode_estimate(estimate, OMNI_MODEL_JOINT_NAMES, BASE_FRAME)


def test_estimate_halves_of_one_log_time_are_all_joined_however_many(tmp_path):
    """A recorder's drain written topic by topic and clamped into one instant: every wrench
    first, then every diagnostics, all at one log time; each estimate is still joined."""
    path, n = tmp_path / "s.mcap", 5000
    halves = [_estimate_halves(k, T_NS + k) for k in range(n)]
    with SessionWriter(path, {"primary_device": "slave"}, profile="ros2") as writer:
        for k, (wrench, _) in enumerate(halves):
            writer.write_ros2("/slave/estimated_cf", interfaces.WRENCH_STAMPED, wrench, k + 1,
                              T_NS + k, T_NS)  # fmt: skip
        for k, (_, diagnostics) in enumerate(halves):
            writer.write_ros2("/slave/estimate_diagnostics", interfaces.ESTIMATE_DIAGNOSTICS,
                              diagnostics, k + 1, T_NS + k, T_NS)  # fmt: skip
    estimates = [e for _, _, e in SessionReader(path).messages(["/slave/estimated_cf"])]
    assert sorted(e.source_seq for e in estimates) == list(range(1, n + 1))


def test_a_half_without_its_other_half_is_dropped_and_the_rest_joined(tmp_path):
    path = tmp_path / "s.mcap"
    orphan, _ = _estimate_halves(0, T_NS - 1)
    with SessionWriter(path, {"primary_device": "slave"}, profile="ros2") as writer:
        writer.write_ros2("/slave/estimated_cf", interfaces.WRENCH_STAMPED, orphan, 1, T_NS, T_NS)
        for k in range(1, 4):  # 20 s apart: far beyond any recorder's drain
            t = T_NS + k * 20_000_000_000
            wrench, diagnostics = _estimate_halves(k, t)
            writer.write_ros2("/slave/estimate_diagnostics", interfaces.ESTIMATE_DIAGNOSTICS,
                              diagnostics, k + 1, t, t)  # fmt: skip
            writer.write_ros2("/slave/estimated_cf", interfaces.WRENCH_STAMPED, wrench, k + 1,
                              t, t + 1)  # fmt: skip
    estimates = [e for _, _, e in SessionReader(path).messages(["/slave/estimated_cf"])]
    assert [e.source_seq for e in estimates] == [2, 3, 4]


def test_joint_states_of_several_layouts_read_alike(tmp_path):
    from teleop_force.io.cdr_columns import read_joint_state_arrays

    one, mixed = tmp_path / "one.mcap", tmp_path / "mixed.mcap"
    _write_session(one)
    # same payload size, other length words: the codec decodes them one by one
    _write_session(mixed, names=[("a", "bb", "c"), ("bb", "a", "c"), ("c", "a", "bb")])
    a, b = (
        read_joint_state_arrays(one, "/slave/measured_js"),
        read_joint_state_arrays(mixed, "/slave/measured_js"),
    )
    for name in ("seq", "t_ns", "log_time_ns", "q_rad", "qd_rad_s", "effort_nm"):
        assert getattr(a, name).tolist() == getattr(b, name).tolist(), name


def test_a_truncated_ros2_session_is_read_up_to_its_last_chunk(tmp_path):
    from teleop_force.io.cdr_columns import read_joint_state_arrays

    path = tmp_path / "s.mcap"
    _write_session(path, n=400, chunk_size_bytes=4096)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    reader = SessionReader(cut)
    assert reader.truncated
    states = [js for _, _, js in reader.messages(["/slave/measured_js"])]
    assert 0 < len(states) < 400
    arrays = read_joint_state_arrays(cut, "/slave/measured_js")
    assert arrays.seq.tolist() == [js.seq for js in states]


def test_a_ros2_session_exports_to_json_and_reads_back(tmp_path):
    from teleop_force.io.mcap_session import export_session_json

    path, target = tmp_path / "s.mcap", tmp_path / "j.mcap"
    _write_session(path)
    done = export_session_json(path, target)
    assert done.messages == 50 * 3 + 5 and done.skipped == 0  # estimates joined
    a, b = SessionReader(path), SessionReader(target)
    assert b.streams.keys() == a.streams.keys() - {
        s for s in a.streams if s.kind == "estimate_diagnostics"
    }
    assert list(b.messages()) == list(a.messages())


def test_a_bad_ros2_message_is_counted_and_skipped(tmp_path):
    """A session holds the traffic as received: a malformed message is skipped, counted."""
    path = tmp_path / "s.mcap"
    good = codec.encode_joint_state(m.JointState(0, T_NS, (0.1,), (0.0,), (0.0,)), ())
    with SessionWriter(path, profile="ros2") as writer:
        writer.write_ros2("/slave/measured_js", interfaces.JOINT_STATE, b"\x00\x01\x00\x00\x01",
                          1, T_NS, T_NS)  # fmt: skip
        writer.write_ros2("/slave/measured_js", interfaces.JOINT_STATE, good, 2, T_NS, T_NS + 1)
        writer.write_ros2("/slave/estimated_cf", interfaces.WRENCH_STAMPED, b"\x00\x01", 1, T_NS,
                          T_NS + 2)  # fmt: skip
    reader = SessionReader(path)
    got = list(reader.messages())
    assert [(topic, message.seq) for topic, _, message in got] == [("/slave/measured_js", 2)]
    assert reader.malformed == {"/slave/measured_js": 1, "/slave/estimated_cf": 1}
