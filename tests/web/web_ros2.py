"""What the dashboard's tests publish: the slave's, master's and service's ROS 2 topics.

:class:`Talker` is a ROS 2 node (:class:`teleop_force.ros2.node.Node`) with one publisher per
topic the dashboard subscribes to, each message encoded by :mod:`teleop_force.ros2.codec`
(rosbags CDR) with rmw_zenoh's attachment, as the live processes publish them.
:func:`attachment` builds an attachment for the handlers' unit tests.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import zenoh

from teleop_force.ros2 import codec, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node, Publisher
from teleop_force.transport import messages as m
from teleop_force.transport import pubsub

TIMEOUT_S = 10.0
GID = bytes(range(16))
NAMES = topics.OMNI_MODEL_JOINT_NAMES


def attachment(seq: int, source_timestamp_ns: int = 0, gid: bytes = GID) -> Attachment:
    """rmw_zenoh's attachment of sample ``seq`` (from 1) sent at ``source_timestamp_ns``."""
    return Attachment(seq, source_timestamp_ns, gid)


def wait_for(predicate: Callable[[], bool], what: str, timeout_s: float = TIMEOUT_S) -> None:
    """Return once ``predicate()`` holds; AssertionError naming ``what`` after the timeout."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.01)


class Talker:
    """Publishers of the slave's (``device``), master's and service's topics on one node."""

    def __init__(
        self, session: zenoh.Session, device: str = "slave", master_device: str = "master"
    ) -> None:
        """Declare the node ``test_talker`` and its publishers."""
        self.node = Node(session, "test_talker")
        slave_topics = (
            topics.MEASURED_JS, topics.ESTIMATED_CF, topics.ESTIMATE_DIAGNOSTICS,
            topics.TRUE_CF, topics.STATUS, topics.SERVICE_DIAGNOSTICS,
        )  # fmt: skip
        self.publishers: dict[topics.Topic, Publisher] = {
            topic: self.node.publisher(topics.topic_name(device, topic), topic.ros_type)
            for topic in slave_topics
        }
        self.publishers[topics.SETPOINT_JS] = self.node.publisher(
            topics.topic_name(master_device, topics.SETPOINT_JS), topics.SETPOINT_JS.ros_type
        )

    def wait_for_subscribers(self, *wanted: topics.Topic) -> None:
        """Wait until every publisher of ``wanted`` (all if none given) has a subscriber."""
        for topic in wanted or tuple(self.publishers):
            publisher = self.publishers[topic].zenoh_publisher
            assert pubsub.wait_for_subscribers(publisher, TIMEOUT_S), f"no subscriber: {topic}"

    def joint_state(self, msg: m.JointState) -> Attachment:
        """Publish ``msg`` on ``measured_js``; return the attachment sent."""
        return self.publishers[topics.MEASURED_JS].publish(codec.encode_joint_state(msg, NAMES))

    def setpoint(self, msg: m.JointSetpoint) -> Attachment:
        """Publish ``msg`` on the master's ``setpoint_js``."""
        payload = codec.encode_joint_setpoint(msg, NAMES)
        return self.publishers[topics.SETPOINT_JS].publish(payload)

    def estimate(self, msg: m.ForceEstimateMessage) -> Attachment:
        """Publish ``msg`` as its WrenchStamped and EstimateDiagnostics (wrench first)."""
        wrench, diagnostics = codec.encode_estimate(msg, NAMES, topics.BASE_FRAME)
        sent = self.publishers[topics.ESTIMATED_CF].publish(wrench)
        self.publishers[topics.ESTIMATE_DIAGNOSTICS].publish(diagnostics)
        return sent

    def true_force(self, msg: m.ContactForce) -> Attachment:
        """Publish ``msg`` on ``true_cf``."""
        payload = codec.encode_contact_force(msg, topics.BASE_FRAME)
        return self.publishers[topics.TRUE_CF].publish(payload)

    def status(self, msg: m.Status) -> Attachment:
        """Publish ``msg`` on ``status``."""
        return self.publishers[topics.STATUS].publish(codec.encode_status(msg))

    def service_diagnostics(self, msg: m.ServiceDiagnostics) -> Attachment:
        """Publish ``msg`` on ``service/diagnostics``."""
        payload = codec.encode_service_diagnostics(msg)
        return self.publishers[topics.SERVICE_DIAGNOSTICS].publish(payload)

    def raw(self, topic: topics.Topic, payload: bytes, sent: Attachment | None) -> None:
        """Put ``payload`` on ``topic``'s key with ``sent`` (``None``: no attachment)."""
        publisher = self.publishers[topic].zenoh_publisher
        publisher.put(payload, attachment=None if sent is None else sent.encode())

    def close(self) -> None:
        """Undeclare the publishers and the node."""
        self.node.close()
