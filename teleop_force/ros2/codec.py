"""The project's messages to and from ROS 2 CDR payloads, serialized by ``rosbags``.

One function pair per topic kind of :mod:`teleop_force.ros2.topics`. Encoders take the
project's message values (:mod:`teleop_force.transport.messages`); their ``seq`` is not in the
payload but in rmw_zenoh's attachment, so decoders take it as an argument (the attachment's
sequence number). ``t_ns`` is the header stamp (``sec`` int32, ``nanosec`` uint32).

Decoding is strict: a payload ``rosbags`` cannot parse (bytes after the last field are
ignored: ``rclpy``'s ``serialize_message`` leaves its size estimate's slack there), arrays
whose lengths disagree, non-finite numbers where the project's messages forbid them, or a
stamp out of range raise :class:`~teleop_force.errors.MessageError`, never anything else, so
a receiver counts and drops a malformed message.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from rosbags.serde import SerdeError

from teleop_force.errors import MessageError
from teleop_force.ros2 import interfaces as i
from teleop_force.transport import messages as m

_NS_PER_S: Final = 1_000_000_000
_INT32_MIN: Final = -(2**31)
_INT32_MAX: Final = 2**31 - 1
_STORE: Final = i.typestore()
_T: Final = _STORE.types
_TIME: Final = _T["builtin_interfaces/msg/Time"]
_HEADER: Final = _T["std_msgs/msg/Header"]
_VECTOR3: Final = _T["geometry_msgs/msg/Vector3"]
_WRENCH: Final = _T["geometry_msgs/msg/Wrench"]
_JOINT_STATE: Final = _T[i.JOINT_STATE]
_WRENCH_STAMPED: Final = _T[i.WRENCH_STAMPED]
_POINT: Final = _T["geometry_msgs/msg/Point"]
_QUATERNION: Final = _T["geometry_msgs/msg/Quaternion"]
_POSE: Final = _T["geometry_msgs/msg/Pose"]
_POSE_STAMPED: Final = _T[i.POSE_STAMPED]
_EMPTY_MSG: Final = _T[i.EMPTY]
_ESTIMATE_DIAGNOSTICS: Final = _T[i.ESTIMATE_DIAGNOSTICS]
_STATUS: Final = _T[i.STATUS]
_SERVICE_DIAGNOSTICS: Final = _T[i.SERVICE_DIAGNOSTICS]
_CHECK: Final = _T[i.DIAGNOSTIC_CHECK]
_FINDING: Final = _T[i.DIAGNOSTIC_FINDING]
_EMPTY: Final[tuple[float, ...]] = ()


def _header(t_ns: int, frame_id: str = "") -> Any:
    sec, nanosec = divmod(int(t_ns), _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise MessageError(f"stamp {t_ns} ns does not fit builtin_interfaces/Time (int32 s)")
    return _HEADER(stamp=_TIME(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * _NS_PER_S + int(header.stamp.nanosec)


def _serialize(message: Any, ros_type: str) -> bytes:
    return bytes(_STORE.serialize_cdr(message, ros_type))


def _deserialize(payload: bytes | bytearray | memoryview, ros_type: str) -> Any:
    # rosbags' deserialize_cdr refuses more than 3 trailing bytes, but rmw_fastrtps'
    # rmw_serialize (rclpy's serialize_message) sizes its buffer by an estimate and leaves
    # the slack after the last field: parse the fields, ignore what follows them.
    raw = bytes(payload)
    if len(raw) < 4 or raw[:2] not in (b"\x00\x00", b"\x00\x01"):
        raise MessageError(f"not a CDR {ros_type}: no plain CDR encapsulation header")
    msgdef = _STORE.get_msgdef(ros_type)
    parse = msgdef.deserialize_cdr_le if raw[1] else msgdef.deserialize_cdr_be
    try:
        message, _ = parse(raw[4:], 0, msgdef.cls, _STORE)
    except (struct.error, UnicodeDecodeError, ValueError, SerdeError) as exc:
        raise MessageError(f"not a CDR {ros_type}: {exc}") from None
    return message


def _names(names: Sequence[str], n: int) -> list[str]:
    result = [str(x) for x in names]
    if result and len(result) != n:  # none (ROS allows it) or one per joint
        raise MessageError(f"{len(result)} joint names for {n} joints")
    return result


def _floats(values: Any) -> tuple[float, ...]:
    return tuple(float(x) for x in values)


# --------------------------------------------------------------------------- JointState


@dataclass(frozen=True, slots=True)
class NamedJoints:
    """A decoded JointState's names, stamp and frame (what the project's message lacks)."""

    names: tuple[str, ...]
    frame_id: str


def encode_joint_state_parts(
    t_ns: int,
    names: Sequence[str],
    frame_id: str,
    q_rad: Sequence[float],
    qd_rad_s: Sequence[float],
    effort_nm: Sequence[float],
) -> bytes:
    """Return ``sensor_msgs/msg/JointState`` from its arrays (no message value is built).

    ``qd_rad_s`` and ``effort_nm`` may be empty (a setpoint); ``names`` has one per position.
    """
    q, qd, effort = (np.asarray(a, dtype=np.float64) for a in (q_rad, qd_rad_s, effort_nm))
    return _serialize(
        _JOINT_STATE(header=_header(t_ns, frame_id), name=_names(names, len(q)), position=q,
                     velocity=qd, effort=effort),
        i.JOINT_STATE,
    )  # fmt: skip


def encode_joint_state(msg: m.JointState, names: Sequence[str], frame_id: str = "") -> bytes:
    """Return ``sensor_msgs/msg/JointState``: position, velocity, effort = q, q̇, motor torque."""
    return encode_joint_state_parts(
        msg.t_ns, names, frame_id, msg.q_rad, msg.qd_rad_s, msg.effort_nm
    )


def decode_joint_state(
    payload: bytes | bytearray | memoryview, seq: int
) -> tuple[m.JointState, NamedJoints]:
    """Parse a JointState with position, velocity and effort for every named joint."""
    d = _deserialize(payload, i.JOINT_STATE)
    n = len(d.position)
    if len(d.velocity) != n or len(d.effort) != n or len(d.name) not in (0, n):
        raise MessageError(
            f"JointState has {len(d.name)} names, {n} positions, {len(d.velocity)} "
            f"velocities and {len(d.effort)} efforts; expected equal counts"
        )
    msg = m.JointState(seq, _stamp_ns(d.header), _floats(d.position), _floats(d.velocity),
                       _floats(d.effort))  # fmt: skip
    return msg, NamedJoints(tuple(d.name), d.header.frame_id)


@dataclass(frozen=True, slots=True)
class RawJointState:
    """A decoded JointState as it came: any names, arrays of any (possibly zero) length."""

    t_ns: int
    frame_id: str
    names: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]


def decode_raw_joint_state(payload: bytes | bytearray | memoryview) -> RawJointState:
    """Parse a JointState without the project's checks (a driver's, in its own conventions)."""
    d = _deserialize(payload, i.JOINT_STATE)
    return RawJointState(
        _stamp_ns(d.header), d.header.frame_id, tuple(d.name), _floats(d.position),
        _floats(d.velocity), _floats(d.effort),
    )  # fmt: skip


def encode_joint_setpoint(msg: m.JointSetpoint, names: Sequence[str], frame_id: str = "") -> bytes:
    """Return ``sensor_msgs/msg/JointState`` with ``position`` only (velocity, effort empty)."""
    return encode_joint_state_parts(msg.t_ns, names, frame_id, msg.q_rad, _EMPTY, _EMPTY)


def decode_joint_setpoint(
    payload: bytes | bytearray | memoryview, seq: int
) -> tuple[m.JointSetpoint, NamedJoints]:
    """Parse a JointState as a setpoint: its positions (velocity and effort are ignored)."""
    d = _deserialize(payload, i.JOINT_STATE)
    if len(d.name) not in (0, len(d.position)):
        raise MessageError(f"JointState has {len(d.name)} names for {len(d.position)} positions")
    msg = m.JointSetpoint(seq, _stamp_ns(d.header), _floats(d.position))
    return msg, NamedJoints(tuple(d.name), d.header.frame_id)


# --------------------------------------------------------------------------- wrenches


@dataclass(frozen=True, slots=True)
class Wrench:
    """A decoded WrenchStamped: stamp [ns], frame, force [N] and torque [N m]."""

    t_ns: int
    frame_id: str
    force_n: tuple[float, float, float]
    torque_nm: tuple[float, float, float]


def encode_wrench(t_ns: int, force_n: Sequence[float], frame_id: str) -> bytes:
    """Return ``geometry_msgs/msg/WrenchStamped`` with ``force_n`` and zero torque."""
    fx, fy, fz = (float(x) for x in force_n)
    return _serialize(
        _WRENCH_STAMPED(
            header=_header(t_ns, frame_id),
            wrench=_WRENCH(force=_VECTOR3(x=fx, y=fy, z=fz), torque=_VECTOR3(x=0.0, y=0.0, z=0.0)),
        ),
        i.WRENCH_STAMPED,
    )


def decode_wrench(payload: bytes | bytearray | memoryview) -> Wrench:
    """Parse a WrenchStamped (any numbers; the caller decides what is allowed)."""
    d = _deserialize(payload, i.WRENCH_STAMPED)
    f, t = d.wrench.force, d.wrench.torque
    return Wrench(_stamp_ns(d.header), d.header.frame_id, (f.x, f.y, f.z), (t.x, t.y, t.z))


def encode_contact_force(msg: m.ContactForce, frame_id: str) -> bytes:
    """Return the true tip force as a WrenchStamped."""
    return encode_wrench(msg.t_ns, msg.f_n, frame_id)


def decode_contact_force(payload: bytes | bytearray | memoryview, seq: int) -> m.ContactForce:
    """Parse a WrenchStamped as the true tip force (finite numbers only)."""
    w = decode_wrench(payload)
    return m.ContactForce(seq, w.t_ns, w.force_n)


# --------------------------------------------------------------------------- poses


@dataclass(frozen=True, slots=True)
class Pose:
    """A decoded PoseStamped: stamp [ns], frame, position [m], orientation (x, y, z, w)."""

    t_ns: int
    frame_id: str
    position_m: tuple[float, float, float]
    orientation_xyzw: tuple[float, float, float, float]


def encode_pose(
    t_ns: int,
    position_m: Sequence[float],
    frame_id: str,
    orientation_xyzw: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
) -> bytes:
    """Return ``geometry_msgs/msg/PoseStamped`` (default orientation: identity)."""
    px, py, pz = (float(v) for v in position_m)
    qx, qy, qz, qw = (float(v) for v in orientation_xyzw)
    return _serialize(
        _POSE_STAMPED(
            header=_header(t_ns, frame_id),
            pose=_POSE(position=_POINT(x=px, y=py, z=pz),
                       orientation=_QUATERNION(x=qx, y=qy, z=qz, w=qw)),
        ),
        i.POSE_STAMPED,
    )  # fmt: skip


def decode_pose(payload: bytes | bytearray | memoryview) -> Pose:
    """Parse a PoseStamped (any numbers; the caller decides what is allowed)."""
    d = _deserialize(payload, i.POSE_STAMPED)
    p, o = d.pose.position, d.pose.orientation
    return Pose(_stamp_ns(d.header), d.header.frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w))


# --------------------------------------------------------------------------- empty


def encode_empty() -> bytes:
    """Return ``std_msgs/msg/Empty`` (its one placeholder byte, as every ROS 2 type has)."""
    return _serialize(_EMPTY_MSG(structure_needs_at_least_one_member=0), i.EMPTY)


def decode_empty(payload: bytes | bytearray | memoryview) -> None:
    """Check that ``payload`` is a ``std_msgs/msg/Empty``; raise MessageError if not."""
    _deserialize(payload, i.EMPTY)


# --------------------------------------------------------------------------- estimate


@dataclass(frozen=True, slots=True)
class EstimateDiagnostics:
    """A decoded ``teleop_force_msgs/msg/EstimateDiagnostics``."""

    t_ns: int
    frame_id: str
    source_sequence: int
    names: tuple[str, ...]
    tau_ext_nm: tuple[float, ...]
    coverage_weight: tuple[float, ...]
    on_trained_ground: tuple[bool, ...]
    tau_motor_filtered_nm: tuple[float, ...]
    tau_model_filtered_nm: tuple[float, ...]


def encode_estimate_parts(
    t_ns: int,
    source_sequence: int,
    force_n: Sequence[float],
    tau_ext_nm: Sequence[float],
    coverage_weight: Sequence[float],
    on_trained_ground: Sequence[bool],
    tau_motor_filtered_nm: Sequence[float],
    tau_model_filtered_nm: Sequence[float],
    names: Sequence[str],
    frame_id: str,
) -> tuple[bytes, bytes]:
    """Return an estimate's WrenchStamped and EstimateDiagnostics (one header) from its parts.

    No message value is built; ``force_n`` may hold NaN (near-singular).
    """
    diagnostics = _serialize(
        _ESTIMATE_DIAGNOSTICS(
            header=_header(t_ns, frame_id),
            source_sequence=int(source_sequence),
            name=_names(names, len(tau_ext_nm)),
            external_torque_nm=np.asarray(tau_ext_nm, dtype=np.float64),
            coverage_weight=np.asarray(coverage_weight, dtype=np.float64),
            on_trained_ground=np.asarray(on_trained_ground, dtype=np.bool_),
            motor_torque_filtered_nm=np.asarray(tau_motor_filtered_nm, dtype=np.float64),
            model_torque_filtered_nm=np.asarray(tau_model_filtered_nm, dtype=np.float64),
        ),
        i.ESTIMATE_DIAGNOSTICS,
    )
    return encode_wrench(t_ns, force_n, frame_id), diagnostics


def encode_estimate(
    msg: m.ForceEstimateMessage, names: Sequence[str], frame_id: str
) -> tuple[bytes, bytes]:
    """Return the estimate's WrenchStamped and its EstimateDiagnostics, with one header."""
    return encode_estimate_parts(
        msg.t_ns, msg.source_seq, msg.f_n, msg.tau_ext_nm, msg.coverage_weight,
        msg.on_trained_ground, msg.tau_motor_filtered_nm, msg.tau_model_filtered_nm, names,
        frame_id,
    )  # fmt: skip


