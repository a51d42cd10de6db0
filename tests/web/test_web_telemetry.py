"""The dashboard's telemetry: handlers fed message values and attachments, and over ROS 2."""

import math

import numpy as np
import pytest
from web_ros2 import NAMES, Talker, attachment, wait_for

from teleop_force.errors import ConfigurationError
from teleop_force.ros2 import codec, topics
from teleop_force.ros2.node import Node
from teleop_force.transport import messages as m
from web.telemetry import (
    FE_F,
    FE_SOURCE_SEQ,
    FE_TRAINED,
    JS_QD,
    NODE_NAME,
    Subscriptions,
    Telemetry,
)

T0_NS = 1_000_000_000


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def estimate(seq, trained=(True, True, True), f=(0.1, -1.0, 0.2)):
    return m.ForceEstimateMessage(
        seq, T0_NS + seq * 1_000_000, seq + 7, f, (0.01, 0.02, 0.03), trained,
        (1.0, 0.5, 0.2), (0.1, 0.2, 0.3), (0.09, 0.19, 0.29),
    )  # fmt: skip


def joint_state(k, n=3):
    return m.JointState(
        k, T0_NS + k * 1_000_000, (0.1, 0.2, 0.3)[:n], (1.0, 2.0, 3.0)[:n], (0.0,) * n
    )


def test_handlers_fill_the_rings_and_counters():
    clock = Clock()
    tel = Telemetry(capacity=64, clock=clock, wall_clock_ns=lambda: 2_000_000_000)
    sent_ns = 1_500_000_000  # the attachment's source time, not the header stamp
    for k in range(5):
        tel.on_joint_state(joint_state(k), attachment(k + 1, sent_ns))
        tel.on_estimate(estimate(k), attachment(k + 1, sent_ns))
        tel.on_contact(m.ContactForce(k, T0_NS + k * 1_000_000, (0.0, -1.0, 0.0)),
                       attachment(k + 1, sent_ns))  # fmt: skip
    tel.on_joint_state(joint_state(7), attachment(8, sent_ns))  # 6 and 7 lost
    tel.on_setpoint(m.JointSetpoint(0, 1, (0.5, 0.6, 0.7)), attachment(1))
    tel.on_status(m.Status(0, 1, m.SafetyState.HOLDING, "limit"), attachment(1))
    js = tel.joint_state.window()
    assert len(js) == 6 and js.values[0, JS_QD].tolist() == [1.0, 2.0, 3.0]
    assert math.isclose(js.t_s[1] - js.t_s[0], 1e-3)  # the rings keep the header stamps
    _, row = tel.estimate.latest()
    assert row[FE_F].tolist() == [0.1, -1.0, 0.2] and row[FE_SOURCE_SEQ] == 11
    assert row[FE_TRAINED].tolist() == [1.0, 1.0, 1.0]
    assert tel.setpoint.latest()[1].tolist() == [0.5, 0.6, 0.7]
    assert tel.status().state is m.SafetyState.HOLDING and tel.status().reason == "limit"
    snaps = tel.snapshots()
    assert snaps["measured_js"].received == 6 and snaps["measured_js"].lost == 2
    assert snaps["estimated_cf"].lost == 0 and snaps["true_cf"].received == 5
    assert math.isclose(snaps["estimated_cf"].latency_ms_mean, 500.0)
    clock.now += 2.0
    assert math.isclose(tel.estimate_age_s(), 2.0) and math.isclose(tel.status_age_s(), 2.0)


def test_wrong_joint_counts_and_dropped_samples_are_counted_not_raised():
    tel = Telemetry(capacity=8)
    tel.on_joint_state(joint_state(0, n=2), attachment(1))
    tel.on_setpoint(m.JointSetpoint(0, 1, (0.1,)), attachment(1))
    tel.on_malformed("measured_js")
    tel.on_malformed("status")
    snaps = tel.snapshots()
    assert snaps["measured_js"].malformed == 2 and len(tel.joint_state) == 0
    assert snaps["setpoint_js"].malformed == 1 and len(tel.setpoint) == 0
    assert snaps["status"].malformed == 1 and snaps["estimated_cf"].malformed == 0


