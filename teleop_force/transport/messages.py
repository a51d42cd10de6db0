"""The project's message values, one class per message, and their fixed binary layouts.

On the wire every message is a ROS 2 message in CDR (:mod:`teleop_force.ros2.codec`); these
classes are the values the processes work with. Their binary layouts below (the "TF" layouts)
are fixed-size in-process records (the residual watch's ring, batch replays); nothing is
published in them.

Every message starts with the same 16-byte header, then its own fields. ``n`` is the joint
count (1..255). Floats are IEEE-754 float64, integers little-endian. ``t_ns`` is the time the
data was sampled at its source, in nanoseconds since the UNIX epoch (``time.time_ns()``), so a
receiver on a clock-synchronised machine measures latency as ``time.time_ns() - t_ns``; ``seq``
counts messages per publisher (wrapping at 2**32) so gaps reveal lost messages.

Decoding is strict: wrong magic, unknown version or type, a length that does not match the
layout exactly, a non-finite number where one is not allowed, unused bitmask bits set or
invalid UTF-8 all raise :class:`~teleop_force.errors.MessageError`, never anything else.

Common header (all messages)

| offset | type    | field                                      |
|-------:|---------|--------------------------------------------|
| 0      | 2 bytes | magic ``b"TF"``                            |
| 2      | uint8   | version (currently 1)                      |
| 3      | uint8   | message type (below)                       |
| 4      | uint32  | seq                                        |
| 8      | int64   | t_ns, source timestamp [ns since epoch]    |

JointState (type 1), key ``omni/<device>/measured_js``; size 17 + 24 n

| offset  | type       | field                                   |
|--------:|------------|-----------------------------------------|
| 0       | header     | magic, version, type, seq, t_ns         |
| 16      | uint8      | n                                       |
| 17      | float64[n] | q_rad, measured joint angles            |
| 17+8n   | float64[n] | qd_rad_s, joint velocities              |
| 17+16n  | float64[n] | effort_nm, commanded motor torques      |

JointSetpoint (type 2), key ``omni/<device>/setpoint_js``; size 17 + 8 n

| offset | type       | field                                    |
|-------:|------------|------------------------------------------|
| 0      | header     | magic, version, type, seq, t_ns          |
| 16     | uint8      | n                                        |
| 17     | float64[n] | q_rad, joint position setpoint           |

ContactForce (type 3), key ``omni/<device>/measured_cf``; size 40

| offset | type       | field                                                    |
|-------:|------------|----------------------------------------------------------|
| 0      | header     | magic, version, type, seq, t_ns                          |
| 16     | float64[3] | f_n = (f_x, f_y, f_z), tip force on the environment, base frame [N] |

ForceEstimateMessage (type 4, MCAP schema ``teleop_force/msg/ForceEstimate``; JSON recordings:
``teleop_force.ForceEstimate``), key
``omni/<device>/estimated_cf``; size 45 + 32 n + ceil(n/8)

| offset  | type             | field                                                   |
|--------:|------------------|---------------------------------------------------------|
| 0       | header           | magic, version, type, seq, t_ns (of the estimate)       |
| 16      | uint32           | source_seq, seq of the JointState it was computed from  |
| 20      | uint8            | n                                                       |
| 21      | float64[3]       | f_n, estimated tip force, base frame [N]; NaN = none    |
| 45      | float64[n]       | tau_ext_nm, external joint torques                      |
| 45+8n   | float64[n]       | coverage_weight, training-data coverage per joint       |
| 45+16n  | float64[n]       | tau_motor_filtered_nm, low-passed motor torques         |
| 45+24n  | float64[n]       | tau_model_filtered_nm, low-passed model torques         |
| 45+32n  | uint8[ceil(n/8)] | on_trained_ground bitmask: bit j%8 of byte j//8 = joint j |

Status (type 5), key ``omni/<device>/status``; size 19 + L

| offset | type      | field                                                         |
|-------:|-----------|---------------------------------------------------------------|
| 0      | header    | magic, version, type, seq, t_ns                               |
| 16     | uint8     | state: 0 starting, 1 following, 2 holding, 3 stopped          |
| 17     | uint16    | L, length of the reason in bytes                              |
| 19     | bytes[L]  | reason, UTF-8                                                 |

ServiceDiagnostics, key ``omni/<device>/service/diagnostics``: UTF-8 JSON (the residual
watch's low-rate report; its fields in :class:`ServiceDiagnostics`), not a binary layout.
"""

from __future__ import annotations

import json
import math
import operator
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum
from types import MappingProxyType
from typing import Any, ClassVar, Final, Self

from teleop_force.errors import MessageError

MAGIC: Final = b"TF"
#: Layout version written by :meth:`encode` and the only one :meth:`decode` accepts.
VERSION: Final = 1
MAX_JOINTS: Final = 255
MAX_REASON_BYTES: Final = 0xFFFF
_UINT32_MAX: Final = 0xFFFF_FFFF
_INT64_MIN: Final = -(2**63)
_INT64_MAX: Final = 2**63 - 1

_HEADER: Final = struct.Struct("<2sBBIq")
HEADER_SIZE: Final = _HEADER.size  # 16


class MessageType(IntEnum):
    """Message type byte (offset 3 of every message)."""

    JOINT_STATE = 1
    JOINT_SETPOINT = 2
    CONTACT_FORCE = 3
    FORCE_ESTIMATE = 4
    STATUS = 5


class SafetyState(IntEnum):
    """Safety state of a device, carried by :class:`Status`."""

    STARTING = 0
    FOLLOWING = 1
    HOLDING = 2
    STOPPED = 3


def _mask_bytes(n: int) -> int:
    return (n + 7) // 8


