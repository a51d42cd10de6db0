"""The master's haptic feedback from the ROS 2 estimate : attachment seq and time."""

import math
import time

import numpy as np

from master_slave.master import FeedbackInbox
from teleop_force.ros2 import codec
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.topics import BASE_FRAME

GID = bytes(range(16))


def test_ros2_estimates_feed_the_inbox_with_the_attachments_seq_and_time():
    inbox = FeedbackInbox()
    now = time.time_ns()
    for seq in (1, 2, 4):  # 3 lost
        payload = codec.encode_wrench(now, (0.5 * seq, -1.0, 0.25), BASE_FRAME)
        inbox.on_sample(payload, Attachment(seq, now - 1_000_000, GID))
    force, arrival_s = inbox.latest()
    assert np.array_equal(force, [2.0, -1.0, 0.25]) and arrival_s is not None
    stats = inbox.stats()
    assert (stats["received"], stats["lost"]) == (3, 1)
    assert stats["latency_ms"]["max"] >= 1.0  # source time 1 ms before it was sent


def test_a_malformed_ros2_estimate_is_counted_and_dropped():
    inbox = FeedbackInbox()
    inbox.on_sample(b"\x00\x01\x00\x00", Attachment(1, time.time_ns(), GID))
    assert inbox.stats()["malformed"] == 1 and inbox.latest()[1] is None
    singular = codec.encode_wrench(time.time_ns(), (math.nan,) * 3, BASE_FRAME)
    inbox.on_sample(singular, Attachment(2, time.time_ns(), GID))
    assert np.isnan(inbox.latest()[0]).all()  # kept: the feedback torque is zero for it


def test_the_slave_takes_ros2_setpoints_in_model_coordinates_only():
    from master_slave.slave import SetpointInbox
    from teleop_force.ros2.topics import DRIVER_JOINT_NAMES, OMNI_MODEL_JOINT_NAMES
    from teleop_force.transport import messages as m

    inbox = SetpointInbox()
    now = time.time_ns()
    setpoint = m.JointSetpoint(0, now, (0.1, 0.2, 0.3))
    for seq in (1, 2, 5):  # 3 and 4 lost
        payload = codec.encode_joint_setpoint(setpoint, OMNI_MODEL_JOINT_NAMES)
        inbox.on_sample(payload, Attachment(seq, now, GID))
    inbox.on_sample(codec.encode_joint_setpoint(setpoint, DRIVER_JOINT_NAMES),
                         Attachment(6, now, GID))  # fmt: skip
    two = m.JointSetpoint(0, now, (0.1, 0.2))
    inbox.on_sample(codec.encode_joint_setpoint(two, ("model_q1", "model_q2")),
                         Attachment(7, now, GID))  # fmt: skip
    q, arrival_s, count = inbox.latest()
    assert q == (0.1, 0.2, 0.3) and arrival_s is not None and count == 3
    stats = inbox.stats()
    assert (stats["received"], stats["lost"], stats["malformed"]) == (3, 2, 2)
    assert "waist" in stats["last_malformed"] or "model_q1" in stats["last_malformed"]
