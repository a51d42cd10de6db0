"""The ROS 2 node of the master or the slave: its publishers, on rmw_zenoh's keys.

One ROS 2 node per process (``teleop_force_master``, ``teleop_force_slave``, namespace ``/``),
declared as rmw_zenoh declares one (:mod:`teleop_force.ros2.node`), publishing standard
messages on the topics of :mod:`teleop_force.ros2.topics`: the slave its
``/<device>/measured_js`` (``sensor_msgs/msg/JointState``), ``/<device>/true_cf``
(``geometry_msgs/msg/WrenchStamped``, the simulated true tip force; zero out of contact) and
``/<device>/status``; the master its ``/<device>/measured_js`` and ``/<device>/setpoint_js``.
Joint names are the model's (``model_q1 model_q2 model_q3_absolute``): the plants run in the
model's coordinates. The header stamp is the sample time; the attachment's source time the
moment of publication. A tick's messages leave in one Zenoh batch: all but the tick's last
are declared ``followed`` (not express). The processes subscribe through :attr:`Ros2Outputs.node`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import zenoh

from teleop_force.ros2 import codec, fast_cdr, topics
from teleop_force.ros2.node import Node, Publisher
from teleop_force.transport import messages as m

JOINTS: Final = 3


class Ros2Outputs:
    """The node of one process and the publishers it asked for; :meth:`close` undeclares."""

    def __init__(
        self,
        session: zenoh.Session,
        role: str,
        device: str,
        kinds: Sequence[topics.Topic],
        *,
        followed: Sequence[topics.Topic] = (),
    ) -> None:
        """Declare node ``teleop_force_<role>`` and a publisher per topic kind of ``device``.

        ``followed``: the kinds whose message is always followed, in the same tick, by one of
        another kind: they are not express, and wait to leave with it in one batch.
        """
        codec.warm_up()  # rosbags compiles on first use: not on the loop's first tick
        self.node = Node(session, f"teleop_force_{role}")
        self.names = topics.model_joint_names(JOINTS)
        # the 1 kHz messages in one struct call each (fast_cdr: byte for byte rosbags' CDR)
        self._joint_state = fast_cdr.JointStateLayout(self.names)
        self._setpoint = fast_cdr.JointStateLayout(self.names, velocities=False, efforts=False)
        self._wrench = fast_cdr.WrenchLayout(topics.BASE_FRAME)
        self._publishers: dict[str, Publisher] = {
            topic.kind: self.node.publisher(
                topics.topic_name(device, topic), topic.ros_type, express=topic not in followed
            )
            for topic in kinds
        }

    def zenoh_publisher(self, topic: topics.Topic) -> zenoh.Publisher:
        """Return the Zenoh publisher of ``topic`` (to wait for its subscribers)."""
        return self._publishers[topic.kind].zenoh_publisher

    def joint_state(
        self,
        t_ns: int,
        q_rad: Sequence[float],
        qd_rad_s: Sequence[float],
        effort_nm: Sequence[float],
    ) -> None:
        """Publish a measured joint state (position, velocity, commanded motor torque)."""
        self._publishers[topics.MEASURED_JS.kind].publish(
            self._joint_state.pack(t_ns, q_rad, qd_rad_s, effort_nm)
        )

    def setpoint(self, t_ns: int, q_rad: Sequence[float]) -> None:
        """Publish a joint position setpoint (a JointState with positions only)."""
        self._publishers[topics.SETPOINT_JS.kind].publish(self._setpoint.pack(t_ns, q_rad))

    def true_force(self, t_ns: int, force_n: Sequence[float]) -> None:
        """Publish the true tip force on the environment, in the base frame [N]."""
        self._publishers[topics.TRUE_CF.kind].publish(self._wrench.pack(t_ns, force_n))

    def status(self, msg: m.Status) -> None:
        """Publish the safety state."""
        self._publishers[topics.STATUS.kind].publish(codec.encode_status(msg))

    def close(self) -> None:
        """Undeclare the publishers and the node's token."""
        self.node.close()
