"""Columnar reading of ROS 2 CDR payloads: a block of same-size messages split into arrays.

A ``sensor_msgs/msg/JointState`` or ``geometry_msgs/msg/WrenchStamped`` payload has a variable
layout (strings, sequences), but a publisher whose frame and joint names do not change writes
every message with the same layout. :func:`joint_state_columns` and :func:`wrench_columns`
take ``(N, width)`` rows of same-size payloads, find the layout from the first row, check that
every row has that layout (all its length words equal the first row's: the layout follows from
them), and read the fields as numpy columns, with the checks of :mod:`teleop_force.ros2.codec`
(equal array lengths, finite numbers). :class:`LayoutMismatch` means the rows do not share one
layout (or are big-endian): the caller decodes them one by one with the codec.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

import numpy as np

from teleop_force.errors import MessageError, TeleopForceError

_LE_HEADERS: Final = (b"\x00\x01",)  # plain CDR, little-endian (what every ROS 2 rmw writes)
_NS_PER_S: Final = 1_000_000_000
_U32: Final = struct.Struct("<I")


class LayoutMismatch(TeleopForceError):  # noqa: N818 - a signal to fall back, not a fault
    """The rows do not share one little-endian layout: decode them one by one."""


@dataclass(frozen=True)
class JointStateColumns:
    """JointState fields of N rows: stamp [ns] and ``(N, n)`` position, velocity, effort."""

    t_ns: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


@dataclass(frozen=True)
class WrenchColumns:
    """WrenchStamped fields of N rows: stamp [ns], ``(N, 3)`` force [N] and torque [N m]."""

    t_ns: np.ndarray
    force: np.ndarray
    torque: np.ndarray


class _Layout:
    """Walk the first row of a CDR body, remembering where every length word is."""

    def __init__(self, row: bytes) -> None:
        if row[:2] not in _LE_HEADERS:
            raise LayoutMismatch("not little-endian plain CDR")
        self.body = row[4:]
        self.pos = 0
        self.length_words: list[int] = []  # offsets in the body

    def align(self, n: int) -> None:
        self.pos += -self.pos % n

    def u32(self, *, length: bool) -> int:
        self.align(4)
        if self.pos + 4 > len(self.body):
            raise LayoutMismatch("payload too short")
        (value,) = _U32.unpack_from(self.body, self.pos)
        if length:
            self.length_words.append(self.pos)
        self.pos += 4
        return int(value)

    def string(self) -> None:
        n = self.u32(length=True)
        self.pos += n
        if self.pos > len(self.body):
            raise LayoutMismatch("string past the end")

    def header(self) -> int:
        """Skip a std_msgs/Header; return the body offset of its stamp."""
        self.align(4)
        stamp = self.pos
        self.pos += 8
        self.string()
        return stamp

    def scalar(self, size: int) -> int:
        """Skip an aligned scalar of ``size`` bytes; return its offset."""
        self.align(size)
        offset = self.pos
        self.pos += size
        return offset

    def bools(self) -> tuple[int, int]:
        """Skip a ``bool[]``; return (offset, count)."""
        count = self.u32(length=True)
        offset = self.pos
        self.pos += count
        if self.pos > len(self.body):
            raise LayoutMismatch("array past the end")
        return offset, count

    def doubles(self, count: int | None = None) -> tuple[int, int]:
        """Skip a ``float64[]`` (``count`` None) or ``float64[count]``; return (offset, count)."""
        if count is None:
            count = self.u32(length=True)
        self.align(8)
        offset = self.pos
        self.pos += 8 * count
        if self.pos > len(self.body):
            raise LayoutMismatch("array past the end")
        return offset, count


def _check_rows(block: np.ndarray, layout: _Layout) -> None:
    """Raise LayoutMismatch unless every row has the first row's header and length words."""
    head = block[:, :4]
    if not (head == head[0]).all():
        raise LayoutMismatch("encapsulation headers differ")
    for pos in layout.length_words:
        words = block[:, 4 + pos : 8 + pos]
        if not (words == words[0]).all():
            raise LayoutMismatch("layouts differ")


def _f8(block: np.ndarray, offset: int, count: int) -> np.ndarray:
    start = 4 + offset
    raw = np.ascontiguousarray(block[:, start : start + 8 * count])
    return raw.view("<f8").reshape(block.shape[0], count).astype(np.float64)


def _stamps(block: np.ndarray, offset: int) -> np.ndarray:
    start = 4 + offset
    sec = np.ascontiguousarray(block[:, start : start + 4]).view("<i4").reshape(-1)
    nanosec = np.ascontiguousarray(block[:, start + 4 : start + 8]).view("<u4").reshape(-1)
    return sec.astype(np.int64) * _NS_PER_S + nanosec.astype(np.int64)


