"""``teleop-force demo``: every message of a live demo, read as a ROS 2 peer would, with rclpy.

A peer joined to the demo's router captures every sample on ``0/**`` (rmw_zenoh's data keys,
domain 0) with its attachment, and every liveliness token under ``@ros2_lv/0/``. Each sample
must carry rmw_zenoh's attachment of the publisher that declared the key, and decode with
rclpy (rmw_fastrtps's serializer; the project's own types with :mod:`teleop_force.ros2.codec`)
to the values the processes sent: a JointState's values are the ones the project decodes,
the true force is stamped like the slave's joint state of its tick, and every estimate names
(``source_sequence``) a JointState the slave sent. The project's TF keys
(``omni/<device>/measured_js`` ...) carry nothing. The graph the tokens describe is printed as
``ros2 topic list -t`` would show it.
"""

from __future__ import annotations

import collections
import math
import subprocess
import time

import pytest
import zenoh
from mcap.reader import make_reader
from teleop_helpers import STARTUP_TIMEOUT_S, python_module

from teleop_force.errors import TransportError
from teleop_force.ros2 import codec, graph, interfaces, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.transport import messages as m
from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)

serialization = pytest.importorskip("rclpy.serialization")
sensor_msgs = pytest.importorskip("sensor_msgs.msg")
geometry_msgs = pytest.importorskip("geometry_msgs.msg")

pytestmark = pytest.mark.zenoh
KEPT = 400  # samples kept per key
#: The 1 kHz topics (status is 10 Hz, the service's diagnostics 1 Hz)
ONE_KHZ = {"measured_js", "setpoint_js", "true_cf", "estimated_cf", "estimate_diagnostics"}
#: The project's own binary keys of before: nothing may be put on them any more.
TF_KINDS = {"measured_js", "setpoint_js", "measured_cf", "estimated_cf", "status", "diagnostics"}
EXPECTED_PUBLISHED = {
    "/slave/measured_js", "/slave/true_cf", "/slave/status", "/slave/estimated_cf",
    "/slave/estimate_diagnostics", "/master/measured_js", "/master/setpoint_js",
    "/slave/service/diagnostics",
}  # fmt: skip


