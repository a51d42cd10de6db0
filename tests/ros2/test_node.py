"""A node on real Zenoh sessions (loopback, multicast off): tokens, keys and attachments."""

import json
import queue
import time

import pytest
import zenoh

from teleop_force.ros2 import codec, graph, interfaces, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node
from teleop_force.transport import messages as m
from teleop_force.transport import pubsub
from teleop_force.transport.session import (
    ZenohOptions,
    open_session,
)

# rmw_zenoh's docs/design.md, the listener node of demo_nodes_cpp (as in test_graph.py)
LISTENER_ZID = "aac3178e146ba6f1fc6e6a4085e77f21"
DOC_NODE = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"

serialization = pytest.importorskip("rclpy.serialization")
sensor_msgs = pytest.importorskip("sensor_msgs.msg")

TIMEOUT_S = 10.0
pytestmark = pytest.mark.zenoh


def wait_for(predicate, what):
    deadline = time.monotonic() + TIMEOUT_S
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def tokens(session, domain_id):
    replies = session.liveliness().get(f"@ros2_lv/{domain_id}/**", timeout=2.0)
    return {str(reply.ok.key_expr) for reply in replies if reply.ok is not None}


def test_node_token_is_the_design_docs_with_the_zenoh_id_from_config(tmp_path, zenoh_pair):
    config = tmp_path / "zenoh.json5"
    config.write_text(json.dumps({
        "id": LISTENER_ZID, "mode": "peer",
        "connect": {"endpoints": [zenoh_pair.endpoint]},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}},
    }))  # fmt: skip
    session = open_session(ZenohOptions(config_path=config))
    try:
        assert str(session.zid()) == LISTENER_ZID
        node = Node(session, "listener", domain_id=2)
        assert node.entity.token_key == DOC_NODE
        wait_for(lambda: DOC_NODE in tokens(zenoh_pair.listener, 2), "the node's token")
        node.close()
        wait_for(lambda: DOC_NODE not in tokens(zenoh_pair.listener, 2), "the token to go")
    finally:
        session.close()


def test_published_joint_states_carry_rmw_zenohs_attachment_and_decode_with_rclpy(zenoh_pair):
    talker = Node(zenoh_pair.listener, "teleop_force_slave", domain_id=0)
    listener = Node(zenoh_pair.connector, "teleop_force_service", domain_id=0)
    received: queue.Queue[tuple[bytes, Attachment]] = queue.Queue()
    name = topics.topic_name("slave", topics.MEASURED_JS)
    sub = listener.subscription(name, interfaces.JOINT_STATE, lambda p, a: received.put((p, a)))
    pub = talker.publisher(name, interfaces.JOINT_STATE)
    assert pub.key == topics.data_key("slave", topics.MEASURED_JS, 0)
    assert sub.key == topics.subscription_key("slave", topics.MEASURED_JS, 0)
    assert pubsub.wait_for_subscribers(pub.zenoh_publisher, TIMEOUT_S)
    sent = [m.JointState(k, time.time_ns(), (0.1 * k, 0.2, 0.3), (1.0, 2.0, 3.0), (0.0,) * 3)
            for k in range(5)]  # fmt: skip
    before = time.time_ns()
    for msg in sent:
        pub.publish(codec.encode_joint_state(msg, topics.OMNI_MODEL_JOINT_NAMES))
    got = [received.get(timeout=TIMEOUT_S) for _ in sent]
    assert [a.sequence_number for _, a in got] == [1, 2, 3, 4, 5]
    assert all(a.gid == pub.entity.gid == graph.entity_gid(pub.entity.token_key) for _, a in got)
    assert all(before <= a.source_timestamp_ns <= time.time_ns() for _, a in got)
    for (payload, _), msg in zip(got, sent, strict=True):
        ros = serialization.deserialize_message(payload, sensor_msgs.JointState)
        assert tuple(ros.position) == msg.q_rad and tuple(ros.velocity) == msg.qd_rad_s
        assert list(ros.name) == list(topics.OMNI_MODEL_JOINT_NAMES)

    seen = {graph.parse_token(key) for key in tokens(zenoh_pair.connector, 0)}
    assert {talker.entity, listener.entity, pub.entity, sub.entity} <= seen
    assert pub.entity.topic.type_hash == interfaces.type_hash(interfaces.JOINT_STATE)
    talker.close()
    listener.close()


def test_a_humble_publisher_is_heard_and_a_sample_without_attachment_is_dropped(zenoh_pair):
    listener = Node(zenoh_pair.connector, "teleop_force_service", domain_id=0)
    received: queue.Queue[tuple[bytes, Attachment]] = queue.Queue()
    name = topics.topic_name("slave", topics.MEASURED_JS)
    sub = listener.subscription(name, interfaces.JOINT_STATE, lambda p, a: received.put((p, a)))
    humble_key = graph.topic_key(0, name, interfaces.JOINT_STATE, graph.HASH_NOT_SUPPORTED)
    raw = pubsub.declare_data_publisher(zenoh_pair.listener, humble_key)
    assert pubsub.wait_for_subscribers(raw, TIMEOUT_S)
    payload = codec.encode_joint_state(m.JointState(0, 5, (0.1,), (0.2,), (0.3,)), ["model_q1"])
    raw.put(payload)  # no attachment: counted, dropped
    attachment = Attachment(1, time.time_ns(), bytes(range(16)))
    raw.put(payload, attachment=attachment.encode())
    got_payload, got_attachment = received.get(timeout=TIMEOUT_S)
    assert (got_payload, got_attachment) == (payload, attachment)
    assert sub.malformed == 1 and received.empty()
    pubsub.undeclare_all(raw)
    listener.close()


def test_subscription_key_matches_every_device_with_a_star():
    key = topics.subscription_key(None, topics.ESTIMATED_CF, 0)
    concrete = topics.data_key("slave", topics.ESTIMATED_CF, 0)
    assert zenoh.KeyExpr(key).intersects(zenoh.KeyExpr(concrete))
