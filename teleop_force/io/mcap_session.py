"""Recorded sessions: MCAP files with one JSON channel per Zenoh key, readable by Foxglove.

Layout of a session file:

- one channel per Zenoh key (``omni/<device>/measured_js`` ...), message encoding ``json``,
  with a ``jsonschema`` schema per message class (``teleop_force.JointState`` ...) so
  Foxglove shows and plots every field;
- MCAP ``log_time`` = when the recorder got the message, ``publish_time`` = the message's
  own source stamp ``t_ns``, MCAP ``sequence`` = the message's ``seq``;
- a metadata record ``teleop_force.session`` with the writer's key/value metadata.

Crash safety: data is written in zstd-compressed chunks (at most 1 MiB uncompressed by
default) straight to the operating system (no user-space buffer), and a chunk is closed at
least every ``flush_interval_s``, so a recorder killed with SIGKILL leaves a file whose
complete chunks are all readable: it loses at most the last ``flush_interval_s`` of data.
The writer keeps one chunk index per chunk in memory until the summary is written at close
(about 0.7 kB each): with 128 KiB chunks the demo's recording (1 MB/s uncompressed) made 4770
chunks in 10 minutes, 3.3 MB of indexes; with 1 MiB chunks the 0.5 s flush closes them
first (1193 chunks of 552 kB on average, 0.9 MB of indexes): the same loss bound.
:class:`SessionReader` reads such a truncated file (no summary or footer) as well as a
complete one.
"""

from __future__ import annotations

import heapq
import io
import json
import os
import struct
import threading
import time
import zlib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Final, Self

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from teleop_force.errors import ConfigurationError, DataError, MessageError, TeleopForceError
from teleop_force.io.interchange_csv import Recording
from teleop_force.transport import keys
from teleop_force.transport import messages as msg

#: Name of the MCAP metadata record holding the session metadata.
METADATA_NAME: Final = "teleop_force.session"
#: Value of the ``format`` metadata key, with ``format_version``.
FORMAT_NAME: Final = "teleop-force-session"
FORMAT_VERSION: Final = "1"
DEFAULT_CHUNK_SIZE_BYTES: Final = 1024 * 1024
DEFAULT_FLUSH_INTERVAL_S: Final = 0.5

_MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
_RECORD_HEAD: Final = struct.Struct("<BQ")
_MAX_RECORD_BYTES: Final = 1 << 30  # larger than any record this project writes: corrupt
_PARSED_OPCODES: Final = frozenset(
    (Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.METADATA)
)
_COMPRESSION: Final = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


# --------------------------------------------------------------------------- writing


class _DirectFile:
    """Append-only file that hands every write straight to the OS and counts the bytes."""

    def __init__(self, path: Path) -> None:
        self._raw = open(path, "wb", buffering=0)  # noqa: SIM115 - closed by close()
        self.position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view.nbytes:
            written = self._raw.write(view)
            if written is None:  # pragma: no cover - only for non-blocking files
                continue
            view = view[written:]
            self.position += written
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        """Nothing is buffered in user space."""

    def fsync(self) -> None:
        os.fsync(self._raw.fileno())

    def close(self) -> None:
        self._raw.close()


