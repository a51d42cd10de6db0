"""The MCAP container of a recording: top-level records, one chunk per channel, message indexes.

Writing (:class:`ChunkedMcapWriter`): schema and channel records are written at the top level
as soon as a channel is first used (so a truncated file has them); messages gather in one open
chunk *per channel*, closed when it reaches the chunk size or on :meth:`~ChunkedMcapWriter.
close_chunks`, and written, compressed, in one write call together with its message index
record. A chunk therefore holds the messages of one channel only, in the order they were
added: a reader of one channel decompresses only that channel's chunks, and a channel of
fixed-size messages (joint states) is a plain ``(count, record size)`` array once decompressed.
Blocks of messages are added as numpy arrays (:meth:`~ChunkedMcapWriter.add_messages`), without
a Python object per message. :meth:`~ChunkedMcapWriter.finish` writes the summary (schemas,
channels, statistics, chunk and metadata indexes) and the footer, as the MCAP specification
describes, so any MCAP reader (Foxglove, ``mcap`` CLI, the ``mcap`` Python reader) reads it.

Reading (:func:`scan_mcap`): one pass over the top-level records of a file's bytes, complete
or truncated by a crash of its writer, listing schemas, channels, metadata, loose messages and
chunks with the channels their message index records name; :func:`chunk_records` decompresses
one chunk and checks its CRC; :func:`walk_chunk` lists the records inside one;
:func:`channel_records` locates the messages of one channel in a chunk with numpy (to copy them
without a Python object each).
"""

from __future__ import annotations

import io
import mmap
import os
import struct
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from teleop_force.errors import ConfigurationError, DataError

MAGIC: Final = b"\x89MCAP0\r\n"
#: Chunk compressions a writer offers, by option name (value: the MCAP compression field).
COMPRESSIONS: Final = {"zstd": "zstd", "lz4": "lz4", "none": ""}
#: Larger than any record this project writes: a longer length means a corrupt file.
MAX_RECORD_BYTES: Final = 1 << 30

RECORD_HEAD: Final = struct.Struct("<BQ")  # opcode, body length
MESSAGE_HEAD: Final = struct.Struct("<BQHIQQ")  # + channel, sequence, log time, publish time
MESSAGE_FIELDS: Final = struct.Struct("<HIQQ")  # a message record's body before its data
_CHUNK_HEAD: Final = struct.Struct("<BQQQQII")  # + start, end, size, crc, compression length
_CHUNK_FIELDS: Final = struct.Struct("<QQQII")  # a chunk body up to the compression string
_U64: Final = struct.Struct("<Q")
_INDEX_HEAD: Final = struct.Struct("<BQHI")  # + channel id, byte length of the entries
_INDEX_FIELDS: Final = struct.Struct("<HI")
_INDEX_ENTRY: Final = struct.Struct("<QQ")  # log time, offset in the chunk's records


