"""Per-tick wire encoding of the 3-joint master and slave: precompiled structs, plain floats.

The master and slave publish two messages every 1 ms tick and receive one. Building a message
object (:mod:`teleop_force.transport.messages`), validating it and encoding it costs several
microseconds of Python per message; the functions here pack the same bytes directly from
float sequences with one precompiled :class:`struct.Struct` each, and unpack the messages the
processes receive the same way. The bytes are exactly those of
``messages.X(...).encode()`` (the tests compare them byte for byte), and the checks are the
same: a non-finite value, a ``seq`` outside uint32, a ``t_ns`` outside int64 or a wrong
number of values raise :class:`~teleop_force.errors.MessageError`.

Decoding is as strict as ``messages.X.decode``: the fast path accepts only a well-formed
3-joint message; anything else goes to the full decoder, which raises MessageError with the
reason (or returns the values when the message is valid but only the fast path's sum test was
fooled, e.g. by huge finite values).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import Final

from teleop_force.errors import MessageError
from teleop_force.transport import messages as m

#: Joints of the Omni: the fast layouts are for this count only.
JOINTS: Final = 3

_JOINT_STATE: Final = struct.Struct(f"<2sBBIqB{3 * JOINTS}d")
_JOINT_SETPOINT: Final = struct.Struct(f"<2sBBIqB{JOINTS}d")
_CONTACT_FORCE: Final = struct.Struct("<2sBBIq3d")
#: The whole 3-joint ForceEstimate: header, source_seq, n, f_n, 4 x n joint values, mask byte.
_FORCE_ESTIMATE: Final = struct.Struct(f"<2sBBIqIB{3 + 4 * JOINTS}d1s")

_MAGIC: Final = m.MAGIC
_VERSION: Final = m.VERSION
_JOINT_STATE_TYPE: Final = int(m.MessageType.JOINT_STATE)
_JOINT_SETPOINT_TYPE: Final = int(m.MessageType.JOINT_SETPOINT)
_CONTACT_FORCE_TYPE: Final = int(m.MessageType.CONTACT_FORCE)
_FORCE_ESTIMATE_TYPE: Final = int(m.MessageType.FORCE_ESTIMATE)
_MASK_BITS: Final = (1 << JOINTS) - 1

#: Wire sizes of the 3-joint messages [bytes].
JOINT_STATE_SIZE: Final = _JOINT_STATE.size
JOINT_SETPOINT_SIZE: Final = _JOINT_SETPOINT.size
CONTACT_FORCE_SIZE: Final = _CONTACT_FORCE.size
FORCE_ESTIMATE_SIZE: Final = _FORCE_ESTIMATE.size


def _all_finite(*groups: Sequence[float]) -> bool:
    """Whether every value is finite (one sum first; the exact test only if it is not)."""
    if math.isfinite(sum(map(sum, groups))):
        return True
    return all(math.isfinite(x) for group in groups for x in group)


def pack_joint_state(
    seq: int,
    t_ns: int,
    q_rad: Sequence[float],
    qd_rad_s: Sequence[float],
    effort_nm: Sequence[float],
) -> bytes:
    """Return the bytes of ``messages.JointState(seq, t_ns, q_rad, qd_rad_s, effort_nm)``."""
    if not len(q_rad) == len(qd_rad_s) == len(effort_nm) == JOINTS:
        raise MessageError(f"JointState: the fast layout needs {JOINTS} values per field")
    try:
        payload = _JOINT_STATE.pack(
            _MAGIC, _VERSION, _JOINT_STATE_TYPE, seq, t_ns, JOINTS,
            *q_rad, *qd_rad_s, *effort_nm,
        )  # fmt: skip
    except struct.error as exc:
        raise MessageError(f"JointState: cannot encode: {exc}") from None
    if not _all_finite(q_rad, qd_rad_s, effort_nm):
        raise MessageError("JointState: non-finite q_rad, qd_rad_s or effort_nm")
    return payload


def pack_joint_setpoint(seq: int, t_ns: int, q_rad: Sequence[float]) -> bytes:
    """Return the bytes of ``messages.JointSetpoint(seq, t_ns, q_rad).encode()``."""
    if len(q_rad) != JOINTS:
        raise MessageError(f"JointSetpoint: the fast layout needs {JOINTS} values")
    try:
        payload = _JOINT_SETPOINT.pack(
            _MAGIC, _VERSION, _JOINT_SETPOINT_TYPE, seq, t_ns, JOINTS, *q_rad
        )
    except struct.error as exc:
        raise MessageError(f"JointSetpoint: cannot encode: {exc}") from None
    if not _all_finite(q_rad):
        raise MessageError("JointSetpoint: non-finite q_rad")
    return payload


def pack_contact_force(seq: int, t_ns: int, f_n: Sequence[float]) -> bytes:
    """Return the bytes of ``messages.ContactForce(seq, t_ns, f_n).encode()``."""
    if len(f_n) != 3:
        raise MessageError(f"ContactForce: f_n has {len(f_n)} values, expected 3")
    try:
        payload = _CONTACT_FORCE.pack(_MAGIC, _VERSION, _CONTACT_FORCE_TYPE, seq, t_ns, *f_n)
    except struct.error as exc:
        raise MessageError(f"ContactForce: cannot encode: {exc}") from None
    if not _all_finite(f_n):
        raise MessageError("ContactForce: non-finite f_n")
    return payload


def unpack_joint_setpoint(payload: bytes) -> tuple[int, int, tuple[float, ...]]:
    """``(seq, t_ns, q_rad)`` of a 3-joint JointSetpoint; raise MessageError otherwise."""
    if len(payload) == JOINT_SETPOINT_SIZE:
        magic, version, kind, seq, t_ns, n, *q = _JOINT_SETPOINT.unpack(payload)
        if (
            magic == _MAGIC
            and version == _VERSION
            and kind == _JOINT_SETPOINT_TYPE
            and n == JOINTS
            and math.isfinite(q[0] + q[1] + q[2])
        ):
            return seq, t_ns, tuple(q)
    setpoint = m.JointSetpoint.decode(payload)  # raises MessageError with the reason
    if setpoint.n_joints != JOINTS:
        raise MessageError(f"JointSetpoint: {setpoint.n_joints} joints, expected {JOINTS}")
    return setpoint.seq, setpoint.t_ns, setpoint.q_rad


def unpack_force_estimate(payload: bytes) -> tuple[int, int, int, tuple[float, ...]]:
    """``(seq, t_ns, source_seq, f_n)`` of a 3-joint ForceEstimate; raise MessageError otherwise.

    The whole message is checked (``f_n`` may hold NaN, nothing else may be non-finite);
    only the fields a receiver of the force needs are returned.
    """
    if len(payload) == FORCE_ESTIMATE_SIZE:
        v = _FORCE_ESTIMATE.unpack(payload)
        if (
            v[0] == _MAGIC
            and v[1] == _VERSION
            and v[2] == _FORCE_ESTIMATE_TYPE
            and v[6] == JOINTS
            and not v[-1][0] & ~_MASK_BITS
            and not any(map(math.isinf, v[7:10]))
            and math.isfinite(sum(v[10:-1]))
        ):
            return v[3], v[4], v[5], v[7:10]
    estimate = m.ForceEstimateMessage.decode(payload)  # raises MessageError with the reason
    if estimate.n_joints != JOINTS:
        raise MessageError(f"ForceEstimate: {estimate.n_joints} joints, expected {JOINTS}")
    return estimate.seq, estimate.t_ns, estimate.source_seq, estimate.f_n


__all__ = [
    "CONTACT_FORCE_SIZE",
    "FORCE_ESTIMATE_SIZE",
    "JOINTS",
    "JOINT_SETPOINT_SIZE",
    "JOINT_STATE_SIZE",
    "pack_contact_force",
    "pack_joint_setpoint",
    "pack_joint_state",
    "unpack_force_estimate",
    "unpack_joint_setpoint",
]
