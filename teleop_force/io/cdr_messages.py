"""Recorded message encoding: ROS 2 CDR payloads and their ``ros2msg`` schemas, from wire bytes.

A session (:mod:`teleop_force.io.mcap_session`) records every wire message
(:mod:`teleop_force.transport.messages`) as a CDR payload, MCAP message encoding ``cdr`` with a
``ros2msg`` schema per message class (:data:`CDR_SCHEMAS`), so Foxglove decodes and plots every
field natively. A CDR payload is a re-layout of the wire message: the same numbers, in the same
order, with the CDR framing:

- a 4-byte encapsulation header ``00 01 00 00`` (plain CDR, little endian, no options);
- every primitive aligned to its own size (``uint32`` to 4, ``int64``/``float64`` to 8),
  counted from the first byte *after* the encapsulation header, padding bytes zero;
- a variable-length array (``float64[]``, ``bool[]``) is a ``uint32`` element count, then its
  elements (the first one aligned to its size); a fixed array (``float64[3]``) has no count;
- a ``string`` is a ``uint32`` byte count including a terminating NUL, the UTF-8 bytes, NUL;
- ``bool`` is one byte, 0 or 1; nothing is padded after the last field.

Layouts, offsets counted after the 4-byte header (payload byte = offset + 4); ``n`` is the joint
count (1..255); ``pad`` is zero padding; ``[n]`` is the ``uint32`` count ``n`` before an array:

- ``JointState`` (44 + 24 n bytes): 0 seq, 4 pad, 8 t_ns, 16 [n], 20 pad, 24 q_rad,
  24+8n [n], pad, 32+8n qd_rad_s, 32+16n [n], pad, 40+16n effort_nm.
- ``JointSetpoint`` (28 + 8 n): 0 seq, 4 pad, 8 t_ns, 16 [n], 20 pad, 24 q_rad.
- ``ContactForce`` (44): 0 seq, 4 pad, 8 t_ns, 16 f_n (``float64[3]``).
- ``ForceEstimate`` (88 + 33 n): 0 seq, 4 pad, 8 t_ns, 16 source_seq, 20 pad, 24 f_n,
  48 [n], pad, 56 tau_ext_nm, 56+8n [n], pad, 64+8n coverage_weight, 64+16n [n], pad,
  72+16n tau_motor_filtered_nm, 72+24n [n], pad, 80+24n tau_model_filtered_nm,
  80+32n [n], 84+32n on_trained_ground (``bool[n]``).
- ``Status`` (29 + L, L the reason's UTF-8 length): 0 seq, 4 pad, 8 t_ns, 16 state
  (``uint8``), 17 pad, 20 ``uint32`` L + 1, 24 reason, 24+L NUL.

The paddings never depend on ``n`` (every array of float64 starts 8-aligned), so a block of
same-size wire messages maps to a block of same-size payloads column by column.

Conversions never build message objects on the recording path: :func:`wire_block_to_cdr`
checks and converts a block of same-size wire messages with numpy (every check of the wire
decoders: magic, version, type, joint count, exact size, finite numbers, no stray mask bits),
:func:`joint_state_columns` turns a block of JointState CDR payloads into arrays. Single
messages go through :func:`encode_cdr` and :func:`decode_cdr` (which checks the CDR framing,
then decodes with the wire decoder, so it is exactly as strict).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from types import MappingProxyType
from typing import Final

import numpy as np

from teleop_force.errors import ConfigurationError, DataError, MessageError
from teleop_force.transport import messages as m

#: Encapsulation header of every payload: plain CDR, little endian, options 0.
ENCAPSULATION: Final = b"\x00\x01\x00\x00"
#: MCAP message encoding and schema encoding of a recording's channels.
MESSAGE_ENCODING: Final = "cdr"
SCHEMA_ENCODING: Final = "ros2msg"

_HEAD: Final = len(ENCAPSULATION)
_U32: Final = struct.Struct("<I")
_STATUS_CDR: Final = struct.Struct("<4sI4xqB3xI")  # header, seq, t_ns, state, string length
_STATUS_WIRE: Final = struct.Struct("<2sBBIqBH")


@dataclass(frozen=True)
class CdrSchema:
    """The ``ros2msg`` schema of one message class: MCAP schema name and definition text."""

    name: str
    text: str

    def __post_init__(self) -> None:
        """Check the name is ``package/msg/Type``."""
        parts = self.name.split("/")
        if len(parts) != 3 or parts[1] != "msg" or not all(parts):
            raise ConfigurationError(
                f"ros2msg schema name must be package/msg/Type, got {self.name!r}"
            )


_HEADER_FIELDS: Final = (
    "uint32 seq  # per-publisher message counter (wraps at 2**32)\n"
    "int64 t_ns  # source timestamp [ns since the UNIX epoch]\n"
)

#: The ``ros2msg`` schema of every message class.
CDR_SCHEMAS: Final[Mapping[type[m.Message], CdrSchema]] = MappingProxyType(
    {
        m.JointState: CdrSchema(
            "teleop_force/msg/JointState",
            "# Measured joint state (key omni/<device>/measured_js)\n"
            + _HEADER_FIELDS
            + "float64[] q_rad  # measured joint angles [rad]\n"
            "float64[] qd_rad_s  # joint velocities [rad/s]\n"
            "float64[] effort_nm  # commanded motor torques [N m]\n",
        ),
        m.JointSetpoint: CdrSchema(
            "teleop_force/msg/JointSetpoint",
            "# Joint position setpoint sent to a slave (key omni/<device>/setpoint_js)\n"
            + _HEADER_FIELDS
            + "float64[] q_rad  # joint position setpoint [rad]\n",
        ),
        m.ContactForce: CdrSchema(
            "teleop_force/msg/ContactForce",
            "# Measured tip force (key omni/<device>/measured_cf)\n"
            + _HEADER_FIELDS
            + "float64[3] f_n  # (x, y, z) tip force on the environment, base frame [N]\n",
        ),
        m.ForceEstimateMessage: CdrSchema(
            "teleop_force/msg/ForceEstimate",
            "# Estimated contact force (key omni/<device>/estimated_cf)\n"
            + _HEADER_FIELDS
            + "uint32 source_seq  # seq of the JointState it was computed from\n"
            "float64[3] f_n  # (x, y, z) estimated tip force, base frame [N]; NaN: none\n"
            "float64[] tau_ext_nm  # external joint torques [N m]\n"
            "float64[] coverage_weight  # training-data coverage per joint\n"
            "float64[] tau_motor_filtered_nm  # low-passed motor torques [N m]\n"
            "float64[] tau_model_filtered_nm  # low-passed model torques [N m]\n"
            "bool[] on_trained_ground  # joint inside the friction model's training region\n",
        ),
        m.Status: CdrSchema(
            "teleop_force/msg/Status",
            "# Safety state of a device (key omni/<device>/status)\n"
            "uint8 STARTING=0\n"
            "uint8 FOLLOWING=1\n"
            "uint8 HOLDING=2\n"
            "uint8 STOPPED=3\n" + _HEADER_FIELDS + "uint8 state  # one of the constants above\n"
            "string reason  # why, for a person\n",
        ),
    }
)

#: Message class by ``ros2msg`` schema name.
MESSAGE_CLASSES_BY_CDR_SCHEMA: Final[Mapping[str, type[m.Message]]] = MappingProxyType(
    {schema.name: cls for cls, schema in CDR_SCHEMAS.items()}
)


# --------------------------------------------------------------------------- fixed layouts


@dataclass(frozen=True)
class _Layout:
    """Byte correspondence between a fixed-size wire message and its CDR payload."""

    wire_size: int
    cdr_size: int
    wire_template: bytes  # the wire message's constant bytes (magic, version, type, n)
    cdr_template: bytes  # the payload's constant bytes (header, padding, element counts)
    copies: tuple[tuple[int, int, int], ...]  # (wire offset, payload offset, length)
    floats: tuple[tuple[int, int, bool], ...]  # (wire offset, count, NaN allowed)
    mask: tuple[int, int, int] | None  # (wire offset of the bitmask, payload offset, n)
    wire_constant: tuple[tuple[int, int], ...]  # [start, stop) ranges of constant wire bytes
    cdr_constant: tuple[tuple[int, int], ...]  # [start, stop) ranges of constant payload bytes


class _LayoutBuilder:
    """Lay out CDR fields one after the other, recording where each wire field goes."""

    def __init__(self, message_type: m.MessageType, n: int | None, n_offset: int | None) -> None:
        self.cdr = bytearray(ENCAPSULATION)
        self.wire = bytearray(b"TF" + bytes((m.VERSION, message_type)))
        self.wire_size = m.HEADER_SIZE
        self.copies: list[tuple[int, int, int]] = []
        self.floats: list[tuple[int, int, bool]] = []
        self.variable_cdr: list[tuple[int, int]] = []
        self.variable_wire: list[tuple[int, int]] = []
        self.mask: tuple[int, int, int] | None = None
        self.n_offset = n_offset
        self.n = n

    def _align(self, size: int) -> None:
        self.cdr += bytes(-(len(self.cdr) - _HEAD) % size)

    def copy(self, wire_offset: int, size: int, align: int) -> None:
        self._align(align)
        self.copies.append((wire_offset, len(self.cdr), size))
        self.variable_cdr.append((len(self.cdr), size))
        self.variable_wire.append((wire_offset, size))
        self.cdr += bytes(size)

    def floats_at(self, wire_offset: int, count: int, *, sequence: bool, nan: bool = False) -> None:
        if sequence:
            self._align(4)
            self.cdr += _U32.pack(count)
        self.copy(wire_offset, 8 * count, 8)
        self.floats.append((wire_offset, count, nan))

    def bools_from_mask(self, wire_offset: int, n: int) -> None:
        self._align(4)
        self.cdr += _U32.pack(n)
        self.mask = (wire_offset, len(self.cdr), n)
        self.variable_cdr.append((len(self.cdr), n))
        self.variable_wire.append((wire_offset, (n + 7) // 8))
        self.cdr += bytes(n)

    def build(self, wire_size: int) -> _Layout:
        wire = bytearray(wire_size)
        wire[:4] = self.wire
        if self.n_offset is not None and self.n is not None:
            wire[self.n_offset] = self.n
        return _Layout(
            wire_size=wire_size,
            cdr_size=len(self.cdr),
            wire_template=bytes(wire),
            cdr_template=bytes(self.cdr),
            copies=tuple(self.copies),
            floats=tuple(self.floats),
            mask=self.mask,
            wire_constant=_complement(wire_size, self.variable_wire),
            cdr_constant=_complement(len(self.cdr), self.variable_cdr),
        )


def _complement(size: int, ranges: list[tuple[int, int]]) -> tuple[tuple[int, int], ...]:
    """Return the ``[start, stop)`` ranges of ``range(size)`` outside ``(start, length)`` ones."""
    variable = np.zeros(size + 2, dtype=bool)
    variable[0] = variable[-1] = True
    for start, length in ranges:
        variable[start + 1 : start + 1 + length] = True
    edges = np.flatnonzero(np.diff(variable.astype(np.int8)))
    return tuple((int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True))


def _field(block: np.ndarray, offset: int, dtype: str, shape: tuple[int, ...] = ()) -> np.ndarray:
    """View the ``dtype`` value (or array of ``shape``) at byte ``offset`` of every row.

    ``block`` is a C-contiguous ``(N, width)`` uint8 array; the view is strided, not copied.
    """
    item = np.dtype(dtype)
    rows, width = block.shape
    if rows == 0:  # no buffer to view (numpy refuses an offset into an empty one)
        return np.empty((0, *shape), dtype=item)
    return np.ndarray(
        (rows, *shape),
        dtype=item,
        buffer=block,
        offset=offset,
        strides=(width, *(item.itemsize for _ in shape)),
    )


def _rows_match(
    block: np.ndarray, template: bytes, ranges: tuple[tuple[int, int], ...], offset: int = 0
) -> np.ndarray:
    """Return, per row, whether its bytes ``offset + [start, stop)`` equal ``template``'s."""
    ok = np.ones(block.shape[0], dtype=bool)
    for start, stop in ranges:
        at = start
        while at < stop:  # compare 8, 4 or 1 bytes at a time, as integers
            size = 8 if stop - at >= 8 else 4 if stop - at >= 4 else 1
            kind = {8: "<u8", 4: "<u4", 1: "u1"}[size]
            expected = int.from_bytes(template[at : at + size], "little")
            ok &= _field(block, offset + at, kind) == expected
            at += size
    return ok


