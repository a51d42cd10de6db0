"""Fixed-layout CDR for the 1 kHz messages: one ``struct`` call per message, checked by rosbags.

``rosbags`` serializes any message (:mod:`teleop_force.ros2.codec`), at 5-25 µs a message in
Python; at six 1 kHz topics that cost a quarter of a core per process and pushed the
slave -> estimate p99 past the 2 ms budget (BENCHMARKS.md, "ROS 2 on the wire"). The 1 kHz
messages have a layout fixed by their joint names, frame and joint count, so each is one
precomputed :class:`struct.Struct` over little-endian plain CDR (XCDR1: every primitive
aligned to its size from the end of the 4-byte encapsulation header; a string is a uint32
length counting its NUL, its bytes and the NUL; a sequence a uint32 count, then its
elements).

Encoders write exactly what ``rosbags`` writes (tested byte for byte, with its padding
zeroed). A decoder reads a payload only when its bytes match the layout (size, the names and
frame, the counts); any other payload (another driver's names, Fast CDR's uninitialised
padding makes no difference: padding is not compared) returns ``None``, and the caller falls
back to :mod:`teleop_force.ros2.codec`.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Final

_ENCAPSULATION: Final = b"\x00\x01\x00\x00"  # CDR_LE, no options
_NS_PER_S: Final = 1_000_000_000
_INT32_MIN: Final = -(2**31)
_INT32_MAX: Final = 2**31 - 1


class _Layout:
    """A struct format built field by field with CDR's alignment (offsets after the header)."""

    def __init__(self) -> None:
        self.fmt = ["<"]
        self.size = 0
        self.fixed: list[tuple[int, bytes]] = []  # (offset, bytes) that identify the layout

    def _align(self, n: int) -> None:
        pad = (-self.size) % n
        if pad:
            self.fmt.append(f"{pad}x")
            self.size += pad

    def primitive(self, code: str, count: int = 1) -> int:
        width = struct.calcsize("<" + code)
        self._align(width)
        offset = self.size
        self.fmt.append(f"{count}{code}" if count != 1 else code)
        self.size += width * count
        return offset

    def constant(self, data: bytes, align: int = 1) -> None:
        self._align(align)
        self.fixed.append((self.size, data))
        self.fmt.append(f"{len(data)}x")
        self.size += len(data)

    def string(self, text: str) -> None:
        raw = text.encode("utf-8") + b"\x00"
        self._align(4)
        self.constant(struct.pack("<I", len(raw)) + raw)

    def count(self, n: int) -> None:
        self._align(4)
        self.constant(struct.pack("<I", n))

    def header(self, frame_id: str) -> None:
        self.primitive("i")  # stamp.sec
        self.primitive("I")  # stamp.nanosec
        self.string(frame_id)

    def build(self) -> struct.Struct:
        return struct.Struct("".join(self.fmt))