def decode_estimate_diagnostics(payload: bytes | bytearray | memoryview) -> EstimateDiagnostics:
    """Parse an EstimateDiagnostics whose arrays all have one entry per joint."""
    d = _deserialize(payload, i.ESTIMATE_DIAGNOSTICS)
    n = len(d.external_torque_nm)
    counts = (len(d.coverage_weight), len(d.on_trained_ground), len(d.motor_torque_filtered_nm),
              len(d.model_torque_filtered_nm))  # fmt: skip
    if any(c != n for c in counts) or len(d.name) not in (0, n):
        raise MessageError(f"EstimateDiagnostics arrays have different lengths: {n}, {counts}")
    return EstimateDiagnostics(
        t_ns=_stamp_ns(d.header),
        frame_id=d.header.frame_id,
        source_sequence=int(d.source_sequence),
        names=tuple(d.name),
        tau_ext_nm=_floats(d.external_torque_nm),
        coverage_weight=_floats(d.coverage_weight),
        on_trained_ground=tuple(bool(x) for x in d.on_trained_ground),
        tau_motor_filtered_nm=_floats(d.motor_torque_filtered_nm),
        tau_model_filtered_nm=_floats(d.model_torque_filtered_nm),
    )


def estimate_message(
    seq: int, wrench: Wrench, diagnostics: EstimateDiagnostics
) -> m.ForceEstimateMessage:
    """Join an estimate's two halves (same stamp) into the project's message."""
    if wrench.t_ns != diagnostics.t_ns:
        raise MessageError(
            f"estimate stamp {wrench.t_ns} ns and diagnostics stamp {diagnostics.t_ns} ns differ"
        )
    return m.ForceEstimateMessage(
        seq=seq,
        t_ns=wrench.t_ns,
        source_seq=diagnostics.source_sequence & 0xFFFF_FFFF,
        f_n=wrench.force_n,
        tau_ext_nm=diagnostics.tau_ext_nm,
        on_trained_ground=diagnostics.on_trained_ground,
        coverage_weight=diagnostics.coverage_weight,
        tau_motor_filtered_nm=diagnostics.tau_motor_filtered_nm,
        tau_model_filtered_nm=diagnostics.tau_model_filtered_nm,
    )


