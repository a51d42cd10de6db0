"""``teleop-force demo --ros2``: every ROS 2 message of a live demo, read as rmw_zenoh's peer.

A client of the demo's router captures every sample on ``0/**`` with its attachment and every
liveliness token under ``@ros2_lv/0/``, and the wire streams beside them; rclpy
(rmw_fastrtps's serializer) decodes each ROS message to the values of the wire message with
the same stamp.
"""

from __future__ import annotations

import collections
import subprocess
import time

import pytest
from mcap.reader import make_reader
from teleop_helpers import STARTUP_TIMEOUT_S, python_module

from teleop_force.errors import TransportError
from teleop_force.ros2 import codec, graph, interfaces, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.session import ZenohOptions, free_tcp_port, open_session

serialization = pytest.importorskip("rclpy.serialization")
sensor_msgs = pytest.importorskip("sensor_msgs.msg")
geometry_msgs = pytest.importorskip("geometry_msgs.msg")

pytestmark = pytest.mark.zenoh
KEPT = 400  # samples kept per key
#: The 1 kHz topics (status is 10 Hz, the service's diagnostics 1 Hz)
ONE_KHZ = {"measured_js", "setpoint_js", "true_cf", "estimated_cf", "estimate_diagnostics"}


def _client(port: int):
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    options = ZenohOptions(mode="client", connect=(f"tcp/127.0.0.1:{port}",),
                           multicast_scouting=False)  # fmt: skip
    while True:
        try:
            return open_session(options)
        except TransportError:  # the router is not up yet: retry until the deadline
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def test_demo_ros2_messages_decode_with_rclpy_to_the_wire_values(tmp_path):
    port = free_tcp_port()
    demo = subprocess.Popen(
        python_module("teleop_force.cli.main", "demo", "--ros2", "--headless", "--duration", "6",
                      "--zenoh-port", str(port), "--record-dir", str(tmp_path)),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )  # fmt: skip
    ros: dict[str, list[tuple[bytes, Attachment]]] = collections.defaultdict(list)
    wire: dict[str, list[bytes]] = collections.defaultdict(list)

    def keep_ros(sample) -> None:
        kept = ros[str(sample.key_expr)]
        if len(kept) < KEPT:
            kept.append(
                (sample.payload.to_bytes(), Attachment.decode(sample.attachment.to_bytes()))
            )

    def keep_wire(sample) -> None:
        kept = wire[str(sample.key_expr)]
        if len(kept) < 4 * KEPT:
            kept.append(sample.payload.to_bytes())

    session = _client(port)
    try:
        subs = [session.declare_subscriber("0/**", keep_ros),
                session.declare_subscriber("omni/*/*", keep_wire)]  # fmt: skip
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while time.monotonic() < deadline and (
            len(ros) < 7 or any(len(v) < KEPT for k, v in ros.items() if k.split("/")[2] in ONE_KHZ)
        ):
            time.sleep(0.2)
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**", timeout=3)
                  if r.ok is not None]  # fmt: skip
        for sub in subs:
            sub.undeclare()
    finally:
        session.close()
    out, _ = demo.communicate(timeout=STARTUP_TIMEOUT_S + 60)
    assert demo.returncode == 0, out[-3000:]

    entities = [graph.parse_token(t) for t in tokens]
    nodes = {e.node_name for e in entities if e.kind is graph.EntityKind.NODE}
    assert nodes == {"teleop_force_master", "teleop_force_slave", "teleop_force_service"}
    publishers = {e.topic.name: e for e in entities if e.kind is graph.EntityKind.PUBLISHER}
    expected = {
        "/slave/measured_js", "/slave/true_cf", "/slave/status", "/slave/estimated_cf",
        "/slave/estimate_diagnostics", "/master/measured_js", "/master/setpoint_js",
        "/slave/service/diagnostics",
    }  # fmt: skip
    assert set(publishers) == expected
    for name, entity in publishers.items():
        key = graph.topic_key(0, name, entity.topic.ros_type, entity.topic.type_hash)
        assert entity.topic.type_hash == interfaces.type_hash(entity.topic.ros_type)
        samples = ros[key]
        assert samples or name == "/slave/service/diagnostics", key  # 1 Hz, after a warm-up
        seqs = [a.sequence_number for _, a in samples]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), key
        assert all(a.gid == entity.gid for _, a in samples), key

    def wire_by_stamp(key):
        return {msg.t_ns: msg for msg in map(m.decode, wire[key])}

    def ros_key(device, topic):
        return topics.data_key(device, topic, 0)

    for device in ("slave", "master"):  # JointStates: equal to the wire's of the same stamp
        by_stamp = wire_by_stamp(keys.measured_js(device))
        matched = 0
        for payload, _ in ros[ros_key(device, topics.MEASURED_JS)]:
            msg = serialization.deserialize_message(payload, sensor_msgs.JointState)
            assert list(msg.name) == list(topics.OMNI_MODEL_JOINT_NAMES)
            t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if t_ns in by_stamp:
                sent = by_stamp[t_ns]
                assert tuple(msg.position) == sent.q_rad and tuple(msg.effort) == sent.effort_nm
                assert tuple(msg.velocity) == sent.qd_rad_s
                matched += 1
        assert matched > 0, device
    estimates = wire_by_stamp(keys.estimated_cf("slave"))
    matched = 0
    for payload, _ in ros[ros_key("slave", topics.ESTIMATED_CF)]:
        msg = serialization.deserialize_message(payload, geometry_msgs.WrenchStamped)
        assert msg.header.frame_id == topics.BASE_FRAME
        t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if t_ns in estimates:
            f = msg.wrench.force
            assert (f.x, f.y, f.z) == estimates[t_ns].f_n
            matched += 1
    assert matched > 0
    for payload, _ in ros[ros_key("slave", topics.ESTIMATE_DIAGNOSTICS)]:
        assert codec.decode_estimate_diagnostics(payload).names == topics.OMNI_MODEL_JOINT_NAMES
    for payload, _ in ros[ros_key("slave", topics.TRUE_CF)]:
        msg = serialization.deserialize_message(payload, geometry_msgs.WrenchStamped)
        assert msg.header.frame_id == topics.BASE_FRAME
    statuses = [codec.decode_status(p, a.sequence_number) for p, a in
                ros[ros_key("slave", topics.STATUS)]]  # fmt: skip
    assert statuses and all(isinstance(s.state, m.SafetyState) for s in statuses)
    for payload, a in ros[ros_key("slave", topics.SERVICE_DIAGNOSTICS)]:
        assert codec.decode_service_diagnostics(payload, a.sequence_number).device == "slave"

    # The recording: the ROS messages as they arrived, seq and source time from the attachment
    (recording,) = tmp_path.glob("demo-*.mcap")
    with open(recording, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        recorded = collections.defaultdict(dict)
        for schema, channel, message in reader.iter_messages():
            if channel.topic.startswith("/"):
                assert schema.name == publishers[channel.topic].topic.ros_type
                recorded[channel.topic][message.sequence] = message
    assert set(recorded) >= expected - {"/slave/service/diagnostics"}
    for name, entity in publishers.items():
        key = graph.topic_key(0, name, entity.topic.ros_type, entity.topic.type_hash)
        for payload, attachment in ros[key]:
            message = recorded[name].get(attachment.sequence_number)
            assert message is not None, (name, attachment.sequence_number)
            assert message.data == payload
            assert message.publish_time == attachment.source_timestamp_ns
