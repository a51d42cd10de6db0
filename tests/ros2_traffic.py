"""Tests' side of the live topics: publish and collect ROS 2 messages on a Zenoh session.

The tests talk to the processes as any ROS 2 peer would: CDR payloads on rmw_zenoh's keys,
with its attachment. :func:`put` chooses the attachment's sequence number itself (loss,
duplicates and restarts are what the tests exercise); :class:`Collector` decodes what a
process publishes with :mod:`teleop_force.ros2.streams`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import zenoh

from teleop_force.errors import MessageError
from teleop_force.ros2 import codec, streams, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node, Publisher
from teleop_force.transport import messages as m

NAMES = topics.OMNI_MODEL_JOINT_NAMES


def put(publisher: Publisher, payload: bytes, seq: int, source_ns: int | None = None) -> None:
    """Put ``payload`` with an attachment of sequence number ``seq`` (chosen by the test)."""
    stamp = time.time_ns() if source_ns is None else source_ns
    attachment = Attachment(seq, stamp, publisher.gid)
    publisher.zenoh_publisher.put(payload, attachment=attachment.encode())


def joint_state_payload(js: m.JointState, names: Sequence[str] = NAMES) -> bytes:
    """A ``sensor_msgs/msg/JointState`` of ``js`` (``names`` one per joint, or empty)."""
    return codec.encode_joint_state(js, names if names else ())


class JointStatePublisher:
    """A node publishing ``/<device>/measured_js``; :meth:`send` uses the message's seq."""

    def __init__(self, session: zenoh.Session, device: str, node_name: str = "test_driver"):
        self.node = Node(session, node_name)
        self.publisher = self.node.publisher(
            topics.topic_name(device, topics.MEASURED_JS), topics.MEASURED_JS.ros_type
        )

    def send(self, js: m.JointState, names: Sequence[str] = NAMES) -> None:
        put(self.publisher, joint_state_payload(js, names), js.seq)

    def send_raw(self, payload: bytes, seq: int) -> None:
        put(self.publisher, payload, seq)

    def close(self) -> None:
        self.node.close()


class Collector:
    """Every message of one topic of ``device``, decoded, in arrival order."""

    def __init__(
        self,
        session: zenoh.Session,
        device: str,
        topic: topics.Topic,
        node_name: str = "test_listener",
        n_joints: int | None = None,
    ):
        self.messages: list[Any] = []
        self.attachments: list[Attachment] = []
        self.malformed: list[tuple[str, MessageError]] = []
        self._lock = threading.Lock()
        self.node = Node(session, node_name)
        streams.subscribe(
            self.node, device, topic, self._on_message, self._on_malformed, n_joints=n_joints,
            max_unpaired=1 << 16,  # a test may collect thousands while the machine is loaded
        )  # fmt: skip

    def _on_message(self, message: Any, attachment: Attachment) -> None:
        with self._lock:
            self.messages.append(message)
            self.attachments.append(attachment)

    def _on_malformed(self, topic: str, error: MessageError) -> None:
        with self._lock:
            self.malformed.append((topic, error))

    def __len__(self) -> int:
        return len(self.messages)

    def close(self) -> None:
        self.node.close()


def joint_states_500hz(n: int, t0_ns: int = 1_764_158_400_000_000_000) -> list[m.JointState]:
    """A smooth joint-state stream at the Omni driver's 500 Hz (model coordinates)."""
    t = np.arange(n) * 2e-3
    q = np.column_stack([0.2 * np.sin(2 * t), 0.8 + 0.3 * np.sin(3 * t), 0.3 + 0.2 * t])
    tau = np.column_stack([0.02 * np.sin(5 * t), 0.15 + 0.01 * t, 0.05 + 0.01 * np.sin(7 * t)])
    return [m.JointState(k + 1, t0_ns + k * 2_000_000, tuple(q[k]), (0.0,) * 3, tuple(tau[k]))
            for k in range(n)]  # fmt: skip