# --------------------------------------------------------------------------- status


def encode_status(msg: m.Status) -> bytes:
    """Return ``teleop_force_msgs/msg/Status`` (the state constants equal SafetyState)."""
    return _serialize(
        _STATUS(header=_header(msg.t_ns), state=int(msg.state), reason=msg.reason), i.STATUS
    )


def decode_status(payload: bytes | bytearray | memoryview, seq: int) -> m.Status:
    """Parse a Status; an unknown state raises MessageError."""
    d = _deserialize(payload, i.STATUS)
    return m.Status(seq, _stamp_ns(d.header), d.state, d.reason)


# --------------------------------------------------------------------------- service


def encode_service_diagnostics(msg: m.ServiceDiagnostics) -> bytes:
    """Return ``teleop_force_msgs/msg/ServiceDiagnostics`` (a missing variable is ``""``)."""
    checks = [
        _CHECK(joint=c.joint, rows=c.rows, variable=c.variable or "", p_value=float(c.p_value),
               effect_fraction=float(c.effect_fraction), consecutive=c.consecutive)
        for c in msg.checks
    ]  # fmt: skip
    f = msg.finding
    finding = (
        []
        if f is None
        else [
            _FINDING(joint=f.joint, variable=f.variable, effect_fraction=float(f.effect_fraction),
                     effect_nm=float(f.effect_nm), p_value=float(f.p_value),
                     since_s=float(f.since_s), holds=bool(f.holds))
        ]
    )  # fmt: skip
    return _serialize(
        _SERVICE_DIAGNOSTICS(
            header=_header(msg.t_ns),
            device=msg.device,
            state=msg.state,
            stream_s=float(msg.stream_s),
            baseline_complete=bool(msg.baseline_complete),
            rms_torque_nm=np.asarray(msg.rms_torque_nm, dtype=np.float64),
            checks=checks,
            finding=finding,
            command=msg.command,
        ),
        i.SERVICE_DIAGNOSTICS,
    )


