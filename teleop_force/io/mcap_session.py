"""Recorded sessions: MCAP files with one channel per Zenoh key, in ROS 2 CDR, read by Foxglove.

Layout of a session file:

- one channel per Zenoh key (``omni/<device>/measured_js`` ...), message encoding ``cdr`` with
  a ``ros2msg`` schema per message class (``teleop_force/msg/JointState`` ...), the payloads and
  schemas of :mod:`teleop_force.io.cdr_messages`: Foxglove decodes and plots every field;
- MCAP ``log_time`` = when the recorder got the message, ``publish_time`` = the message's
  own source stamp ``t_ns`` (``log_time`` if negative), MCAP ``sequence`` = the message's
  ``seq``;
- a metadata record ``teleop_force.session`` with the writer's key/value metadata, plus
  ``format`` (``teleop-force-session``), ``format_version`` (``2``: CDR; ``1``: JSON) and
  ``message_encoding``;
- schemas and channels as top-level records, written when a key is first recorded; each
  chunk holds the messages of one channel (:mod:`teleop_force.io.cdr_chunks`).

Recordings made before the CDR encoding (format version 1: JSON channels with a
``jsonschema`` schema per class, ``teleop_force.JointState`` ...) are read the same way, and
:func:`export_session_json` rewrites any session in that layout (``SessionWriter(...,
message_encoding="json")`` writes it directly).

Writing: :meth:`SessionWriter.write_payloads` records a batch of wire payloads, checked and
converted to CDR with numpy per key (no Python object per message); a malformed payload (or
one of another class than its key's first) is rejected and returned, the rest written.
:meth:`SessionWriter.write` records one message object.

Crash safety: data is written in zstd-compressed chunks (at most ``chunk_size_bytes``
uncompressed, 1 MiB by default) straight to the operating system (no user-space buffer), and
the open chunks are closed at least every ``flush_interval_s`` (checked on every write and by
:meth:`SessionWriter.flush_if_due`), so a recorder killed with SIGKILL leaves a file whose
complete chunks are all readable: it loses at most the last ``flush_interval_s`` of data.
The writer keeps one chunk index per chunk in memory until the summary is written at close
(under 1 kB each: the demo's six keys flushed every 0.4 s by the recorder make 9000 chunks in
10 minutes, a few MB). :class:`SessionReader` reads such a truncated file (no summary or
footer) as well as a complete one; :func:`~teleop_force.io.cdr_columns.read_joint_state_arrays`
reads the joint states of one key as arrays.
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
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Final, Self

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from teleop_force.errors import (
    ConfigurationError,
    DataError,
    MessageError,
    TeleopForceError,
)
from teleop_force.io import cdr_messages as cdr
from teleop_force.io.cdr_chunks import COMPRESSIONS, ChunkedMcapWriter, DirectFile
from teleop_force.io.cdr_columns import read_joint_state_arrays
from teleop_force.io.interchange_csv import Recording
from teleop_force.transport import keys
from teleop_force.transport import messages as msg

#: Name of the MCAP metadata record holding the session metadata.
METADATA_NAME: Final = "teleop_force.session"
#: Value of the ``format`` metadata key, with ``format_version``.
FORMAT_NAME: Final = "teleop-force-session"
#: ``format_version`` by message encoding: CDR sessions are version 2, JSON ones version 1.
FORMAT_VERSIONS: Final = {"cdr": "2", "json": "1"}
#: Message encodings a writer offers: ``cdr`` (the default) and ``json`` (the export layout).
MESSAGE_ENCODINGS: Final = tuple(FORMAT_VERSIONS)
DEFAULT_CHUNK_SIZE_BYTES: Final = 1024 * 1024
DEFAULT_FLUSH_INTERVAL_S: Final = 0.5

_MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
_RECORD_HEAD: Final = struct.Struct("<BQ")
_MAX_RECORD_BYTES: Final = 1 << 30  # larger than any record this project writes: corrupt
_PARSED_OPCODES: Final = frozenset(
    (Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.METADATA)
)
_MAX_LOG_TIME_NS: Final = 2**63  # log times are int64 nanoseconds since the epoch
_MESSAGE_CLASSES: Final = tuple(msg.MESSAGE_CLASSES.values())


# --------------------------------------------------------------------------- writing


@dataclass(frozen=True)
class _Channel:
    """A recorded key: its MCAP channel id and the one message class it carries."""

    channel_id: int
    message_class: type[msg.Message]


class SessionWriter:
    """Write a session MCAP file; thread-safe, usable as a context manager.

    Args:
        path: File to create (overwritten if it exists).
        metadata: Free key/value strings stored in the file (robot, model, operator...).
        chunk_size_bytes: Uncompressed size at which a channel's chunk is closed and written.
        flush_interval_s: The open chunks are also closed once this old, bounding data loss
            on a crash in time as well as in bytes.
        compression: ``zstd`` (default), ``lz4`` or ``none``.
        message_encoding: ``cdr`` (default) or ``json`` (the layout of recordings made before
            the CDR encoding, for export).

    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        metadata: Mapping[str, Any] | None = None,
        *,
        chunk_size_bytes: int = DEFAULT_CHUNK_SIZE_BYTES,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        compression: str = "zstd",
        message_encoding: str = "cdr",
    ) -> None:
        if compression not in COMPRESSIONS:
            raise ConfigurationError(
                f"compression must be one of {', '.join(COMPRESSIONS)}, got {compression!r}"
            )
        if message_encoding not in MESSAGE_ENCODINGS:
            raise ConfigurationError(
                f"message_encoding must be one of {', '.join(MESSAGE_ENCODINGS)}, "
                f"got {message_encoding!r}"
            )
        if chunk_size_bytes < 1024:
            raise ConfigurationError(f"chunk_size_bytes must be >= 1024, got {chunk_size_bytes}")
        if not flush_interval_s > 0.0:
            raise ConfigurationError(f"flush_interval_s must be > 0, got {flush_interval_s}")
        self.path = Path(path)
        self.message_encoding = message_encoding
        self._json_encoder = (
            json.JSONEncoder(separators=(",", ":"), allow_nan=False)
            if message_encoding == "json"
            else None
        )
        self._flush_interval_s = float(flush_interval_s)
        self._lock = threading.Lock()
        self._schema_ids: dict[type[msg.Message], int] = {}
        self._channels: dict[str, _Channel] = {}
        self._closed = False
        try:
            self._file = DirectFile(self.path)
        except OSError as exc:
            raise DataError(f"cannot create file: {exc.strerror or exc}", path=self.path) from None
        try:
            self._mcap = ChunkedMcapWriter(
                self._file, chunk_size_bytes=chunk_size_bytes, compression=compression
            )
            info = {
                "format": FORMAT_NAME,
                "format_version": FORMAT_VERSIONS[message_encoding],
                "message_encoding": message_encoding,
            }
            info.update({str(k): str(v) for k, v in (metadata or {}).items()})
            self._mcap.add_metadata(METADATA_NAME, info)
        except OSError as exc:
            self._file.close()
            raise DataError(f"cannot write file: {exc.strerror or exc}", path=self.path) from None
        self._last_flush_s = time.perf_counter()

    @property
    def flush_interval_s(self) -> float:
        """The open chunks are written at least this often [s]."""
        return self._flush_interval_s

    @property
    def messages_written(self) -> int:
        """Messages recorded so far."""
        return self._mcap.messages

    @property
    def messages_durable(self) -> int:
        """Messages already in complete chunks handed to the OS (they survive a crash)."""
        return self._mcap.messages - self._mcap.open_messages

    # -- one message object

    def write(self, topic: str, message: msg.Message, log_time_ns: int | None = None) -> None:
        """Record ``message`` on channel ``topic`` (a Zenoh key), received at ``log_time_ns``.

        ``log_time_ns`` defaults to now (``time.time_ns()``); raise DataError if ``topic``
        already carries another message class, or on a write error.
        """
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        else:
            self._check_log_time(log_time_ns)
        with self._lock:
            self._check_open()
            channel = self._channel(topic, type(message))
            with self._io_errors():
                self._add(channel, message, log_time_ns)
                self._flush_locked(due_only=True)

    def _check_log_time(self, log_time_ns: int) -> None:
        if not isinstance(log_time_ns, int) or not 0 <= log_time_ns < _MAX_LOG_TIME_NS:
            raise DataError(f"log time {log_time_ns!r} ns is outside [0, 2**63)", path=self.path)

    def _check_open(self) -> None:
        if self._closed:
            raise DataError("session file is already closed", path=self.path)

    def _io_errors(self) -> AbstractContextManager[None]:
        return _io_errors(self.path)

    def _add(self, channel: _Channel, message: msg.Message, log_time_ns: int) -> None:
        """Add one (valid) message; the lock is held."""
        if self._json_encoder is None:
            data = cdr.encode_cdr(message)
        else:
            data = self._json_encoder.encode(message.to_json_dict()).encode("utf-8")
        publish_ns = message.t_ns if message.t_ns >= 0 else log_time_ns
        self._mcap.add_message(channel.channel_id, message.seq, log_time_ns, publish_ns, data)

    def _channel(self, topic: str, cls: type[msg.Message]) -> _Channel:
        channel = self._channels.get(topic)
        if channel is not None:
            if channel.message_class is not cls:
                raise DataError(
                    f"channel {topic!r} carries {channel.message_class.__name__}, "
                    f"not {cls.__name__}",
                    path=self.path,
                )
            return channel
        if not isinstance(topic, str) or not topic:
            raise DataError(f"bad channel name {topic!r}", path=self.path)
        if cls not in _MESSAGE_CLASSES:
            raise DataError(f"cannot record a {cls.__name__}", path=self.path)
        with self._io_errors():
            schema_id = self._schema_ids.get(cls)
            if schema_id is None:
                if self._json_encoder is None:
                    schema = cdr.CDR_SCHEMAS[cls]
                    schema_id = self._mcap.add_schema(
                        schema.name, cdr.SCHEMA_ENCODING, schema.text.encode("utf-8")
                    )
                else:
                    schema_id = self._mcap.add_schema(
                        msg.schema_name(cls),
                        "jsonschema",
                        json.dumps(cls.json_schema()).encode("utf-8"),
                    )
                self._schema_ids[cls] = schema_id
            channel_id = self._mcap.add_channel(topic, self.message_encoding, schema_id)
        channel = self._channels[topic] = _Channel(channel_id, cls)
        return channel

    # -- batches of wire payloads

    def write_payloads(
        self,
        topics: Sequence[str],
        payloads: Sequence[bytes],
        log_times_ns: Sequence[int],
    ) -> list[tuple[int, TeleopForceError]]:
        """Record a batch of wire payloads; return ``(i, error)`` for each one rejected.

        ``payloads[i]`` was received on key ``topics[i]`` at ``log_times_ns[i]``; the
        rejected ones come back in input order.
        A payload is rejected (MessageError) when it is malformed (the checks of
        :func:`teleop_force.transport.messages.decode`), and (DataError) when its key already
        carries another message class (the first valid message on a key fixes its class) or
        its log time is outside [0, 2**63). Payloads of one key keep their order. Raise
        DataError if the file is closed or cannot be written.
        """
        if not len(topics) == len(payloads) == len(log_times_ns):
            raise DataError("topics, payloads and log times differ in length", path=self.path)
        groups: dict[str, list[int]] = {}
        for i, topic in enumerate(topics):
            group = groups.get(topic)
            if group is None:
                groups[topic] = [i]
            else:
                group.append(i)
        rejected: list[tuple[int, TeleopForceError]] = []
        with self._lock:
            self._check_open()
            with self._io_errors():
                for topic, indexes in groups.items():
                    self._write_group(topic, indexes, payloads, log_times_ns, rejected)
                self._flush_locked(due_only=True)
        rejected.sort(key=lambda item: item[0])
        return rejected

    def _write_group(
        self,
        topic: str,
        indexes: list[int],
        payloads: Sequence[bytes],
        log_times_ns: Sequence[int],
        rejected: list[tuple[int, TeleopForceError]],
    ) -> None:
        """Write the payloads of one key, in order; the lock is held."""
        channel = self._channels.get(topic)
        start = 0
        while channel is None and start < len(indexes):
            i = indexes[start]
            start += 1
            try:
                self._check_log_time(log_times_ns[i])
                message = msg.decode(payloads[i])
                channel = self._channel(topic, type(message))
            except TeleopForceError as exc:
                rejected.append((i, exc))
                continue
            self._add(channel, message, log_times_ns[i])
        rest = indexes[start:]
        if channel is None or not rest:
            return
        if (
            self._json_encoder is None
            and cdr.has_fixed_layout(channel.message_class)
            and self._write_block(topic, channel, rest, payloads, log_times_ns, rejected)
        ):
            return
        for i in rest:
            self._write_payload(topic, channel, i, payloads, log_times_ns, rejected)

    def _write_payload(
        self,
        topic: str,
        channel: _Channel,
        i: int,
        payloads: Sequence[bytes],
        log_times_ns: Sequence[int],
        rejected: list[tuple[int, TeleopForceError]],
    ) -> None:
        try:
            self._check_log_time(log_times_ns[i])
            message = msg.decode(payloads[i])
            if type(message) is not channel.message_class:
                raise self._wrong_class(topic, channel, type(message))
        except TeleopForceError as exc:
            rejected.append((i, exc))
            return
        self._add(channel, message, log_times_ns[i])

    def _wrong_class(self, topic: str, channel: _Channel, cls: type[msg.Message]) -> DataError:
        return DataError(
            f"channel {topic!r} carries {channel.message_class.__name__}, not {cls.__name__}",
            path=self.path,
        )

    def _write_block(
        self,
        topic: str,
        channel: _Channel,
        rows: list[int],
        payloads: Sequence[bytes],
        log_times_ns: Sequence[int],
        rejected: list[tuple[int, TeleopForceError]],
    ) -> bool:
        """Write same-size payloads as one numpy block; False (nothing written) if they are not."""
        block_payloads = [payloads[i] for i in rows]
        size = len(block_payloads[0])
        if size == 0 or any(len(p) != size for p in block_payloads):
            return False
        try:
            logs = np.array([log_times_ns[i] for i in rows], dtype=np.int64)
        except (OverflowError, TypeError, ValueError):
            return False
        if logs.size and int(logs.min()) < 0:
            return False
        block = np.frombuffer(b"".join(block_payloads), dtype=np.uint8).reshape(len(rows), size)
        result = cdr.wire_block_to_cdr(channel.message_class, block)
        accepted = result.accepted
        if not accepted.all():
            for k in np.flatnonzero(~accepted).tolist():
                try:
                    message = msg.decode(block_payloads[k])
                except MessageError as exc:
                    rejected.append((rows[k], exc))
                    continue
                if type(message) is channel.message_class:  # pragma: no cover - same checks
                    self._add(channel, message, int(logs[k]))
                else:
                    rejected.append((rows[k], self._wrong_class(topic, channel, type(message))))
            logs = logs[accepted]
        publish = np.where(result.t_ns >= 0, result.t_ns, logs)
        self._mcap.add_messages(channel.channel_id, result.cdr, result.seq, logs, publish)
        return True

    # -- flushing, closing

    def _flush_locked(self, *, due_only: bool, margin_s: float = 0.0) -> None:
        now_s = time.perf_counter()
        if due_only and now_s - self._last_flush_s < self._flush_interval_s - margin_s:
            return
        self._mcap.close_chunks()
        self._last_flush_s = now_s

    def flush(self) -> None:
        """Close the open chunks and hand them to the OS now."""
        with self._lock:
            if not self._closed:
                with self._io_errors():
                    self._flush_locked(due_only=False)

    def flush_if_due(self, margin_s: float = 0.0) -> None:
        """Close the open chunks if the last flush is ``flush_interval_s - margin_s`` old.

        A caller that writes every ``margin_s`` at most (a batching recorder) passes it, so
        that nothing stays in an open chunk longer than ``flush_interval_s``.
        """
        with self._lock:
            if not self._closed:
                with self._io_errors():
                    self._flush_locked(due_only=True, margin_s=margin_s)

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                with self._io_errors():
                    self._mcap.finish()
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


