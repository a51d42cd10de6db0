"""The session recorder: every ROS 2 message of the domain, as received, to an MCAP ROS 2 bag."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from teleop_force.errors import ConfigurationError
from teleop_force.io.cdr_columns import read_joint_state_arrays
from teleop_force.io.mcap_session import SessionReader, SessionWriter, read_session_as_recording
from teleop_force.ros2 import codec, graph, interfaces, topics
from teleop_force.ros2.node import Node
from teleop_force.service.session_recorder import SessionRecorder, build_parser, final_line
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import declare_queue_subscriber, wait_for_subscribers

_COUNT = 600
_NAMES = topics.OMNI_MODEL_JOINT_NAMES


def _joint_state(seq: int, stamp_ns: int) -> m.JointState:
    return m.JointState(seq, stamp_ns, (0.001 * seq, 0.2, 0.3), (0.0, 0.1, 0.0), (0.01, 0.02, 0.0))


def _publish_and_record(
    zenoh_pair: Any, path: Path, stamp_offset_ns: int
) -> tuple[SessionRecorder, list[Any]]:
    """Publish joint states and true forces from a ROS 2 node; return what was sent."""
    domain = graph.domain_id_from_env()
    writer = SessionWriter(path, {"primary_device": "slave", "source": "live"}, profile="ros2")
    recorder = SessionRecorder(zenoh_pair.listener, writer, "slave").start()
    node = Node(zenoh_pair.connector, "recorder_test_publisher", domain_id=domain)
    sent = []
    try:
        js = node.publisher("/slave/measured_js", interfaces.JOINT_STATE)
        cf = node.publisher("/slave/true_cf", interfaces.WRENCH_STAMPED)
        assert wait_for_subscribers(js.zenoh_publisher, 5.0)
        for seq in range(_COUNT):
            stamp = time.time_ns() + stamp_offset_ns
            attachment = js.publish(codec.encode_joint_state(_joint_state(seq, stamp), _NAMES),
                                    stamp)  # fmt: skip
            sent.append(attachment)
            if seq % 10 == 0:
                force = m.ContactForce(seq, stamp, (1.0, 2.0, 0.01 * seq))
                cf.publish(codec.encode_contact_force(force, topics.BASE_FRAME), stamp)
            if seq % 100 == 0:
                time.sleep(0.03)  # several drains, not one
        zenoh_pair.connector.put(js.key, b"no attachment")  # counted as malformed
        deadline = time.monotonic() + 5.0
        while recorder.received < _COUNT + _COUNT // 10 + 1 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        node.close()
        recorder.close()
    return recorder, sent


def test_ros2_messages_recorded_as_received_with_the_attachments_seq_and_time(
    zenoh_pair: Any, tmp_path: Path
) -> None:
    path = tmp_path / "session.mcap"
    before_ns = time.time_ns()
    recorder, sent = _publish_and_record(zenoh_pair, path, 0)
    after_ns = time.time_ns()
    stats = recorder.stats()
    forces = _COUNT // 10
    assert stats["received"] == _COUNT + forces + 1
    assert stats["recorder"]["messages"] == _COUNT + forces
    assert stats["malformed"]["dropped"] == 1
    assert final_line(stats) == (
        f"stopped: {_COUNT + forces} messages written to {path} ({_COUNT + forces + 1} "
        "received, 0 dropped, 1 malformed)"
    )
    reader = SessionReader(path)
    # Data keys only: the nodes' liveliness tokens (@ros2_lv/...) are not in <domain>/**.
    assert reader.topics == {
        "/slave/measured_js": interfaces.JOINT_STATE,
        "/slave/true_cf": interfaces.WRENCH_STAMPED,
    }
    rows = list(reader.messages(["/slave/measured_js"]))
    # seq = the attachment's sequence number, the values those sent
    assert [msg.seq for _, _, msg in rows] == [a.sequence_number for a in sent]
    assert [msg.q_rad[0] for _, _, msg in rows] == [0.001 * k for k in range(_COUNT)]
    raw = list(reader.raw_messages(["/slave/measured_js"]))
    assert [r.publish_time_ns for r in raw] == [a.source_timestamp_ns for a in sent]
    log_times = [r.log_time_ns for r in raw]
    assert log_times == sorted(log_times)
    for r in raw:
        # received after it was stamped, within the drain interval it arrived in
        assert r.publish_time_ns <= r.log_time_ns <= r.publish_time_ns + 500_000_000
        assert before_ns <= r.log_time_ns <= after_ns
    arrays = read_joint_state_arrays(path, "/slave/measured_js")  # the columnar path agrees
    assert arrays.seq.tolist() == [msg.seq for _, _, msg in rows]
    assert arrays.t_ns.tolist() == [msg.t_ns for _, _, msg in rows]
    recording = read_session_as_recording(path)
    assert recording.f_tip_in_base_n is not None
    np.testing.assert_allclose(recording.q_rad[:, 0], [0.001 * k for k in range(_COUNT)])


def test_a_recorded_session_is_a_ros2_bag_for_mcap_and_rosbags(
    zenoh_pair: Any, tmp_path: Path
) -> None:
    path = tmp_path / "session.mcap"
    _, sent = _publish_and_record(zenoh_pair, path, 0)
    with open(path, "rb") as f:
        mcap = make_reader(f)
        assert mcap.get_header().profile == "ros2"
        sequences = [msg.sequence for _, c, msg in mcap.iter_messages() if c.topic.endswith("js")]
    assert sequences == [a.sequence_number for a in sent]
    with AnyReader([path]) as bag:  # rosbags' own MCAP reader and deserializer
        assert {c.topic: c.msgtype for c in bag.connections} == {
            "/slave/measured_js": interfaces.JOINT_STATE,
            "/slave/true_cf": interfaces.WRENCH_STAMPED,
        }
        js = [c for c in bag.connections if c.topic == "/slave/measured_js"]
        decoded = [bag.deserialize(raw, c.msgtype) for c, _, raw in bag.messages(js)]
    assert [list(d.name) for d in decoded[:1]] == [list(_NAMES)]
    assert [float(d.position[0]) for d in decoded] == [0.001 * k for k in range(_COUNT)]
    stamps = [d.header.stamp.sec * 10**9 + d.header.stamp.nanosec for d in decoded]
    assert stamps == [a.source_timestamp_ns for a in sent]


def test_stamp_from_another_clock_clamped_into_the_drain_interval(
    zenoh_pair: Any, tmp_path: Path
) -> None:
    path = tmp_path / "session.mcap"
    before_ns = time.time_ns()
    _publish_and_record(zenoh_pair, path, -3600 * 10**9)  # an hour behind
    after_ns = time.time_ns()
    raw = list(SessionReader(path).raw_messages(["/slave/measured_js"]))
    assert len(raw) == _COUNT
    log_times = [r.log_time_ns for r in raw]
    assert log_times == sorted(log_times)
    assert all(before_ns <= log_ns <= after_ns for log_ns in log_times)
    assert all(r.publish_time_ns < before_ns for r in raw)  # the source time is kept


def test_the_recorder_has_no_ros2_flag_any_more() -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--record", "x.mcap", "--ros2"])


def test_queue_subscriber_refuses_an_empty_fifo(zenoh_pair: Any) -> None:
    with pytest.raises(ConfigurationError, match="queue capacity"):
        declare_queue_subscriber(zenoh_pair.listener, keys.measured_js("slave"), 0)


def test_the_recorder_keeps_the_demo_monitor_figures(zenoh_pair: Any, tmp_path: Path) -> None:
    from teleop_force.service.session_monitor import SessionMonitor

    writer = SessionWriter(tmp_path / "m.mcap", {"primary_device": "slave"}, profile="ros2")
    monitor = SessionMonitor("slave")
    recorder = SessionRecorder(zenoh_pair.listener, writer, "slave", monitor=monitor).start()
    node = Node(zenoh_pair.connector, "monitor_test_publisher")
    try:
        true_cf = node.publisher("/slave/true_cf", interfaces.WRENCH_STAMPED)
        wrench_pub = node.publisher("/slave/estimated_cf", interfaces.WRENCH_STAMPED)
        diagnostics_pub = node.publisher(
            "/slave/estimate_diagnostics", interfaces.ESTIMATE_DIAGNOSTICS
        )
        for publisher in (true_cf, wrench_pub, diagnostics_pub):
            assert wait_for_subscribers(publisher.zenoh_publisher, 5.0)
        time.sleep(0.1)
        for k in range(1, 201):
            stamp = 1_000 + k
            attachment = true_cf.publish(
                codec.encode_contact_force(m.ContactForce(k, stamp, (0.0, -2.0, 0.0)), "base"),
                stamp,
            )
            estimate = m.ForceEstimateMessage(
                k, stamp, attachment.sequence_number, (0.0, -1.8, 0.0), [0.0] * 3, [True] * 3,
                [1.0] * 3, [0.0] * 3, [0.0] * 3,
            )  # fmt: skip
            wrench, diagnostics = codec.encode_estimate(estimate, (), topics.BASE_FRAME)
            wrench_pub.publish(wrench, stamp)
            diagnostics_pub.publish(diagnostics, stamp)
        deadline = time.monotonic() + 5.0
        while recorder.received < 600 and time.monotonic() < deadline:
            time.sleep(0.01)
        figures = recorder.stats()["monitor"]
    finally:
        node.close()
        recorder.close()
    assert figures["estimates"] == {"received": 200, "lost": 0}
    assert figures["true_forces"] == {"received": 200, "lost": 0}
    assert figures["force_error"]["paired_samples"] == 200
    assert figures["force_error"]["relative_rms_error"] == pytest.approx(0.1, rel=1e-9)
    assert figures["malformed"] == 0
