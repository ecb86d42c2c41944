"""The MCAP file as rosbag2's MCAP storage plugin writes it (:class:`McapBagWriter`):
profile ``ros2``, ``ros2msg`` schemas, ``cdr`` channels with their QoS metadata, chunks
with message indexes and CRCs, a summary section and the ``rosbag2`` metadata record.
Messages are appended as received (serialized CDR), one ``struct.pack`` per message.

A write that fails (the disk full, an I/O error) leaves a file a reader can use: the file
is cut back to its last whole record and closed, without a summary (readers then read it
linearly, as a recording cut short), and the OSError is raised to the caller.
"""

from __future__ import annotations

import bisect
import os
import struct
import sys
import zlib
from array import array
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.writer import MCAP0_MAGIC, CompressionType

from cr_control.recording.definitions import (
    ROSBAG2_METADATA_VERSION,
    PlainDumper,
    message_definition,
    qos_profiles_yaml,
)

# -- the MCAP file ---------------------------------------------------------------------

_STAMP_LE = struct.Struct("<iI")
_STAMP_BE = struct.Struct(">iI")
#: Opcode, record length, channel id, sequence, log time, publish time of a Message record.
_MESSAGE = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = 22  # bytes of a Message record body before its data
#: Opcode, record length, channel id, byte length of the (log time, offset) pairs.
_MESSAGE_INDEX = struct.Struct("<BQHI")
#: Chunk record up to its compression string: opcode, length, start, end, size, crc,
#: length of the compression name.
_CHUNK_HEAD = struct.Struct("<BQQQQII")
_LITTLE_ENDIAN = sys.byteorder == "little"
#: Chunk compression by name (the recorder's ``compression`` parameter).
COMPRESSIONS = ("zstd", "lz4", "none")


def header_stamp_ns(cdr: bytes) -> int:
    """``header.stamp`` (ns) of a serialized message whose first field is a Header."""
    stamp = _STAMP_LE if cdr[1] & 1 else _STAMP_BE
    sec, nanosec = stamp.unpack_from(cdr, 4)
    return sec * 1_000_000_000 + nanosec


def _compressor(name: str) -> Callable[[bytes], bytes] | None:
    """The chunk compression function of ``name`` (None: uncompressed)."""
    if name == "zstd":
        # lazy: an optional compression, imported when chosen
        import zstandard

        return zstandard.ZstdCompressor().compress
    if name == "lz4":
        # lazy: an optional compression, imported when chosen
        import lz4.frame

        return lz4.frame.compress
    if name == "none":
        return None
    raise ValueError(f"compression must be one of {', '.join(COMPRESSIONS)}, not {name!r}")


@dataclass
class _Topic:
    name: str
    type: str
    offered_qos: list[dict[str, Any]]
    type_hash: str
    has_header: bool
    count: int = 0
    #: (log time, offset in the chunk) pairs of this chunk's messages, flat.
    index: array = field(default_factory=lambda: array("q"))


