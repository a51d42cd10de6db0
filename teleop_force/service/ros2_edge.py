"""The estimation service's ROS 2 node: rmw_zenoh JointStates in, estimates out.

A ROS 2 node ``teleop_force_service`` on the service's session, as rmw_zenoh declares one
(:mod:`teleop_force.ros2.node`): it subscribes to ``/<device>/measured_js``
(``sensor_msgs/msg/JointState``, any type hash) and publishes every estimate as
``geometry_msgs/msg/WrenchStamped`` on ``/<device>/estimated_cf`` and
``teleop_force_msgs/msg/EstimateDiagnostics`` on ``/<device>/estimate_diagnostics`` (one
header stamp), and each report of the residual watch as
``teleop_force_msgs/msg/ServiceDiagnostics`` on ``/<device>/service/diagnostics``.

A received JointState must be in the model's coordinates: its names are empty or the
model's (:func:`teleop_force.ros2.topics.model_joint_names`); the Omni driver's ``waist,
shoulder, elbow`` (a relative elbow) or any other names are counted as malformed under the
topic's name and dropped, as are payloads that do not parse and samples without a valid
attachment (:attr:`Ros2Edge.malformed_attachments`). With a ``driver`` interface
(:class:`~teleop_force.robots.driver_interface.DriverInterface`) it is the driver's JointState
instead: the joints named there are read and converted to the model's q and torques, once, on
reading (a velocity is not needed: the estimator differentiates the angles itself).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Final

import zenoh

from teleop_force.errors import ConfigurationError, DataError, MessageError
from teleop_force.robots.driver_interface import DriverInterface
from teleop_force.ros2 import codec, fast_cdr, streams, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node, Subscription
from teleop_force.transport import messages as m

#: The node's name (namespace ``/``).
NODE_NAME: Final = "teleop_force_service"

#: ``on_joint_state(message, attachment, arrival_ns)``: one accepted JointState.
JointStateCallback = Callable[[m.JointState, Attachment, int], None]


class Ros2Edge:
    """The ROS 2 node of one service (module docstring); :meth:`close` undeclares it."""

    def __init__(
        self,
        session: zenoh.Session,
        device: str,
        n_joints: int,
        on_joint_state: JointStateCallback,
        count_malformed: Callable[[str, Exception], None],
        domain_id: int | None = None,
        driver: DriverInterface | None = None,
    ) -> None:
        """Declare the node and its publishers; :meth:`subscribe` starts the input.

        ``count_malformed(topic, error)`` gets every refused JointState; ``domain_id``: the
        ROS domain (``None``: ``ROS_DOMAIN_ID``, default 0); ``driver``: the JointStates are
        the driver's, converted with it.
        """
        self.device = topics.validate_device(device)
        self.n_joints = n_joints
        self.names = topics.model_joint_names(n_joints)
        self.joint_state_topic = topics.topic_name(device, topics.MEASURED_JS)
        self._on_joint_state = on_joint_state
        self._count_malformed = count_malformed
        self.driver = driver
        if driver is not None and driver.n_joints != n_joints:
            raise ConfigurationError(
                f"driver {driver.name} maps {driver.n_joints} joints, the model has {n_joints}"
            )
        self._zeros = (0.0,) * n_joints
        # the 1 kHz messages in one struct call each; any other layout goes through rosbags
        self._decode_joint_state = streams.decoder(topics.MEASURED_JS, n_joints)
        self._wrench = fast_cdr.WrenchLayout(topics.BASE_FRAME)
        self._diagnostics = fast_cdr.EstimateDiagnosticsLayout(self.names, topics.BASE_FRAME)
        codec.warm_up()  # rosbags compiles each type on first use: not on a 1 kHz path
        self.node = Node(session, NODE_NAME, domain_id=domain_id)
        # the wrench waits for its diagnostics, published next: the two leave in one batch
        self.estimates = self.node.publisher(
            topics.topic_name(device, topics.ESTIMATED_CF),
            topics.ESTIMATED_CF.ros_type,
            express=False,
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

    def subscribe(self, raw: Callable[[bytes, Attachment], None] | None = None) -> None:
        """Declare the subscription to ``/<device>/measured_js``: estimation starts.

        ``raw``: hand every sample to it undecoded instead (the Zenoh floor of the bench).
        """
        self.joint_states = self.node.subscription(
            self.joint_state_topic,
            topics.MEASURED_JS.ros_type,
            self._on_sample if raw is None else raw,
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
        seq = attachment.sequence_number & 0xFFFF_FFFF
        try:
            if self.driver is None:
                msg = self._decode_joint_state(payload, seq)
            else:
                msg = self._from_driver(payload, seq)
        except (MessageError, DataError) as exc:
            self._count_malformed(self.joint_state_topic, exc)
            return
        self._on_joint_state(msg, attachment, arrival_ns)

    def _from_driver(self, payload: bytes, seq: int) -> m.JointState:
        raw = codec.decode_raw_joint_state(payload)
        assert self.driver is not None
        q, tau = self.driver.to_model(raw.names, raw.position, raw.effort)
        if tau is None:
            raise MessageError(f"driver {self.driver.name}: a JointState without efforts")
        return m.JointState(seq, raw.t_ns, tuple(q.tolist()), self._zeros, tuple(tau.tolist()))

    def publish_estimate(
        self,
        t_ns: int,
        source_sequence: int,
        force_n: Sequence[float],
        tau_ext_nm: Sequence[float],
        coverage_weight: Sequence[float],
        on_trained_ground: Sequence[bool],
        tau_motor_filtered_nm: Sequence[float],
        tau_model_filtered_nm: Sequence[float],
    ) -> None:
        """Publish one estimate as its WrenchStamped, then its EstimateDiagnostics."""
        wrench = self._wrench.pack(t_ns, force_n)
        diagnostics = self._diagnostics.pack(
            t_ns, source_sequence, tau_ext_nm, coverage_weight, on_trained_ground,
            tau_motor_filtered_nm, tau_model_filtered_nm,
        )  # fmt: skip
        self.estimates.publish(wrench, t_ns)
        self.diagnostics.publish(diagnostics, t_ns)

    def publish_payloads(self, wrench: bytes, diagnostics: bytes) -> None:
        """Publish an estimate already encoded (the Zenoh floor's fixed one)."""
        self.estimates.publish(wrench)
        self.diagnostics.publish(diagnostics)

    def close(self) -> None:
        """Undeclare the node's entities and its token."""
        self.node.close()