class SessionWriter:
    """Write a session MCAP file; thread-safe, usable as a context manager.

    Args:
        path: File to create (overwritten if it exists).
        metadata: Free key/value strings stored in the file (robot, model, operator...).
        chunk_size_bytes: Uncompressed size at which a chunk is closed and written.
        flush_interval_s: A chunk is also closed once it is this old, bounding data loss
            on a crash in time as well as in bytes.
        compression: ``zstd`` (default), ``lz4`` or ``none``.

    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        metadata: Mapping[str, Any] | None = None,
        *,
        chunk_size_bytes: int = DEFAULT_CHUNK_SIZE_BYTES,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        compression: str = "zstd",
    ) -> None:
        if compression not in _COMPRESSION:
            raise ConfigurationError(
                f"compression must be one of {', '.join(_COMPRESSION)}, got {compression!r}"
            )
        if chunk_size_bytes < 1024:
            raise ConfigurationError(f"chunk_size_bytes must be >= 1024, got {chunk_size_bytes}")
        if not flush_interval_s > 0.0:
            raise ConfigurationError(f"flush_interval_s must be > 0, got {flush_interval_s}")
        self.path = Path(path)
        self._flush_interval_s = float(flush_interval_s)
        self._lock = threading.Lock()
        self._json = json.JSONEncoder(separators=(",", ":"), allow_nan=False)
        self._schema_ids: dict[type[msg.Message], int] = {}
        self._channels: dict[str, tuple[int, type[msg.Message]]] = {}
        self._written = 0
        self._durable = 0
        self._closed = False
        try:
            self._file = _DirectFile(self.path)
        except OSError as exc:
            raise DataError(f"cannot create file: {exc.strerror or exc}", path=self.path) from None
        self._writer = Writer(
            self._file,  # type: ignore[arg-type]
            chunk_size=chunk_size_bytes,
            compression=_COMPRESSION[compression],
        )
        try:
            self._writer.start(profile="", library="teleop-force")
            info = {"format": FORMAT_NAME, "format_version": FORMAT_VERSION}
            info.update({str(k): str(v) for k, v in (metadata or {}).items()})
            self._writer.add_metadata(METADATA_NAME, info)
        except OSError as exc:
            self._file.close()
            raise DataError(f"cannot write file: {exc.strerror or exc}", path=self.path) from None
        self._last_flush_s = time.perf_counter()

    @property
    def messages_written(self) -> int:
        """Messages handed to :meth:`write` so far."""
        return self._written

    @property
    def messages_durable(self) -> int:
        """Messages already in complete chunks handed to the OS (they survive a crash)."""
        return self._durable

    def write(self, topic: str, message: msg.Message, log_time_ns: int | None = None) -> None:
        """Record ``message`` on channel ``topic`` (a Zenoh key), received at ``log_time_ns``.

        ``log_time_ns`` defaults to now (``time.time_ns()``).
        """
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        elif not 0 <= log_time_ns < 2**64:
            raise DataError(f"log time {log_time_ns} ns is outside [0, 2**64)", path=self.path)
        cls = type(message)
        data = self._json.encode(message.to_json_dict()).encode("utf-8")
        publish_ns = message.t_ns if message.t_ns >= 0 else log_time_ns
        with self._lock:
            if self._closed:
                raise DataError("session file is already closed", path=self.path)
            channel_id = self._channel(topic, cls)
            position = self._file.position
            try:
                self._writer.add_message(
                    channel_id=channel_id,
                    log_time=log_time_ns,
                    data=data,
                    publish_time=publish_ns,
                    sequence=message.seq,
                )
                self._written += 1
                if self._file.position != position:
                    self._durable = self._written
                now_s = time.perf_counter()
                if now_s - self._last_flush_s >= self._flush_interval_s:
                    self._flush_locked(now_s)
            except OSError as exc:
                raise DataError(
                    f"cannot write file: {exc.strerror or exc}", path=self.path
                ) from None

    def _channel(self, topic: str, cls: type[msg.Message]) -> int:
        entry = self._channels.get(topic)
        if entry is not None:
            channel_id, channel_cls = entry
            if channel_cls is not cls:
                raise DataError(
                    f"channel {topic!r} carries {channel_cls.__name__}, not {cls.__name__}",
                    path=self.path,
                )
            return channel_id
        if not isinstance(topic, str) or not topic:
            raise DataError(f"bad channel name {topic!r}", path=self.path)
        schema_id = self._schema_ids.get(cls)
        if schema_id is None:
            schema_id = self._writer.register_schema(
                name=msg.schema_name(cls),
                encoding="jsonschema",
                data=json.dumps(cls.json_schema()).encode("utf-8"),
            )
            self._schema_ids[cls] = schema_id
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding="json", schema_id=schema_id
        )
        self._channels[topic] = (channel_id, cls)
        return channel_id

    def _flush_locked(self, now_s: float) -> None:
        self._writer.flush()
        self._durable = self._written
        self._last_flush_s = now_s

    def flush(self) -> None:
        """Close the current chunk and hand it to the OS now."""
        with self._lock:
            if self._closed:
                return
            try:
                self._flush_locked(time.perf_counter())
            except OSError as exc:
                raise DataError(
                    f"cannot write file: {exc.strerror or exc}", path=self.path
                ) from None

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()
                self._durable = self._written
            except OSError as exc:
                raise DataError(
                    f"cannot write file: {exc.strerror or exc}", path=self.path
                ) from None
            finally:
                self._file.close()

    def __enter__(self) -> Self:
        """Return the writer."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Close the file (also on error, so what was written stays readable)."""
        self.close()