class DirectFile:
    """Append-only file that hands every write straight to the OS and counts the bytes."""

    def __init__(self, path: Path) -> None:
        """Create (or truncate) ``path``; raise OSError."""
        self._raw = open(path, "wb", buffering=0)  # noqa: SIM115 - closed by close()
        self.position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Write all of ``data``; return its length."""
        view = memoryview(data).cast("B")
        total = view.nbytes
        while view.nbytes:
            written = self._raw.write(view)
            if written is None:  # pragma: no cover - only for non-blocking files
                continue
            view = view[written:]
            self.position += written
        return total

    def close(self) -> None:
        """Close the file."""
        self._raw.close()


@dataclass
class _OpenChunk:
    """Messages of one channel waiting to be written as a chunk."""

    parts: list[bytes] = field(default_factory=list)
    size: int = 0
    count: int = 0
    start_ns: int = 2**64
    end_ns: int = 0
    index: bytearray = field(default_factory=bytearray)


class ChunkedMcapWriter:
    """Write an MCAP file with one open chunk per channel (module docstring); not thread-safe.

    Args:
        file: Where the bytes go (written in whole records, never buffered).
        chunk_size_bytes: Uncompressed size at which a channel's chunk is written.
        compression: ``zstd``, ``lz4`` or ``none``.

    """

    def __init__(
        self, file: DirectFile, *, chunk_size_bytes: int, compression: str, profile: str = ""
    ) -> None:
        """Start the file: magic and header record (``profile``: MCAP's, e.g. ``ros2``)."""
        if compression not in COMPRESSIONS:
            raise ConfigurationError(
                f"compression must be one of {', '.join(COMPRESSIONS)}, got {compression!r}"
            )
        self._file = file
        self._chunk_size = int(chunk_size_bytes)
        self._compression = COMPRESSIONS[compression]
        self._zstd = zstandard.ZstdCompressor()
        self._open: dict[int, _OpenChunk] = {}
        self._record_dtypes: dict[int, np.dtype] = {}
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = {}
        self._start_ns = 2**64
        self._end_ns = 0
        #: Messages added so far, and those still in open (unwritten) chunks.
        self.messages = 0
        self.open_messages = 0
        builder = RecordBuilder()
        Header(profile=profile, library="teleop-force").write(builder)
        self._file.write(MAGIC + builder.end())

    # -- top-level records

    def _write_record(self, record: Schema | Channel | Metadata) -> int:
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        offset = self._file.position
        self._file.write(data)
        return offset

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        """Write a metadata record now."""
        offset = self._file.position
        builder = RecordBuilder()
        Metadata(name=name, metadata=values).write(builder)
        data = builder.end()
        self._file.write(data)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(data), name=name))

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a schema record now; return its id."""
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._write_record(schema)
        self._schemas.append(schema)
        return schema.id

    def add_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        """Write a channel record now; return its id."""
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            metadata={},
            schema_id=schema_id,
        )
        self._write_record(channel)
        self._channels.append(channel)
        return channel.id

    # -- messages

    def _count(self, channel_id: int, count: int, start_ns: int, end_ns: int) -> None:
        self._counts[channel_id] = self._counts.get(channel_id, 0) + count
        self.messages += count
        self.open_messages += count
        self._start_ns = min(self._start_ns, start_ns)
        self._end_ns = max(self._end_ns, end_ns)

    def add_message(
        self, channel_id: int, sequence: int, log_time_ns: int, publish_time_ns: int, data: bytes
    ) -> None:
        """Add one message to its channel's chunk (written when full)."""
        record = MESSAGE_HEAD.pack(
            Opcode.MESSAGE,
            MESSAGE_HEAD.size - RECORD_HEAD.size + len(data),
            channel_id,
            sequence,
            log_time_ns,
            publish_time_ns,
        )
        chunk = self._open.get(channel_id)
        if chunk is None:
            chunk = self._open[channel_id] = _OpenChunk()
        chunk.index += _INDEX_ENTRY.pack(log_time_ns, chunk.size)
        chunk.parts.append(record + data)
        chunk.size += len(record) + len(data)
        chunk.count += 1
        chunk.start_ns = min(chunk.start_ns, log_time_ns)
        chunk.end_ns = max(chunk.end_ns, log_time_ns)
        self._count(channel_id, 1, log_time_ns, log_time_ns)
        if chunk.size >= self._chunk_size:
            self._close_chunk(channel_id)

    def add_messages(
        self,
        channel_id: int,
        data: np.ndarray,
        sequence: np.ndarray,
        log_time_ns: np.ndarray,
        publish_time_ns: np.ndarray,
    ) -> None:
        """Add a block of same-size messages (``data``: ``(K, size)`` uint8) to the channel.

        ``sequence`` (uint32), ``log_time_ns`` and ``publish_time_ns`` (non-negative int64)
        have one entry per row; rows keep their order.
        """
        rows, size = data.shape
        if rows == 0:
            return
        dtype = self._record_dtypes.get(size)
        if dtype is None:
            dtype = self._record_dtypes[size] = _record_dtype(size)
        width = dtype.itemsize
        records = np.empty(rows, dtype=dtype)
        records["opcode"] = Opcode.MESSAGE
        records["length"] = width - RECORD_HEAD.size
        records["channel"] = channel_id
        records["sequence"] = sequence
        records["log_time"] = log_time_ns
        records["publish_time"] = publish_time_ns
        records["data"] = data
        logs = records["log_time"]
        self._count(channel_id, rows, int(logs.min()), int(logs.max()))
        start = 0
        while start < rows:
            chunk = self._open.get(channel_id)
            if chunk is None:
                chunk = self._open[channel_id] = _OpenChunk()
            room = max(1, -(-(self._chunk_size - chunk.size) // width))
            stop = min(rows, start + room)
            entries = np.empty((stop - start, 2), dtype="<u8")
            entries[:, 0] = logs[start:stop]
            entries[:, 1] = np.arange(chunk.size, chunk.size + (stop - start) * width, width)
            chunk.index += entries.tobytes()
            chunk.parts.append(records[start:stop].tobytes())
            chunk.size += (stop - start) * width
            chunk.count += stop - start
            chunk.start_ns = min(chunk.start_ns, int(logs[start:stop].min()))
            chunk.end_ns = max(chunk.end_ns, int(logs[start:stop].max()))
            if chunk.size >= self._chunk_size:
                self._close_chunk(channel_id)
            start = stop

    # -- chunks

    def _compress(self, data: bytes) -> bytes:
        if self._compression == "zstd":
            return self._zstd.compress(data)
        if self._compression == "lz4":
            return bytes(lz4.frame.compress(data))
        return data

    def _close_chunk(self, channel_id: int) -> None:
        chunk = self._open.pop(channel_id)
        data = b"".join(chunk.parts)
        compressed = self._compress(data)
        name = self._compression.encode()
        body = _CHUNK_FIELDS.size + len(name) + _U64.size + len(compressed)
        head = _CHUNK_HEAD.pack(
            Opcode.CHUNK,
            body,
            chunk.start_ns,
            chunk.end_ns,
            len(data),
            zlib.crc32(data),
            len(name),
        )
        head += name + _U64.pack(len(compressed))
        index = _INDEX_HEAD.pack(
            Opcode.MESSAGE_INDEX,
            _INDEX_FIELDS.size + len(chunk.index),
            channel_id,
            len(chunk.index),
        )
        offset = self._file.position
        self._file.write(b"".join((head, compressed, index, chunk.index)))
        chunk_length = len(head) + len(compressed)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=chunk.start_ns,
                message_end_time=chunk.end_ns,
                chunk_start_offset=offset,
                chunk_length=chunk_length,
                message_index_offsets={channel_id: offset + chunk_length},
                message_index_length=len(index) + len(chunk.index),
                compression=self._compression,
                compressed_size=len(compressed),
                uncompressed_size=len(data),
            )
        )
        self.open_messages -= chunk.count

    def close_chunks(self) -> None:
        """Write every open chunk now."""
        for channel_id in list(self._open):
            self._close_chunk(channel_id)

    def finish(self) -> None:
        """Write the open chunks, the summary and the footer (the file stays open)."""
        self.close_chunks()
        builder = RecordBuilder()
        DataEnd(data_section_crc=0).write(builder)
        self._file.write(builder.end())
        summary_start = self._file.position
        summary = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records: Sequence[McapRecord]) -> None:
            start = summary.count
            for record in records:
                record.write(summary)
            if summary.count > start:
                offsets.append(SummaryOffset(opcode, summary_start + start, summary.count - start))

        statistics = Statistics(
            message_count=self.messages,
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=0,
            metadata_count=len(self._metadata_indexes),
            chunk_count=len(self._chunk_indexes),
            message_start_time=self._start_ns if self.messages else 0,
            message_end_time=self._end_ns,
            channel_message_counts=dict(self._counts),
        )
        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        group(Opcode.STATISTICS, [statistics])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offset_start = summary_start + summary.count
        for item in offsets:
            item.write(summary)
        data = summary.end()
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(data))
        builder = RecordBuilder()
        Footer(
            summary_start=summary_start, summary_offset_start=offset_start, summary_crc=crc
        ).write(builder)
        self._file.write(data + builder.end() + MAGIC)


