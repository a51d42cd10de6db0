"""Columnar reading of recorded joint states: one topic of a session as numpy arrays.

:func:`read_joint_state_arrays` returns the JointState messages of one channel exactly as
:class:`~teleop_force.io.mcap_session.SessionReader` yields them (same order: by log time,
ties in file order; same checks), but as arrays and without a Python object per message.
In a CDR recording each chunk holds one channel (:mod:`teleop_force.io.cdr_chunks`), so only
the topic's chunks are decompressed, and a decompressed chunk of joint states is reshaped to a
``(count, record size)`` array whose columns are the fields. Anything else (recordings with JSON
channels made before the CDR encoding, chunks mixing channels, the last chunk of a crashed
recording whose message index was not written) is read record by record: correct, slower.

A ROS 2 session's ``sensor_msgs/msg/JointState`` channel (``/slave/measured_js``) is read the
same way: a chunk of same-size payloads is split with :mod:`teleop_force.io.ros2_columns`
(``seq`` is the MCAP sequence, rmw_zenoh's attachment sequence number; ``t_ns`` the header
stamp), any other with :mod:`teleop_force.ros2.codec`.
"""

from __future__ import annotations

import io
import itertools
import json
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Schema

from teleop_force.errors import DataError, MessageError
from teleop_force.io import cdr_chunks as mc
from teleop_force.io import cdr_messages as cdr
from teleop_force.io import ros2_columns
from teleop_force.transport import messages as m

#: Value of a session's ``format`` metadata key (in the ``teleop_force.session`` record).
_METADATA_NAME: Final = "teleop_force.session"
_FORMAT_NAME: Final = "teleop-force-session"
_CDR_SCHEMA: Final = cdr.CDR_SCHEMAS[m.JointState].name
_ROS2_SCHEMA: Final = "sensor_msgs/msg/JointState"
_ROS2_WRENCH: Final = "geometry_msgs/msg/WrenchStamped"


@dataclass(frozen=True)
class JointStateArrays:
    """The JointState messages of one recorded topic, as arrays in the order they are read.

    Attributes:
        seq: ``(N,)`` uint32, each message's counter.
        t_ns: ``(N,)`` int64, its source stamp [ns since the epoch].
        log_time_ns: ``(N,)`` int64, when the recorder received it [ns since the epoch].
        q_rad: ``(N, n)`` float64 joint angles.
        qd_rad_s: ``(N, n)`` float64 joint velocities.
        effort_nm: ``(N, n)`` float64 commanded motor torques.

    """

    seq: np.ndarray
    t_ns: np.ndarray
    log_time_ns: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    effort_nm: np.ndarray

    def __post_init__(self) -> None:
        """Check dtypes and shapes agree; raise DataError."""
        n = self.seq.shape[0]
        for name, dtype in (("seq", np.uint32), ("t_ns", np.int64), ("log_time_ns", np.int64)):
            array = getattr(self, name)
            if array.dtype != dtype or array.shape != (n,):
                raise DataError(f"{name} must be ({n},) {np.dtype(dtype).name}")
        joints = self.q_rad.shape[1] if self.q_rad.ndim == 2 else -1
        for name in ("q_rad", "qd_rad_s", "effort_nm"):
            array = getattr(self, name)
            if array.dtype != np.float64 or array.shape != (n, joints):
                raise DataError(f"{name} must be ({n}, n_joints) float64")

    @property
    def n_samples(self) -> int:
        """Number of messages."""
        return int(self.seq.shape[0])

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return int(self.q_rad.shape[1])


@dataclass(frozen=True)
class _Piece:
    """Messages read from one place of the file, in record order."""

    order: int
    log_time_ns: np.ndarray
    seq: np.ndarray
    t_ns: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    effort_nm: np.ndarray


@dataclass(frozen=True)
class _Block:
    """A decompressed chunk of same-size JointState CDR records, not yet split in columns."""

    order: int
    records: np.ndarray  # (K, record size) uint8
    ros2: bool  # sensor_msgs/msg/JointState (else the project's teleop_force/msg/JointState)