def decode_service_diagnostics(
    payload: bytes | bytearray | memoryview, seq: int
) -> m.ServiceDiagnostics:
    """Parse a ServiceDiagnostics into the project's message (validated there)."""
    d = _deserialize(payload, i.SERVICE_DIAGNOSTICS)
    if len(d.finding) > 1:
        raise MessageError(f"ServiceDiagnostics has {len(d.finding)} findings, at most 1")
    finding = None
    if d.finding:
        f = d.finding[0]
        finding = m.DiagnosticFinding(f.joint, f.variable, f.effect_fraction, f.effect_nm,
                                      f.p_value, f.since_s, bool(f.holds))  # fmt: skip
    checks = tuple(
        m.DiagnosticCheck(c.joint, c.rows, c.variable or None, c.p_value, c.effect_fraction,
                          c.consecutive)
        for c in d.checks
    )  # fmt: skip
    return m.ServiceDiagnostics(
        seq=seq,
        t_ns=_stamp_ns(d.header),
        device=d.device,
        state=d.state,
        stream_s=float(d.stream_s),
        baseline_complete=bool(d.baseline_complete),
        rms_torque_nm=_floats(d.rms_torque_nm),
        checks=checks,
        finding=finding,
        command=d.command,
    )


def warm_up() -> None:
    """Encode and decode one message of every type, so that none is compiled on a 1 kHz path.

    ``rosbags`` compiles a type's (de)serializer on its first use (hundreds of ms).
    """
    t_ns = 1
    names = ("q1",)
    js = m.JointState(0, t_ns, (0.0,), (0.0,), (0.0,))
    decode_joint_state(encode_joint_state(js, names), 0)
    decode_joint_setpoint(encode_joint_setpoint(m.JointSetpoint(0, t_ns, (0.0,)), names), 0)
    decode_contact_force(encode_contact_force(m.ContactForce(0, t_ns, (0.0, 0.0, 0.0)), ""), 0)
    decode_pose(encode_pose(t_ns, (0.0, 0.0, 0.0), ""))
    decode_empty(encode_empty())
    estimate = m.ForceEstimateMessage(0, t_ns, 0, (0.0, 0.0, 0.0), (0.0,), (True,), (1.0,),
                                      (0.0,), (0.0,))  # fmt: skip
    wrench, diagnostics = encode_estimate(estimate, names, "")
    estimate_message(0, decode_wrench(wrench), decode_estimate_diagnostics(diagnostics))
    decode_status(encode_status(m.Status(0, t_ns, m.SafetyState.STARTING, "")), 0)
    report = m.ServiceDiagnostics(0, t_ns, "d", "baseline", 0.0, False, (), (), None, "")
    decode_service_diagnostics(encode_service_diagnostics(report), 0)