def test_untrained_joints_are_held_for_a_while_and_nan_force_is_stored():
    clock = Clock()
    tel = Telemetry(capacity=8, clock=clock)
    assert math.isinf(tel.estimate_age_s()) and tel.untrained_joints(0.5) == ()
    tel.on_estimate(estimate(0, trained=(True, False, False), f=(math.nan,) * 3), attachment(1))
    tel.on_estimate(estimate(1), attachment(2))  # back on trained ground
    assert tel.untrained_joints(0.5) == (1, 2)
    assert np.all(np.isnan(tel.estimate.window().values[0, FE_F]))
    clock.now += 0.6
    assert tel.untrained_joints(0.5) == ()


def test_subscriptions_feed_the_telemetry_from_the_ros2_topics(zenoh_pair):
    """Real sessions: the slave's and master's topics, a gap, garbage and a bare sample."""
    talker = Talker(zenoh_pair.listener)
    node = Node(zenoh_pair.connector, NODE_NAME)
    tel = Telemetry(capacity=64)
    subs = Subscriptions(node, tel, "slave", "master")
    try:
        assert len(subs.keys) == 6  # the estimate is two topics
        talker.wait_for_subscribers(
            topics.MEASURED_JS, topics.ESTIMATED_CF, topics.ESTIMATE_DIAGNOSTICS,
            topics.TRUE_CF, topics.STATUS, topics.SETPOINT_JS,
        )  # fmt: skip
        for k in range(5):
            talker.joint_state(joint_state(k))
            talker.estimate(estimate(k))
            talker.true_force(m.ContactForce(k, T0_NS + k * 1_000_000, (0.0, -1.0, 0.0)))
        talker.setpoint(m.JointSetpoint(0, T0_NS, (0.5, 0.6, 0.7)))
        talker.status(m.Status(0, T0_NS, m.SafetyState.STOPPED, "operator"))
        last = talker.joint_state(joint_state(5))
        gap = attachment(last.sequence_number + 3, last.source_timestamp_ns, last.gid)
        skipped = codec.encode_joint_state(joint_state(8), NAMES)
        talker.raw(topics.MEASURED_JS, skipped, gap)  # seq 2 ahead: two samples lost
        talker.raw(topics.MEASURED_JS, b"\x00\x01\x00\x00garbage", gap)  # does not decode
        talker.raw(topics.TRUE_CF, b"no attachment", None)
        talker.raw(topics.ESTIMATE_DIAGNOSTICS, b"\x00\x01\x00\x00", attachment(1))

        def settled():
            s = subs.snapshots()
            return (s["measured_js"].received == 7 and s["measured_js"].malformed == 1
                    and s["estimated_cf"].received == 5 and s["estimated_cf"].malformed == 1
                    and s["true_cf"].malformed == 1 and s["status"].received == 1
                    and s["setpoint_js"].received == 1)  # fmt: skip

        wait_for(settled, "every sample at the dashboard")
        snaps = subs.snapshots()
        assert snaps["measured_js"].lost == 2 and snaps["estimated_cf"].lost == 0
        assert snaps["true_cf"].received == 5 and snaps["true_cf"].lost == 0
        assert tel.snapshots()["true_cf"].malformed == 0  # dropped by the node, before decoding
        assert all(0.0 <= s.latency_ms_mean < 60_000.0 for s in snaps.values() if s.received)
        js = tel.joint_state.window()
        assert np.allclose(js.t_s, [(T0_NS + k * 1_000_000) * 1e-9 for k in (0, 1, 2, 3, 4, 5, 8)])
        _, row = tel.estimate.latest()
        assert row[FE_F].tolist() == [0.1, -1.0, 0.2] and row[FE_SOURCE_SEQ] == 4 + 7
        assert tel.setpoint.latest()[1].tolist() == [0.5, 0.6, 0.7]
        assert tel.status().state is m.SafetyState.STOPPED
    finally:
        subs.close()
        node.close()
        talker.close()


def test_a_device_id_that_is_no_ros_name_is_refused(zenoh_session):
    node = Node(zenoh_session, NODE_NAME)
    try:
        with pytest.raises(ConfigurationError, match="ROS 2 name token"):
            Subscriptions(node, Telemetry(capacity=8), "bad-id", "master")
    finally:
        node.close()