@dataclass
class McapBagWriter:
    """An MCAP file written as rosbag2's MCAP storage plugin writes it (see module doc).

    Lean on the hot path: a message is one ``struct.pack`` and two appends to the open
    chunk (a bytearray) plus two to its channel's message index (an ``array``); the
    records written once per chunk or file use the ``mcap`` package's record classes.
    Not thread-safe. :meth:`close` must be called to leave a complete file. If writing the
    file fails (OSError: disk full, I/O error), the file is cut back to its last whole record
    and closed (see the module doc), :attr:`error` holds the error, and every later write
    raises it again; :meth:`close` then does nothing.
    """

    path: Path
    compression: str | CompressionType = "zstd"
    chunk_size: int = 1 << 20
    _topics: dict[int, _Topic] = field(default_factory=dict, init=False)
    _channels: dict[str, int] = field(default_factory=dict, init=False)
    _schemas: dict[str, int] = field(default_factory=dict, init=False)
    _start_ns: int | None = field(default=None, init=False)
    _end_ns: int = field(default=0, init=False)
    _count: int = field(default=0, init=False)
    _closed: bool = field(default=False, init=False)
    #: The OSError that stopped the writing (None: none).
    error: OSError | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if isinstance(self.compression, CompressionType):
            self.compression = self.compression.name.lower()
        self._compress = _compressor(self.compression)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream = open(self.path, "wb", buffering=1 << 16)  # noqa: SIM115 (closed by close())
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = 0
        self._chunk_end = 0
        self._schema_records: list[Schema] = []
        self._channel_records: list[Channel] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._metadata_count = 0
        self._chunk_count = 0
        self._ends = [0]  # file offsets where a group of whole records ends, ascending
        with self._writing():
            self._stream.write(MCAP0_MAGIC)
            self._write_records(Header(profile="ros2",
                                       library="cr_control recorder (mcap-python records)"))

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self._count

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """Around each group of writes to the file: after it the file ends with a whole
        record; if it raises OSError, the file is cut back to the last whole record and
        closed (:meth:`_abandon`) and the error raised again."""
        if self.error is not None:
            raise OSError(self.error.errno, self.error.strerror, str(self.path))
        try:
            yield
        except OSError as exc:
            self._abandon(exc)
            raise
        self._ends.append(self._stream.tell())

    def _abandon(self, exc: OSError) -> None:
        """Stop writing after ``exc``: drop what is buffered, cut the file back to the end of
        the last whole record that reached it, close it."""
        if self.error is not None:
            return
        self.error = exc
        self._closed = True
        raw = getattr(self._stream, "raw", self._stream)
        try:
            fd = raw.fileno()
            size = os.fstat(fd).st_size
            os.ftruncate(fd, self._ends[bisect.bisect_right(self._ends, size) - 1])
        except OSError:
            pass  # e.g. not a regular file: left as written
        finally:
            raw.close()  # the buffer's bytes are not written: the BufferedWriter is closed too
            self._chunk = bytearray()

    def _write_records(self, *records: Any) -> int:
        """Write records straight into the data section; returns the offset of the first."""
        builder = RecordBuilder()
        for record in records:
            record.write(builder)
        offset = self._stream.tell()
        self._stream.write(builder.end())
        return offset

    def _to_chunk(self, record: Any) -> None:
        builder = RecordBuilder()
        record.write(builder)
        self._chunk += builder.end()

    def add_topic(self, topic: str, type_name: str,
                  offered_qos: Sequence[dict[str, Any]] = (), type_hash: str = "",
                  has_header: bool = False) -> int:
        """Register a topic (schema and channel); returns its channel id.

        ``has_header``: the type's first field is a ``std_msgs/Header`` (its stamp
        becomes the publish time).
        """
        if topic in self._channels:
            return self._channels[topic]
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            encoding, text = message_definition(type_name)
            schema_id = len(self._schema_records) + 1
            schema = Schema(id=schema_id, data=text.encode(), encoding=encoding, name=type_name)
            self._schema_records.append(schema)
            self._to_chunk(schema)
            self._schemas[type_name] = schema_id
        metadata = {"offered_qos_profiles": qos_profiles_yaml(offered_qos),
                    "topic_type_hash": type_hash}
        channel_id = len(self._channel_records) + 1
        channel = Channel(id=channel_id, topic=topic, message_encoding="cdr", schema_id=schema_id,
                          metadata=metadata)
        self._channel_records.append(channel)
        self._to_chunk(channel)
        self._channels[topic] = channel_id
        self._topics[channel_id] = _Topic(topic, type_name, list(offered_qos), type_hash,
                                          has_header)
        return channel_id

    def topic_name(self, channel_id: int) -> str:
        """The topic of a channel."""
        return self._topics[channel_id].name

    def has_header(self, channel_id: int) -> bool:
        """The channel's type starts with a ``std_msgs/Header``."""
        return self._topics[channel_id].has_header

    def write(self, channel_id: int, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Write one serialized message (publish time: header stamp or log time if None)."""
        info = self._topics[channel_id]
        if publish_time_ns is None:
            publish_time_ns = header_stamp_ns(data) if info.has_header else log_time_ns
        info.count += 1
        chunk = self._chunk
        info.index.append(log_time_ns)
        info.index.append(len(chunk))
        chunk += _MESSAGE.pack(0x05, _MESSAGE_FIXED + len(data), channel_id, info.count,
                               log_time_ns, publish_time_ns)
        chunk += data
        if self._chunk_messages:
            if log_time_ns < self._chunk_start:
                self._chunk_start = log_time_ns
            elif log_time_ns > self._chunk_end:
                self._chunk_end = log_time_ns
        else:
            self._chunk_start = self._chunk_end = log_time_ns
        self._chunk_messages += 1
        self._count += 1
        if len(chunk) > self.chunk_size:
            with self._writing():
                self._finish_chunk()

    def _finish_chunk(self) -> None:
        """Write the open chunk and its message indexes (nothing if it holds no message)."""
        if not self._chunk_messages:
            return
        records = bytes(self._chunk)
        data = self._compress(records) if self._compress is not None else records
        compression = self.compression if self._compress is not None else ""
        stream = self._stream
        chunk_offset = stream.tell()
        name = compression.encode()
        body = 8 + 8 + 8 + 4 + 4 + len(name) + 8 + len(data)
        stream.write(_CHUNK_HEAD.pack(0x06, body, self._chunk_start, self._chunk_end, len(records),
                                      zlib.crc32(records), len(name)))
        stream.write(name)
        stream.write(struct.pack("<Q", len(data)))
        stream.write(data)
        index_start = stream.tell()
        offsets: dict[int, int] = {}
        for channel_id, topic in self._topics.items():
            pairs = topic.index
            if not pairs:
                continue
            if not _LITTLE_ENDIAN:
                pairs.byteswap()
            offsets[channel_id] = stream.tell()
            stream.write(_MESSAGE_INDEX.pack(0x07, 2 + 4 + 8 * len(pairs), channel_id, 8 * len(pairs)))
            stream.write(pairs.tobytes())
            topic.index = array("q")
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=self._chunk_start, message_end_time=self._chunk_end,
            chunk_start_offset=chunk_offset, chunk_length=index_start - chunk_offset,
            message_index_offsets=offsets, message_index_length=stream.tell() - index_start,
            compression=compression, compressed_size=len(data), uncompressed_size=len(records)))
        self._chunk_count += 1
        if self._start_ns is None or self._chunk_start < self._start_ns:
            self._start_ns = self._chunk_start
        self._end_ns = max(self._end_ns, self._chunk_end)
        self._chunk = bytearray()
        self._chunk_messages = 0

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a metadata record (string keys and values)."""
        builder = RecordBuilder()
        Metadata(name=name, metadata=data).write(builder)
        record = builder.end()
        with self._writing():
            offset = self._stream.tell()
            self._stream.write(record)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(record), name=name))
        self._metadata_count += 1

    def _time_range(self) -> tuple[int, int]:
        """First and last log time written so far, the open chunk included (0, 0 if none)."""
        start, end = self._start_ns, self._end_ns
        if self._chunk_messages:
            start = self._chunk_start if start is None else min(start, self._chunk_start)
            end = max(end, self._chunk_end)
        return (start or 0), (end if start is not None else 0)

    def bag_metadata(self) -> dict[str, Any]:
        """rosbag2's BagMetadata of what was written so far (the ``rosbag2`` record)."""
        start, end = self._time_range()

        def duration() -> dict[str, int]:  # fresh dicts: no YAML anchors/aliases
            return {"nanoseconds": max(0, end - start)}

        def starting_time() -> dict[str, int]:
            return {"nanoseconds_since_epoch": start}

        return {
            "version": ROSBAG2_METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": duration(),
            "starting_time": starting_time(),
            "message_count": self._count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.type,
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": t.offered_qos,
                                    "type_description_hash": t.type_hash},
                 "message_count": t.count}
                for t in self._topics.values()
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.path.name],
            "files": [{"path": self.path.name, "starting_time": starting_time(),
                       "duration": duration(), "message_count": self._count}],
            "custom_data": None,
            "ros_distro": os.environ.get("ROS_DISTRO", "jazzy"),
        }

    def flush(self) -> None:
        """Write the open chunk and hand everything to the operating system."""
        with self._writing():
            self._finish_chunk()
            self._stream.flush()

    def close(self) -> None:
        """Write the ``rosbag2`` record, the summary and the footer; close the file.

        OSError if that fails (the file then cut back to its last whole record and closed)."""
        if self._closed:
            return
        serialized = yaml.dump(self.bag_metadata(), Dumper=PlainDumper, sort_keys=False)
        with self._writing():
            self._finish_chunk()
            if self._chunk:  # schemas/channels of a chunk without messages: outside chunks
                self._stream.write(bytes(self._chunk))
                self._chunk = bytearray()
        self.add_metadata("rosbag2", {"serialized_metadata": serialized})
        with self._writing():
            self._write_summary()
            self._stream.flush()   # may be where the disk turns out full
        self._closed = True
        self._stream.close()

    def _write_summary(self) -> None:
        """DataEnd, the summary section (schemas, channels, statistics, chunk and metadata
        indexes, summary offsets), the footer and the closing magic."""
        stream = self._stream
        self._write_records(DataEnd(data_section_crc=0))
        summary_start = stream.tell()
        builder = RecordBuilder()
        offsets: list[SummaryOffset] = []
        start, end = self._time_range()
        statistics = Statistics(
            attachment_count=0, channel_count=len(self._channel_records),
            channel_message_counts={cid: t.count for cid, t in self._topics.items()},
            chunk_count=self._chunk_count, message_count=self._count,
            metadata_count=self._metadata_count, message_start_time=start, message_end_time=end,
            schema_count=len(self._schema_records))
        for opcode, group in ((Opcode.SCHEMA, self._schema_records),
                              (Opcode.CHANNEL, self._channel_records),
                              (Opcode.STATISTICS, [statistics]),
                              (Opcode.CHUNK_INDEX, self._chunk_indexes),
                              (Opcode.METADATA_INDEX, self._metadata_indexes)):
            if not group:
                continue
            group_start = builder.count
            for record in group:
                record.write(builder)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + group_start,
                                         group_length=builder.count - group_start))
        summary_offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start,
                                     summary_offset_start), zlib.crc32(summary))
        stream.write(summary)
        self._write_records(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                                   summary_crc=crc))
        stream.write(MCAP0_MAGIC)