def _record_dtype(size: int) -> np.dtype:
    """Return the numpy layout of a message record with ``size`` bytes of data (packed)."""
    return np.dtype(
        [
            ("opcode", "u1"),
            ("length", "<u8"),
            ("channel", "<u2"),
            ("sequence", "<u4"),
            ("log_time", "<u8"),
            ("publish_time", "<u8"),
            ("data", "u1", (size,)),
        ]
    )


# --------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class ChunkRef:
    """A chunk record of a scanned file.

    Attributes:
        order: Position among the file's top-level records read.
        offset: Byte offset of the chunk record's body.
        length: Length of the body.
        start_ns: ``message_start_time`` of the chunk.
        index: Message index records after the chunk: channel id -> (body offset, length).
        index_complete: Whether those index records are all there (a complete record that
            is not a message index follows them).

    """

    order: int
    offset: int
    length: int
    start_ns: int
    index: dict[int, tuple[int, int]]
    index_complete: bool


@dataclass
class McapScan:
    """What :func:`scan_mcap` found in a file."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    chunks: list[ChunkRef] = field(default_factory=list)
    #: Messages outside chunks: (order, body offset, body length).
    loose: list[tuple[int, int, int]] = field(default_factory=list)
    #: Whether the file lacks its footer (the writer did not close it).
    truncated: bool = True


#: The bytes of a file being read: in memory, or mapped.
Buffer = bytes | mmap.mmap


@contextmanager
def mapped_file(path: Path) -> Iterator[Buffer]:
    """Map ``path`` into memory for reading (pages are read when touched); raise DataError."""
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed below
    except IsADirectoryError:
        raise DataError("is a directory, not an MCAP file", path=path) from None
    except OSError as exc:
        raise DataError(f"cannot read file: {exc.strerror or exc}", path=path) from None
    with f:
        if os.fstat(f.fileno()).st_size == 0:
            yield b""
            return
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            yield data


def scan_mcap(data: Buffer, path: Path) -> McapScan:
    """List the top-level records of an MCAP file's bytes; raise DataError naming ``path``."""
    if data[: len(MAGIC)] != MAGIC:
        raise DataError("not an MCAP file (bad magic)", path=path)
    scan = McapScan()
    offset = len(MAGIC)
    order = 0
    pending: dict[int, tuple[int, int]] | None = None  # index records of the last chunk
    last: tuple[int, int, int, int] | None = None
    size = len(data)
    while offset + RECORD_HEAD.size <= size:
        opcode, length = RECORD_HEAD.unpack_from(data, offset)
        body = offset + RECORD_HEAD.size
        if length > MAX_RECORD_BYTES:
            raise DataError(f"corrupt record at byte {offset}: length {length}", path=path)
        if body + length > size:
            break  # the writer died while writing this record
        if opcode == Opcode.MESSAGE_INDEX and pending is not None:
            channel_id, _ = _INDEX_FIELDS.unpack_from(data, body)
            pending[channel_id] = (body, length)
        else:
            if last is not None and pending is not None:
                scan.chunks.append(ChunkRef(*last, pending, True))
                last = pending = None
            if opcode == Opcode.FOOTER:
                scan.truncated = False
                break
            try:
                if opcode == Opcode.CHUNK:
                    start_ns = _U64.unpack_from(data, body)[0]
                    last, pending = (order, body, length, start_ns), {}
                elif opcode == Opcode.MESSAGE:
                    scan.loose.append((order, body, length))
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA):
                    stream = ReadDataStream(io.BytesIO(data[body : body + length]))
                    if opcode == Opcode.SCHEMA:
                        schema = Schema.read(stream)
                        scan.schemas[schema.id] = schema
                    elif opcode == Opcode.CHANNEL:
                        channel = Channel.read(stream)
                        scan.channels[channel.id] = channel
                    else:
                        record = Metadata.read(stream)
                        scan.metadata.setdefault(record.name, {}).update(record.metadata)
            except (struct.error, ValueError, UnicodeDecodeError, McapError) as exc:
                # McapError: a record shorter than its fields (mcap's EndOfFile)
                raise DataError(
                    f"corrupt MCAP record (opcode {opcode:#04x}) at byte {offset}: "
                    f"{exc or type(exc).__name__}",
                    path=path,
                ) from None
        order += 1
        offset = body + length
    if last is not None and pending is not None:
        scan.chunks.append(ChunkRef(*last, pending, False))
    return scan