# Immutable tables of precompiled layouts, indexed by the joint count n (0..255).
_JOINT_STATE: Final = tuple(struct.Struct(f"<2sBBIqB{3 * n}d") for n in range(MAX_JOINTS + 1))
_JOINT_SETPOINT: Final = tuple(struct.Struct(f"<2sBBIqB{n}d") for n in range(MAX_JOINTS + 1))
_CONTACT_FORCE: Final = struct.Struct("<2sBBIq3d")
_FORCE_ESTIMATE: Final = tuple(
    struct.Struct(f"<2sBBIqIB{3 + 4 * n}d{_mask_bytes(n)}s") for n in range(MAX_JOINTS + 1)
)
_STATUS_FIXED: Final = struct.Struct("<2sBBIqBH")


# --------------------------------------------------------------------------- helpers


def _buffer(data: object) -> bytes | bytearray | memoryview:
    if isinstance(data, bytes | bytearray):
        return data
    if isinstance(data, memoryview):
        if data.ndim != 1 or data.itemsize != 1:
            return data.cast("B") if data.c_contiguous else memoryview(data.tobytes())
        return data
    raise MessageError(f"expected bytes, got {type(data).__name__}")


def _check_header(buf: bytes | bytearray | memoryview, expected: MessageType) -> None:
    if len(buf) < HEADER_SIZE:
        raise MessageError(f"{len(buf)} bytes is shorter than the {HEADER_SIZE}-byte header")
    magic, version, kind, _seq, _t = _HEADER.unpack_from(buf)
    if magic != MAGIC:
        raise MessageError(f"bad magic {bytes(magic)!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise MessageError(f"unsupported message version {version} (this build reads {VERSION})")
    if kind != expected:
        raise MessageError(f"message type {kind} is not {expected.name} ({int(expected)})")


def _joint_count(buf: bytes | bytearray | memoryview, name: str, offset: int = HEADER_SIZE) -> int:
    if len(buf) <= offset:
        raise MessageError(f"{name}: truncated before the joint count")
    n = buf[offset]
    if n == 0:
        raise MessageError(f"{name}: joint count is 0")
    return n


def _check_size(buf: bytes | bytearray | memoryview, size: int, name: str) -> None:
    if len(buf) != size:
        raise MessageError(f"{name}: {len(buf)} bytes, the layout needs exactly {size}")


def _int(value: object, name: str, low: int, high: int) -> int:
    try:
        result = operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise MessageError(f"{name} must be an integer, got {type(value).__name__}") from None
    if not low <= result <= high:
        raise MessageError(f"{name}={result} is outside [{low}, {high}]")
    return result


def _floats(values: object, name: str, *, finite: bool = True) -> tuple[float, ...]:
    try:
        result = tuple(map(float, values))  # type: ignore[call-overload]
    except (TypeError, ValueError, OverflowError) as exc:
        raise MessageError(f"{name} must be a sequence of numbers: {exc}") from None
    if finite and not _all_finite(result):
        raise MessageError(f"{name} contains a non-finite value: {result}")
    return result


def _all_finite(values: tuple[float, ...]) -> bool:
    # A sum is finite only if every term is; the exact test runs only when it is not.
    return math.isfinite(sum(values)) or all(map(math.isfinite, values))


def _build(cls: type, names: tuple[str, ...], values: Iterable[object]) -> Any:
    """Create a message from already-validated field values, skipping ``__post_init__``."""
    obj: Any = object.__new__(cls)
    for name, value in zip(names, values, strict=True):
        object.__setattr__(obj, name, value)
    return obj


def _joints(values: object, name: str, n: int | None = None) -> tuple[float, ...]:
    result = _floats(values, name)
    if n is None:
        if not 1 <= len(result) <= MAX_JOINTS:
            raise MessageError(f"{name} has {len(result)} joints, expected 1..{MAX_JOINTS}")
    elif len(result) != n:
        raise MessageError(f"{name} has {len(result)} values, expected {n}")
    return result


def _set(obj: object, name: str, value: object) -> None:
    object.__setattr__(obj, name, value)


def _header_fields(obj: Any) -> None:
    _set(obj, "seq", _int(obj.seq, "seq", 0, _UINT32_MAX))
    _set(obj, "t_ns", _int(obj.t_ns, "t_ns", _INT64_MIN, _INT64_MAX))


def _from_json(cls: type, data: Mapping[str, Any], build: Any) -> Any:
    """Call ``build(data)``, turning any lookup or type error into MessageError."""
    if not isinstance(data, Mapping):
        raise MessageError(f"{cls.__name__}: expected a JSON object, got {type(data).__name__}")
    try:
        return build(data)
    except MessageError:
        raise
    except (KeyError, TypeError, ValueError) as exc:
        raise MessageError(f"{cls.__name__}: bad JSON field: {exc!r}") from None


def _number_array(description: str, length: int | None = None) -> dict[str, Any]:
    schema: dict[str, Any] = {
        "type": "array",
        "items": {"type": "number"},
        "description": description,
    }
    if length is not None:
        schema["minItems"] = length
        schema["maxItems"] = length
    return schema


_SEQ_SCHEMA: Final = MappingProxyType(
    {"type": "integer", "description": "per-publisher message counter (uint32)"}
)
_T_SCHEMA: Final = MappingProxyType(
    {"type": "integer", "description": "source timestamp, ns since the UNIX epoch"}
)


def _object_schema(title: str, properties: dict[str, Any]) -> dict[str, Any]:
    props = {"seq": dict(_SEQ_SCHEMA), "t_ns": dict(_T_SCHEMA), **properties}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": props,
        "required": list(props),
    }


# --------------------------------------------------------------------------- messages