# --------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class _ChunkRef:
    order: int
    offset: int  # of the chunk record body in the file
    length: int
    start_ns: int


@dataclass(frozen=True)
class _Loose:
    """A message stored outside any chunk (files written without chunking)."""

    order: int
    record: Message


class SessionReader:
    """Read a session MCAP file, complete or truncated by a crash of its writer.

    Opening scans the whole file once (checking chunk CRCs) and raises DataError naming the
    file for anything that is not a readable MCAP. Iterating yields ``(topic, log_time_ns,
    message)`` in log-time order, decompressing one chunk at a time; ``message`` is a
    :mod:`teleop_force.transport.messages` object for this project's schemas, the decoded JSON
    value for
    other JSON channels, and the raw bytes otherwise.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.metadata: dict[str, str] = {}
        #: Whether the file lacks its footer (the writer did not close it).
        self.truncated = True
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunks: list[_ChunkRef] = []
        self._loose: list[_Loose] = []
        self._counts: dict[int, int] = {}
        self._scan()

    # -- scanning

    def _error(self, problem: str) -> DataError:
        return DataError(problem, path=self.path)

    def _scan(self) -> None:
        try:
            f = open(self.path, "rb")  # noqa: SIM115 - closed below
        except IsADirectoryError:
            raise self._error("is a directory, not an MCAP file") from None
        except OSError as exc:
            raise self._error(f"cannot read file: {exc.strerror or exc}") from None
        with f:
            size = os.fstat(f.fileno()).st_size
            if f.read(len(_MCAP_MAGIC)) != _MCAP_MAGIC:
                raise self._error("not an MCAP file (bad magic)")
            offset = len(_MCAP_MAGIC)
            order = 0
            while offset + _RECORD_HEAD.size <= size:
                opcode, length = _RECORD_HEAD.unpack(f.read(_RECORD_HEAD.size))
                body_offset = offset + _RECORD_HEAD.size
                if body_offset + length > size:
                    break  # the writer died while writing this record
                if length > _MAX_RECORD_BYTES:
                    raise self._error(f"corrupt record at byte {offset}: length {length}")
                if opcode == Opcode.FOOTER:
                    self.truncated = False
                    break
                if opcode in _PARSED_OPCODES:
                    body = f.read(length)
                    try:
                        self._record(opcode, body, body_offset, order)
                    except DataError:
                        raise
                    except Exception as exc:  # any parse failure means a corrupt file
                        raise self._error(
                            f"corrupt MCAP record (opcode {opcode:#04x}) at byte {offset}: {exc}"
                        ) from None
                    order += 1
                else:
                    f.seek(length, io.SEEK_CUR)
                offset = body_offset + length
        if self.metadata.get("format", FORMAT_NAME) != FORMAT_NAME:
            raise self._error(f"not a teleop-force session (format {self.metadata['format']!r})")

    def _record(self, opcode: int, body: bytes, body_offset: int, order: int) -> None:
        stream = ReadDataStream(io.BytesIO(body))
        if opcode == Opcode.SCHEMA:
            self._add_schema(Schema.read(stream))
        elif opcode == Opcode.CHANNEL:
            self._add_channel(Channel.read(stream))
        elif opcode == Opcode.MESSAGE:
            record = Message.read(stream, len(body))
            self._check_channel(record.channel_id)
            self._counts[record.channel_id] = self._counts.get(record.channel_id, 0) + 1
            self._loose.append(_Loose(order, record))
        elif opcode == Opcode.METADATA:
            record = Metadata.read(stream)
            if record.name == METADATA_NAME:
                self.metadata.update(record.metadata)
        else:  # chunk
            start_ns = None
            for item in self._chunk_records(body):
                if isinstance(item, Schema):
                    self._add_schema(item)
                elif isinstance(item, Channel):
                    self._add_channel(item)
                elif isinstance(item, Message):
                    self._check_channel(item.channel_id)
                    self._counts[item.channel_id] = self._counts.get(item.channel_id, 0) + 1
                    if start_ns is None or item.log_time < start_ns:
                        start_ns = item.log_time
            if start_ns is not None:
                self._chunks.append(_ChunkRef(order, body_offset, len(body), start_ns))

    def _chunk_records(self, body: bytes) -> list[Any]:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
        if chunk.uncompressed_size > _MAX_RECORD_BYTES:
            raise self._error(f"corrupt chunk: uncompressed size {chunk.uncompressed_size}")
        # breakup_chunk checks the CRC of compressed chunks only.
        uncompressed = chunk.compression == ""
        if (
            uncompressed
            and chunk.uncompressed_crc
            and zlib.crc32(chunk.data) != chunk.uncompressed_crc
        ):
            raise self._error("corrupt chunk: CRC mismatch")
        return breakup_chunk(chunk, validate_crc=True)

    def _add_schema(self, schema: Schema) -> None:
        self._schemas[schema.id] = schema

    def _add_channel(self, channel: Channel) -> None:
        if channel.schema_id != 0 and channel.schema_id not in self._schemas:
            raise self._error(f"channel {channel.topic!r} refers to unknown schema")
        self._channels[channel.id] = channel

    def _check_channel(self, channel_id: int) -> None:
        if channel_id not in self._channels:
            raise self._error(f"message on unknown channel id {channel_id}")

    # -- queries

    @property
    def topics(self) -> dict[str, str]:
        """Map each channel topic to its schema name (empty if it has none)."""
        return {
            c.topic: self._schemas[c.schema_id].name if c.schema_id else ""
            for c in self._channels.values()
        }

    @property
    def message_counts(self) -> dict[str, int]:
        """Number of readable messages per topic."""
        counts: dict[str, int] = {}
        for channel_id, count in self._counts.items():
            topic = self._channels[channel_id].topic
            counts[topic] = counts.get(topic, 0) + count
        return counts

    def __len__(self) -> int:
        """Return the number of readable messages."""
        return sum(self._counts.values())

    def devices(self) -> list[str]:
        """Device ids that have at least one project channel, sorted."""
        found = set()
        for topic in self.topics:
            try:
                found.add(keys.parse(topic).device)
            except TeleopForceError:
                continue
        return sorted(found)

    # -- iteration

    def __iter__(self) -> Iterator[tuple[str, int, Any]]:
        """Iterate over every message, in log-time order."""
        return self.messages()

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, Any]]:
        """Iterate ``(topic, log_time_ns, message)`` in log-time order, optionally filtered."""
        wanted = None if topics is None else set(topics)
        for channel, record in self._records_in_time_order():
            if wanted is not None and channel.topic not in wanted:
                continue
            yield channel.topic, record.log_time, self._decode(channel, record)

    def _records_in_time_order(self) -> Iterator[tuple[Channel, Message]]:
        # Heap entries: (time, order, index, payload). A chunk enters as a placeholder keyed by
        # its earliest message and is expanded when it reaches the top, so only chunks whose
        # time ranges overlap are in memory at once.
        heap: list[tuple[int, int, int, Any]] = [
            (ref.start_ns, ref.order, -1, ref) for ref in self._chunks
        ]
        heap += [(lo.record.log_time, lo.order, 0, lo.record) for lo in self._loose]
        heapq.heapify(heap)
        try:
            f = open(self.path, "rb")  # noqa: SIM115 - closed below
        except OSError as exc:
            raise self._error(f"cannot read file: {exc.strerror or exc}") from None
        with f:
            while heap:
                _, order, _, item = heapq.heappop(heap)
                if isinstance(item, _ChunkRef):
                    f.seek(item.offset)
                    body = f.read(item.length)
                    try:
                        records = self._chunk_records(body)
                    except DataError:
                        raise
                    except Exception as exc:  # the file changed since the scan
                        raise self._error(f"corrupt chunk at byte {item.offset}: {exc}") from None
                    for i, rec in enumerate(records):
                        if isinstance(rec, Message):
                            heapq.heappush(heap, (rec.log_time, order, i, rec))
                    continue
                yield self._channels[item.channel_id], item

    def _decode(self, channel: Channel, record: Message) -> Any:
        if channel.message_encoding != "json":
            return record.data
        try:
            value = json.loads(record.data)
        except ValueError as exc:
            raise DataError(
                f"message at log time {record.log_time} ns is not valid JSON: {exc}",
                path=self.path,
                column=channel.topic,
            ) from None
        schema = self._schemas.get(channel.schema_id)
        cls = None if schema is None else msg.MESSAGE_CLASSES_BY_SCHEMA.get(schema.name)
        if cls is None:
            return value
        try:
            return cls.from_json_dict(value)
        except MessageError as exc:
            raise DataError(
                f"bad {cls.__name__} at log time {record.log_time} ns: {exc}",
                path=self.path,
                column=channel.topic,
            ) from None


# --------------------------------------------------------------------------- to Recording


def _pick_device(reader: SessionReader, device: str | None) -> str:
    with_js = sorted(
        d for d in reader.devices() if reader.message_counts.get(keys.measured_js(d), 0) > 0
    )
    if device is not None:
        keys.validate_chunk(device)
        if device not in with_js:
            raise DataError(
                f"no joint states for device {device!r} (devices with joint states: "
                f"{', '.join(with_js) or 'none'})",
                path=reader.path,
            )
        return device
    if not with_js:
        raise DataError(f"no joint states ({keys.measured_js('<device>')})", path=reader.path)
    primary = reader.metadata.get("primary_device")
    if primary in with_js:
        return primary
    if len(with_js) == 1:
        return with_js[0]
    counts = reader.message_counts
    with_force = [
        d
        for d in with_js
        if counts.get(keys.measured_cf(d), 0) + counts.get(keys.estimated_cf(d), 0) > 0
    ]
    if len(with_force) == 1:
        return with_force[0]
    raise DataError(
        f"joint states of several devices ({', '.join(with_js)}); choose one "
        "(metadata 'primary_device' or the device argument)",
        path=reader.path,
    )


def read_session_as_recording(path: str | os.PathLike[str], device: str | None = None) -> Recording:
    """Turn a session into an interchange :class:`Recording` of one device.

    Samples are the ``measured_js`` messages of ``device`` ordered by their source stamp
    (duplicate stamps dropped), with ``t_s`` counted from the first one; ``tau_nm`` is their
    ``effort`` (commanded torque). The ``measured_cf`` force, if recorded, is linearly
    interpolated at those stamps (held constant beyond its first and last sample).
    Without ``device``: the metadata's ``primary_device``, else the only device with joint
    states, else the only one of those with a force channel.
    """
    reader = SessionReader(path)
    device = _pick_device(reader, device)
    js_key, cf_key = keys.measured_js(device), keys.measured_cf(device)
    stamps: list[int] = []
    rows: list[tuple[float, ...]] = []
    f_stamps: list[int] = []
    forces: list[tuple[float, ...]] = []
    n_joints = None
    for topic, _, message in reader.messages([js_key, cf_key]):
        if topic == js_key:
            if not isinstance(message, msg.JointState):
                raise DataError(f"{js_key} does not hold JointState messages", path=reader.path)
            if n_joints is None:
                n_joints = message.n_joints
            elif message.n_joints != n_joints:
                raise DataError(
                    f"joint count changes from {n_joints} to {message.n_joints} "
                    f"at seq {message.seq}",
                    path=reader.path,
                    column=js_key,
                )
            stamps.append(message.t_ns)
            rows.append(message.q_rad + message.effort_nm)
        elif isinstance(message, msg.ContactForce):
            f_stamps.append(message.t_ns)
            forces.append(message.f_n)
    t_ns = np.asarray(stamps, dtype=np.int64)
    table = np.asarray(rows, dtype=np.float64)
    order = np.argsort(t_ns, kind="stable")
    t_ns, table = t_ns[order], table[order]
    keep = np.concatenate(([True], np.diff(t_ns) > 0))
    t_ns, table = t_ns[keep], table[keep]
    if n_joints is None:  # pragma: no cover - _pick_device found joint states
        raise DataError(f"no joint states on {js_key}", path=reader.path)
    force = None
    if forces:
        fs = np.asarray(f_stamps, dtype=np.int64)
        fo = np.argsort(fs, kind="stable")
        fv = np.asarray(forces, dtype=np.float64)[fo]
        fx = (fs[fo] - t_ns[0]).astype(np.float64)
        tx = (t_ns - t_ns[0]).astype(np.float64)
        force = np.column_stack([np.interp(tx, fx, fv[:, k]) for k in range(3)])
    return Recording(
        t_s=(t_ns - t_ns[0]).astype(np.float64) * 1e-9,
        q_rad=table[:, :n_joints],
        tau_nm=table[:, n_joints:],
        f_tip_in_base_n=force,
        source=reader.path,
    )