def chunk_records(
    data: Buffer,
    ref: ChunkRef,
    path: Path,
    decompressor: zstandard.ZstdDecompressor | None = None,
) -> bytes:
    """Return the decompressed records of chunk ``ref``; raise DataError if it is corrupt."""
    try:
        _, _, size, crc, name_length = _CHUNK_FIELDS.unpack_from(data, ref.offset)
        at = ref.offset + _CHUNK_FIELDS.size
        name = bytes(data[at : at + name_length]).decode()
        at += name_length
        (stored,) = _U64.unpack_from(data, at)
        at += _U64.size
        if at + stored > ref.offset + ref.length or size > MAX_RECORD_BYTES:
            raise ValueError("inconsistent lengths")
        payload = data[at : at + stored]
        if name == "zstd":
            records = (decompressor or zstandard.ZstdDecompressor()).decompress(
                payload, max_output_size=size
            )
        elif name == "lz4":
            records = lz4.frame.decompress(payload)
        elif name == "":
            records = bytes(payload)
        else:
            raise ValueError(f"unknown compression {name!r}")
    except (struct.error, ValueError, UnicodeDecodeError, RuntimeError, zstandard.ZstdError) as exc:
        raise DataError(f"corrupt chunk at byte {ref.offset}: {exc}", path=path) from None
    if len(records) != size or (crc and zlib.crc32(records) != crc):
        raise DataError(f"corrupt chunk at byte {ref.offset}: CRC mismatch", path=path)
    return records


