"""Hypothesis strategies mutating valid inputs: bytes, text lines and tokens, JSON structure."""

from __future__ import annotations

import copy
import json
import re
from typing import Any

from hypothesis import strategies as st

INTERESTING_NUMBERS: list[Any] = [
    0, -1, 1, 3, 255, 256, 2**31, 2**32, 2**63, -(2**63), 10**30, -(10**30), 1e308, -1e308,
    5e-324, 1e-300, float("nan"), float("inf"), float("-inf"), 0.5, -0.0,
]  # fmt: skip
INTERESTING_TOKENS = [
    "nan", "NaN", "inf", "-inf", "Infinity", "1e999", "-1e999", "", "-0", "0x1f", "1_0", "٣",
    "true", "null", '"', "[", "]", "{", "}", "=", ",", ":", "\x00", "9" * 400, "1e-400", "-",
    "+", ".", "e5", "\t", "\r", "\ufeff", "'", "<", ">", "/>", "</robot>", "&amp;", "#",
]  # fmt: skip
INTERESTING_BYTES = [
    b"\x00", b"\xff", b"\x7f", b"\x80", b"\xff\xff\xff\xff", b"\x00\x00\x00\x80",
    b"\xff\xff\xff\xff\xff\xff\xff\x7f", b"\x00\x00\x00\x00\x00\x00\xf8\x7f",  # NaN
    b"\x00\x00\x00\x00\x00\x00\xf0\x7f",  # +inf
    b"\x89MCAP0\r\n", b"TF\x01",
]  # fmt: skip

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12)
    | st.sampled_from(INTERESTING_NUMBERS),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4)
    ),
    max_leaves=8,
)


@st.composite
def mutate_bytes(draw: st.DrawFn, data: bytes, max_ops: int = 6) -> bytes:
    """Apply 1..max_ops byte-level mutations to ``data``."""
    buf = bytearray(data)
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(
            st.sampled_from(
                ["flip", "set", "truncate", "insert", "delete", "duplicate", "interesting"]
            )
        )
        n = len(buf)
        if op == "truncate":
            del buf[draw(st.integers(0, n)) :]
        elif op == "insert":
            i = draw(st.integers(0, n))
            buf[i:i] = draw(st.binary(min_size=1, max_size=16))
        elif n == 0:
            continue
        elif op == "delete":
            i = draw(st.integers(0, n - 1))
            del buf[i : i + draw(st.integers(1, 64))]
        elif op == "duplicate":
            i = draw(st.integers(0, n - 1))
            piece = buf[i : i + draw(st.integers(1, 256))]
            j = draw(st.integers(0, n))
            buf[j:j] = piece
        elif op == "interesting":
            i = draw(st.integers(0, n - 1))
            piece = draw(st.sampled_from(INTERESTING_BYTES))
            buf[i : i + len(piece)] = piece
        else:
            i = draw(st.integers(0, n - 1))
            if op == "flip":
                buf[i] ^= 1 << draw(st.integers(0, 7))
            else:
                buf[i] = draw(st.integers(0, 255))
    return bytes(buf)


_TOKEN = re.compile(rb"[^\s,=:\[\]{}<>\"']+")


@st.composite
def mutate_text(draw: st.DrawFn, data: bytes, max_ops: int = 4) -> bytes:
    """Mutate lines and tokens of a text file (CSV, TOML, XML), sometimes bytes too."""
    lines = data.split(b"\n")
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(st.sampled_from(["token", "token", "token", "delete", "duplicate", "swap"]))
        if not lines:
            break
        i = draw(st.integers(0, len(lines) - 1))
        if op == "delete":
            del lines[i]
        elif op == "duplicate":
            lines.insert(draw(st.integers(0, len(lines))), lines[i])
        elif op == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        else:
            tokens = list(_TOKEN.finditer(lines[i]))
            if not tokens:
                continue
            token = tokens[draw(st.integers(0, len(tokens) - 1))]
            new = draw(
                st.sampled_from(INTERESTING_TOKENS).map(lambda s: s.encode("utf-8"))
                | st.text(max_size=6).map(lambda s: s.encode("utf-8", "surrogatepass"))
            )
            lines[i] = lines[i][: token.start()] + new + lines[i][token.end() :]
    text = b"\n".join(lines)
    if draw(st.integers(0, 3)) == 0:
        text = draw(mutate_bytes(text, max_ops=2))
    return text


def _paths(value: Any, prefix: tuple = (), depth: int = 0) -> list[tuple]:
    out = [prefix]
    if depth > 6:
        return out
    if isinstance(value, dict):
        for key, child in value.items():
            out += _paths(child, (*prefix, key), depth + 1)
    elif isinstance(value, list):
        # Long numeric lists: a few positions are enough.
        indices = range(len(value)) if len(value) <= 8 else (0, 1, len(value) // 2, len(value) - 1)
        for i in indices:
            out += _paths(value[i], (*prefix, i), depth + 1)
    return out


def _parent(root: Any, path: tuple) -> Any:
    node = root
    for key in path[:-1]:
        node = node[key]
    return node


@st.composite
def mutate_json(draw: st.DrawFn, seed: Any, max_ops: int = 3) -> bytes:
    """Mutate the structure of a JSON document: replace, delete, add, duplicate, wrap values."""
    doc = copy.deepcopy(seed)
    for _ in range(draw(st.integers(1, max_ops))):
        paths = [p for p in _paths(doc) if p]
        if not paths:
            doc = draw(json_values)
            break
        path = draw(st.sampled_from(paths))
        parent = _parent(doc, path)
        key = path[-1]
        op = draw(st.sampled_from(["replace", "replace", "number", "delete", "add", "wrap", "dup"]))
        if op == "replace":
            parent[key] = draw(json_values)
        elif op == "number":
            parent[key] = draw(st.sampled_from(INTERESTING_NUMBERS))
        elif op == "delete":
            del parent[key]
        elif op == "add" and isinstance(parent[key], dict):
            parent[key][draw(st.text(max_size=8))] = draw(json_values)
        elif op == "add" and isinstance(parent[key], list):
            parent[key].insert(draw(st.integers(0, len(parent[key]))), draw(json_values))
        elif op == "wrap":
            parent[key] = [parent[key]]
        elif op == "dup" and isinstance(parent[key], list) and parent[key]:
            parent[key] = parent[key] + parent[key][:1]
        else:
            parent[key] = draw(json_values)
    text = json.dumps(doc).encode("utf-8")
    if draw(st.integers(0, 5)) == 0:
        text = draw(mutate_bytes(text, max_ops=2))
    return text
