"""An independent ROS 2 CDR decoder for the tests, written from the specification.

It parses a ``ros2msg`` schema text (``type name`` lines, ``#`` comments, ``TYPE NAME=value``
constants) and decodes a payload field by field: a 4-byte encapsulation header (``00 01``:
CDR little endian), then each primitive aligned to its size counted from the end of that
header, ``T[]`` as a uint32 count and the elements, ``T[N]`` as N elements, ``string`` as a
uint32 length including a NUL, the bytes, the NUL. It shares no code with
``teleop_force.io.cdr_messages`` and also returns the offset (after the header) of every field,
so tests can check alignment directly.
"""

from __future__ import annotations

import re
import struct

PRIMITIVES = {
    "bool": "?",
    "uint8": "B",
    "int8": "b",
    "uint16": "H",
    "int16": "h",
    "uint32": "I",
    "int32": "i",
    "uint64": "Q",
    "int64": "q",
    "float32": "f",
    "float64": "d",
}
FIELD = re.compile(
    r"^(?P<type>[a-z0-9]+)(?P<array>\[(?P<size>\d*)\])?\s+(?P<name>[a-z][a-z0-9_]*)$"
)


def parse_schema(text: str) -> list[tuple[str, str, int | None]]:
    """``(type, name, array size)`` per field; size None: scalar, -1: sequence."""
    fields = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or "=" in line:  # blank, comment or constant
            continue
        match = FIELD.match(line)
        assert match, f"cannot parse schema line {raw!r}"
        array = match["array"]
        size = None if array is None else (-1 if match["size"] == "" else int(match["size"]))
        fields.append((match["type"], match["name"], size))
    return fields


class Reader:
    """Read CDR values with alignment counted after the 4-byte header."""

    def __init__(self, data: bytes) -> None:
        assert data[:2] == b"\x00\x01", f"not CDR little endian: {data[:4]!r}"
        assert data[2:4] == b"\x00\x00", "options must be zero"
        self.data = data
        self.pos = 4

    def align(self, size: int) -> None:
        padding = -(self.pos - 4) % size
        assert self.data[self.pos : self.pos + padding] == bytes(padding), "non-zero padding"
        self.pos += padding

    def primitive(self, kind: str):
        code = PRIMITIVES[kind]
        size = struct.calcsize(code)
        self.align(size)
        (value,) = struct.unpack_from("<" + code, self.data, self.pos)
        if kind == "bool":
            assert self.data[self.pos] in (0, 1), "bool neither 0 nor 1"
        self.pos += size
        return value

    def string(self) -> str:
        length = self.primitive("uint32")
        raw = self.data[self.pos : self.pos + length]
        assert len(raw) == length and raw.endswith(b"\0"), "string without its NUL"
        self.pos += length
        return raw[:-1].decode("utf-8")


def decode(schema_text: str, data: bytes) -> tuple[dict, dict]:
    """Decode ``data``; return ``(values by field, offset after the header by field)``."""
    reader = Reader(data)
    values, offsets = {}, {}
    for kind, name, size in parse_schema(schema_text):
        if kind == "string":
            reader.align(4)
            offsets[name] = reader.pos - 4
            values[name] = reader.string()
            continue
        if size is None:
            reader.align(struct.calcsize(PRIMITIVES[kind]))
            offsets[name] = reader.pos - 4
            values[name] = reader.primitive(kind)
            continue
        count = size
        if size == -1:
            count = reader.primitive("uint32")
        if count:
            reader.align(struct.calcsize(PRIMITIVES[kind]))
        offsets[name] = reader.pos - 4
        values[name] = [reader.primitive(kind) for _ in range(count)]
    assert reader.pos == len(data), f"{len(data) - reader.pos} bytes left after the last field"
    return values, offsets


def normalised(values: dict) -> dict:
    """``values`` with NaN replaced by the string ``"nan"`` (so == compares them)."""

    def fix(x):
        if isinstance(x, list):
            return [fix(v) for v in x]
        return "nan" if isinstance(x, float) and x != x else x

    return {k: fix(v) for k, v in values.items()}