def _stamp(t_ns: int) -> tuple[int, int]:
    sec, nanosec = divmod(int(t_ns), _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise OverflowError(f"stamp {t_ns} ns does not fit builtin_interfaces/Time")
    return sec, nanosec


class _Message:
    """One fixed layout: pack values into a payload, unpack a payload that matches it."""

    def __init__(self, layout: _Layout) -> None:
        self._struct = layout.build()
        self._fixed = tuple((4 + offset, data) for offset, data in layout.fixed)
        self.size = 4 + self._struct.size
        template = bytearray(_ENCAPSULATION + bytes(self._struct.size))
        for offset, data in self._fixed:
            template[offset : offset + len(data)] = data
        self._template = bytes(template)

    def pack(self, *values: float | int) -> bytes:
        out = bytearray(self._template)
        self._struct.pack_into(out, 4, *values)
        for offset, data in self._fixed:  # pack_into zeroes the pad bytes it skips
            out[offset : offset + len(data)] = data
        return bytes(out)

    def unpack(self, payload: bytes) -> tuple[float | int, ...] | None:
        if len(payload) != self.size or payload[:2] != b"\x00\x01":
            return None
        for offset, data in self._fixed:
            if payload[offset : offset + len(data)] != data:
                return None
        return self._struct.unpack_from(payload, 4)


class JointStateLayout:
    """``sensor_msgs/msg/JointState`` of fixed names and frame; positions, velocities, efforts.

    ``velocities`` / ``efforts``: whether those arrays are there (one per name) or empty (a
    setpoint, a driver without velocity).
    """

    def __init__(
        self, names: Sequence[str], frame_id: str = "", *, velocities: bool = True,
        efforts: bool = True,
    ) -> None:  # fmt: skip
        """Precompute the layout."""
        n = len(names)
        layout = _Layout()
        layout.header(frame_id)
        layout.count(n)
        for name in names:
            layout.string(name)
        self.n = n
        self._counts = (n, n if velocities else 0, n if efforts else 0)
        for k in self._counts:
            layout.count(k)
            if k:
                layout.primitive("d", k)
        self._message = _Message(layout)

    def pack(
        self,
        t_ns: int,
        q_rad: Sequence[float],
        qd_rad_s: Sequence[float] = (),
        effort_nm: Sequence[float] = (),
    ) -> bytes:
        """Return the payload (the arrays' lengths must match the layout)."""
        return self._message.pack(*_stamp(t_ns), *q_rad, *qd_rad_s, *effort_nm)

    def unpack(
        self, payload: bytes
    ) -> tuple[int, tuple[float, ...], tuple[float, ...], tuple[float, ...]] | None:
        """Return ``(t_ns, q, qd, effort)``, or None when the payload has another layout."""
        values = self._message.unpack(payload)
        if values is None:
            return None
        t_ns = int(values[0]) * _NS_PER_S + int(values[1])
        n_q, n_v, _ = self._counts
        floats = values[2:]
        return (
            t_ns,
            tuple(floats[:n_q]),
            tuple(floats[n_q : n_q + n_v]),
            tuple(floats[n_q + n_v :]),
        )


class WrenchLayout:
    """``geometry_msgs/msg/WrenchStamped`` of a fixed frame (torque zero when packing)."""

    def __init__(self, frame_id: str) -> None:
        """Precompute the layout."""
        layout = _Layout()
        layout.header(frame_id)
        layout.primitive("d", 6)
        self._message = _Message(layout)

    def pack(self, t_ns: int, force_n: Sequence[float]) -> bytes:
        """Return the payload: force [N], torque zero."""
        fx, fy, fz = force_n
        return self._message.pack(*_stamp(t_ns), fx, fy, fz, 0.0, 0.0, 0.0)

    def unpack(
        self, payload: bytes
    ) -> tuple[int, tuple[float, float, float], tuple[float, float, float]] | None:
        """Return ``(t_ns, force, torque)``, or None when the payload has another layout."""
        values = self._message.unpack(payload)
        if values is None:
            return None
        t_ns = int(values[0]) * _NS_PER_S + int(values[1])
        return t_ns, tuple(values[2:5]), tuple(values[5:8])  # type: ignore[return-value]


class EstimateDiagnosticsLayout:
    """``teleop_force_msgs/msg/EstimateDiagnostics`` of fixed names and frame."""

    def __init__(self, names: Sequence[str], frame_id: str) -> None:
        """Precompute the layout."""
        n = len(names)
        layout = _Layout()
        layout.header(frame_id)
        layout.primitive("q")  # source_sequence
        layout.count(n)
        for name in names:
            layout.string(name)
        for code in ("d", "d", "?", "d", "d"):  # tau_ext, coverage, on_ground, motor, model
            layout.count(n)
            layout.primitive(code, n)
        self.n = n
        self._message = _Message(layout)

    def pack(
        self,
        t_ns: int,
        source_sequence: int,
        tau_ext_nm: Sequence[float],
        coverage_weight: Sequence[float],
        on_trained_ground: Sequence[bool],
        tau_motor_filtered_nm: Sequence[float],
        tau_model_filtered_nm: Sequence[float],
    ) -> bytes:
        """Return the payload."""
        return self._message.pack(
            *_stamp(t_ns), int(source_sequence), *tau_ext_nm, *coverage_weight,
            *(bool(x) for x in on_trained_ground), *tau_motor_filtered_nm,
            *tau_model_filtered_nm,
        )  # fmt: skip

    def unpack(
        self, payload: bytes
    ) -> tuple[int, int, tuple[tuple[float, ...], ...], tuple[bool, ...]] | None:
        """Return ``(t_ns, source_sequence, (tau_ext, coverage, motor, model), on_ground)``.

        None when the payload has another layout.
        """
        values = self._message.unpack(payload)
        if values is None:
            return None
        n = self.n
        rest = values[3:]
        floats = (rest[:n], rest[n : 2 * n], rest[3 * n : 4 * n], rest[4 * n :])
        on_ground = tuple(bool(x) for x in rest[2 * n : 3 * n])
        t_ns = int(values[0]) * _NS_PER_S + int(values[1])
        return t_ns, int(values[2]), floats, on_ground
