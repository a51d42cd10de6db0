"""The ROS 2 message types the project speaks, their RIHS01 hashes and ``ros2msg`` schemas.

Standard types where one exists (``sensor_msgs/msg/JointState``,
``geometry_msgs/msg/WrenchStamped``); the rest come from the project's own interface package
``teleop_force_msgs`` (``interfaces/teleop_force_msgs`` next to this module: ``package.xml``,
``CMakeLists.txt``, ``msg/*.msg``; a lab builds it with colcon so ``ros2 topic echo`` decodes
them). Every type, standard or not, lives in one ``rosbags`` typestore (ROS 2 Kilted's
definitions plus ``teleop_force_msgs``), which serializes CDR and computes the RIHS01 hashes
as ``rosidl_generator_type_description`` does.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Final

from teleop_force.errors import ConfigurationError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

#: The project's interface package, as a lab builds it.
INTERFACE_PACKAGE: Final = "teleop_force_msgs"
INTERFACE_DIR: Final = Path(__file__).resolve().parent / "interfaces" / INTERFACE_PACKAGE

JOINT_STATE: Final = "sensor_msgs/msg/JointState"
WRENCH_STAMPED: Final = "geometry_msgs/msg/WrenchStamped"
#: The Omni driver's ``measured_cp`` (sawSensablePhantom; the simulated driver publishes it).
POSE_STAMPED: Final = "geometry_msgs/msg/PoseStamped"
#: The CRTK bridge's void commands (``hold``, ``free``): cisst-ros' ``mtsROSSubscriberVoid``.
EMPTY: Final = "std_msgs/msg/Empty"
ESTIMATE_DIAGNOSTICS: Final = f"{INTERFACE_PACKAGE}/msg/EstimateDiagnostics"
STATUS: Final = f"{INTERFACE_PACKAGE}/msg/Status"
SERVICE_DIAGNOSTICS: Final = f"{INTERFACE_PACKAGE}/msg/ServiceDiagnostics"
DIAGNOSTIC_CHECK: Final = f"{INTERFACE_PACKAGE}/msg/DiagnosticCheck"
DIAGNOSTIC_FINDING: Final = f"{INTERFACE_PACKAGE}/msg/DiagnosticFinding"

#: Every type a teleop-force process publishes, standard types first.
PUBLISHED_TYPES: Final = (
    JOINT_STATE,
    WRENCH_STAMPED,
    ESTIMATE_DIAGNOSTICS,
    STATUS,
    SERVICE_DIAGNOSTICS,
)
#: The project's own types (the ``.msg`` files of :data:`INTERFACE_DIR`).
PROJECT_TYPES: Final = (
    DIAGNOSTIC_CHECK,
    DIAGNOSTIC_FINDING,
    ESTIMATE_DIAGNOSTICS,
    SERVICE_DIAGNOSTICS,
    STATUS,
)


def msg_file(ros_type: str) -> Path:
    """Return the ``.msg`` file of one of :data:`PROJECT_TYPES`."""
    if ros_type not in PROJECT_TYPES:
        raise ConfigurationError(f"{ros_type!r} is not one of {PROJECT_TYPES}")
    return INTERFACE_DIR / "msg" / f"{ros_type.rsplit('/', 1)[1]}.msg"


@cache
def typestore() -> Typestore:
    """Return the shared typestore: ROS 2 Kilted's types and ``teleop_force_msgs``."""
    from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_KILTED)
    types = {}
    for ros_type in PROJECT_TYPES:
        path = msg_file(ros_type)
        try:
            types.update(get_types_from_msg(path.read_text(encoding="utf-8"), ros_type))
        except (OSError, TypesysError) as exc:
            raise ConfigurationError(f"{path}: {exc}") from exc
    store.register(types)
    return store


@cache
def type_hash(ros_type: str) -> str:
    """Return ``RIHS01_<hex>`` of ``ros_type``, the hash rmw_zenoh puts in its keys."""
    from rosbags.typesys import TypesysError

    try:
        return str(typestore().hash_rihs01(ros_type))
    except (KeyError, TypesysError) as exc:
        raise ConfigurationError(f"no ROS 2 type {ros_type!r}: {exc}") from exc


@cache
def schema_text(ros_type: str) -> str:
    """Return the ``ros2msg`` schema of ``ros_type`` with its dependencies (MCAP, rosbag2)."""
    from rosbags.typesys import TypesysError

    try:
        text, _ = typestore().generate_msgdef(ros_type, ros_version=2)
    except (KeyError, TypesysError) as exc:
        raise ConfigurationError(f"no ROS 2 type {ros_type!r}: {exc}") from exc
    return text