@dataclass(frozen=True, slots=True)
class JointState:
    """Measured joint state: angles, velocities and the commanded motor torques (``effort``)."""

    TYPE: ClassVar[MessageType] = MessageType.JOINT_STATE
    SCHEMA_NAME: ClassVar[str] = "teleop_force.JointState"
    seq: int
    t_ns: int
    q_rad: tuple[float, ...]
    qd_rad_s: tuple[float, ...]
    effort_nm: tuple[float, ...]

    def __post_init__(self) -> None:
        """Validate and normalise the fields; raise MessageError."""
        _header_fields(self)
        q = _joints(self.q_rad, "q_rad")
        _set(self, "q_rad", q)
        _set(self, "qd_rad_s", _joints(self.qd_rad_s, "qd_rad_s", len(q)))
        _set(self, "effort_nm", _joints(self.effort_nm, "effort_nm", len(q)))

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return len(self.q_rad)

    def encode(self) -> bytes:
        """Serialise to the binary layout of the module docstring."""
        n = len(self.q_rad)
        return _JOINT_STATE[n].pack(
            MAGIC, VERSION, self.TYPE, self.seq, self.t_ns, n,
            *self.q_rad, *self.qd_rad_s, *self.effort_nm,
        )  # fmt: skip

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Parse a binary message; raise MessageError if it is malformed in any way."""
        buf = _buffer(data)
        _check_header(buf, cls.TYPE)
        n = _joint_count(buf, "JointState")
        layout = _JOINT_STATE[n]
        _check_size(buf, layout.size, "JointState")
        v = layout.unpack(buf)
        if not _all_finite(v[6:]):
            raise MessageError("JointState: non-finite q_rad, qd_rad_s or effort_nm")
        return _build(
            cls,
            _JOINT_STATE_FIELDS,
            (v[3], v[4], v[6 : 6 + n], v[6 + n : 6 + 2 * n], v[6 + 2 * n :]),
        )

    def to_json_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dict (the MCAP JSON channel encoding)."""
        return {
            "seq": self.seq,
            "t_ns": self.t_ns,
            "q_rad": list(self.q_rad),
            "qd_rad_s": list(self.qd_rad_s),
            "effort_nm": list(self.effort_nm),
        }

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any]) -> Self:
        """Inverse of :meth:`to_json_dict`; raise MessageError."""
        return _from_json(
            cls,
            data,
            lambda d: cls(d["seq"], d["t_ns"], d["q_rad"], d["qd_rad_s"], d["effort_nm"]),
        )

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        """JSON schema of :meth:`to_json_dict` (for Foxglove)."""
        return _object_schema(
            cls.SCHEMA_NAME,
            {
                "q_rad": _number_array("measured joint angles [rad]"),
                "qd_rad_s": _number_array("joint velocities [rad/s]"),
                "effort_nm": _number_array("commanded motor torques [N m]"),
            },
        )


@dataclass(frozen=True, slots=True)
class JointSetpoint:
    """Joint position setpoint (the master pose) sent to a slave."""

    TYPE: ClassVar[MessageType] = MessageType.JOINT_SETPOINT
    SCHEMA_NAME: ClassVar[str] = "teleop_force.JointSetpoint"
    seq: int
    t_ns: int
    q_rad: tuple[float, ...]

    def __post_init__(self) -> None:
        """Validate and normalise the fields; raise MessageError."""
        _header_fields(self)
        _set(self, "q_rad", _joints(self.q_rad, "q_rad"))

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return len(self.q_rad)

    def encode(self) -> bytes:
        """Serialise to the binary layout of the module docstring."""
        n = len(self.q_rad)
        return _JOINT_SETPOINT[n].pack(
            MAGIC, VERSION, self.TYPE, self.seq, self.t_ns, n, *self.q_rad
        )

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Parse a binary message; raise MessageError if it is malformed in any way."""
        buf = _buffer(data)
        _check_header(buf, cls.TYPE)
        n = _joint_count(buf, "JointSetpoint")
        layout = _JOINT_SETPOINT[n]
        _check_size(buf, layout.size, "JointSetpoint")
        v = layout.unpack(buf)
        if not _all_finite(v[6:]):
            raise MessageError("JointSetpoint: non-finite q_rad")
        return _build(cls, _JOINT_SETPOINT_FIELDS, (v[3], v[4], v[6:]))

    def to_json_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dict (the MCAP JSON channel encoding)."""
        return {"seq": self.seq, "t_ns": self.t_ns, "q_rad": list(self.q_rad)}

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any]) -> Self:
        """Inverse of :meth:`to_json_dict`; raise MessageError."""
        return _from_json(cls, data, lambda d: cls(d["seq"], d["t_ns"], d["q_rad"]))

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        """JSON schema of :meth:`to_json_dict` (for Foxglove)."""
        return _object_schema(
            cls.SCHEMA_NAME,
            {"q_rad": _number_array("joint position setpoint [rad]")},
        )


@dataclass(frozen=True, slots=True)
class ContactForce:
    """Ground-truth force of the tip on the environment, base frame (sensor or simulator)."""

    TYPE: ClassVar[MessageType] = MessageType.CONTACT_FORCE
    SCHEMA_NAME: ClassVar[str] = "teleop_force.ContactForce"
    seq: int
    t_ns: int
    f_n: tuple[float, ...]

    def __post_init__(self) -> None:
        """Validate and normalise the fields; raise MessageError."""
        _header_fields(self)
        f = _floats(self.f_n, "f_n")
        if len(f) != 3:
            raise MessageError(f"f_n has {len(f)} values, expected 3")
        _set(self, "f_n", f)

    def encode(self) -> bytes:
        """Serialise to the binary layout of the module docstring."""
        return _CONTACT_FORCE.pack(MAGIC, VERSION, self.TYPE, self.seq, self.t_ns, *self.f_n)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Parse a binary message; raise MessageError if it is malformed in any way."""
        buf = _buffer(data)
        _check_header(buf, cls.TYPE)
        _check_size(buf, _CONTACT_FORCE.size, "ContactForce")
        v = _CONTACT_FORCE.unpack(buf)
        if not _all_finite(v[5:]):
            raise MessageError("ContactForce: non-finite f_n")
        return _build(cls, _CONTACT_FORCE_FIELDS, (v[3], v[4], v[5:]))

    def to_json_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dict (the MCAP JSON channel encoding)."""
        fx, fy, fz = self.f_n
        return {"seq": self.seq, "t_ns": self.t_ns, "f_n": {"x": fx, "y": fy, "z": fz}}

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any]) -> Self:
        """Inverse of :meth:`to_json_dict`; raise MessageError."""

        def build(d: Mapping[str, Any]) -> ContactForce:
            f = d["f_n"]
            return cls(d["seq"], d["t_ns"], (f["x"], f["y"], f["z"]))

        return _from_json(cls, data, build)

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        """JSON schema of :meth:`to_json_dict` (for Foxglove)."""
        return _object_schema(cls.SCHEMA_NAME, {"f_n": _vector3_schema()})