def _layout(cls: type[m.Message], n: int) -> _Layout:
    """Return the layout of ``cls`` with ``n`` joints (``n`` ignored for ContactForce)."""
    return _layout_of_type(int(cls.TYPE), n)


@cache
def _layout_of_type(message_type: int, n: int) -> _Layout:
    """Return the layout of message type ``message_type`` with ``n`` joints."""
    cls = m.MESSAGE_CLASSES[message_type]
    if cls is m.JointState:
        b = _LayoutBuilder(cls.TYPE, n, 16)
        b.copy(4, 4, 4)
        b.copy(8, 8, 8)
        for k in range(3):
            b.floats_at(17 + 8 * n * k, n, sequence=True)
        return b.build(17 + 24 * n)
    if cls is m.JointSetpoint:
        b = _LayoutBuilder(cls.TYPE, n, 16)
        b.copy(4, 4, 4)
        b.copy(8, 8, 8)
        b.floats_at(17, n, sequence=True)
        return b.build(17 + 8 * n)
    if cls is m.ContactForce:
        b = _LayoutBuilder(cls.TYPE, None, None)
        b.copy(4, 4, 4)
        b.copy(8, 8, 8)
        b.floats_at(16, 3, sequence=False)
        return b.build(40)
    if cls is m.ForceEstimateMessage:
        b = _LayoutBuilder(cls.TYPE, n, 20)
        b.copy(4, 4, 4)
        b.copy(8, 8, 8)
        b.copy(16, 4, 4)
        b.floats_at(21, 3, sequence=False, nan=True)
        for k in range(4):
            b.floats_at(45 + 8 * n * k, n, sequence=True)
        b.bools_from_mask(45 + 32 * n, n)
        return b.build(45 + 32 * n + (n + 7) // 8)
    raise MessageError(f"{cls.__name__} has no fixed layout")


def _joint_count_for_wire_size(cls: type[m.Message], size: int) -> int | None:
    """Return the joint count whose wire message of ``cls`` is ``size`` bytes, or None."""
    if cls is m.ContactForce:
        return 0 if size == 40 else None
    if cls is m.JointState:
        n, rest = divmod(size - 17, 24)
    elif cls is m.JointSetpoint:
        n, rest = divmod(size - 17, 8)
    elif cls is m.ForceEstimateMessage:
        n = (size - 45) // 32
        rest = size - (45 + 32 * n + (n + 7) // 8)
    else:
        return None
    return n if rest == 0 and 1 <= n <= m.MAX_JOINTS else None


def _joint_count_for_cdr_size(cls: type[m.Message], size: int) -> int | None:
    """Return the joint count whose CDR payload of ``cls`` is ``size`` bytes, or None."""
    if cls is m.ContactForce:
        return 0 if size == _layout(cls, 0).cdr_size else None
    if cls is m.JointState:
        n, rest = divmod(size - 44, 24)
    elif cls is m.JointSetpoint:
        n, rest = divmod(size - 28, 8)
    elif cls is m.ForceEstimateMessage:
        n, rest = divmod(size - 88, 33)
    else:
        return None
    return n if rest == 0 and 1 <= n <= m.MAX_JOINTS else None


def has_fixed_layout(cls: type[m.Message]) -> bool:
    """Whether messages of ``cls`` of one size convert as a block (all but Status)."""
    return cls is not m.Status


# --------------------------------------------------------------------------- one message


def encode_cdr(message: m.Message) -> bytes:
    """Return the CDR payload of ``message`` (its schema: ``CDR_SCHEMAS[type(message)]``)."""
    if isinstance(message, m.Status):
        reason = message.reason.encode("utf-8")
        head = _STATUS_CDR.pack(
            ENCAPSULATION, message.seq, message.t_ns, message.state, len(reason) + 1
        )
        return head + reason + b"\0"
    wire = message.encode()
    layout = _layout(type(message), 0 if isinstance(message, m.ContactForce) else message.n_joints)
    out = bytearray(layout.cdr_template)
    for wire_offset, cdr_offset, size in layout.copies:
        out[cdr_offset : cdr_offset + size] = wire[wire_offset : wire_offset + size]
    if layout.mask is not None:
        wire_offset, cdr_offset, n = layout.mask
        mask = int.from_bytes(wire[wire_offset:], "little")
        out[cdr_offset : cdr_offset + n] = bytes(mask >> j & 1 for j in range(n))
    return bytes(out)


def decode_cdr(cls: type[m.Message], data: bytes | bytearray | memoryview) -> m.Message:
    """Parse the CDR payload of a ``cls`` message; raise MessageError if it is malformed."""
    data = bytes(data)
    if cls is m.Status:
        return _decode_status(data)
    n = _joint_count_for_cdr_size(cls, len(data))
    if n is None:
        raise MessageError(f"{cls.__name__}: {len(data)} bytes is no CDR payload size of it")
    layout = _layout(cls, n)
    if any(data[a:b] != layout.cdr_template[a:b] for a, b in layout.cdr_constant):
        raise MessageError(f"{cls.__name__}: bad CDR header, padding or element count")
    wire = bytearray(layout.wire_template)
    for wire_offset, cdr_offset, size in layout.copies:
        wire[wire_offset : wire_offset + size] = data[cdr_offset : cdr_offset + size]
    if layout.mask is not None:
        wire_offset, cdr_offset, n = layout.mask
        flags = data[cdr_offset : cdr_offset + n]
        if flags.strip(b"\0\1"):
            raise MessageError(f"{cls.__name__}: a bool is neither 0 nor 1")
        mask = sum(1 << j for j, flag in enumerate(flags) if flag)
        wire[wire_offset:] = mask.to_bytes((n + 7) // 8, "little")
    return cls.decode(wire)


def _decode_status(data: bytes) -> m.Status:
    if len(data) < _STATUS_CDR.size + 1:
        raise MessageError(f"Status: {len(data)} bytes is shorter than its CDR payload")
    header, seq, t_ns, state, length = _STATUS_CDR.unpack_from(data)
    if header != ENCAPSULATION or data[8:12] != bytes(4) or data[21:24] != bytes(3):
        raise MessageError("Status: bad CDR header or padding")
    if length < 1 or len(data) != _STATUS_CDR.size + length or data[-1] != 0:
        raise MessageError("Status: bad CDR string (length or terminating NUL)")
    reason = data[_STATUS_CDR.size : -1]
    if len(reason) > m.MAX_REASON_BYTES:
        raise MessageError(f"Status: reason is {len(reason)} bytes, at most {m.MAX_REASON_BYTES}")
    wire = _STATUS_WIRE.pack(
        m.MAGIC, m.VERSION, m.MessageType.STATUS, seq, t_ns, state, len(reason)
    )
    return m.Status.decode(wire + reason)


# --------------------------------------------------------------------------- blocks


@dataclass(frozen=True)
class CdrBlock:
    """Wire messages of one class and size converted together.

    Attributes:
        message_class: Class of every row.
        accepted: ``(N,)`` bool, whether each input row was a valid message (the others are
            malformed, and have no payload here).
        cdr: ``(K, size)`` uint8, the CDR payload of each accepted row, in input order.
        seq: ``(K,)`` uint32, their ``seq``.
        t_ns: ``(K,)`` int64, their source stamps.

    """

    message_class: type[m.Message]
    accepted: np.ndarray
    cdr: np.ndarray
    seq: np.ndarray
    t_ns: np.ndarray

    def __post_init__(self) -> None:
        """Check the shapes agree."""
        k = int(np.count_nonzero(self.accepted))
        if self.cdr.ndim != 2 or self.cdr.shape[0] != k or self.seq.shape != (k,):
            raise DataError("CdrBlock arrays disagree with the accepted rows")
        if self.t_ns.shape != (k,):
            raise DataError("CdrBlock arrays disagree with the accepted rows")


def _columns(block: np.ndarray, start: int, size: int, dtype: str) -> np.ndarray:
    """Return bytes ``[start, start + size)`` of every row as contiguous ``dtype`` values."""
    count = size // np.dtype(dtype).itemsize
    return np.ascontiguousarray(_field(block, start, dtype, (count,)))


def wire_block_to_cdr(cls: type[m.Message], block: np.ndarray) -> CdrBlock:
    """Check and convert ``block`` (``(N, size)`` uint8, one wire message of ``cls`` a row).

    A row is accepted exactly when ``cls.decode`` would accept it; the others are left out.
    Status (variable size) has no block form: use :func:`encode_cdr` on decoded messages.
    """
    if block.ndim != 2 or block.dtype != np.uint8:
        raise DataError("block must be a 2-d uint8 array")
    block = np.ascontiguousarray(block)
    rows, size = block.shape
    n = _joint_count_for_wire_size(cls, size)
    if n is None:
        return CdrBlock(
            cls,
            np.zeros(rows, dtype=bool),
            np.empty((0, 0), np.uint8),
            np.empty(0, np.uint32),
            np.empty(0, np.int64),
        )
    layout = _layout(cls, n)
    ok = _rows_match(block, layout.wire_template, layout.wire_constant)
    for wire_offset, count, nan in layout.floats:
        values = _columns(block, wire_offset, 8 * count, "<f8")
        good = ~np.isinf(values) if nan else np.isfinite(values)
        ok &= good.all(axis=1)
    if layout.mask is not None and n % 8:
        last = layout.mask[0] + (n + 7) // 8 - 1
        ok &= (block[:, last] >> (n % 8)) == 0
    good_rows = block if ok.all() else block[ok]
    out = np.empty((good_rows.shape[0], layout.cdr_size), dtype=np.uint8)
    out[:] = np.frombuffer(layout.cdr_template, dtype=np.uint8)
    for wire_offset, cdr_offset, length in layout.copies:
        out[:, cdr_offset : cdr_offset + length] = good_rows[:, wire_offset : wire_offset + length]
    if layout.mask is not None:
        wire_offset, cdr_offset, n = layout.mask
        bits = np.unpackbits(
            good_rows[:, wire_offset : wire_offset + (n + 7) // 8], axis=1, bitorder="little"
        )
        out[:, cdr_offset : cdr_offset + n] = bits[:, :n]
    return CdrBlock(
        cls,
        ok,
        out,
        _columns(good_rows, 4, 4, "<u4").reshape(-1),
        _columns(good_rows, 8, 8, "<i8").reshape(-1),
    )


def joint_state_columns(
    block: np.ndarray, offset: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split JointState CDR payloads into arrays; raise MessageError.

    ``block`` is ``(N, width)`` uint8, each row holding one payload at byte ``offset`` to its
    end (e.g. whole MCAP message records). Returns ``(seq uint32, t_ns int64, q_rad,
    qd_rad_s, effort_nm)``, the last three ``(N, n)`` float64. Every row is checked as
    :func:`decode_cdr` would (framing, finite numbers).
    """
    block = np.ascontiguousarray(block)
    size = block.shape[1] - offset
    n = _joint_count_for_cdr_size(m.JointState, size)
    if n is None:
        raise MessageError(f"JointState: {size} bytes is no CDR payload size of it")
    layout = _layout(m.JointState, n)
    bad = ~_rows_match(block, layout.cdr_template, layout.cdr_constant, offset)
    if bad.any():
        row = int(np.argmax(bad))
        raise MessageError(f"JointState: bad CDR header, padding or element count (row {row})")
    arrays = []
    for _wire_offset, cdr_offset, length in layout.copies[2:]:
        values = _columns(block, offset + cdr_offset, length, "<f8")
        finite = np.isfinite(values).all(axis=1)
        if not finite.all():
            row = int(np.argmin(finite))
            raise MessageError(f"JointState: non-finite q_rad, qd_rad_s or effort_nm (row {row})")
        arrays.append(values)
    seq = _columns(block, offset + layout.copies[0][1], 4, "<u4").reshape(-1)
    t_ns = _columns(block, offset + layout.copies[1][1], 8, "<i8").reshape(-1)
    return seq, t_ns, arrays[0], arrays[1], arrays[2]


__all__ = (
    "CDR_SCHEMAS",
    "ENCAPSULATION",
    "MESSAGE_CLASSES_BY_CDR_SCHEMA",
    "MESSAGE_ENCODING",
    "SCHEMA_ENCODING",
    "CdrBlock",
    "CdrSchema",
    "decode_cdr",
    "encode_cdr",
    "has_fixed_layout",
    "joint_state_columns",
    "wire_block_to_cdr",
)