def index_entries(data: Buffer, body: int, length: int) -> np.ndarray:
    """Return the ``(K, 2)`` uint64 (log time, offset) entries of a message index body."""
    _, size = _INDEX_FIELDS.unpack_from(data, body)
    if size % _INDEX_ENTRY.size or _INDEX_FIELDS.size + size > length:
        raise ValueError("bad message index length")
    start = body + _INDEX_FIELDS.size
    entries = np.frombuffer(data, dtype="<u8", count=size // 8, offset=start).reshape(-1, 2)
    return entries.copy()  # no view may outlive a mapped file


def walk_chunk(records: bytes) -> Iterator[tuple[int, int, int]]:
    """Yield ``(opcode, body offset, body length)`` of every record in a chunk's records."""
    offset = 0
    size = len(records)
    while offset < size:
        if offset + RECORD_HEAD.size > size:
            raise ValueError("record head cut short")
        opcode, length = RECORD_HEAD.unpack_from(records, offset)
        body = offset + RECORD_HEAD.size
        if body + length > size:
            raise ValueError("record cut short")
        yield opcode, body, length
        offset = body + length


@dataclass(frozen=True)
class ChannelRecords:
    """The message records of one channel in a chunk's decompressed records, in record order.

    Attributes:
        log_time_ns: ``(K,)`` int64 log time of each message.
        payload_offset: ``(K,)`` int64 offset of each message's data in the records.
        payload_size: ``(K,)`` int64 byte length of each message's data.

    """

    log_time_ns: np.ndarray
    payload_offset: np.ndarray
    payload_size: np.ndarray

    def __post_init__(self) -> None:
        """Check the three arrays have one entry per message."""
        count = self.log_time_ns.shape[0]
        if self.payload_offset.shape != (count,) or self.payload_size.shape != (count,):
            raise DataError("channel record arrays must have one entry per message")


#: Offset of a message record's data after its record start (head, channel, seq, times).
MESSAGE_DATA_OFFSET: Final = MESSAGE_HEAD.size


def channel_records(records: bytes, channel_id: int, entries: np.ndarray) -> ChannelRecords:
    """Locate the messages of ``channel_id`` in a chunk's ``records``, without a Python object each.

    ``entries`` is the channel's message index (``(K, 2)`` log time, record offset). When the
    index says the chunk holds only that channel's message records back to back (what
    :class:`ChunkedMcapWriter` writes), the records are checked and located with numpy;
    otherwise the chunk is walked record by record. Raise ValueError if it is corrupt.
    """
    count = entries.shape[0]
    order = np.argsort(entries[:, 1], kind="stable")
    starts = entries[order, 1].astype(np.int64)
    size = len(records)
    if count and int(starts[-1]) + MESSAGE_HEAD.size <= size and int(starts[0]) == 0:
        raw = np.frombuffer(records, dtype=np.uint8)
        head = raw[starts[:, None] + np.arange(MESSAGE_HEAD.size)]
        fields = np.ascontiguousarray(head).view(_record_dtype(0)).reshape(-1)
        lengths = fields["length"].astype(np.int64)
        ends = starts + RECORD_HEAD.size + lengths
        if (
            (fields["opcode"] == Opcode.MESSAGE).all()
            and (fields["channel"] == channel_id).all()
            and (lengths >= MESSAGE_HEAD.size - RECORD_HEAD.size).all()
            and np.array_equal(ends[:-1], starts[1:])
            and int(ends[-1]) == size
        ):
            return ChannelRecords(
                fields["log_time"].astype(np.int64),
                starts + MESSAGE_HEAD.size,
                ends - starts - MESSAGE_HEAD.size,
            )
    logs, offsets, sizes = [], [], []
    for opcode, body, length in walk_chunk(records):
        if opcode != Opcode.MESSAGE:
            continue
        if length < MESSAGE_FIELDS.size:
            raise ValueError("message record cut short")
        channel, _, log_time_ns, _ = MESSAGE_FIELDS.unpack_from(records, body)
        if channel == channel_id:
            logs.append(log_time_ns)
            offsets.append(body + MESSAGE_FIELDS.size)
            sizes.append(length - MESSAGE_FIELDS.size)
    return ChannelRecords(
        np.array(logs, dtype=np.uint64).astype(np.int64),
        np.array(offsets, dtype=np.int64),
        np.array(sizes, dtype=np.int64),
    )