def _vector3_schema(nullable: bool = False) -> dict[str, Any]:
    component: dict[str, Any] = {"type": ["number", "null"] if nullable else "number"}
    return {
        "type": "object",
        "description": "tip force on the environment, base frame [N]",
        "properties": {"x": component, "y": component, "z": component},
        "required": ["x", "y", "z"],
    }


@dataclass(frozen=True, slots=True)
class ForceEstimateMessage:
    """Estimated contact force and the joint-space quantities it was computed from.

    ``f_n`` may hold NaN when no estimate exists (tip Jacobian near singular); every other
    number must be finite. ``on_trained_ground[j]`` tells whether joint ``j`` is inside the
    region the friction model was trained on.
    """

    TYPE: ClassVar[MessageType] = MessageType.FORCE_ESTIMATE
    #: Recorded name (MCAP schema), kept from before the class was renamed.
    SCHEMA_NAME: ClassVar[str] = "teleop_force.ForceEstimate"
    seq: int
    t_ns: int
    source_seq: int
    f_n: tuple[float, ...]
    tau_ext_nm: tuple[float, ...]
    on_trained_ground: tuple[bool, ...]
    coverage_weight: tuple[float, ...]
    tau_motor_filtered_nm: tuple[float, ...]
    tau_model_filtered_nm: tuple[float, ...]

    def __post_init__(self) -> None:
        """Validate and normalise the fields; raise MessageError."""
        _header_fields(self)
        _set(self, "source_seq", _int(self.source_seq, "source_seq", 0, _UINT32_MAX))
        f = _floats(self.f_n, "f_n", finite=False)
        if len(f) != 3:
            raise MessageError(f"f_n has {len(f)} values, expected 3")
        if any(math.isinf(x) for x in f):
            raise MessageError(f"f_n contains an infinite value: {f}")
        _set(self, "f_n", f)
        tau = _joints(self.tau_ext_nm, "tau_ext_nm")
        n = len(tau)
        _set(self, "tau_ext_nm", tau)
        try:
            flags = tuple(bool(x) for x in self.on_trained_ground)
        except TypeError:
            raise MessageError("on_trained_ground must be a sequence of booleans") from None
        if len(flags) != n:
            raise MessageError(f"on_trained_ground has {len(flags)} values, expected {n}")
        _set(self, "on_trained_ground", flags)
        _set(self, "coverage_weight", _joints(self.coverage_weight, "coverage_weight", n))
        _set(
            self,
            "tau_motor_filtered_nm",
            _joints(self.tau_motor_filtered_nm, "tau_motor_filtered_nm", n),
        )
        _set(
            self,
            "tau_model_filtered_nm",
            _joints(self.tau_model_filtered_nm, "tau_model_filtered_nm", n),
        )

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return len(self.tau_ext_nm)

    @property
    def on_trained_ground_mask(self) -> int:
        """The flags as an integer bitmask (bit j = joint j)."""
        mask = 0
        for j, flag in enumerate(self.on_trained_ground):
            if flag:
                mask |= 1 << j
        return mask

    def encode(self) -> bytes:
        """Serialise to the binary layout of the module docstring."""
        n = len(self.tau_ext_nm)
        mask = self.on_trained_ground_mask.to_bytes(_mask_bytes(n), "little")
        return _FORCE_ESTIMATE[n].pack(
            MAGIC, VERSION, self.TYPE, self.seq, self.t_ns, self.source_seq, n,
            *self.f_n, *self.tau_ext_nm, *self.coverage_weight,
            *self.tau_motor_filtered_nm, *self.tau_model_filtered_nm, mask,
        )  # fmt: skip

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Parse a binary message; raise MessageError if it is malformed in any way."""
        buf = _buffer(data)
        _check_header(buf, cls.TYPE)
        n = _joint_count(buf, "ForceEstimate", offset=HEADER_SIZE + 4)
        layout = _FORCE_ESTIMATE[n]
        _check_size(buf, layout.size, "ForceEstimate")
        v = layout.unpack(buf)
        mask = int.from_bytes(v[-1], "little")
        if mask >> n:
            raise MessageError(f"ForceEstimate: on_trained_ground bits set beyond joint {n}")
        f = v[7:10]
        if any(map(math.isinf, f)):
            raise MessageError("ForceEstimate: infinite f_n")
        o = 10  # index of tau_ext_nm[0] in v
        if not _all_finite(v[o:-1]):
            raise MessageError("ForceEstimate: non-finite joint-space value")
        flags = tuple(bool(mask >> j & 1) for j in range(n))
        return _build(
            cls,
            _FORCE_ESTIMATE_FIELDS,
            (
                v[3], v[4], v[5], f,
                v[o : o + n], flags, v[o + n : o + 2 * n],
                v[o + 2 * n : o + 3 * n], v[o + 3 * n : o + 4 * n],
            ),
        )  # fmt: skip

    def to_json_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dict (NaN force components become ``null``)."""
        fx, fy, fz = (None if math.isnan(x) else x for x in self.f_n)
        return {
            "seq": self.seq,
            "t_ns": self.t_ns,
            "source_seq": self.source_seq,
            "f_n": {"x": fx, "y": fy, "z": fz},
            "tau_ext_nm": list(self.tau_ext_nm),
            "on_trained_ground": list(self.on_trained_ground),
            "coverage_weight": list(self.coverage_weight),
            "tau_motor_filtered_nm": list(self.tau_motor_filtered_nm),
            "tau_model_filtered_nm": list(self.tau_model_filtered_nm),
        }

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any]) -> Self:
        """Inverse of :meth:`to_json_dict`; raise MessageError."""

        def build(d: Mapping[str, Any]) -> ForceEstimateMessage:
            f = d["f_n"]
            force = tuple(math.nan if f[k] is None else f[k] for k in ("x", "y", "z"))
            flags = d["on_trained_ground"]
            if not isinstance(flags, list) or not all(isinstance(x, bool) for x in flags):
                raise MessageError("ForceEstimate: on_trained_ground must be a list of booleans")
            return cls(
                d["seq"], d["t_ns"], d["source_seq"], force, d["tau_ext_nm"], tuple(flags),
                d["coverage_weight"], d["tau_motor_filtered_nm"], d["tau_model_filtered_nm"],
            )  # fmt: skip

        return _from_json(cls, data, build)

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        """JSON schema of :meth:`to_json_dict` (for Foxglove)."""
        return _object_schema(
            cls.SCHEMA_NAME,
            {
                "source_seq": {
                    "type": "integer",
                    "description": "seq of the JointState this estimate was computed from",
                },
                "f_n": _vector3_schema(nullable=True),
                "tau_ext_nm": _number_array("external joint torques [N m]"),
                "on_trained_ground": {
                    "type": "array",
                    "items": {"type": "boolean"},
                    "description": "joint inside the friction model's training region",
                },
                "coverage_weight": _number_array("training-data coverage weight per joint"),
                "tau_motor_filtered_nm": _number_array("low-passed motor torques [N m]"),
                "tau_model_filtered_nm": _number_array("low-passed model torques [N m]"),
            },
        )


