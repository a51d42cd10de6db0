"""Recorded sessions: MCAP files read by Foxglove, rosbag2 and this project.

A session recorded today is a ROS 2 bag (profile ``ros2``, written by
:class:`~teleop_force.service.ros2_recorder.Ros2Recorder` with :meth:`SessionWriter.write_ros2`):
one channel per ROS 2 topic (``/slave/measured_js``), message encoding ``cdr``, the standard
``ros2msg`` schemas (``sensor_msgs/msg/JointState`` ...), the CDR bytes as received, MCAP
``sequence`` and ``publish_time`` = rmw_zenoh's attachment sequence number and source time,
``log_time`` = when the recorder got the message.

Sessions recorded before ROS 2 stay readable, replayable and writable (format version 2): one
channel per Zenoh key (``omni/<device>/measured_js`` ...), ``cdr`` with a ``ros2msg`` schema
per message class (``teleop_force/msg/JointState`` ...), the payloads of
:mod:`teleop_force.io.cdr_messages`, ``publish_time`` = the message's stamp ``t_ns``
(``log_time`` if negative), ``sequence`` = its ``seq``; and before the CDR encoding (format
version 1) JSON channels with a ``jsonschema`` schema per class (``teleop_force.JointState``
...). :func:`export_session_json` rewrites any session in that layout (``SessionWriter(...,
message_encoding="json")`` writes it directly).

Every session has a metadata record ``teleop_force.session`` with the writer's key/value
metadata, plus ``format`` (``teleop-force-session``), ``format_version`` and
``message_encoding``; schemas and channels are top-level records, written when a channel is
first recorded; each chunk holds the messages of one channel (:mod:`teleop_force.io.cdr_chunks`).

Reading: :class:`SessionReader` names each channel by its :class:`Stream` (device and kind,
:func:`parse_stream`), so one API serves ``/slave/measured_js`` and ``omni/slave/measured_js``;
it decodes ROS 2 channels with :mod:`teleop_force.ros2.codec` into the project's messages.

Writing: :meth:`SessionWriter.write_ros2` records one ROS 2 message as received,
:meth:`SessionWriter.write_ros2_block` a block of same-size ones (numpy rows).
:meth:`SessionWriter.write_payloads` records a batch of older wire payloads, checked and
converted to CDR with numpy per key (no Python object per message); a malformed payload (or
one of another class than its key's first) is rejected and returned, the rest written.
:meth:`SessionWriter.write` records one message object. :meth:`SessionWriter.copy_from` copies
the messages of some keys from another session, chunk by chunk (no Python object per message).

Crash safety: data is written in zstd-compressed chunks (at most ``chunk_size_bytes``
uncompressed, 1 MiB by default) straight to the operating system (no user-space buffer), and
the open chunks are closed at least every ``flush_interval_s`` (checked on every write and by
:meth:`SessionWriter.flush_if_due`), so a recorder killed with SIGKILL leaves a file whose
complete chunks are all readable: it loses at most the last ``flush_interval_s`` of data.
The writer keeps one chunk index per chunk in memory until the summary is written at close
(under 1 kB each: eight channels flushed every 0.5 s make 10 000 chunks in 10 minutes, a
few MB). :class:`SessionReader` reads such a truncated file (no summary or
footer) as well as a complete one; :func:`~teleop_force.io.cdr_columns.read_joint_state_arrays`
reads the joint states of one key as arrays.
"""

from __future__ import annotations

import heapq
import io
import itertools
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
import zstandard
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
from teleop_force.io import cdr_chunks as mc
from teleop_force.io import cdr_messages as cdr
from teleop_force.io.cdr_chunks import COMPRESSIONS, ChunkedMcapWriter, DirectFile
from teleop_force.io.cdr_columns import read_joint_state_arrays, read_wrench_arrays
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.driver_interface import DriverInterface
from teleop_force.ros2 import interfaces
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

_MAX_RECORD_BYTES: Final = 1 << 30  # larger than any record this project writes: corrupt
_MAX_LOG_TIME_NS: Final = 2**63  # log times are int64 nanoseconds since the epoch
_MESSAGE_CLASSES: Final = tuple(msg.MESSAGE_CLASSES.values())

#: Stream kinds, named as the ROS 2 topics name them (:mod:`teleop_force.ros2.topics`).
MEASURED_JS: Final = "measured_js"
SETPOINT_JS: Final = "setpoint_js"
TRUE_CF: Final = "true_cf"
ESTIMATED_CF: Final = "estimated_cf"
ESTIMATE_DIAGNOSTICS: Final = "estimate_diagnostics"
STATUS: Final = "status"
SERVICE_DIAGNOSTICS: Final = "service/diagnostics"
STREAM_KINDS: Final = (
    MEASURED_JS, SETPOINT_JS, TRUE_CF, ESTIMATED_CF, ESTIMATE_DIAGNOSTICS, STATUS,
    SERVICE_DIAGNOSTICS,
)  # fmt: skip
#: The kind of each channel of a session recorded before ROS 2 (``omni/<device>/<kind>``).
_OLD_KINDS: Final = {
    keys.MEASURED_JS: MEASURED_JS, keys.SETPOINT_JS: SETPOINT_JS, keys.MEASURED_CF: TRUE_CF,
    keys.ESTIMATED_CF: ESTIMATED_CF, keys.STATUS: STATUS,
    keys.SERVICE_DIAGNOSTICS: SERVICE_DIAGNOSTICS,
}  # fmt: skip
#: The ROS 2 types a session's ROS channels are decoded from (``ros2msg`` schemas).
ROS2_TYPES: Final = interfaces.PUBLISHED_TYPES
#: An estimate half waits this long in log time for its other half, then is dropped [ns].
#: A recorder writes the two halves of one estimate (published back to back) in the same or
#: the next drain, so their log times differ by a drain's span at most; halves of one log time
#: (a drain clamped into one instant) are never dropped, however many there are.
_HALF_WAIT_NS: Final = 10_000_000_000