@contextmanager
def _io_errors(path: Path) -> Iterator[None]:
    """Turn an OSError into a DataError naming ``path``."""
    try:
        yield
    except OSError as exc:
        raise DataError(f"cannot write file: {exc.strerror or exc}", path=path) from None


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
    message)`` in log-time order (equal log times: in file order), decompressing one chunk at a
    time; ``message`` is a :mod:`teleop_force.transport.messages` object for this project's
    schemas (CDR ``teleop_force/msg/...`` or, in recordings made before the CDR encoding, JSON
    ``teleop_force....``), the decoded JSON value for other JSON channels, and the raw bytes
    otherwise. :attr:`topics` maps each key to its schema name.
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
        if channel.message_encoding == cdr.MESSAGE_ENCODING:
            return self._decode_cdr(channel, record)
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

    def _decode_cdr(self, channel: Channel, record: Message) -> Any:
        schema = self._schemas.get(channel.schema_id)
        cls = None
        if schema is not None and schema.encoding == cdr.SCHEMA_ENCODING:
            cls = cdr.MESSAGE_CLASSES_BY_CDR_SCHEMA.get(schema.name)
        if cls is None:
            return record.data
        try:
            return cdr.decode_cdr(cls, record.data)
        except MessageError as exc:
            raise DataError(
                f"bad {cls.__name__} at log time {record.log_time} ns: {exc}",
                path=self.path,
                column=channel.topic,
            ) from None


