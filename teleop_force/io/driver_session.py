"""Sessions recorded from a device's own driver: its JointStates converted once, on reading.

A session recorded through a live driver (``teleop-force excite``, or rosbag2 recording its
topics) holds the driver's ``sensor_msgs/msg/JointState`` in the driver's conventions: its
joint names, signs and zero pose, a relative elbow, efforts in mN m and, for
sawSensablePhantom, no velocity at all. :func:`session_driver` returns the description to
convert them with when the recording carries one in its metadata (``driver_description``:
the JSON of :func:`~teleop_force.robots.file.driver_document`, written by ``excite``);
:func:`read_driver_joint_states` reads one topic's messages with their names and converts
them with :meth:`~teleop_force.robots.driver_interface.DriverInterface.to_model`, one matrix
product per set of names. Velocities are never read: identification and the estimator
differentiate the angles themselves, as for the lab logs (dVRK MTM, test stand), so a driver
that publishes none needs nothing more.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np

from teleop_force.errors import DataError, MessageError, ModelError
from teleop_force.robots.driver_interface import DriverInterface

if TYPE_CHECKING:
    from teleop_force.io.mcap_session import RawMessage, SessionReader

#: Metadata key: the driver description's name (for people; the conversion uses the next).
METADATA_DRIVER: Final = "driver"
#: Metadata key: the driver description as JSON (``format = "teleop-force-driver"``).
METADATA_DRIVER_DESCRIPTION: Final = "driver_description"
_JOINT_STATE: Final = "sensor_msgs/msg/JointState"
_CDR: Final = "cdr"


def driver_metadata(interface: DriverInterface) -> dict[str, str]:
    """Return the session metadata that makes a reader convert with ``interface``."""
    from teleop_force.robots.file import driver_document

    return {
        METADATA_DRIVER: interface.name,
        METADATA_DRIVER_DESCRIPTION: json.dumps(driver_document(interface), sort_keys=True),
    }


def session_driver(metadata: dict[str, str], path: Path) -> DriverInterface | None:
    """Return the driver description a session's metadata carries, or None.

    Raises:
        DataError: the metadata's description is not JSON or not a valid description
            (the message names the file and the field).

    """
    text = metadata.get(METADATA_DRIVER_DESCRIPTION)
    if not text:
        return None
    from teleop_force.robots.file import driver_interface_from_document

    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataError(
            f"metadata {METADATA_DRIVER_DESCRIPTION!r} is not JSON: {exc.msg}", path=path
        ) from None
    try:
        return driver_interface_from_document(data, f"{path} (metadata)")
    except ModelError as exc:
        raise DataError(str(exc)) from None


@dataclass(frozen=True)
class DriverJointStates:
    """One topic's driver JointStates in the model's coordinates, in the order read.

    Attributes:
        t_ns: ``(N,)`` int64 header stamps [ns since the epoch] (the rmw_zenoh source time
            where the driver leaves its stamps zero).
        q_rad: ``(N, n)`` model joint angles [rad].
        tau_nm: ``(N, n)`` model joint torques [N m].
        names: The driver's joint names of the first message.
        stamped: Whether ``t_ns`` are the header stamps.

    """

    t_ns: np.ndarray
    q_rad: np.ndarray
    tau_nm: np.ndarray
    names: tuple[str, ...]
    stamped: bool

    def __post_init__(self) -> None:
        """Check the shapes agree; raise DataError."""
        n = self.t_ns.shape[0]
        if self.t_ns.ndim != 1 or self.q_rad.ndim != 2 or self.q_rad.shape[0] != n:
            raise DataError(f"t_ns must be (N,) and q_rad (N, n), got {self.q_rad.shape}")
        if self.tau_nm.shape != self.q_rad.shape:
            raise DataError(f"tau_nm must be {self.q_rad.shape}, got {self.tau_nm.shape}")


def _raw_joint_states(
    messages: Iterator[RawMessage], path: Path, topic: str
) -> Iterator[tuple[int, int, tuple[str, ...], tuple[float, ...], tuple[float, ...]]]:
    """Yield ``(stamp, publish time, names, position, effort)`` of each message, checked."""
    from teleop_force.ros2 import codec

    for raw in messages:
        where = f"the JointState logged at {raw.log_time_ns} ns"
        if (raw.schema_name, raw.message_encoding) != (_JOINT_STATE, _CDR):
            raise DataError(
                f"holds {raw.schema_name or 'schemaless'} ({raw.message_encoding}) messages, "
                f"not {_JOINT_STATE} in CDR",
                path=path,
                column=topic,
            )
        try:
            js = codec.decode_raw_joint_state(raw.data)
        except MessageError as exc:
            raise DataError(f"{where} does not parse: {exc}", path=path, column=topic) from None
        n = len(js.names)
        if n == 0 or len(js.position) != n:
            raise DataError(
                f"{where} has {n} names and {len(js.position)} positions: a driver's JointState "
                "names every joint it gives a position",
                path=path,
                column=topic,
            )
        if len(js.effort) != n:
            raise DataError(
                f"{where} has {len(js.effort)} efforts for {n} joints: identification needs "
                "the driver's joint torques",
                path=path,
                column=topic,
            )
        yield js.t_ns, raw.publish_time_ns, js.names, js.position, js.effort


def read_driver_joint_states(
    reader: SessionReader, topic: str, interface: DriverInterface
) -> DriverJointStates:
    """Read the driver JointStates of ``topic`` and convert them with ``interface``.

    Raises:
        DataError: naming the file and the topic: no messages, a message that does not parse,
            has no efforts, or lacks a joint the description reads.

    """
    stamps: list[int] = []
    published: list[int] = []
    rows: dict[tuple[str, ...], list[int]] = {}
    positions: list[tuple[float, ...]] = []
    efforts: list[tuple[float, ...]] = []
    for stamp, publish_ns, names, position, effort in _raw_joint_states(
        reader.raw_messages([topic]), reader.path, topic
    ):
        rows.setdefault(names, []).append(len(stamps))
        stamps.append(stamp)
        published.append(publish_ns)
        positions.append(position)
        efforts.append(effort)
    if not stamps:
        raise DataError("no joint states", path=reader.path, column=topic)
    n = interface.n_joints
    q = np.empty((len(stamps), n))
    tau = np.empty((len(stamps), n))
    for names, index in rows.items():
        take = np.asarray(index)
        x = np.asarray([positions[i] for i in index])
        e = np.asarray([efforts[i] for i in index])
        try:
            q_part, tau_part = interface.to_model(names, x, e)
        except DataError as exc:
            raise DataError(exc.problem, path=reader.path, column=topic) from None
        assert tau_part is not None  # efforts are checked non-empty above
        q[take], tau[take] = q_part, tau_part
    t_ns = np.asarray(stamps, dtype=np.int64)
    stamped = bool(np.all(t_ns > 0))
    if not stamped:
        t_ns = np.asarray(published, dtype=np.int64)
    first = next(iter(rows))
    return DriverJointStates(t_ns, q, tau, first, stamped)


def driver_hint(reader: SessionReader, topic: str) -> str | None:
    """Why ``topic``'s first JointState looks like a driver's (no velocity), or None.

    For the error of a session read without a description.
    """
    from teleop_force.ros2 import codec

    for raw in reader.raw_messages([topic]):
        if (raw.schema_name, raw.message_encoding) != (_JOINT_STATE, _CDR):
            return None
        try:
            js = codec.decode_raw_joint_state(raw.data)
        except MessageError:
            return None
        if js.position and not js.velocity:
            names = ", ".join(js.names) or "none"
            return (
                f"its JointStates have no velocities (names {names}): a driver's, in the "
                "driver's conventions; give the driver's description with --driver NAME|FILE "
                "(built-in: sensable-phantom)"
            )
        return None
    return None


__all__ = (
    "METADATA_DRIVER",
    "METADATA_DRIVER_DESCRIPTION",
    "DriverJointStates",
    "driver_hint",
    "driver_metadata",
    "read_driver_joint_states",
    "session_driver",
)
