"""The fixed-layout CDR of the 1 kHz messages equals rosbags' bytes and reads what it reads."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.ros2 import codec, fast_cdr, topics
from teleop_force.transport import messages as m

names_st = st.lists(st.text(min_size=0, max_size=12), min_size=1, max_size=9)
frames = st.text(max_size=20)
stamps = st.integers(min_value=0, max_value=(2**31 - 1) * 10**9)
floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=300, deadline=None)
@given(names_st, frames, stamps, st.data(), st.booleans(), st.booleans())
def test_joint_states_are_rosbags_bytes_and_read_back(names, frame, t_ns, data, vel, eff):
    n = len(names)
    q = data.draw(st.lists(floats, min_size=n, max_size=n))
    qd = data.draw(st.lists(floats, min_size=n, max_size=n)) if vel else []
    e = data.draw(st.lists(floats, min_size=n, max_size=n)) if eff else []
    layout = fast_cdr.JointStateLayout(names, frame, velocities=vel, efforts=eff)
    ours = layout.pack(t_ns, q, qd, e)
    assert ours == codec.encode_joint_state_parts(t_ns, names, frame, q, qd, e)
    got = layout.unpack(ours)
    assert got is not None and got[0] == t_ns
    for a, b in zip((q, qd, e), got[1:], strict=True):
        assert len(a) == len(b)
        assert all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b, strict=True))


@settings(max_examples=200, deadline=None)
@given(names_st, names_st, frames)
def test_another_layout_is_left_to_rosbags(names, other, frame):
    layout = fast_cdr.JointStateLayout(names, frame)
    payload = codec.encode_joint_state_parts(
        5, other, frame, [0.1] * len(other), [0.0] * len(other), [0.0] * len(other)
    )
    got = layout.unpack(payload)
    assert (got is None) == (list(other) != list(names))


@settings(max_examples=200, deadline=None)
@given(frames, stamps, st.lists(floats, min_size=3, max_size=3))
def test_wrenches_are_rosbags_bytes_and_read_back(frame, t_ns, force):
    layout = fast_cdr.WrenchLayout(frame)
    ours = layout.pack(t_ns, force)
    assert ours == codec.encode_wrench(t_ns, force, frame)
    got = layout.unpack(ours)
    assert got is not None and got[0] == t_ns and got[2] == (0.0, 0.0, 0.0)
    decoded = codec.decode_wrench(ours)
    assert all(
        x == y or (math.isnan(x) and math.isnan(y))
        for x, y in zip(got[1], decoded.force_n, strict=True)
    )


@settings(max_examples=200, deadline=None)
@given(names_st, frames, stamps, st.integers(0, 2**63 - 1), st.data())
def test_estimate_diagnostics_are_rosbags_bytes_and_read_back(names, frame, t_ns, source, data):
    n = len(names)
    arrays = [data.draw(st.lists(floats, min_size=n, max_size=n)) for _ in range(4)]
    on_ground = data.draw(st.lists(st.booleans(), min_size=n, max_size=n))
    layout = fast_cdr.EstimateDiagnosticsLayout(names, frame)
    ours = layout.pack(t_ns, source, arrays[0], arrays[1], on_ground, arrays[2], arrays[3])
    _, theirs = codec.encode_estimate_parts(
        t_ns, source, (0.0, 0.0, 0.0), arrays[0], arrays[1], on_ground, arrays[2], arrays[3],
        names, frame,
    )  # fmt: skip
    assert ours == theirs
    got = layout.unpack(ours)
    assert got is not None and got[:2] == (t_ns, source) and got[3] == tuple(on_ground)
    decoded = codec.decode_estimate_diagnostics(ours)
    assert decoded.source_sequence == source and decoded.on_trained_ground == tuple(on_ground)


def test_rclpy_payloads_with_slack_are_left_to_rosbags():
    """rclpy's serializer leaves its size estimate's slack after the fields: another size."""
    serialization = pytest.importorskip("rclpy.serialization")
    sensor_msgs = pytest.importorskip("sensor_msgs.msg")
    ros = sensor_msgs.JointState()
    ros.name = list(topics.OMNI_MODEL_JOINT_NAMES)
    ros.position, ros.velocity, ros.effort = [0.1, 0.2, 0.3], [0.0] * 3, [0.0] * 3
    payload = serialization.serialize_message(ros)
    layout = fast_cdr.JointStateLayout(topics.OMNI_MODEL_JOINT_NAMES)
    fast = layout.unpack(payload)
    msg, _ = codec.decode_joint_state(payload, 1)
    assert fast is None or fast[1] == msg.q_rad  # either way, the values sent
    assert msg == m.JointState(1, 0, (0.1, 0.2, 0.3), (0.0,) * 3, (0.0,) * 3)