@dataclass(frozen=True, slots=True)
class Status:
    """Safety state of a device and the human-readable reason for it."""

    TYPE: ClassVar[MessageType] = MessageType.STATUS
    SCHEMA_NAME: ClassVar[str] = "teleop_force.Status"
    seq: int
    t_ns: int
    state: SafetyState
    reason: str = ""

    def __post_init__(self) -> None:
        """Validate and normalise the fields; raise MessageError."""
        _header_fields(self)
        try:
            _set(self, "state", SafetyState(self.state))
        except (ValueError, TypeError):
            raise MessageError(f"unknown safety state {self.state!r}") from None
        if not isinstance(self.reason, str):
            raise MessageError(f"reason must be a string, got {type(self.reason).__name__}")
        try:
            size = len(self.reason.encode("utf-8"))
        except UnicodeEncodeError:
            raise MessageError("reason is not encodable as UTF-8") from None
        if size > MAX_REASON_BYTES:
            raise MessageError(f"reason is {size} bytes long, at most {MAX_REASON_BYTES}")

    def encode(self) -> bytes:
        """Serialise to the binary layout of the module docstring."""
        reason = self.reason.encode("utf-8")
        head = _STATUS_FIXED.pack(
            MAGIC, VERSION, self.TYPE, self.seq, self.t_ns, self.state, len(reason)
        )
        return head + reason

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Parse a binary message; raise MessageError if it is malformed in any way."""
        buf = _buffer(data)
        _check_header(buf, cls.TYPE)
        if len(buf) < _STATUS_FIXED.size:
            raise MessageError(f"Status: {len(buf)} bytes, at least {_STATUS_FIXED.size} needed")
        v = _STATUS_FIXED.unpack_from(buf)
        _check_size(buf, _STATUS_FIXED.size + v[6], "Status")
        try:
            reason = bytes(buf[_STATUS_FIXED.size :]).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise MessageError(f"Status: reason is not valid UTF-8: {exc.reason}") from None
        try:
            state = SafetyState(v[5])
        except ValueError:
            raise MessageError(f"Status: unknown safety state {v[5]}") from None
        return _build(cls, _STATUS_FIELDS, (v[3], v[4], state, reason))

    def to_json_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dict (the MCAP JSON channel encoding)."""
        return {
            "seq": self.seq,
            "t_ns": self.t_ns,
            "state": self.state.name.lower(),
            "reason": self.reason,
        }

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any]) -> Self:
        """Inverse of :meth:`to_json_dict`; raise MessageError."""

        def build(d: Mapping[str, Any]) -> Status:
            name = d["state"]
            if not isinstance(name, str) or name.upper() not in SafetyState.__members__:
                raise MessageError(f"Status: unknown state {name!r}")
            return cls(d["seq"], d["t_ns"], SafetyState[name.upper()], d["reason"])

        return _from_json(cls, data, build)

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        """JSON schema of :meth:`to_json_dict` (for Foxglove)."""
        return _object_schema(
            cls.SCHEMA_NAME,
            {
                "state": {"type": "string", "enum": [s.name.lower() for s in SafetyState]},
                "reason": {"type": "string"},
            },
        )


_JOINT_STATE_FIELDS: Final = ("seq", "t_ns", "q_rad", "qd_rad_s", "effort_nm")
_JOINT_SETPOINT_FIELDS: Final = ("seq", "t_ns", "q_rad")
_CONTACT_FORCE_FIELDS: Final = ("seq", "t_ns", "f_n")
_FORCE_ESTIMATE_FIELDS: Final = (
    "seq", "t_ns", "source_seq", "f_n", "tau_ext_nm", "on_trained_ground",
    "coverage_weight", "tau_motor_filtered_nm", "tau_model_filtered_nm",
)  # fmt: skip
_STATUS_FIELDS: Final = ("seq", "t_ns", "state", "reason")

# --------------------------------------------------------------------------- dispatch

#: Any wire message.
Message = JointState | JointSetpoint | ContactForce | ForceEstimateMessage | Status

#: Message class by type byte.
MESSAGE_CLASSES: Final[Mapping[int, type[Message]]] = MappingProxyType(
    {
        MessageType.JOINT_STATE: JointState,
        MessageType.JOINT_SETPOINT: JointSetpoint,
        MessageType.CONTACT_FORCE: ContactForce,
        MessageType.FORCE_ESTIMATE: ForceEstimateMessage,
        MessageType.STATUS: Status,
    }
)