@dataclass(frozen=True, order=True)
class Stream:
    """One recorded stream: a device and a kind of :data:`STREAM_KINDS`.

    A session recorded from ROS 2 names its channels by topic (``/slave/measured_js``), one
    recorded before by Zenoh key (``omni/slave/measured_js``; its ``measured_cf`` is the
    ``true_cf`` stream): :func:`parse_stream` maps either to the same stream.
    """

    device: str
    kind: str

    def ros2_topic(self) -> str:
        """Return the ROS 2 topic name ``/<device>/<kind>``."""
        return f"/{self.device}/{self.kind}"


def parse_stream(topic: str) -> Stream | None:
    """Return the stream a channel carries (``/<device>/<kind>`` or ``omni/<device>/<kind>``)."""
    if topic.startswith("/"):
        device, _, kind = topic[1:].partition("/")
        if device and kind in STREAM_KINDS and "/" not in device:
            return Stream(device, kind)
        return None
    try:
        parsed = keys.parse(topic)
    except TeleopForceError:
        return None
    old = _OLD_KINDS.get(parsed.kind)
    return None if old is None else Stream(parsed.device, old)


@dataclass(frozen=True)
class RawMessage:
    """A recorded message as stored: channel, schema name, MCAP times and sequence, bytes."""

    topic: str
    schema_name: str
    message_encoding: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes


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
        profile: The MCAP header's profile: ``ros2`` for a session that records ROS 2
            messages (:meth:`write_ros2`), ``""`` (default) otherwise.

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
        profile: str = "",
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
        self._ros2_schema_ids: dict[str, int] = {}
        self._ros2_channels: dict[str, tuple[int, str]] = {}
        self._closed = False
        try:
            self._file = DirectFile(self.path)
        except OSError as exc:
            raise DataError(f"cannot create file: {exc.strerror or exc}", path=self.path) from None
        try:
            self._mcap = ChunkedMcapWriter(
                self._file,
                chunk_size_bytes=chunk_size_bytes,
                compression=compression,
                profile=profile,
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

    def write_ros2(
        self,
        topic: str,
        ros_type: str,
        payload: bytes,
        sequence: int,
        publish_time_ns: int,
        log_time_ns: int,
    ) -> None:
        """Record one ROS 2 message as it was received (the CDR bytes untouched).

        Channel ``topic`` (a ROS topic name, ``/slave/measured_js``), message encoding
        ``cdr``, a ``ros2msg`` schema named ``ros_type`` (``sensor_msgs/msg/JointState``,
        its text with its dependencies from :mod:`teleop_force.ros2.interfaces`); MCAP
        ``sequence`` = ``sequence`` modulo 2**32 (rmw_zenoh's attachment), ``publish_time`` =
        ``publish_time_ns`` (its source time; ``log_time_ns`` if negative). Raise DataError for
        a topic that is no ROS name or already carries another type, an unknown type, or on
        a write error.
        """
        self._check_log_time(log_time_ns)
        with self._lock:
            self._check_open()
            channel_id = self._ros2_channel(topic, ros_type)
            publish_ns = publish_time_ns if publish_time_ns >= 0 else log_time_ns
            with self._io_errors():
                self._mcap.add_message(
                    channel_id, sequence & 0xFFFF_FFFF, log_time_ns, publish_ns, bytes(payload)
                )
                self._flush_locked(due_only=True)

    def write_ros2_block(
        self,
        topic: str,
        ros_type: str,
        payloads: np.ndarray,
        sequence: np.ndarray,
        publish_time_ns: np.ndarray,
        log_time_ns: np.ndarray,
    ) -> None:
        """Record ``(K, size)`` uint8 rows of same-size ROS 2 payloads, as :meth:`write_ros2`.

        One entry per row in ``sequence`` (modulo 2**32), ``publish_time_ns`` and
        ``log_time_ns`` (in [0, 2**63)); rows keep their order.
        """
        rows = payloads.shape[0]
        logs = np.asarray(log_time_ns, dtype=np.int64)
        publish = np.asarray(publish_time_ns, dtype=np.int64)
        if payloads.ndim != 2 or payloads.dtype != np.uint8 or logs.shape != (rows,):
            raise DataError("payload rows and log times do not match", path=self.path)
        if publish.shape != (rows,) or np.shape(sequence) != (rows,):
            raise DataError("payload rows and sequence / publish times differ", path=self.path)
        if rows and int(logs.min()) < 0:
            raise DataError("log times must be >= 0", path=self.path)
        seq = (np.asarray(sequence, dtype=np.int64) & 0xFFFF_FFFF).astype(np.uint32)
        with self._lock:
            self._check_open()
            channel_id = self._ros2_channel(topic, ros_type)
            with self._io_errors():
                self._mcap.add_messages(
                    channel_id, payloads, seq, logs, np.where(publish >= 0, publish, logs)
                )
                self._flush_locked(due_only=True)

    def _ros2_channel(self, topic: str, ros_type: str) -> int:
        """Return the channel id of a ROS 2 topic, declaring it (and its schema) first."""
        known = self._ros2_channels.get(topic)
        if known is not None:
            if known[1] != ros_type:
                raise DataError(
                    f"channel {topic!r} carries {known[1]}, not {ros_type}", path=self.path
                )
            return known[0]
        if not isinstance(topic, str) or not topic.startswith("/") or topic in self._channels:
            raise DataError(f"bad ROS 2 channel name {topic!r}", path=self.path)
        from teleop_force.ros2.interfaces import schema_text  # rosbags: only when recording ROS

        schema_id = self._ros2_schema_ids.get(ros_type)
        if schema_id is None:
            try:
                text = schema_text(ros_type)
            except ConfigurationError as exc:
                raise DataError(str(exc), path=self.path, column=topic) from None
            with self._io_errors():
                schema_id = self._mcap.add_schema(
                    ros_type, cdr.SCHEMA_ENCODING, text.encode("utf-8")
                )
            self._ros2_schema_ids[ros_type] = schema_id
        with self._io_errors():
            channel_id = self._mcap.add_channel(topic, cdr.MESSAGE_ENCODING, schema_id)
        self._ros2_channels[topic] = (channel_id, ros_type)
        return channel_id

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

    # -- copying another recording

    def copy_from(
        self,
        source: str | os.PathLike[str],
        topics: Iterable[str],
        *,
        keep: Mapping[str, np.ndarray] | None = None,
    ) -> CopiedMessages:
        """Record the messages of ``topics`` from the session ``source``, with their log times.

        Per topic, the messages are written in the order :meth:`SessionReader.messages`
        yields them (log-time order, ties in file order), with the source's log times; each
        one's ``seq`` and publish time are its own (as :meth:`write` records them).
        ``keep`` maps a topic to a boolean mask over its messages in that order: the ``False``
        ones are read, not written. A CDR session whose chunks hold one channel each (what
        this writer writes) is copied chunk by chunk with numpy, each chunk decompressed
        once; any other (JSON channels, chunks mixing channels, messages out of log-time
        order) message by message. A ROS 2 channel is copied as recorded: the bytes, the
        MCAP sequence and publish time. Raise DataError for an unreadable source, a ``keep`` mask
        of another length than its topic's messages, or a write error.
        """
        source = Path(source)
        wanted = list(dict.fromkeys(topics))
        masks = dict(keep or {})
        with self._lock:
            self._check_open()
        with mc.mapped_file(source) as data:
            scan = mc.scan_mcap(data, source)
            plan = _bulk_plan(data, scan, wanted, source)
            if plan is not None:
                return self._copy_chunks(data, plan, wanted, masks, source)
        return self._copy_messages(SessionReader(source), wanted, masks)

    def _copy_messages(
        self, reader: SessionReader, topics: list[str], keep: dict[str, np.ndarray]
    ) -> CopiedMessages:
        """Copy message by message (any session)."""
        counts = reader.message_counts
        for topic, mask in keep.items():
            self._check_mask(topic, mask, counts.get(topic, 0) if topic in topics else 0)
        read = dict.fromkeys(topics, 0)
        first: int | None = None
        last: int | None = None
        written = 0
        wanted = set(topics)
        for channel, record in reader._records_in_time_order():
            topic, log_time_ns = channel.topic, record.log_time
            if topic not in wanted:
                continue
            index = read[topic]
            read[topic] += 1
            first = log_time_ns if first is None else first
            last = log_time_ns
            kept = keep.get(topic)
            if kept is not None and not kept[index]:
                continue
            if reader._is_ros2(channel):  # the bytes as recorded
                ros_type = reader._schemas[channel.schema_id].name
                self.write_ros2(topic, ros_type, record.data, record.sequence,
                                record.publish_time, log_time_ns)  # fmt: skip
                written += 1
                continue
            message = reader._decode(channel, record)
            if not isinstance(message, _MESSAGE_CLASSES):
                raise DataError(f"cannot record {topic}: not a message", path=reader.path)
            self.write(topic, message, log_time_ns)
            written += 1
        return CopiedMessages(read, written, first, last)

    def _check_mask(self, topic: str, mask: np.ndarray, count: int) -> None:
        if mask.dtype != np.bool_ or mask.shape != (count,):
            raise DataError(
                f"keep mask of {topic} must be ({count},) bool, got {mask.shape} {mask.dtype}",
                path=self.path,
            )

    def _copy_chunks(
        self,
        data: mc.Buffer,
        plan: dict[str, _TopicChunks],
        topics: list[str],
        keep: dict[str, np.ndarray],
        source: Path,
    ) -> CopiedMessages:
        """Copy chunk by chunk (module docstring of :mod:`~teleop_force.io.cdr_chunks`)."""
        read = dict.fromkeys(topics, 0)
        for topic in topics:
            count = sum(e.shape[0] for e in plan[topic].entries) if topic in plan else 0
            read[topic] = count
            if topic in keep:
                self._check_mask(topic, keep[topic], count)
        starts = [
            (int(entries[0, 0]), n, k)
            for n, topic in enumerate(topics)
            if topic in plan
            for k, entries in enumerate(plan[topic].entries)
        ]
        firsts = [int(e[0, 0]) for t in plan.values() for e in t.entries]
        lasts = [int(e[-1, 0]) for t in plan.values() for e in t.entries]
        done = dict.fromkeys(topics, 0)
        decompressor = zstandard.ZstdDecompressor()
        written = 0
        for _, n, k in sorted(starts):
            topic = topics[n]
            chunks = plan[topic]
            ref, entries = chunks.refs[k], chunks.entries[k]
            records = mc.chunk_records(data, ref, source, decompressor)
            try:
                located = mc.channel_records(records, chunks.channel_id, entries)
            except ValueError as exc:
                raise DataError(f"corrupt chunk at byte {ref.offset}: {exc}", path=source) from None
            if not np.array_equal(located.log_time_ns, entries[:, 0].astype(np.int64)):
                raise DataError(f"chunk at byte {ref.offset} disagrees with its index", path=source)
            rows = np.ones(located.log_time_ns.shape[0], dtype=bool)
            if topic in keep:
                rows = keep[topic][done[topic] : done[topic] + rows.shape[0]]
            done[topic] += rows.shape[0]
            if chunks.message_class is None:
                written += self._add_located_ros2(topic, chunks.ros_type, records, located, rows)
            else:
                written += self._add_located(topic, chunks.message_class, records, located, rows)
        return CopiedMessages(read, written, min(firsts, default=None), max(lasts, default=None))

    def _add_located(
        self,
        topic: str,
        cls: type[msg.Message],
        records: bytes,
        located: mc.ChannelRecords,
        rows: np.ndarray,
    ) -> int:
        """Write the ``rows`` of the located CDR messages, in runs of one size; return how many."""
        logs = located.log_time_ns[rows]
        offsets = located.payload_offset[rows]
        sizes = located.payload_size[rows]
        if logs.size == 0:
            return 0
        if int(logs.min()) < 0 or int(sizes.min()) < _CDR_STAMP_END:
            raise DataError(f"bad message on {topic} (size or log time)", path=self.path)
        raw = np.frombuffer(records, dtype=np.uint8)
        bounds = [0, *(np.flatnonzero(np.diff(sizes)) + 1).tolist(), sizes.shape[0]]
        with self._lock:
            self._check_open()
            channel = self._channel(topic, cls)
            with self._io_errors():
                for a, b in itertools.pairwise(bounds):
                    size = int(sizes[a])
                    block = _gather(raw, offsets[a:b], size)
                    seq = np.ascontiguousarray(block[:, 4:8]).view("<u4").reshape(-1)
                    t_ns = np.ascontiguousarray(block[:, 12:20]).view("<i8").reshape(-1)
                    publish = np.where(t_ns >= 0, t_ns, logs[a:b])
                    self._mcap.add_messages(channel.channel_id, block, seq, logs[a:b], publish)
                self._flush_locked(due_only=True)
        return int(logs.size)

    def _add_located_ros2(
        self,
        topic: str,
        ros_type: str,
        records: bytes,
        located: mc.ChannelRecords,
        rows: np.ndarray,
    ) -> int:
        """Write the ``rows`` of located ROS 2 messages as recorded (bytes, sequence, times)."""
        logs = located.log_time_ns[rows]
        offsets = located.payload_offset[rows]
        sizes = located.payload_size[rows]
        if logs.size == 0:
            return 0
        raw = np.frombuffer(records, dtype=np.uint8)
        # the record's sequence and publish time precede its data (MESSAGE_FIELDS)
        seq = np.ascontiguousarray(raw[offsets[:, None] - 20 + np.arange(4)]).view("<u4")
        publish = np.ascontiguousarray(raw[offsets[:, None] - 8 + np.arange(8)]).view("<i8")
        seq, publish = seq.reshape(-1), publish.reshape(-1)
        bounds = [0, *(np.flatnonzero(np.diff(sizes)) + 1).tolist(), sizes.shape[0]]
        for a, b in itertools.pairwise(bounds):
            block = np.ascontiguousarray(_gather(raw, offsets[a:b], int(sizes[a])))
            self.write_ros2_block(topic, ros_type, block, seq[a:b], publish[a:b], logs[a:b])
        return int(logs.size)

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


#: Every CDR payload begins with its header (4), seq (4), padding (4), stamp ``t_ns`` (8).
_CDR_STAMP_END: Final = 20


@dataclass(frozen=True)
class CopiedMessages:
    """What :meth:`SessionWriter.copy_from` read and wrote.

    Attributes:
        read: Messages read per topic asked for.
        written: Messages written.
        first_log_time_ns: Earliest log time among those read (``None``: none read).
        last_log_time_ns: Latest one.

    """

    read: dict[str, int]
    written: int
    first_log_time_ns: int | None
    last_log_time_ns: int | None

    def __post_init__(self) -> None:
        """Check the counts."""
        if self.written < 0 or any(count < 0 for count in self.read.values()):
            raise DataError("message counts must be >= 0")
        if self.written > sum(self.read.values()):
            raise DataError("cannot write more messages than were read")


@dataclass(frozen=True)
class _TopicChunks:
    """The chunks holding one topic's messages, and their message indexes, in file order."""

    channel_id: int
    message_class: type[msg.Message] | None  # None: a ROS 2 channel (``ros_type``)
    refs: list[mc.ChunkRef]
    entries: list[np.ndarray]  # (K, 2) uint64 log time, offset; sorted by offset
    ros_type: str = ""


def _bulk_plan(
    data: mc.Buffer, scan: mc.McapScan, topics: list[str], path: Path
) -> dict[str, _TopicChunks] | None:
    """Return where each of ``topics`` is in a CDR session of one-channel chunks, else None.

    None: the copy must go message by message (a topic on several channels or not in CDR,
    a message outside chunks, a chunk without complete message indexes or holding several
    channels one of which is asked for, messages out of log-time order).
    """
    found = scan.metadata.get(METADATA_NAME, {}).get("format", FORMAT_NAME)
    if found != FORMAT_NAME:
        raise DataError(f"not a teleop-force session (format {found!r})", path=path)
    by_id: dict[int, str] = {}
    plan: dict[str, _TopicChunks] = {}
    wanted = set(topics)
    for channel in scan.channels.values():
        if channel.topic not in wanted:
            continue
        schema = scan.schemas.get(channel.schema_id)
        cls: type[msg.Message] | None = None
        ros_type = ""
        if schema is not None and schema.encoding == cdr.SCHEMA_ENCODING:
            cls = cdr.MESSAGE_CLASSES_BY_CDR_SCHEMA.get(schema.name)
            if cls is None and schema.name in ROS2_TYPES:
                ros_type = schema.name
        if (cls is None and not ros_type) or channel.message_encoding != cdr.MESSAGE_ENCODING:
            return None
        if channel.topic in plan:
            return None
        by_id[channel.id] = channel.topic
        plan[channel.topic] = _TopicChunks(channel.id, cls, [], [], ros_type)
    for _, body, _ in scan.loose:
        if mc.MESSAGE_FIELDS.unpack_from(data, body)[0] in by_id:
            return None
    for ref in scan.chunks:
        ids = set(ref.index)
        if not (ref.index_complete and ids and ids <= set(scan.channels)):
            return None
        asked = ids & set(by_id)
        if not asked:
            continue
        if len(ids) > 1:
            return None
        (channel_id,) = asked
        try:
            entries = mc.index_entries(data, *ref.index[channel_id])
        except (ValueError, struct.error) as exc:
            problem = f"corrupt message index at byte {ref.offset}: {exc}"
            raise DataError(problem, path=path) from None
        if entries.shape[0] == 0:
            continue
        entries = entries[np.argsort(entries[:, 1], kind="stable")]
        plan[by_id[channel_id]].refs.append(ref)
        plan[by_id[channel_id]].entries.append(entries)
    for chunks in plan.values():
        if chunks.entries:
            logs = np.concatenate([e[:, 0] for e in chunks.entries])
            if (logs[1:] < logs[:-1]).any() or int(logs.max()) >= _MAX_LOG_TIME_NS:
                return None
    return {topic: chunks for topic, chunks in plan.items() if chunks.entries}


def _gather(raw: np.ndarray, offsets: np.ndarray, size: int) -> np.ndarray:
    """Return the ``(K, size)`` bytes at ``offsets`` of ``raw`` (a strided view if regular)."""
    count = offsets.shape[0]
    if count > 1:
        steps = np.diff(offsets)
        step = int(steps[0])
        regular = step >= size and bool((steps == step).all())
    else:
        step, regular = size, True
    start = int(offsets[0])
    if regular:
        return np.lib.stride_tricks.as_strided(
            raw[start:], shape=(count, size), strides=(step, 1), writeable=False
        )
    return raw[offsets[:, None] + np.arange(size)]


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


class _EstimateJoin:
    """Pair one device's estimate halves (WrenchStamped, EstimateDiagnostics) by header stamp.

    Halves come in log-time order; one waits :data:`_HALF_WAIT_NS` of log time for its other
    half, then is forgotten (so memory is bounded by the halves of that span of the file).
    """

    def __init__(self, path: Path, topic: str) -> None:
        self.path, self.topic = path, topic
        # stamp -> (log time, MCAP sequence, Wrench) / (log time, EstimateDiagnostics), in
        # log-time order (insertion order), so the oldest are first
        self.wrenches: dict[int, tuple[int, int, Any]] = {}
        self.diagnostics: dict[int, tuple[int, Any]] = {}
        self.malformed = 0

    def add(self, kind: str, record: Message) -> msg.ForceEstimateMessage | None:
        """Add one half; return the estimate once both halves of its stamp are in."""
        from teleop_force.ros2 import codec  # rosbags: for ROS 2 sessions only

        oldest_kept_ns = record.log_time - _HALF_WAIT_NS
        _forget_before(self.wrenches, oldest_kept_ns)
        _forget_before(self.diagnostics, oldest_kept_ns)
        try:
            if kind == ESTIMATED_CF:
                wrench = codec.decode_wrench(record.data)
                other = self.diagnostics.pop(wrench.t_ns, None)
                if other is None:
                    self.wrenches[wrench.t_ns] = (record.log_time, record.sequence, wrench)
                    return None
                seq, diagnostics = record.sequence, other[1]
            else:
                diagnostics = codec.decode_estimate_diagnostics(record.data)
                half = self.wrenches.pop(diagnostics.t_ns, None)
                if half is None:
                    self.diagnostics[diagnostics.t_ns] = (record.log_time, diagnostics)
                    return None
                _, seq, wrench = half
            return codec.estimate_message(seq, wrench, diagnostics)
        except MessageError:
            self.malformed += 1  # recorded as received; skipped (SessionReader.messages)
            return None


def _forget_before(pending: dict[int, tuple[Any, ...]], oldest_kept_ns: int) -> None:
    """Drop the halves logged before ``oldest_kept_ns`` (the first ones: log-time order)."""
    while pending:
        stamp = next(iter(pending))
        if pending[stamp][0] >= oldest_kept_ns:
            return
        del pending[stamp]


#: What :meth:`SessionReader._decode_ros2` returns for a message that does not decode.
_MALFORMED: Any = object()


class SessionReader:
    """Read a session MCAP file (ROS 2 or older), complete or truncated by a crash of its writer.

    Opening lists the file's records and raises DataError naming the file for anything that
    is not a readable MCAP; a chunk with complete message indexes is not decompressed then
    (its counts come from the indexes, its CRC is checked when it is read), so opening
    costs little more than reading the schemas and indexes. Iterating yields ``(topic, log_time_ns,
    message)`` in log-time order (equal log times: in file order), decompressing one chunk at a
    time; ``message`` is a :mod:`teleop_force.transport.messages` object for the ROS 2 types
    of :mod:`teleop_force.ros2.topics` (:meth:`messages`) and this project's older schemas (CDR
    ``teleop_force/msg/...`` or JSON ``teleop_force....``), the decoded JSON value for other
    JSON channels, and the raw bytes otherwise (:meth:`raw_messages`: every message as
    stored). :attr:`topics` maps each channel to its schema name, :attr:`streams` each stream
    to its channel.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.metadata: dict[str, str] = {}
        #: Whether the file lacks its footer (the writer did not close it).
        self.truncated = True
        #: Messages of ROS 2 channels that did not decode in the last :meth:`messages`, by topic.
        self.malformed: dict[str, int] = {}
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
        """List the file's records: a chunk whose message indexes are complete is not read.

        Its message counts and earliest log time come from its message index records; its
        CRC is checked when it is read (iterating). Other chunks (no or partial index: the
        last chunk of a crashed recording, other writers) are decompressed and parsed now.
        """
        with mc.mapped_file(self.path) as data:
            scan = mc.scan_mcap(data, self.path)
            self.truncated = scan.truncated
            self.metadata.update(scan.metadata.get(METADATA_NAME, {}))
            for schema in scan.schemas.values():
                self._add_schema(schema)
            for channel in scan.channels.values():
                self._add_channel(channel)
            for ref in scan.chunks:
                self._scan_chunk(data, ref)
            for order, body, length in scan.loose:
                try:
                    record = Message.read(
                        ReadDataStream(io.BytesIO(data[body : body + length])), length
                    )
                except Exception as exc:  # any parse failure means a corrupt file
                    problem = f"corrupt MCAP message record at byte {body}: {exc}"
                    raise self._error(problem) from None
                self._check_channel(record.channel_id)
                self._counts[record.channel_id] = self._counts.get(record.channel_id, 0) + 1
                self._loose.append(_Loose(order, record))
        if self.metadata.get("format", FORMAT_NAME) != FORMAT_NAME:
            raise self._error(f"not a teleop-force session (format {self.metadata['format']!r})")

    def _scan_chunk(self, data: mc.Buffer, ref: mc.ChunkRef) -> None:
        ids = set(ref.index)
        if ref.index_complete and ids and ids <= set(self._channels):
            counts: dict[int, int] = {}
            start_ns: int | None = None
            for channel_id, (body, length) in ref.index.items():
                try:
                    entries = mc.index_entries(data, body, length)
                except (ValueError, struct.error) as exc:
                    raise self._error(f"corrupt message index at byte {body}: {exc}") from None
                if entries.shape[0]:
                    counts[channel_id] = entries.shape[0]
                    first = int(entries[:, 0].min())
                    start_ns = first if start_ns is None else min(start_ns, first)
            if start_ns is not None:
                for channel_id, count in counts.items():
                    self._counts[channel_id] = self._counts.get(channel_id, 0) + count
                self._chunks.append(_ChunkRef(ref.order, ref.offset, ref.length, start_ns))
            return
        chunk = bytes(data[ref.offset : ref.offset + ref.length])
        try:
            self._record(Opcode.CHUNK, chunk, ref.offset, ref.order)
        except DataError:
            raise
        except Exception as exc:  # any parse failure means a corrupt file
            raise self._error(f"corrupt chunk at byte {ref.offset}: {exc}") from None

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
        """Device ids that have at least one stream (:class:`Stream`), sorted."""
        return sorted({stream.device for stream in self.streams})

    @property
    def streams(self) -> dict[Stream, str]:
        """Map each recorded stream to its channel topic (a ROS 2 channel before an old one)."""
        found: dict[Stream, str] = {}
        for channel in sorted(self._channels.values(), key=lambda c: not self._is_ros2(c)):
            stream = parse_stream(channel.topic)
            if stream is not None:
                found.setdefault(stream, channel.topic)
        return found

    def stream_topic(self, device: str, kind: str) -> str | None:
        """Return the channel topic of ``device``'s ``kind`` stream (``None``: not recorded)."""
        return self.streams.get(Stream(device, kind))

    def stream_count(self, device: str, kind: str) -> int:
        """Return the messages recorded on ``device``'s ``kind`` stream."""
        topic = self.stream_topic(device, kind)
        return 0 if topic is None else self.message_counts.get(topic, 0)

    @property
    def ros2(self) -> bool:
        """Whether the session holds ROS 2 channels (``ros2msg`` schemas of ROS 2 types)."""
        return any(self._is_ros2(channel) for channel in self._channels.values())

    def is_ros2_topic(self, topic: str) -> bool:
        """Whether channel ``topic`` carries ROS 2 messages (a ``ros2msg`` schema of ROS 2)."""
        return any(c.topic == topic and self._is_ros2(c) for c in self._channels.values())

    def _is_ros2(self, channel: Channel) -> bool:
        schema = self._schemas.get(channel.schema_id)
        return (
            schema is not None
            and schema.encoding == cdr.SCHEMA_ENCODING
            and channel.message_encoding == cdr.MESSAGE_ENCODING
            and schema.name not in cdr.MESSAGE_CLASSES_BY_CDR_SCHEMA
        )

    # -- iteration

    def __iter__(self) -> Iterator[tuple[str, int, Any]]:
        """Iterate over every message, in log-time order."""
        return self.messages()

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, Any]]:
        """Iterate ``(topic, log_time_ns, message)`` in log-time order, optionally filtered.

        A ROS 2 channel's message is decoded with :mod:`teleop_force.ros2.codec` into the
        project's message of its stream (``seq``: the MCAP sequence); an estimate's two halves
        (``/<device>/estimated_cf`` and ``/<device>/estimate_diagnostics``, one header stamp)
        are joined (:func:`~teleop_force.ros2.codec.estimate_message`) into one
        ForceEstimateMessage on the ``estimated_cf`` topic, yielded with the later half's
        log time; the diagnostics are not yielded on their own, and a half whose other half
        never comes is dropped. Other ROS 2 types are yielded as bytes. A ROS 2 session holds
        the messages as they were received: one that does not decode is skipped and counted in
        :attr:`malformed` (by topic).
        """
        wanted = None if topics is None else set(topics)
        joins: dict[str, _EstimateJoin] = {}
        self.malformed = {}
        for channel, record in self._records_in_time_order():
            ros2 = self._is_ros2(channel)
            if ros2:
                stream = parse_stream(channel.topic)
                if stream is not None and stream.kind in (ESTIMATED_CF, ESTIMATE_DIAGNOSTICS):
                    target = Stream(stream.device, ESTIMATED_CF).ros2_topic()
                    if wanted is not None and target not in wanted:
                        continue
                    join = joins.get(stream.device)
                    if join is None:
                        join = joins[stream.device] = _EstimateJoin(self.path, target)
                    before = join.malformed
                    joined = join.add(stream.kind, record)
                    if join.malformed != before:
                        self.malformed[channel.topic] = self.malformed.get(channel.topic, 0) + 1
                    if joined is not None:
                        yield target, record.log_time, joined
                    continue
            if wanted is not None and channel.topic not in wanted:
                continue
            if ros2:
                decoded = self._decode_ros2(channel, record)
                if decoded is _MALFORMED:
                    self.malformed[channel.topic] = self.malformed.get(channel.topic, 0) + 1
                    continue
                yield channel.topic, record.log_time, decoded
            else:
                yield channel.topic, record.log_time, self._decode(channel, record)

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """Iterate the messages as stored (:class:`RawMessage`), in log-time order."""
        wanted = None if topics is None else set(topics)
        for channel, record in self._records_in_time_order():
            if wanted is not None and channel.topic not in wanted:
                continue
            schema = self._schemas.get(channel.schema_id)
            yield RawMessage(
                topic=channel.topic,
                schema_name="" if schema is None else schema.name,
                message_encoding=channel.message_encoding,
                log_time_ns=record.log_time,
                publish_time_ns=record.publish_time,
                sequence=record.sequence,
                data=record.data,
            )

    def _decode_ros2(self, channel: Channel, record: Message) -> Any:
        from teleop_force.ros2 import codec  # rosbags: for ROS 2 sessions only

        schema = self._schemas[channel.schema_id]
        stream = parse_stream(channel.topic)
        kind = None if stream is None else stream.kind
        seq, data = record.sequence, record.data
        try:
            if schema.name == interfaces.JOINT_STATE:
                if kind == SETPOINT_JS:
                    return codec.decode_joint_setpoint(data, seq)[0]
                return codec.decode_joint_state(data, seq)[0]
            if schema.name == interfaces.WRENCH_STAMPED:
                return codec.decode_contact_force(data, seq)
            if schema.name == interfaces.STATUS:
                return codec.decode_status(data, seq)
            if schema.name == interfaces.SERVICE_DIAGNOSTICS:
                return codec.decode_service_diagnostics(data, seq)
        except MessageError:
            return _MALFORMED
        return data

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
    with_js = sorted(d for d in reader.devices() if reader.stream_count(d, MEASURED_JS) > 0)
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
        raise DataError(
            "no joint states (/<device>/measured_js or omni/<device>/measured_js)",
            path=reader.path,
        )
    primary = reader.metadata.get("primary_device")
    if primary in with_js:
        return primary
    if len(with_js) == 1:
        return with_js[0]
    with_force = [
        d
        for d in with_js
        if reader.stream_count(d, TRUE_CF) + reader.stream_count(d, ESTIMATED_CF) > 0
    ]
    if len(with_force) == 1:
        return with_force[0]
    raise DataError(
        f"joint states of several devices ({', '.join(with_js)}); choose one "
        "(metadata 'primary_device' or the device argument)",
        path=reader.path,
    )


