"""Typed reading of parsed JSON / TOML files: msgspec schemas, errors that name the field.

A file format is declared as :class:`msgspec.Struct` classes (types, defaults, ranges through
:class:`msgspec.Meta`, cross-field checks in ``__post_init__``); :func:`read_entry` converts
the parsed value into them. Every problem becomes one :class:`~teleop_force.errors.ModelFileError`
whose ``column`` is the field's path (``friction.joints[0].m_min``) and whose problem is one
line in the project's words (``missing``, ``expected a number, got 'down'``, ``must be finite,
got nan``), never a raw msgspec exception.

A ``__post_init__`` (or a ``dec_hook`` building a custom type) raises ModelFileError with a
``column`` relative to its own entry: the path of the entry is put in front of it.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Mapping
from typing import Annotated, Any, TypeVar

import msgspec
import msgspec.inspect as mi

from teleop_force.errors import ModelFileError

T = TypeVar("T")

#: A finite float (NaN and infinities fail; an integer beyond float64 too).
Finite = Annotated[float, msgspec.Meta(ge=-sys.float_info.max, le=sys.float_info.max)]
#: A string of at least one character.
NonEmptyStr = Annotated[str, msgspec.Meta(min_length=1)]

_AT = re.compile(r"(?P<message>.*?)(?: - at `\$(?P<path>[^`]*)`)?", re.S)
_STEP = re.compile(r"\.([^.\[]+)|\[(\d+|\.\.\.)\]")
_NOUNS = {
    "object": "an object",
    "array": "a list",
    "str": "a string",
    "int": "an integer",
    "float": "a number",
    "bool": "true or false",
    "null": "null",
}
_ABSENT = object()


def read_entry(
    data: object, schema: type[T], *, dec_hook: Callable[[type, Any], Any] | None = None
) -> T:
    """Convert ``data`` (a parsed JSON / TOML value) to ``schema``; errors name the field."""
    try:
        return msgspec.convert(data, schema, dec_hook=dec_hook)
    except msgspec.ValidationError as exc:
        raise _file_error(exc, data, schema) from None


def built_by(
    builders: Mapping[type, Callable[[Any], Any]] | None = None,
) -> Callable[[type, Any], Any]:
    """Return a msgspec ``dec_hook`` building each custom type with its reader.

    The reader is ``builders[type]``, else the type's ``from_dict``; its ModelFileError keeps
    its field (below the entry's path), a numeric or lookup failure becomes one.
    """

    def build(kind: type, value: Any) -> Any:
        reader = (builders or {}).get(kind) or getattr(kind, "from_dict", None)
        if reader is None:
            raise TypeError(f"no reader for {kind.__name__}")
        try:
            return reader(value)
        except (ArithmeticError, LookupError) as exc:
            raise ModelFileError(f"bad value: {exc}") from None

    return build


def join_column(outer: str | None, inner: str | None) -> str | None:
    """``outer`` and ``inner`` field paths as one (``joints[0]`` + ``mu``, ``a`` + ``[2]``)."""
    if not outer or not inner:
        return outer or inner
    return f"{outer}{inner}" if inner.startswith("[") else f"{outer}.{inner}"


def shown(value: object) -> str:
    """``repr`` of a field's value, short (a huge int or long string cannot flood a message)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**30:
        digits = len(str(abs(value))) if abs(value) < 10**4000 else "> 4000"
        return f"an integer of {digits} digits"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _steps(path: str) -> list[str | int | None]:
    """Split a msgspec path: field names, list indices, None for a dict key (``[...]``)."""
    out: list[str | int | None] = []
    for name, index in _STEP.findall(path):
        out.append(name if name else (None if index == "..." else int(index)))
    return out


def _value_at(data: object, steps: list[str | int | None]) -> object:
    for step in steps:
        if isinstance(step, str) and isinstance(data, dict) and step in data:
            data = data[step]
            continue
        if not (isinstance(step, int) and isinstance(data, list) and step < len(data)):
            return _ABSENT
        data = data[step]
    return data


def _type_at(schema: type, steps: list[str | int | None]) -> mi.Type | None:
    """Find the msgspec type at ``steps`` inside ``schema`` (None where it cannot tell)."""
    kind: mi.Type | None = mi.type_info(schema)
    for step in steps:
        kind = _unwrap(kind, step)
        if isinstance(kind, mi.StructType) and isinstance(step, str):
            kind = next((f.type for f in kind.fields if f.encode_name == step), None)
        elif isinstance(kind, mi.ListType | mi.VarTupleType | mi.SetType):
            kind = kind.item_type
        elif isinstance(kind, mi.TupleType) and isinstance(step, int):
            kind = kind.item_types[step] if step < len(kind.item_types) else None
        elif isinstance(kind, mi.DictType):
            kind = kind.value_type
        else:
            return None
    return _unwrap(kind, None)


def _unwrap(kind: mi.Type | None, step: str | int | None) -> mi.Type | None:
    """Pick the member of a union a step can enter (the struct with that field, else any)."""
    while isinstance(kind, mi.Metadata):
        kind = kind.type
    if not isinstance(kind, mi.UnionType):
        return kind
    members = [t for t in kind.types if not isinstance(t, mi.NoneType)]
    for member in members:
        if isinstance(member, mi.StructType) and any(f.encode_name == step for f in member.fields):
            return member
    return members[0] if len(members) == 1 or not isinstance(step, str) else None


def _noun(names: str) -> str:
    return " or ".join(_NOUNS.get(name, name) for name in names.split(" | "))


def _file_error(exc: msgspec.ValidationError, data: object, schema: type) -> ModelFileError:
    """Turn a msgspec ValidationError of ``data`` into the project's ModelFileError."""
    found = _AT.fullmatch(str(exc))
    message = found.group("message") if found else str(exc)
    path = (found.group("path") if found else None) or ""
    column = path.lstrip(".") or None
    steps = _steps(path)
    cause = exc.__cause__
    if isinstance(cause, ModelFileError):  # a __post_init__ or a dec_hook naming its own field
        return ModelFileError(
            cause.problem, row=cause.row, column=join_column(column, cause.column)
        )
    if cause is not None:  # another ValueError / TypeError of a __post_init__ or dec_hook
        return ModelFileError(str(cause), column=column)
    value = _value_at(data, steps)
    got = "" if value is _ABSENT else f", got {shown(value)}"
    if match := re.fullmatch(r"Object (missing required|contains unknown) field `(.+)`", message):
        name = match.group(2)
        if match.group(1) == "missing required":
            return ModelFileError("missing", column=join_column(column, name))
        kind = _type_at(schema, steps)
        names = [f.encode_name for f in kind.fields] if isinstance(kind, mi.StructType) else []
        allowed = f" (allowed: {', '.join(sorted(names))})" if names else ""
        return ModelFileError(f"unknown key{allowed}", column=join_column(column, name))
    if message.startswith(("Invalid enum value", "Invalid value")):
        kind = _type_at(schema, steps)
        if isinstance(kind, mi.LiteralType):
            choices = " or ".join(repr(v) for v in kind.values)
            return ModelFileError(f"expected {choices}{got}", column=column)
        return ModelFileError(f"unknown value{got}", column=column)
    if message == "Number out of range" or re.fullmatch(
        r"Expected `float` [<>]=? -?1\.7976931348623157e\+308", message
    ):
        return ModelFileError(f"must be a finite number{got}", column=column)
    if match := re.fullmatch(r"Expected `([^`]+)`, got `([^`]+)`", message):
        got = got or f", got {_noun(match.group(2))}"
        return ModelFileError(f"expected {_noun(match.group(1))}{got}", column=column)
    if match := re.fullmatch(r"Expected `([^`]+)`(.*)", message):  # a range or a length
        rest = match.group(2) if ", got " in match.group(2) else match.group(2) + got
        return ModelFileError(f"expected {_noun(match.group(1))}{rest}", column=column)
    return ModelFileError(message.replace("`", "'"), column=column)