#: Message class by JSON schema name (the ``title`` of :meth:`json_schema`).
MESSAGE_CLASSES_BY_SCHEMA: Final[Mapping[str, type[Message]]] = MappingProxyType(
    {c.SCHEMA_NAME: c for c in MESSAGE_CLASSES.values()}
)


def schema_name(message_class: type[Message]) -> str:
    """Name under which ``message_class`` is recorded (MCAP schema name)."""
    return message_class.SCHEMA_NAME


def decode(data: bytes | bytearray | memoryview) -> Message:
    """Decode any wire message by its type byte; raise MessageError."""
    buf = _buffer(data)
    if len(buf) < 4:
        raise MessageError(f"{len(buf)} bytes is shorter than the {HEADER_SIZE}-byte header")
    cls = MESSAGE_CLASSES.get(buf[3])
    if cls is None:
        if bytes(buf[:2]) != MAGIC:
            raise MessageError(f"bad magic {bytes(buf[:2])!r}, expected {MAGIC!r}")
        raise MessageError(f"unknown message type {buf[3]}")
    return cls.decode(buf)


def peek_header(data: bytes | bytearray | memoryview) -> tuple[int, int, int, int]:
    """Return ``(version, type, seq, t_ns)`` of a message without decoding its body."""
    buf = _buffer(data)
    if len(buf) < HEADER_SIZE:
        raise MessageError(f"{len(buf)} bytes is shorter than the {HEADER_SIZE}-byte header")
    magic, version, kind, seq, t_ns = _HEADER.unpack_from(buf)
    if magic != MAGIC:
        raise MessageError(f"bad magic {bytes(magic)!r}, expected {MAGIC!r}")
    return version, kind, seq, t_ns


def unpack_joint_state(
    data: bytes | bytearray | memoryview,
) -> tuple[int, int, int, tuple[float, ...]]:
    """Return ``(seq, t_ns, n, (q..., qd..., effort...))`` of a JointState without an object.

    The same checks as :meth:`JointState.decode` (raise MessageError), for receivers at
    1 kHz that need the numbers, not a message object.
    """
    buf = _buffer(data)
    _check_header(buf, MessageType.JOINT_STATE)
    n = _joint_count(buf, "JointState")
    layout = _JOINT_STATE[n]
    _check_size(buf, layout.size, "JointState")
    v = layout.unpack(buf)
    values = v[6:]
    if not _all_finite(values):
        raise MessageError("JointState: non-finite q_rad, qd_rad_s or effort_nm")
    return v[3], v[4], n, values


def _check_joint_count(n: int, expected: int | None, name: str) -> None:
    if expected is not None and n != expected:
        raise MessageError(f"{name}: {n} joints, expected {expected}")


def _packed(layout: struct.Struct, name: str, *values: Any) -> bytes:
    try:
        return layout.pack(*values)
    except struct.error as exc:
        raise MessageError(f"{name}: cannot encode: {exc}") from None


def _joint_layout(table: tuple[struct.Struct, ...], n: int, name: str) -> struct.Struct:
    if not 1 <= n <= MAX_JOINTS:
        raise MessageError(f"{name}: {n} joints, expected 1..{MAX_JOINTS}")
    return table[n]


# Object-free encoding and decoding for 1 kHz senders and receivers: the bytes and checks of
# the classes' encode() / decode(), without building (and validating) a message object.


def pack_joint_state(
    seq: int,
    t_ns: int,
    q_rad: Sequence[float],
    qd_rad_s: Sequence[float],
    effort_nm: Sequence[float],
) -> bytes:
    """Return the bytes of ``JointState(seq, t_ns, q_rad, qd_rad_s, effort_nm).encode()``.

    Raise MessageError where the class would (lengths, non-finite values, ``seq`` or ``t_ns``
    out of range).
    """
    n = len(q_rad)
    if not len(qd_rad_s) == len(effort_nm) == n:
        raise MessageError("JointState: q_rad, qd_rad_s and effort_nm differ in length")
    layout = _joint_layout(_JOINT_STATE, n, "JointState")
    payload = _packed(
        layout, "JointState", MAGIC, VERSION, MessageType.JOINT_STATE, seq, t_ns, n,
        *q_rad, *qd_rad_s, *effort_nm,
    )  # fmt: skip
    if not _all_finite((*q_rad, *qd_rad_s, *effort_nm)):
        raise MessageError("JointState: non-finite q_rad, qd_rad_s or effort_nm")
    return payload


def pack_joint_setpoint(seq: int, t_ns: int, q_rad: Sequence[float]) -> bytes:
    """Return the bytes of ``JointSetpoint(seq, t_ns, q_rad).encode()`` (MessageError as it)."""
    n = len(q_rad)
    layout = _joint_layout(_JOINT_SETPOINT, n, "JointSetpoint")
    payload = _packed(
        layout, "JointSetpoint", MAGIC, VERSION, MessageType.JOINT_SETPOINT, seq, t_ns, n, *q_rad
    )
    if not _all_finite(tuple(q_rad)):
        raise MessageError("JointSetpoint: non-finite q_rad")
    return payload


def pack_contact_force(seq: int, t_ns: int, f_n: Sequence[float]) -> bytes:
    """Return the bytes of ``ContactForce(seq, t_ns, f_n).encode()`` (MessageError as it)."""
    if len(f_n) != 3:
        raise MessageError(f"ContactForce: f_n has {len(f_n)} values, expected 3")
    payload = _packed(
        _CONTACT_FORCE, "ContactForce", MAGIC, VERSION, MessageType.CONTACT_FORCE, seq, t_ns, *f_n
    )
    if not _all_finite(tuple(f_n)):
        raise MessageError("ContactForce: non-finite f_n")
    return payload