# --------------------------------------------------------------------------- JSON export


@dataclass(frozen=True)
class SessionExport:
    """What :func:`export_session_json` wrote.

    Attributes:
        source: The session read.
        target: The JSON session written.
        messages: Messages written.
        skipped: Messages of channels that are not this project's (not written).

    """

    source: Path
    target: Path
    messages: int
    skipped: int

    def __post_init__(self) -> None:
        """Check the counts."""
        if self.messages < 0 or self.skipped < 0:
            raise ConfigurationError("message counts must be >= 0")


def export_session_json(
    source_path: str | os.PathLike[str], target_path: str | os.PathLike[str]
) -> SessionExport:
    """Rewrite a session (CDR or JSON, complete or truncated) with JSON channels.

    The target has the layout of recordings made before the CDR encoding (format version 1:
    one ``json`` channel per key with a ``jsonschema`` schema per class), the same messages
    with the same log times, and the source's metadata plus ``exported_from``. Channels that
    are not this project's are left out (counted in ``skipped``). Raise DataError if the
    source cannot be read or the target written, ConfigurationError if they are one file.
    """
    source, target = Path(source_path), Path(target_path)
    if target.exists() and source.exists() and target.resolve() == source.resolve():
        raise ConfigurationError(f"export target {target} is the source itself")
    reader = SessionReader(source)
    metadata = {
        k: v
        for k, v in reader.metadata.items()
        if k not in ("format", "format_version", "message_encoding")
    }
    metadata["exported_from"] = str(source)
    written = skipped = 0
    with SessionWriter(target, metadata, message_encoding="json") as writer:
        for topic, log_time_ns, message in reader.messages():
            if isinstance(message, _MESSAGE_CLASSES):
                writer.write(topic, message, log_time_ns)
                written += 1
            else:
                skipped += 1
    return SessionExport(source, target, written, skipped)


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
    joint_states = read_joint_state_arrays(reader.path, js_key)
    f_stamps: list[int] = []
    forces: list[tuple[float, ...]] = []
    for _, _, message in reader.messages([cf_key]):
        if isinstance(message, msg.ContactForce):
            f_stamps.append(message.t_ns)
            forces.append(message.f_n)
    n_joints = joint_states.n_joints
    t_ns = joint_states.t_ns
    table = np.hstack((joint_states.q_rad, joint_states.effort_nm))
    order = np.argsort(t_ns, kind="stable")
    t_ns, table = t_ns[order], table[order]
    keep = np.concatenate(([True], np.diff(t_ns) > 0))
    t_ns, table = t_ns[keep], table[keep]
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