class _TopicReader:
    """Collect the joint states of one topic from a scanned file."""

    def __init__(self, data: mc.Buffer, path: Path, topic: str) -> None:
        self.data = data
        self.decompressor = zstandard.ZstdDecompressor()
        self.path = path
        self.topic = topic
        self.scan = mc.scan_mcap(data, path)
        found = self.scan.metadata.get(_METADATA_NAME, {}).get("format", _FORMAT_NAME)
        if found != _FORMAT_NAME:
            raise DataError(f"not a teleop-force session (format {found!r})", path=path)
        self.wanted: set[int] = set()
        self.ros2_ids: set[int] = set()  # the wanted channels of sensor_msgs/msg/JointState
        self.pieces: list[_Piece | _Block] = []
        for channel in list(self.scan.channels.values()):
            self._consider(channel)

    def _error(self, problem: str) -> DataError:
        return DataError(problem, path=self.path, column=self.topic)

    def _consider(self, channel: Channel) -> None:
        """Add ``channel`` to the wanted ones if it is the topic's; check what it holds."""
        if channel.topic != self.topic:
            return
        schema = self.scan.schemas.get(channel.schema_id)
        name = "" if schema is None else schema.name
        pair = (channel.message_encoding, name)
        if pair == (cdr.MESSAGE_ENCODING, _ROS2_SCHEMA):
            self.ros2_ids.add(channel.id)
        elif pair not in ((cdr.MESSAGE_ENCODING, _CDR_SCHEMA), ("json", m.JointState.SCHEMA_NAME)):
            raise self._error(f"{self.topic} does not hold JointState messages")
        self.wanted.add(channel.id)

    def read(self) -> JointStateArrays:
        for ref in self.scan.chunks:
            self._read_chunk(ref)
        loose = [
            (order, body, length)
            for order, body, length in self.scan.loose
            if mc.MESSAGE_FIELDS.unpack_from(self.data, body)[0] in self.wanted
        ]
        for order, body, length in loose:
            self._add_records(order, self.data, [(body, length)])
        if not self.pieces:
            raise self._error(f"no joint states on {self.topic}")
        return self._assemble()

    def _read_chunk(self, ref: mc.ChunkRef) -> None:
        ids = set(ref.index)
        indexed = ref.index_complete and ids and ids <= set(self.scan.channels)
        if indexed and not ids & self.wanted:
            return  # the message indexes say: none of the topic's messages in there
        records = mc.chunk_records(self.data, ref, self.path, self.decompressor)
        if indexed and len(ids) == 1:
            (channel_id,) = ids
            try:
                entries = mc.index_entries(self.data, *ref.index[channel_id])
            except ValueError as exc:
                raise self._error(f"corrupt message index at byte {ref.offset}: {exc}") from None
            if self._read_block(ref.order, records, channel_id, entries):
                return
        try:
            found = []
            for opcode, body, length in mc.walk_chunk(records):
                if opcode == Opcode.MESSAGE:
                    channel_id = mc.MESSAGE_FIELDS.unpack_from(records, body)[0]
                    if channel_id not in self.scan.channels:
                        raise self._error(f"message on unknown channel id {channel_id}")
                    if channel_id in self.wanted:
                        found.append((body, length))
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    self._chunk_definition(opcode, records, body, length)
        except DataError:
            raise
        except (ValueError, struct.error) as exc:
            raise self._error(f"corrupt chunk at byte {ref.offset}: {exc}") from None
        if found:
            self._add_records(ref.order, records, found)

    def _chunk_definition(self, opcode: int, records: bytes, body: int, length: int) -> None:
        stream = ReadDataStream(io.BytesIO(records[body : body + length]))
        if opcode == Opcode.SCHEMA:
            schema = Schema.read(stream)
            self.scan.schemas[schema.id] = schema
        else:
            channel = Channel.read(stream)
            self.scan.channels[channel.id] = channel
            self._consider(channel)

    def _read_block(self, order: int, records: bytes, channel_id: int, entries: np.ndarray) -> bool:
        """Read a chunk holding only same-size records of ``channel_id``; False if it is not."""
        count = entries.shape[0]
        if count == 0 or len(records) % count:
            return False
        width = len(records) // count
        expected = np.arange(count, dtype=np.uint64) * np.uint64(width)
        if not np.array_equal(entries[:, 1], expected) or width <= mc.MESSAGE_HEAD.size:
            return False
        block = np.frombuffer(records, dtype=np.uint8).reshape(count, width)
        head = mc.MESSAGE_HEAD.pack(
            Opcode.MESSAGE, width - mc.RECORD_HEAD.size, channel_id, 0, 0, 0
        )
        if not (block[:, :11] == np.frombuffer(head[:11], dtype=np.uint8)).all():
            return False
        if self.scan.channels[channel_id].message_encoding != cdr.MESSAGE_ENCODING:
            return False
        self.pieces.append(_Block(order, block, channel_id in self.ros2_ids))
        return True

    def _columns(self, order: int, records: np.ndarray, ros2: bool) -> _Piece:
        """Split same-size JointState CDR records in columns (checking them)."""
        records = np.ascontiguousarray(records)
        log_time_ns = np.ascontiguousarray(records[:, 15:23]).view("<i8").reshape(-1)
        if ros2:
            return self._ros2_columns(order, records, log_time_ns)
        try:
            seq, t_ns, q, qd, effort = cdr.joint_state_columns(records, mc.MESSAGE_HEAD.size)
        except MessageError as exc:
            raise self._error(f"bad JointState: {exc}") from None
        return _Piece(order, log_time_ns, seq, t_ns, q, qd, effort)

    def _ros2_columns(self, order: int, records: np.ndarray, log_time_ns: np.ndarray) -> _Piece:
        """Split same-size sensor_msgs/msg/JointState records; seq is the MCAP sequence."""
        seq = np.ascontiguousarray(records[:, 11:15]).view("<u4").reshape(-1)
        try:
            columns = ros2_columns.joint_state_columns(records[:, mc.MESSAGE_HEAD.size :])
        except ros2_columns.LayoutMismatch:  # several layouts: one by one
            return self._ros2_one_by_one(order, records)
        except MessageError as exc:
            raise self._error(f"bad JointState: {exc}") from None
        values = (columns.position, columns.velocity, columns.effort)
        if columns.position.shape[1] == 0:
            raise self._error("bad JointState: no joints")
        for array in values:
            finite = np.isfinite(array).all(axis=1)
            if not finite.all():
                row = int(np.argmin(finite))
                raise self._error(f"bad JointState at log time {log_time_ns[row]} ns: non-finite")
        return _Piece(order, log_time_ns, seq, columns.t_ns, *values)

    def _ros2_one_by_one(self, order: int, records: np.ndarray) -> _Piece:
        """Decode same-size records of differing layouts with the codec (one joint count)."""
        width = records.shape[1]
        raw = records.tobytes()
        found = [(k * width + mc.RECORD_HEAD.size, width - mc.RECORD_HEAD.size)
                 for k in range(records.shape[0])]  # fmt: skip
        before = len(self.pieces)
        self._add_records(order, raw, found)
        pieces = [p for p in self.pieces[before:] if isinstance(p, _Piece)]
        del self.pieces[before:]
        if len(pieces) != 1:
            first, second = pieces[0], pieces[1]
            raise self._error(
                f"joint count changes from {first.q_rad.shape[1]} to {second.q_rad.shape[1]} "
                f"at seq {second.seq[0]}"
            )
        return pieces[0]

    def _merged_pieces(self) -> list[_Piece]:
        """Return the pieces in file order, consecutive blocks of one record size as one."""
        merged: list[_Piece] = []
        run: list[_Block] = []

        def split_run() -> None:
            if run:
                records = run[0].records
                if len(run) > 1:
                    records = np.concatenate([block.records for block in run])
                merged.append(self._columns(run[0].order, records, run[0].ros2))
                run.clear()

        for item in sorted(self.pieces, key=lambda p: p.order):  # stable: record order kept
            if isinstance(item, _Block):
                if run and (run[0].records.shape[1], run[0].ros2) != (
                    item.records.shape[1],
                    item.ros2,
                ):
                    split_run()
                run.append(item)
            else:
                split_run()
                merged.append(item)
        split_run()
        return merged

    def _add_records(self, order: int, buffer: mc.Buffer, found: list[tuple[int, int]]) -> None:
        """Decode messages one by one (JSON channels, mixed chunks)."""
        rows = []
        for body, length in found:
            channel_id, sequence, log_time_ns, _ = mc.MESSAGE_FIELDS.unpack_from(buffer, body)
            payload = buffer[body + mc.MESSAGE_FIELDS.size : body + length]
            channel = self.scan.channels[channel_id]
            try:
                if channel_id in self.ros2_ids:
                    from teleop_force.ros2 import codec  # rosbags: for ROS 2 sessions only

                    js: m.Message = codec.decode_joint_state(bytes(payload), sequence)[0]
                elif channel.message_encoding == cdr.MESSAGE_ENCODING:
                    js = cdr.decode_cdr(m.JointState, payload)
                else:
                    js = m.JointState.from_json_dict(json.loads(payload))
            except (MessageError, ValueError) as exc:
                raise self._error(f"bad JointState at log time {log_time_ns} ns: {exc}") from None
            if not isinstance(js, m.JointState):  # pragma: no cover - decode_cdr's contract
                raise self._error("not a JointState")
            rows.append((log_time_ns, js))
        # One piece per run of equal joint counts (a change is reported once sorted).
        for _, run in itertools.groupby(rows, key=lambda row: row[1].n_joints):
            items = list(run)
            self.pieces.append(
                _Piece(
                    order,
                    np.array([log for log, _ in items], dtype=np.uint64).astype(np.int64),
                    np.array([js.seq for _, js in items], dtype=np.uint32),
                    np.array([js.t_ns for _, js in items], dtype=np.int64),
                    np.array([js.q_rad for _, js in items], dtype=np.float64),
                    np.array([js.qd_rad_s for _, js in items], dtype=np.float64),
                    np.array([js.effort_nm for _, js in items], dtype=np.float64),
                )
            )

    def _assemble(self) -> JointStateArrays:
        pieces = self._merged_pieces()

        def joined(name: str) -> np.ndarray:
            arrays = [getattr(p, name) for p in pieces]
            return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)

        log_time_ns = joined("log_time_ns")
        seq = joined("seq")
        ordered = bool(np.all(log_time_ns[1:] >= log_time_ns[:-1]))
        order = None if ordered else np.argsort(log_time_ns, kind="stable")
        joints = {p.q_rad.shape[1] for p in pieces}
        if len(joints) > 1:
            counts = np.concatenate([np.full(p.seq.shape[0], p.q_rad.shape[1]) for p in pieces])
            if order is not None:
                counts, seq = counts[order], seq[order]
            change = int(np.flatnonzero(np.diff(counts))[0]) + 1
            raise self._error(
                f"joint count changes from {counts[change - 1]} to {counts[change]} "
                f"at seq {seq[change]}"
            )

        def column(name: str) -> np.ndarray:
            array = joined(name)
            return array if order is None else array[order]

        return JointStateArrays(
            seq=column("seq"),
            t_ns=column("t_ns"),
            log_time_ns=column("log_time_ns"),
            q_rad=column("q_rad"),
            qd_rad_s=column("qd_rad_s"),
            effort_nm=column("effort_nm"),
        )