def unpack_joint_setpoint(
    data: bytes | bytearray | memoryview, n_joints: int | None = None
) -> tuple[int, int, tuple[float, ...]]:
    """Return ``(seq, t_ns, q_rad)`` of a JointSetpoint, checked as :meth:`JointSetpoint.decode`.

    ``n_joints``: refuse (MessageError) a setpoint of another joint count.
    """
    buf = _buffer(data)
    _check_header(buf, MessageType.JOINT_SETPOINT)
    n = _joint_count(buf, "JointSetpoint")
    _check_joint_count(n, n_joints, "JointSetpoint")
    layout = _JOINT_SETPOINT[n]
    _check_size(buf, layout.size, "JointSetpoint")
    v = layout.unpack(buf)
    q = v[6:]
    if not _all_finite(q):
        raise MessageError("JointSetpoint: non-finite q_rad")
    return v[3], v[4], q


def unpack_contact_force(
    data: bytes | bytearray | memoryview,
) -> tuple[int, int, tuple[float, ...]]:
    """Return ``(seq, t_ns, f_n)`` of a ContactForce, checked as :meth:`ContactForce.decode`."""
    buf = _buffer(data)
    _check_header(buf, MessageType.CONTACT_FORCE)
    _check_size(buf, _CONTACT_FORCE.size, "ContactForce")
    v = _CONTACT_FORCE.unpack(buf)
    f = v[5:]
    if not _all_finite(f):
        raise MessageError("ContactForce: non-finite f_n")
    return v[3], v[4], f


def unpack_force_estimate(
    data: bytes | bytearray | memoryview, n_joints: int | None = None
) -> tuple[int, int, int, tuple[float, ...]]:
    """Return ``(seq, t_ns, source_seq, f_n)`` of a ForceEstimate, the whole message checked.

    The checks of :meth:`ForceEstimateMessage.decode` (``f_n`` may hold NaN, nothing else may
    be non-finite, no mask bit beyond the joints); ``n_joints``: refuse another joint count.
    """
    buf = _buffer(data)
    _check_header(buf, MessageType.FORCE_ESTIMATE)
    n = _joint_count(buf, "ForceEstimate", offset=HEADER_SIZE + 4)
    _check_joint_count(n, n_joints, "ForceEstimate")
    layout = _FORCE_ESTIMATE[n]
    _check_size(buf, layout.size, "ForceEstimate")
    v = layout.unpack(buf)
    if int.from_bytes(v[-1], "little") >> n:
        raise MessageError(f"ForceEstimate: on_trained_ground bits set beyond joint {n}")
    f = v[7:10]
    if any(map(math.isinf, f)):
        raise MessageError("ForceEstimate: infinite f_n")
    if not _all_finite(v[10:-1]):
        raise MessageError("ForceEstimate: non-finite joint-space value")
    return v[3], v[4], v[5], f


def pack_force_estimate(
    seq: int, t_ns: int, source_seq: int, n: int, values: Sequence[float], mask: int
) -> bytes:
    """Encode a ForceEstimateMessage from its numbers, without an object (unchecked).

    ``values``: ``f_n`` (3), ``tau_ext_nm``, ``coverage_weight``, ``tau_motor_filtered_nm``,
    ``tau_model_filtered_nm`` (n each), in that (wire) order; ``mask``: the on-trained-ground
    bits. The caller guarantees what :class:`ForceEstimateMessage` would check (finite
    joint-space values, no infinite force, ``seq`` and ``source_seq`` in 32 bits); the bytes
    are those of :meth:`ForceEstimateMessage.encode`.
    """
    return _FORCE_ESTIMATE[n].pack(
        MAGIC, VERSION, MessageType.FORCE_ESTIMATE, seq, t_ns, source_seq, n, *values,
        mask.to_bytes(_mask_bytes(n), "little"),
    )  # fmt: skip


def sequence_gap(previous_seq: int, seq: int) -> int:
    """Return how many messages were lost between two consecutive received seqs (mod 2**32)."""
    return (seq - previous_seq - 1) % (_UINT32_MAX + 1)


# --------------------------------------------------------------------------- diagnostics (JSON)

#: Version of the ServiceDiagnostics JSON layout (its ``version`` field).
DIAGNOSTICS_VERSION: Final = 1
#: States of the residual watch, as ServiceDiagnostics ``state``.
DIAGNOSTIC_STATES: Final = ("baseline", "watching", "dependence")


def _json_number(value: float) -> float | None:
    """Return a float for JSON: ``None`` for NaN / infinity."""
    return float(value) if math.isfinite(value) else None


def _number_from_json(data: Mapping[str, Any], key: str) -> float:
    value = data[key]
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MessageError(f"ServiceDiagnostics: {key} must be a number or null, got {value!r}")
    return float(value)


@dataclass(frozen=True, slots=True)
class DiagnosticCheck:
    """The residual watch's test of one joint at its latest evaluation (1-based joint)."""

    joint: int
    rows: int
    variable: str | None
    p_value: float
    effect_fraction: float
    consecutive: int

    def __post_init__(self) -> None:
        """Validate the ranges; raise MessageError."""
        _int(self.joint, "joint", 1, MAX_JOINTS)
        _int(self.rows, "rows", 0, _INT64_MAX)
        _int(self.consecutive, "consecutive", 0, _INT64_MAX)
        if self.variable is not None and not isinstance(self.variable, str):
            raise MessageError(f"variable must be a string or None, got {self.variable!r}")


@dataclass(frozen=True, slots=True)
class DiagnosticFinding:
    """A persistent dependence the residual watch reports (1-based joint)."""

    joint: int
    variable: str
    effect_fraction: float
    effect_nm: float
    p_value: float
    since_s: float
    holds: bool

    def __post_init__(self) -> None:
        """Validate the ranges; raise MessageError."""
        _int(self.joint, "joint", 1, MAX_JOINTS)
        if not isinstance(self.variable, str) or not self.variable:
            raise MessageError(f"variable must be a non-empty string, got {self.variable!r}")