def _peer(port: int):
    """A peer joined to the demo's router (as a ROS 2 node's session), once it listens."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    options = ZenohOptions(mode="peer", connect=(listen_endpoint(port),),
                           listen=("tcp/127.0.0.1:0",), multicast_scouting=False)  # fmt: skip
    while True:
        try:
            return open_session(options)
        except TransportError:  # the router is not up yet: retry until the deadline
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def topic_list(entities: list[graph.Entity]) -> list[str]:
    """``ros2 topic list -t``: every topic with a publisher or a subscription, and its type."""
    types: dict[str, set[str]] = collections.defaultdict(set)
    for e in entities:
        if e.topic is not None:
            types[e.topic.name].add(e.topic.ros_type)
    return [f"{name} [{', '.join(sorted(types[name]))}]" for name in sorted(types)]


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def test_demo_messages_decode_with_rclpy_to_the_values_sent(tmp_path):
    port = free_tcp_port()
    demo = subprocess.Popen(
        python_module("teleop_force.cli.main", "demo", "--headless", "--duration", "6",
                      "--zenoh-port", str(port), "--record-dir", str(tmp_path)),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )  # fmt: skip
    ros: dict[str, list[tuple[bytes, Attachment]]] = collections.defaultdict(list)
    without_attachment: list[str] = []
    project_keys: list[str] = []

    def keep_ros(sample) -> None:
        key = str(sample.key_expr)
        if sample.attachment is None:
            without_attachment.append(key)
            return
        kept = ros[key]
        if len(kept) < KEPT:
            kept.append(
                (sample.payload.to_bytes(), Attachment.decode(sample.attachment.to_bytes()))
            )

    seen_tokens: set[str] = set()

    def keep_token(sample) -> None:  # every token declared while the demo runs
        if sample.kind == zenoh.SampleKind.PUT:
            seen_tokens.add(str(sample.key_expr))

    session = _peer(port)
    try:
        subs = [
            session.declare_subscriber("0/**", keep_ros),
            session.declare_subscriber("omni/**", lambda s: project_keys.append(str(s.key_expr))),
            session.liveliness().declare_subscriber("@ros2_lv/0/**", keep_token, history=True),
        ]
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while time.monotonic() < deadline and (
            len(ros) < 7 or any(len(v) < KEPT for k, v in ros.items() if k.split("/")[2] in ONE_KHZ)
        ):
            time.sleep(0.2)
        time.sleep(0.5)  # the last tokens' samples
        tokens = sorted(seen_tokens)
        for sub in subs:
            sub.undeclare()
    finally:
        session.close()
    out, _ = demo.communicate(timeout=STARTUP_TIMEOUT_S + 60)
    assert demo.returncode == 0, out[-3000:]

    # The graph, as ``ros2 node list`` / ``ros2 topic list -t`` show it.
    entities = [graph.parse_token(t) for t in tokens]
    listing = topic_list(entities)
    print("ros2 topic list -t:\n" + "\n".join(listing))
    print("data keys:\n" + "\n".join(sorted(ros)))
    print("liveliness tokens:\n" + "\n".join(sorted(tokens)))
    nodes = {e.node_name for e in entities if e.kind is graph.EntityKind.NODE}
    assert {"teleop_force_master", "teleop_force_slave", "teleop_force_service"} <= nodes
    publishers = {e.topic.name: e for e in entities if e.kind is graph.EntityKind.PUBLISHER}
    assert set(publishers) == EXPECTED_PUBLISHED
    subscribed = {e.topic.name for e in entities if e.kind is graph.EntityKind.SUBSCRIPTION}
    assert {"/slave/measured_js", "/master/setpoint_js"} <= subscribed
    # Headless, no haptic feedback: nothing subscribes to the estimates as a ROS 2 node; the
    # recorder takes every key (no subscription token) and keeps the supervisor's figures.
    assert "/slave/estimated_cf" not in subscribed
    assert f"/slave/measured_js [{interfaces.JOINT_STATE}]" in listing

    # Every sample: rmw_zenoh's attachment of the publisher of its key, in order.
    assert not without_attachment, without_attachment[:5]
    keys_published = set()
    for name, entity in publishers.items():
        key = graph.topic_key(0, name, entity.topic.ros_type, entity.topic.type_hash)
        keys_published.add(key)
        assert entity.topic.type_hash == interfaces.type_hash(entity.topic.ros_type)
        samples = ros[key]
        assert samples or name == "/slave/service/diagnostics", key  # 1 Hz, after a warm-up
        seqs = [a.sequence_number for _, a in samples]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), key
        assert all(a.gid == entity.gid for _, a in samples), key
    assert set(ros) <= keys_published  # no sample on a key nobody declared
    # The TF keys of before carry nothing (the project's keys left are JSON / control ones).
    assert not [k for k in project_keys if k.split("/")[-1] in TF_KINDS], project_keys[:5]

    def samples(device, topic):
        return ros[topics.data_key(device, topic, 0)]

    # JointStates: rclpy reads the values the project's codec reads (the ones sent).
    sent_seqs: set[int] = set()
    slave_stamps: set[int] = set()
    for device in ("slave", "master"):
        for payload, attachment in samples(device, topics.MEASURED_JS):
            msg = serialization.deserialize_message(payload, sensor_msgs.JointState)
            sent, named = codec.decode_joint_state(payload, attachment.sequence_number)
            assert tuple(msg.name) == named.names == topics.OMNI_MODEL_JOINT_NAMES
            assert stamp_ns(msg.header) == sent.t_ns
            assert tuple(msg.position) == sent.q_rad and tuple(msg.effort) == sent.effort_nm
            assert tuple(msg.velocity) == sent.qd_rad_s
            if device == "slave":
                sent_seqs.add(attachment.sequence_number)
                slave_stamps.add(sent.t_ns)
    for payload, attachment in samples("master", topics.SETPOINT_JS):
        msg = serialization.deserialize_message(payload, sensor_msgs.JointState)
        sent, named = codec.decode_joint_setpoint(payload, attachment.sequence_number)
        assert tuple(msg.name) == named.names == topics.OMNI_MODEL_JOINT_NAMES
        assert tuple(msg.position) == sent.q_rad and len(msg.velocity) == len(msg.effort) == 0
    # The true force: one WrenchStamped per slave tick, stamped as that tick's JointState.
    true_stamps = []
    for payload, attachment in samples("slave", topics.TRUE_CF):
        msg = serialization.deserialize_message(payload, geometry_msgs.WrenchStamped)
        sent = codec.decode_contact_force(payload, attachment.sequence_number)
        assert msg.header.frame_id == topics.BASE_FRAME
        f = msg.wrench.force
        assert (f.x, f.y, f.z) == sent.f_n and stamp_ns(msg.header) == sent.t_ns
        true_stamps.append(sent.t_ns)
    window = [t for t in true_stamps if min(slave_stamps) <= t <= max(slave_stamps)]
    assert window and set(window) <= slave_stamps
    # Estimates: WrenchStamped + EstimateDiagnostics of one stamp, of a JointState sent.
    diagnostics = {}
    for payload, _ in samples("slave", topics.ESTIMATE_DIAGNOSTICS):
        decoded = codec.decode_estimate_diagnostics(payload)
        assert decoded.names == topics.OMNI_MODEL_JOINT_NAMES
        diagnostics[decoded.t_ns] = decoded
    paired = 0
    for payload, _ in samples("slave", topics.ESTIMATED_CF):
        msg = serialization.deserialize_message(payload, geometry_msgs.WrenchStamped)
        wrench = codec.decode_wrench(payload)
        assert msg.header.frame_id == topics.BASE_FRAME
        f = msg.wrench.force
        pairs = zip((f.x, f.y, f.z), wrench.force_n, strict=True)
        same = [u == v or (math.isnan(u) and math.isnan(v)) for u, v in pairs]
        assert all(same) and stamp_ns(msg.header) == wrench.t_ns
        if (half := diagnostics.get(wrench.t_ns)) is not None:
            paired += 1
            lo, hi = min(sent_seqs), max(sent_seqs)
            if lo <= half.source_sequence <= hi:
                assert half.source_sequence in sent_seqs
    assert paired > KEPT // 2
    statuses = [codec.decode_status(p, a.sequence_number) for p, a in
                samples("slave", topics.STATUS)]  # fmt: skip
    assert statuses and all(isinstance(s.state, m.SafetyState) for s in statuses)
    for payload, a in samples("slave", topics.SERVICE_DIAGNOSTICS):
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
    assert set(recorded) >= EXPECTED_PUBLISHED - {"/slave/service/diagnostics"}
    for name, entity in publishers.items():
        key = graph.topic_key(0, name, entity.topic.ros_type, entity.topic.type_hash)
        for payload, attachment in ros[key]:
            message = recorded[name].get(attachment.sequence_number)
            assert message is not None, (name, attachment.sequence_number)
            assert message.data == payload
            assert message.publish_time == attachment.source_timestamp_ns