def read_joint_state_arrays(path: str | os.PathLike[str], topic: str) -> JointStateArrays:
    """Read the JointState messages of channel ``topic`` from a session, as arrays.

    Same messages, order and checks as :class:`~teleop_force.io.mcap_session.SessionReader`
    (also on a file truncated by a crash); raise DataError naming the file if it is not a
    readable session, the topic has no joint states or its joint count changes.
    """
    path = Path(path)
    with mc.mapped_file(path) as data:
        return _TopicReader(data, path, topic).read()


@dataclass(frozen=True)
class WrenchArrays:
    """The WrenchStamped messages of one ROS 2 channel: stamps [ns] and ``(N, 3)`` forces [N]."""

    log_time_ns: np.ndarray
    t_ns: np.ndarray
    force_n: np.ndarray


def read_wrench_arrays(path: str | os.PathLike[str], topic: str) -> WrenchArrays | None:
    """Read a ROS 2 ``geometry_msgs/msg/WrenchStamped`` channel as arrays, in log-time order.

    Only for what :class:`~teleop_force.io.cdr_chunks.ChunkedMcapWriter` writes (each chunk one
    channel, with its message index; one layout per chunk, finite forces): ``None`` otherwise
    (a crashed recording's last chunk, other writers), and the caller reads the messages one
    by one, with their checks. Raise DataError for a file that is not a readable session.
    """
    path = Path(path)
    with mc.mapped_file(path) as data:
        scan = mc.scan_mcap(data, path)
        ids = set()
        for channel in scan.channels.values():
            schema = scan.schemas.get(channel.schema_id)
            if channel.topic == topic:
                if schema is None or schema.name != _ROS2_WRENCH:
                    return None
                ids.add(channel.id)
        if len(ids) != 1 or any(
            mc.MESSAGE_FIELDS.unpack_from(data, body)[0] in ids for _, body, _ in scan.loose
        ):
            return None
        (channel_id,) = ids
        decompressor = zstandard.ZstdDecompressor()
        logs, stamps, forces = [], [], []
        for ref in scan.chunks:
            in_chunk = set(ref.index)
            if not (ref.index_complete and in_chunk and in_chunk <= set(scan.channels)):
                return None
            if channel_id not in in_chunk:
                continue
            if len(in_chunk) > 1:
                return None
            try:
                entries = mc.index_entries(data, *ref.index[channel_id])
                records = mc.chunk_records(data, ref, path, decompressor)
                located = mc.channel_records(records, channel_id, entries)
            except (ValueError, struct.error):
                return None  # read one by one: the reader names the problem
            sizes = located.payload_size
            if sizes.size == 0:
                continue
            if int(sizes.min()) != int(sizes.max()):
                return None
            raw = np.frombuffer(records, dtype=np.uint8)
            block = raw[located.payload_offset[:, None] + np.arange(int(sizes[0]))]
            try:
                columns = ros2_columns.wrench_columns(block)
            except ros2_columns.LayoutMismatch:
                return None
            logs.append(located.log_time_ns)
            stamps.append(columns.t_ns)
            forces.append(columns.force)
    if not logs:
        return WrenchArrays(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
    log_time_ns = np.concatenate(logs)
    force = np.concatenate(forces)
    if not np.isfinite(force).all():
        return None
    order = np.argsort(log_time_ns, kind="stable")
    return WrenchArrays(log_time_ns[order], np.concatenate(stamps)[order], force[order])


__all__ = ("JointStateArrays", "WrenchArrays", "read_joint_state_arrays", "read_wrench_arrays")