@dataclass(frozen=True, slots=True)
class ServiceDiagnostics:
    """The residual watch's report, key ``omni/<device>/service/diagnostics`` (JSON, ~1 Hz).

    UTF-8 JSON (not the binary header: a low-rate, self-describing report like the service's
    queryables), one object::

        {"version": 1, "seq": 17, "t_ns": 1700000000000000000, "device": "slave",
         "state": "dependence",            # baseline | watching | dependence
         "stream_s": 78.0,                 # stream time of the newest sample tested [s]
         "baseline_complete": true,
         "rms_torque_nm": [0.02, 0.03, 0.02],   # per joint, over its free rows
         "checks": [{"joint": 1, "rows": 350, "variable": "t", "p_value": 0.3,
                     "effect_fraction": 0.01, "consecutive": 0}, ...],
         "finding": {"joint": 2, "variable": "tau2", "effect_fraction": 0.11,
                     "effect_nm": 0.017, "p_value": 1e-12, "since_s": 61.0, "holds": true},
         "command": "teleop-force residual RECORDING --model /abs/model.json"}

    ``finding`` is ``null`` and ``command`` empty until a dependence is reported; numbers
    that are not finite are ``null``. ``seq`` counts the reports, ``t_ns`` is when this one
    was made (ns since the UNIX epoch).
    """

    seq: int
    t_ns: int
    device: str
    state: str
    stream_s: float
    baseline_complete: bool
    rms_torque_nm: tuple[float, ...]
    checks: tuple[DiagnosticCheck, ...]
    finding: DiagnosticFinding | None
    command: str

    def __post_init__(self) -> None:
        """Validate the fields; raise MessageError."""
        _header_fields(self)
        if self.state not in DIAGNOSTIC_STATES:
            raise MessageError(f"state must be one of {DIAGNOSTIC_STATES}, got {self.state!r}")
        if not isinstance(self.device, str) or not isinstance(self.command, str):
            raise MessageError("device and command must be strings")
        if (self.finding is None) != (self.command == ""):
            raise MessageError("a finding comes with a command, and only a finding does")

    def to_json_dict(self) -> dict[str, Any]:
        """Return the JSON object of the class docstring."""
        finding = self.finding
        return {
            "version": DIAGNOSTICS_VERSION,
            "seq": self.seq,
            "t_ns": self.t_ns,
            "device": self.device,
            "state": self.state,
            "stream_s": _json_number(self.stream_s),
            "baseline_complete": bool(self.baseline_complete),
            "rms_torque_nm": [_json_number(x) for x in self.rms_torque_nm],
            "checks": [
                {
                    "joint": c.joint,
                    "rows": c.rows,
                    "variable": c.variable,
                    "p_value": _json_number(c.p_value),
                    "effect_fraction": _json_number(c.effect_fraction),
                    "consecutive": c.consecutive,
                }
                for c in self.checks
            ],
            "finding": None
            if finding is None
            else {
                "joint": finding.joint,
                "variable": finding.variable,
                "effect_fraction": _json_number(finding.effect_fraction),
                "effect_nm": _json_number(finding.effect_nm),
                "p_value": _json_number(finding.p_value),
                "since_s": _json_number(finding.since_s),
                "holds": bool(finding.holds),
            },
            "command": self.command,
        }

    def encode(self) -> bytes:
        """UTF-8 JSON bytes (what is published)."""
        return json.dumps(self.to_json_dict(), allow_nan=False).encode("utf-8")

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Self:
        """Parse the published bytes; raise MessageError if malformed in any way."""
        try:
            obj = json.loads(bytes(_buffer(data)).decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            raise MessageError(f"ServiceDiagnostics: not UTF-8 JSON: {exc}") from None
        if not isinstance(obj, dict) or obj.get("version") != DIAGNOSTICS_VERSION:
            raise MessageError("ServiceDiagnostics: not an object of version 1")
        try:
            checks = tuple(
                DiagnosticCheck(
                    c["joint"],
                    c["rows"],
                    c["variable"],
                    _number_from_json(c, "p_value"),
                    _number_from_json(c, "effect_fraction"),
                    c["consecutive"],
                )
                for c in obj["checks"]
            )
            f = obj["finding"]
            finding = (
                None
                if f is None
                else DiagnosticFinding(
                    f["joint"],
                    f["variable"],
                    _number_from_json(f, "effect_fraction"),
                    _number_from_json(f, "effect_nm"),
                    _number_from_json(f, "p_value"),
                    _number_from_json(f, "since_s"),
                    bool(f["holds"]),
                )
            )
            return cls(
                seq=obj["seq"], t_ns=obj["t_ns"], device=obj["device"], state=obj["state"],
                stream_s=_number_from_json(obj, "stream_s"),
                baseline_complete=bool(obj["baseline_complete"]),
                rms_torque_nm=tuple(
                    math.nan if x is None else float(x) for x in obj["rms_torque_nm"]
                ),
                checks=checks, finding=finding, command=obj["command"],
            )  # fmt: skip
        except (KeyError, TypeError) as exc:
            raise MessageError(f"ServiceDiagnostics: missing or wrong field: {exc}") from None


__all__ = (
    "DIAGNOSTICS_VERSION",
    "DIAGNOSTIC_STATES",
    "HEADER_SIZE",
    "MAGIC",
    "MAX_JOINTS",
    "MESSAGE_CLASSES",
    "MESSAGE_CLASSES_BY_SCHEMA",
    "VERSION",
    "ContactForce",
    "DiagnosticCheck",
    "DiagnosticFinding",
    "ForceEstimateMessage",
    "JointSetpoint",
    "JointState",
    "Message",
    "MessageType",
    "SafetyState",
    "ServiceDiagnostics",
    "Status",
    "decode",
    "pack_contact_force",
    "pack_force_estimate",
    "pack_joint_setpoint",
    "pack_joint_state",
    "peek_header",
    "schema_name",
    "sequence_gap",
    "unpack_contact_force",
    "unpack_force_estimate",
    "unpack_joint_setpoint",
    "unpack_joint_state",
)