def read_session_as_recording(
    path: str | os.PathLike[str],
    device: str | None = None,
    driver: DriverInterface | None = None,
) -> Recording:
    """Turn a session into an interchange :class:`Recording` of one device.

    Samples are the ``measured_js`` messages of ``device`` ordered by their source stamp
    (duplicate stamps dropped), with ``t_s`` counted from the first one; ``tau_nm`` is their
    ``effort`` (commanded torque). The true tip force (``true_cf``; ``measured_cf`` in
    sessions recorded before ROS 2), if recorded, is linearly interpolated at those stamps
    (held constant beyond its first and last sample).
    Without ``device``: the metadata's ``primary_device``, else the only device with joint
    states, else the only one of those with a force channel.
    A driver's JointStates (a session recorded through a live driver) are converted with
    ``driver``, else with the description the session's metadata carries
    (:mod:`teleop_force.io.driver_session`).
    """
    return read_session_with_notes(path, device, driver)[0]


def read_session_with_notes(
    path: str | os.PathLike[str],
    device: str | None = None,
    driver: DriverInterface | None = None,
) -> tuple[Recording, tuple[str, ...]]:
    """Like :func:`read_session_as_recording`, plus notes on what reading did."""
    from teleop_force.io import driver_session

    reader = SessionReader(path)
    device = _pick_device(reader, device)
    js_topic = reader.stream_topic(device, MEASURED_JS)
    assert js_topic is not None  # _pick_device's contract
    from_metadata = driver is None
    interface = (
        driver_session.session_driver(reader.metadata, reader.path) if driver is None else driver
    )
    notes: tuple[str, ...] = ()
    if interface is None:
        try:
            joint_states = read_joint_state_arrays(reader.path, js_topic)
        except DataError as exc:
            hint = driver_session.driver_hint(reader, js_topic)
            if hint is None:
                raise
            raise DataError(f"{exc.problem}; {hint}", path=reader.path, column=js_topic) from None
        t_ns, q_rad, tau_nm = joint_states.t_ns, joint_states.q_rad, joint_states.effort_nm
    else:
        converted = driver_session.read_driver_joint_states(reader, js_topic, interface)
        t_ns, q_rad, tau_nm = converted.t_ns, converted.q_rad, converted.tau_nm
        source = "from the recording's metadata" if from_metadata else "as given"
        notes = (
            f"{reader.path}: {js_topic} converted from driver {interface.name}'s conventions "
            f"(the description {source}; names {', '.join(converted.names)}); velocities "
            "derived from the angles"
            + ("" if converted.stamped else "; no header stamps, timed by the source times"),
        )
    recording = _recording_of(reader, device, t_ns, np.hstack((q_rad, tau_nm)), q_rad.shape[1])
    return recording, notes


def _recording_of(
    reader: SessionReader, device: str, t_ns: np.ndarray, table: np.ndarray, n_joints: int
) -> Recording:
    """Return the Recording of ``[q | tau]`` rows stamped ``t_ns``, with the device's true force."""
    cf_topic = reader.stream_topic(device, TRUE_CF)
    f_stamps: list[int] = []
    forces: list[tuple[float, ...]] = []
    wrenches = None if cf_topic is None else read_wrench_arrays(reader.path, cf_topic)
    if wrenches is not None:  # a ROS 2 channel in one layout: as arrays
        f_stamps, forces = wrenches.t_ns.tolist(), wrenches.force_n.tolist()
    elif cf_topic is not None:
        for _, _, message in reader.messages([cf_topic]):
            if isinstance(message, msg.ContactForce):
                f_stamps.append(message.t_ns)
                forces.append(message.f_n)
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
