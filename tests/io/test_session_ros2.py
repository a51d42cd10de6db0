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
