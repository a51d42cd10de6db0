"""The estimation service's ROS 2 edge (``--ros2``): rmw_zenoh JointState in, estimates out.

A ROS 2 node ``teleop_force_service`` on the service's session, as rmw_zenoh declares one
(:mod:`teleop_force.ros2.node`): it subscribes to ``/<device>/measured_js``
(``sensor_msgs/msg/JointState``, any type hash) and publishes every estimate as
``geometry_msgs/msg/WrenchStamped`` on ``/<device>/estimated_cf`` and
``teleop_force_msgs/msg/EstimateDiagnostics`` on ``/<device>/estimate_diagnostics``, and
each report of the residual watch as ``teleop_force_msgs/msg/ServiceDiagnostics`` on
``/<device>/service/diagnostics``.

A received JointState must be in the model's coordinates: its names are empty or the
model's (:func:`teleop_force.ros2.topics.model_joint_names`); the Omni driver's ``waist,
shoulder, elbow`` (a relative elbow) or any other names are counted as malformed under the
ROS key and dropped, as are payloads that do not parse. An accepted one enters the service
as the wire JointState it replaces, with the attachment's sequence number (modulo 2**32) as
its ``seq``: loss and duplicates are counted from rmw_zenoh's sequence numbers.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Final

import zenoh

from teleop_force.errors import MessageError
from teleop_force.ros2 import codec, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node, Subscription
from teleop_force.transport import messages as m

#: The node's name (namespace ``/``).
NODE_NAME: Final = "teleop_force_service"
_SEQ_MASK: Final = 0xFFFF_FFFF


class Ros2Edge:
    """The ROS 2 node of one service (module docstring); :meth:`close` undeclares it."""

    def __init__(
        self,
        session: zenoh.Session,
        device: str,
        n_joints: int,
        on_joint_state: Callable[[bytes, int], None],
        count_malformed: Callable[[str, Exception], None],
    ) -> None:
        """Declare the node and its publishers; :meth:`subscribe` starts the input.

        ``on_joint_state(wire_payload, arrival_ns)`` gets every accepted JointState as the
        wire message; ``count_malformed(key, error)`` every refused one.
        """
        self.device = topics.validate_device(device)
        self.names = topics.model_joint_names(n_joints)
        self._on_joint_state = on_joint_state
        self._count_malformed = count_malformed
        codec.warm_up()  # before the node and its subscription exist
        self.node = Node(session, NODE_NAME)
        self.estimates = self.node.publisher(
            topics.topic_name(device, topics.ESTIMATED_CF), topics.ESTIMATED_CF.ros_type
        )
        self.diagnostics = self.node.publisher(
            topics.topic_name(device, topics.ESTIMATE_DIAGNOSTICS),
            topics.ESTIMATE_DIAGNOSTICS.ros_type,
        )
        self.service_diagnostics = self.node.publisher(
            topics.topic_name(device, topics.SERVICE_DIAGNOSTICS),
            topics.SERVICE_DIAGNOSTICS.ros_type,
        )
        self.joint_states: Subscription | None = None

    def subscribe(self) -> None:
        """Declare the subscription to ``/<device>/measured_js``: estimation starts."""
        self.joint_states = self.node.subscription(
            topics.topic_name(self.device, topics.MEASURED_JS),
            topics.MEASURED_JS.ros_type,
            self._on_sample,
            direct=True,
        )

    @property
    def malformed_attachments(self) -> int:
        """Samples dropped for a missing or malformed rmw_zenoh attachment."""
        return 0 if self.joint_states is None else self.joint_states.malformed

    def publish_service_diagnostics(self, json_payload: bytes) -> None:
        """Publish one residual-watch report (its JSON payload) as ServiceDiagnostics."""
        report = m.ServiceDiagnostics.decode(json_payload)
        self.service_diagnostics.publish(codec.encode_service_diagnostics(report))

    def _on_sample(self, payload: bytes, attachment: Attachment) -> None:
        arrival_ns = time.time_ns()
        try:
            msg, named = codec.decode_joint_state(payload, attachment.sequence_number & _SEQ_MASK)
            if named.names and named.names != self.names:
                raise MessageError(
                    f"joint names {list(named.names)} are not the model's {list(self.names)}"
                    + (
                        " (the driver's relative elbow)"
                        if named.names == topics.DRIVER_JOINT_NAMES
                        else ""
                    )
                )
        except MessageError as exc:
            self._count_malformed(topics.topic_name(self.device, topics.MEASURED_JS), exc)
            return
        self._on_joint_state(msg.encode(), arrival_ns)

    def publish_estimate(self, wire_estimate: bytes) -> None:
        """Publish one estimate (the service's wire ForceEstimate) as its two ROS messages."""
        estimate = m.decode(wire_estimate)
        if not isinstance(estimate, m.ForceEstimateMessage):
            raise MessageError(f"not a ForceEstimate: {type(estimate).__name__}")
        wrench, diagnostics = codec.encode_estimate(estimate, self.names, topics.BASE_FRAME)
        self.estimates.publish(wrench)
        self.diagnostics.publish(diagnostics)

    def close(self) -> None:
        """Undeclare the node's entities and its token."""
        self.node.close()