def joint_state_columns(block: np.ndarray) -> JointStateColumns:
    """Split ``(N, width)`` JointState payloads into columns (module docstring).

    Raise LayoutMismatch (decode one by one) or MessageError (a row the codec would refuse:
    array lengths that differ, a name count other than 0 or n).
    """
    if block.ndim != 2 or block.shape[0] == 0:
        raise LayoutMismatch("no rows")
    layout = _Layout(bytes(block[0]))
    stamp = layout.header()
    names = layout.u32(length=True)
    for _ in range(names):
        layout.string()
    position = layout.doubles()
    velocity = layout.doubles()
    effort = layout.doubles()
    _check_rows(block, layout)
    n = position[1]
    if velocity[1] != n or effort[1] != n or names not in (0, n):
        raise MessageError(
            f"JointState has {names} names, {n} positions, {velocity[1]} velocities and "
            f"{effort[1]} efforts; expected equal counts"
        )
    return JointStateColumns(
        _stamps(block, stamp), _f8(block, *position), _f8(block, *velocity), _f8(block, *effort)
    )


def wrench_columns(block: np.ndarray) -> WrenchColumns:
    """Split ``(N, width)`` WrenchStamped payloads into columns (module docstring)."""
    if block.ndim != 2 or block.shape[0] == 0:
        raise LayoutMismatch("no rows")
    layout = _Layout(bytes(block[0]))
    stamp = layout.header()
    force = layout.doubles(3)
    torque = layout.doubles(3)
    _check_rows(block, layout)
    return WrenchColumns(_stamps(block, stamp), _f8(block, *force), _f8(block, *torque))


def _put(block: np.ndarray, offset: int, values: np.ndarray, dtype: str) -> None:
    raw = np.ascontiguousarray(values, dtype=dtype).view(np.uint8).reshape(block.shape[0], -1)
    block[:, 4 + offset : 4 + offset + raw.shape[1]] = raw


def _put_stamps(block: np.ndarray, offset: int, t_ns: np.ndarray) -> None:
    sec, nanosec = np.divmod(np.asarray(t_ns, dtype=np.int64), _NS_PER_S)
    if sec.size and (int(sec.min()) < -(2**31) or int(sec.max()) >= 2**31):
        raise MessageError("a stamp does not fit builtin_interfaces/Time (int32 s)")
    _put(block, offset, sec, "<i4")
    _put(block, offset + 4, nanosec, "<u4")


@dataclass(frozen=True)
class EstimateRows:
    """K estimates to encode: stamps [ns], source sequence numbers and ``(K, ·)`` values."""

    t_ns: np.ndarray
    source_sequence: np.ndarray
    force_n: np.ndarray
    tau_ext_nm: np.ndarray
    coverage_weight: np.ndarray
    on_trained_ground: np.ndarray
    tau_motor_filtered_nm: np.ndarray
    tau_model_filtered_nm: np.ndarray


def estimate_blocks(
    wrench_template: bytes, diagnostics_template: bytes, rows: EstimateRows
) -> tuple[np.ndarray, np.ndarray]:
    """Return the ``(K, size)`` WrenchStamped and EstimateDiagnostics payloads of ``rows``.

    The templates are one estimate of the same joint names and frame, encoded by
    :func:`teleop_force.ros2.codec.encode_estimate`: every row is a copy with its stamp and
    values written where the template has them, so it is the codec's bytes for that row.
    """
    k = rows.t_ns.shape[0]
    wrench = _Layout(wrench_template)
    w_stamp = wrench.header()
    force = wrench.doubles(3)
    diag = _Layout(diagnostics_template)
    d_stamp = diag.header()
    source = diag.scalar(8)
    for _ in range(diag.u32(length=True)):
        diag.string()
    ext, coverage = diag.doubles(), diag.doubles()
    ground = diag.bools()
    motor, model = diag.doubles(), diag.doubles()
    n = rows.tau_ext_nm.shape[1]
    if any(count != n for count in (ext[1], coverage[1], ground[1], motor[1], model[1])):
        raise MessageError(f"the template has {ext[1]} joints, the rows {n}")
    w_block = np.tile(np.frombuffer(wrench_template, dtype=np.uint8), (k, 1))
    d_block = np.tile(np.frombuffer(diagnostics_template, dtype=np.uint8), (k, 1))
    _put_stamps(w_block, w_stamp, rows.t_ns)
    _put(w_block, force[0], rows.force_n, "<f8")
    _put_stamps(d_block, d_stamp, rows.t_ns)
    _put(d_block, source, rows.source_sequence, "<i8")
    _put(d_block, ext[0], rows.tau_ext_nm, "<f8")
    _put(d_block, coverage[0], rows.coverage_weight, "<f8")
    _put(d_block, ground[0], rows.on_trained_ground, "u1")
    _put(d_block, motor[0], rows.tau_motor_filtered_nm, "<f8")
    _put(d_block, model[0], rows.tau_model_filtered_nm, "<f8")
    return w_block, d_block


__all__ = (
    "EstimateRows",
    "JointStateColumns",
    "LayoutMismatch",
    "WrenchColumns",
    "estimate_blocks",
    "joint_state_columns",
    "wrench_columns",
)
