"""The master's haptic feedback from the ROS 2 estimate (``--ros2``): attachment seq and time."""

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
        inbox.on_ros2_sample(payload, Attachment(seq, now - 1_000_000, GID))
    force, arrival_s = inbox.latest()
    assert np.array_equal(force, [2.0, -1.0, 0.25]) and arrival_s is not None
    stats = inbox.stats()
    assert (stats["received"], stats["lost"]) == (3, 1)
    assert stats["latency_ms"]["max"] >= 1.0  # source time 1 ms before it was sent


def test_a_malformed_ros2_estimate_is_counted_and_dropped():
    inbox = FeedbackInbox()
    inbox.on_ros2_sample(b"\x00\x01\x00\x00", Attachment(1, time.time_ns(), GID))
    assert inbox.stats()["malformed"] == 1 and inbox.latest()[1] is None
    singular = codec.encode_wrench(time.time_ns(), (math.nan,) * 3, BASE_FRAME)
    inbox.on_ros2_sample(singular, Attachment(2, time.time_ns(), GID))
    assert np.isnan(inbox.latest()[0]).all()  # kept: the feedback torque is zero for it
