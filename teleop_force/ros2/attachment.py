"""rmw_zenoh's per-sample attachment: sequence number, source timestamp and publisher GID.

33 bytes, as ``AttachmentData::serialize_to_zbytes`` writes them with zenoh's serializer
(rmw_zenoh >= Jazzy 0.2.4, Rolling 0.6.0, Humble 0.1.2; older releases used string keys):

| offset | type      | field                                                   |
|-------:|-----------|---------------------------------------------------------|
| 0      | int64 LE  | sequence number, 1 for a publisher's first sample       |
| 8      | int64 LE  | source timestamp, ns since the UNIX epoch (system clock) |
| 16     | uint8     | GID length, always 16 (zenoh's LEB128 sequence length)  |
| 17     | uint8[16] | publisher GID                                           |

A gap in the sequence number is a loss; ``receive time - source timestamp`` is the latency,
meaningful across hosts only with synchronised clocks.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

from teleop_force.errors import MessageError
from teleop_force.ros2.graph import GID_SIZE

ATTACHMENT_SIZE: Final = 33
_LAYOUT: Final = struct.Struct("<qqB16s")
_INT64_MIN: Final = -(2**63)
_INT64_MAX: Final = 2**63 - 1


@dataclass(frozen=True, slots=True)
class Attachment:
    """One sample's attachment: ``sequence_number``, ``source_timestamp_ns``, ``gid``."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def __post_init__(self) -> None:
        """Check the int64 ranges and the GID's length; raise MessageError."""
        for name in ("sequence_number", "source_timestamp_ns"):
            value = getattr(self, name)
            if not isinstance(value, int) or not _INT64_MIN <= value <= _INT64_MAX:
                raise MessageError(f"{name} {value!r} is not an int64")
        if not isinstance(self.gid, bytes) or len(self.gid) != GID_SIZE:
            raise MessageError(f"gid must be {GID_SIZE} bytes, got {self.gid!r}")

    def encode(self) -> bytes:
        """Return the 33 bytes of the module docstring."""
        return _LAYOUT.pack(self.sequence_number, self.source_timestamp_ns, GID_SIZE, self.gid)

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Attachment:
        """Parse exactly 33 bytes with a GID length of 16; raise MessageError otherwise."""
        if len(data) != ATTACHMENT_SIZE:
            raise MessageError(f"attachment is {len(data)} bytes, expected {ATTACHMENT_SIZE}")
        seq, stamp, length, gid = _LAYOUT.unpack(data)
        if length != GID_SIZE:
            raise MessageError(f"attachment GID length is {length}, expected {GID_SIZE}")
        return cls(seq, stamp, gid)
