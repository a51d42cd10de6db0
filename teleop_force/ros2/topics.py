"""The project's ROS 2 topics: name, message type and data key, per device.

Topic names are fully qualified, ``/<device>/<kind>``, in the node namespace ``/``:

- ``/<device>/measured_js``, ``sensor_msgs/msg/JointState``: measured q, q̇ and the
  commanded motor torque (``effort``);
- ``/<device>/setpoint_js``, ``sensor_msgs/msg/JointState``: joint position setpoint
  (``position`` only);
- ``/<device>/true_cf``, ``geometry_msgs/msg/WrenchStamped``: the true tip force (simulator
  or force sensor);
- ``/<device>/estimated_cf``, ``geometry_msgs/msg/WrenchStamped``: the service's estimate
  (NaN: near-singular);
- ``/<device>/estimate_diagnostics``, ``teleop_force_msgs/msg/EstimateDiagnostics``: what
  the estimate was computed from;
- ``/<device>/status``, ``teleop_force_msgs/msg/Status``: starting / following / holding /
  stopped and why;
- ``/<device>/service/diagnostics``, ``teleop_force_msgs/msg/ServiceDiagnostics``: the
  residual watch (1 Hz).

The true force is *not* on ``measured_cf``: the Omni's ROS 2 driver (sawSensablePhantom,
``mtsSensableHD.cpp``, ``HD_LAST_FORCE``) publishes its last *commanded* force there, and a
subscriber could not tell the two apart. Wrenches are the force of the tip on the environment
in the base frame (``frame_id``), torque zero.

Joint names say whose coordinates a JointState is in: the model's (``model_q1`` ...; on the
Omni ``model_q3_absolute``, the absolute elbow angle), never the driver's ``waist, shoulder,
elbow``, which name its relative elbow coordinates.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

from teleop_force.errors import ConfigurationError
from teleop_force.ros2 import graph, interfaces


@dataclass(frozen=True, slots=True)
class Topic:
    """A kind of topic: its name below ``/<device>/`` and its ROS 2 type."""

    kind: str
    ros_type: str


MEASURED_JS: Final = Topic("measured_js", interfaces.JOINT_STATE)
SETPOINT_JS: Final = Topic("setpoint_js", interfaces.JOINT_STATE)
TRUE_CF: Final = Topic("true_cf", interfaces.WRENCH_STAMPED)
ESTIMATED_CF: Final = Topic("estimated_cf", interfaces.WRENCH_STAMPED)
ESTIMATE_DIAGNOSTICS: Final = Topic("estimate_diagnostics", interfaces.ESTIMATE_DIAGNOSTICS)
STATUS: Final = Topic("status", interfaces.STATUS)
SERVICE_DIAGNOSTICS: Final = Topic("service/diagnostics", interfaces.SERVICE_DIAGNOSTICS)
ALL_TOPICS: Final = (
    MEASURED_JS, SETPOINT_JS, TRUE_CF, ESTIMATED_CF, ESTIMATE_DIAGNOSTICS, STATUS,
    SERVICE_DIAGNOSTICS,
)  # fmt: skip

#: The base frame's name, ``frame_id`` of every wrench.
BASE_FRAME: Final = "base"
#: The Omni's joints in the model's coordinates (q3 absolute).
OMNI_MODEL_JOINT_NAMES: Final = ("model_q1", "model_q2", "model_q3_absolute")
#: The Omni driver's names (relative elbow): never used for the model's coordinates.
DRIVER_JOINT_NAMES: Final = ("waist", "shoulder", "elbow")

_ROS_NAME_TOKEN: Final = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def model_joint_names(n_joints: int) -> tuple[str, ...]:
    """Return the JointState names of ``n_joints`` model coordinates (the Omni's for 3)."""
    if n_joints == len(OMNI_MODEL_JOINT_NAMES):
        return OMNI_MODEL_JOINT_NAMES
    if not 1 <= n_joints <= 255:
        raise ConfigurationError(f"joint count must be 1..255, got {n_joints}")
    return tuple(f"model_q{j + 1}" for j in range(n_joints))


def validate_device(device: str) -> str:
    """Return ``device`` if it is one ROS name token (a letter, then letters, digits, ``_``)."""
    if not isinstance(device, str) or not _ROS_NAME_TOKEN.match(device):
        raise ConfigurationError(
            f"device id {device!r} must start with a letter and hold only letters, digits "
            "and '_' (one ROS 2 name token)"
        )
    return device


def topic_name(device: str, topic: Topic) -> str:
    """Return the fully qualified topic name ``/<device>/<kind>``."""
    return f"/{validate_device(device)}/{topic.kind}"


def data_key(device: str, topic: Topic, domain_id: int) -> str:
    """Return the data key a publisher puts on (with the type's RIHS01 hash)."""
    return graph.topic_key(
        domain_id, topic_name(device, topic), topic.ros_type, interfaces.type_hash(topic.ros_type)
    )


def subscription_key(device: str | None, topic: Topic, domain_id: int) -> str:
    """Return the key a subscriber declares: any hash (Humble's too), ``*`` for any device."""
    name = f"/*/{topic.kind}" if device is None else topic_name(device, topic)
    return graph.topic_key_any_hash(domain_id, name, topic.ros_type)
