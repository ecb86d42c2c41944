"""MCAP recorder node (executable ``recorder``): the session's topics and parameters in one file.

The file is written the way rosbag2's MCAP storage plugin writes it, so ``ros2 bag``,
Foxglove, PlotJuggler and independent MCAP readers open it: profile ``ros2``; one
``ros2msg`` schema per type holding the full ``.msg`` text with its dependencies
concatenated (rosbag2's ``LocalMessageDefinitionSource`` layout); ``cdr`` channels
with ``offered_qos_profiles`` and ``topic_type_hash`` metadata; chunks (zstd by
default) with message indexes, chunk CRCs and a summary section; and, last, the
``rosbag2`` metadata record (``serialized_metadata``: the bag metadata YAML, version 9
as in Jazzy). Messages are recorded as received (serialized CDR, never deserialized):
log time = the middleware's receive time, publish time = ``header.stamp`` when the type
starts with a ``std_msgs/Header`` and the receive time otherwise.

Per-message cost (it shares a 2-core machine with a 1 kHz loop): the subscriptions
live on a hidden second node that no executor spins, so an arriving message does not
wake this process's Python thread; every ``SLICE_S`` the recorder takes what arrived
on each topic (raw bytes, KEEP_ALL: nothing is overwritten while it waits), sorts the
batch by receive time and appends it to the open chunk with one ``struct.pack`` per
message (:class:`McapBagWriter`). Measured with
``cr_benchmark --only-recorder-load`` (a session's five 1 kHz topics): about 2.2x less
CPU per message than a callback per message into the ``mcap`` package's writer; what is
left is mostly the middleware's own receive path.

A topic is subscribed once it has a publisher, with the QoS adapted to the offers
(reliable when every publisher is; :func:`request_qos`), as rosbag2 does. Not when it
first shows in the graph: a subscriber alone puts it there (the plant subscribes to
/joint_commands before the controller publishes), and with no offer to adapt to the
subscription would be best effort: lossy, and invisible to a lockstep writer waiting
for its readers' acknowledgements.

Once every topic of ``topics`` has a subscription with a matched publisher of a known
node (or ``ready_timeout`` passed, with a warning naming what is missing), the recorder
saves the parameters of the ``parameter_nodes`` (got through the standard
``list_parameters``/``get_parameters`` services, at most ``PARAMETER_TIMEOUT_S`` per
node) as metadata records ``parameters/<node>`` (one key per parameter, its value
YAML-encoded), then publishes ``std_msgs/Bool(True)`` on ``topics.RECORDER_READY``
(reliable, transient local). The plant waits for it, so the start of the session and
its initial parameters are all in the file. Live changes are in the recorded
``/parameter_events``. Topics that appear later are recorded from then on.

Nothing lost is checked, not assumed: on a topic with one publisher, a gap in the
publisher's sequence numbers means messages that never reached the recorder (the
middleware dropped them, e.g. a reliable writer's KEEP_LAST history overtaking a reader
starved of CPU in real time); the exit line reports them per topic ("N missed"). In
lockstep the loop waits for the recorder instead (:mod:`cr_control.nodes.lockstep`).

SIGINT or SIGTERM ends the session: the recorder keeps taking messages until the
topics fall quiet (at most ``DRAIN_MAX_S``), writes all of them, then the summary and
footer, and exits with status 0.

ROS parameters (all read-only, read at start):

- ``output`` (string): path of the ``.mcap`` file. Default ``session.mcap``.
- ``topics`` (string array): topics to record. Default: joint states, wrench, joint
  commands, ``/clock``, plant timing, ``/parameter_events``.
- ``optional_topics`` (string array): topics recorded whenever they appear but never
  waited for. Default ``/clock`` (published only in lockstep mode), ``/plant/sensors`` and
  ``/plant/contact_wrench`` (published by the plants that have them).
- ``parameter_nodes`` (string array): nodes whose parameters are saved. Default empty:
  every node in the graph when ready, except this one.
- ``ready_timeout`` (double, s): how long to wait for the topics before declaring ready
  anyway (with a warning). Default 10.
- ``compression`` (string): chunk compression, ``zstd`` (default), ``lz4`` or ``none``
  (zstd costs ~0.2 µs per message here, a small share of the per-message cost).
"""

from __future__ import annotations

import bisect
import functools
import gc
import importlib
import importlib.util
import os
import re
import signal
import struct
import sys
import time
import zlib
from array import array
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rclpy
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
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.exceptions import ParameterUninitializedException
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from std_msgs.msg import Bool

from cr_control.core import topics
from cr_control.nodes.qos import READY_QOS
from cr_control.nodes.ros_parameters import refuse_undeclared
from cr_control.nodes.spin import refuse_empty_params_files

DEFAULT_TOPICS = [
    topics.JOINT_STATES,
    topics.WRENCH,
    topics.JOINT_COMMANDS,
    topics.CLOCK,
    topics.PLANT_TIMING,
    topics.PARAMETER_EVENTS,
]
DEFAULT_OPTIONAL_TOPICS = [topics.CLOCK, topics.PLANT_SENSORS, topics.CONTACT_WRENCH]

#: Reader history of the recorder's subscriptions: KEEP_ALL, so that a chunk compression
#: or a scheduling hiccup on a busy machine never overwrites messages that arrived but
#: were not yet taken. Fast DDS bounds it (5000 samples per reader, its default resource
#: limit, measured) and, when it is full, stops acknowledging: a lockstep plant, which
#: waits for its readers' acknowledgements, then waits for the recorder (plant_node.py).
SUBSCRIPTION_HISTORY = HistoryPolicy.KEEP_ALL
#: The executor runs in slices of this length; between slices the recorder discovers
#: topics, checks readiness and parameter requests, and notices a stop request.
SLICE_S = 0.1
#: After a stop request: keep recording until no message arrives for DRAIN_QUIET_S,
#: but no longer than DRAIN_MAX_S.
DRAIN_QUIET_S = 0.25
DRAIN_MAX_S = 3.0
#: Messages received this recently wait for the next batch (see Recorder.take_all).
ORDER_MARGIN_NS = 2_000_000
#: Give up on a node's parameters after this long.
PARAMETER_TIMEOUT_S = 5.0

ROSBAG2_METADATA_VERSION = 9
#: Node name of an endpoint whose node is not (yet) known to the graph.
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"
_DELIMITER = "=" * 80 + "\n"
_INFINITE_NS = 9_223_372_036_854_775_807

# -- message definitions (rosbag2's LocalMessageDefinitionSource) ------------------------

# Field types of a .msg ("foo_msgs/Bar" in "foo_msgs/Bar[] bar") and includes of an .idl.
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_IDL_INCLUDE = re.compile(r"(?:^|\n)#include\s+(?:\"|<)([a-zA-Z0-9_/]+)\.idl(?:\"|>)")
_PRIMITIVES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})


class DefinitionNotFoundError(LookupError):
    """No .msg/.idl file for a message type was found."""


@functools.cache
def _share_dirs(package: str) -> tuple[Path, ...]:
    """Candidate ``share/<package>`` directories, most likely first."""
    candidates: list[Path] = []
    spec = importlib.util.find_spec(package)
    if spec is not None and spec.origin:
        # <prefix>/lib/pythonX.Y/site-packages/<package>/__init__.py (or local/lib/...).
        for parent in Path(spec.origin).resolve().parents[1:6]:
            candidates.append(parent / "share" / package)
    candidates.append(Path(sys.prefix) / "share" / package)
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / package)
    return tuple(dict.fromkeys(c for c in candidates if c.is_dir()))


def _split_type(type_name: str) -> tuple[str, str, str]:
    """(package, namespace, name) of ``pkg/Type`` or ``pkg/msg/Type``."""
    parts = type_name.split("/")
    if len(parts) == 2:
        return parts[0], "msg", parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise ValueError(f"invalid message type name {type_name!r}")


@functools.cache
def _definition_file_text(type_name: str, extension: str) -> str:
    package, namespace, name = _split_type(type_name)
    for share in _share_dirs(package):
        path = share / namespace / f"{name}{extension}"
        if path.is_file():
            return path.read_text(encoding="utf-8")
    raise DefinitionNotFoundError(type_name)


def _dependencies(text: str, package: str, idl: bool) -> list[str]:
    """Types a definition refers to, sorted as rosbag2's std::set orders them."""
    if idl:
        return sorted(set(_IDL_INCLUDE.findall(text)))
    found = set()
    for type_name in _MSG_FIELD_TYPE.findall(text):
        if type_name in _PRIMITIVES:
            continue
        found.add(type_name if "/" in type_name else f"{package}/{type_name}")
    return sorted(found)


@functools.cache
def message_definition(type_name: str) -> tuple[str, str]:
    """(schema encoding, full definition text) of ``type_name`` as rosbag2 stores it.

    ``ros2msg``: the type's ``.msg`` text, then each dependency, recursively and once,
    after a line of 80 ``=`` and a line ``MSG: <type>``. Falls back to ``ros2idl`` when
    there is no ``.msg``; raises :class:`DefinitionNotFoundError` when neither exists.
    """
    def full_text(root: str, extension: str, tag: str) -> str:
        seen: set[str] = set()

        def append(name: str, depth: int) -> str:
            if depth <= 0:
                raise RecursionError(f"definition of {root} nests too deeply")
            text = _definition_file_text(name, extension)
            result = text
            for dep in _dependencies(text, _split_type(name)[0], idl=extension == ".idl"):
                if dep not in seen:
                    seen.add(dep)
                    result += "\n" + _DELIMITER + f"{tag}: {dep}\n" + append(dep, depth - 1)
            return result

        return append(root, 50)

    try:
        return "ros2msg", full_text(type_name, ".msg", "MSG")
    except DefinitionNotFoundError:
        text = full_text(type_name, ".idl", "IDL")
        return "ros2idl", _DELIMITER + f"IDL: {type_name}\n" + text


# -- QoS as rosbag2 serializes it ------------------------------------------------------

def _duration_yaml(nanoseconds: int) -> dict[str, int]:
    return {"sec": nanoseconds // 1_000_000_000, "nsec": nanoseconds % 1_000_000_000}


def qos_profile_dict(qos: QoSProfile) -> dict[str, Any]:
    """One offered QoS profile in rosbag2's metadata form (version 9: policy names)."""
    return {
        "history": qos.history.name.lower(),
        "depth": int(qos.depth),
        "reliability": qos.reliability.name.lower(),
        "durability": qos.durability.name.lower(),
        "deadline": _duration_yaml(qos.deadline.nanoseconds),
        "lifespan": _duration_yaml(qos.lifespan.nanoseconds),
        "liveliness": qos.liveliness.name.lower(),
        "liveliness_lease_duration": _duration_yaml(qos.liveliness_lease_duration.nanoseconds),
        "avoid_ros_namespace_conventions": bool(qos.avoid_ros_namespace_conventions),
    }


def qos_profiles_yaml(profiles: Sequence[dict[str, Any]]) -> str:
    """The ``offered_qos_profiles`` channel metadata string."""
    return yaml.safe_dump(list(profiles), sort_keys=False, default_flow_style=False)


def request_qos(offered: Sequence[QoSProfile]) -> QoSProfile:
    """A subscription QoS that matches every offer (rosbag2's adapt_request_to_offers)."""
    reliable = bool(offered) and all(
        q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    transient = bool(offered) and all(
        q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
    return QoSProfile(
        history=SUBSCRIPTION_HISTORY,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)


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
        import zstandard

        return zstandard.ZstdCompressor().compress
    if name == "lz4":
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
    Not thread-safe. :meth:`close` must be called to leave a complete file.
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
        self._stream.write(MCAP0_MAGIC)
        self._write_records(Header(profile="ros2", library="cr_control recorder (mcap-python records)"))

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self._count

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
        self._finish_chunk()
        self._stream.flush()

    def close(self) -> None:
        """Write the ``rosbag2`` record, the summary and the footer; close the file."""
        if self._closed:
            return
        self._closed = True
        try:
            serialized = yaml.safe_dump(self.bag_metadata(), sort_keys=False)
            self._finish_chunk()
            if self._chunk:  # schemas/channels of a chunk without messages: outside chunks
                self._stream.write(bytes(self._chunk))
                self._chunk = bytearray()
            self.add_metadata("rosbag2", {"serialized_metadata": serialized})
            self._write_summary()
        finally:
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


# -- the node --------------------------------------------------------------------------

def _yaml_value(value: Any) -> str:
    """A parameter value as a one-line YAML string."""
    text = yaml.safe_dump(value, default_flow_style=True, width=1 << 30)
    return text.removesuffix("\n...\n").rstrip("\n")


def _python_value(value: Any) -> Any:
    """A parameter value as plain YAML-serializable Python (arrays become lists)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, bytes | bytearray):
        return list(value)
    if isinstance(value, list | tuple):
        return [_python_value(v) for v in value]
    return value


def _has_header(msg_class: type) -> bool:
    fields = iter(msg_class.get_fields_and_field_types().items())
    first = next(fields, None)
    return first is not None and first[1] in ("std_msgs/Header", "std_msgs/msg/Header")


def _import_message(type_name: str) -> type:
    """The Python class of ``pkg/msg/Type``."""
    package, namespace, name = _split_type(type_name)
    return getattr(importlib.import_module(f"{package}.{namespace}"), name)


class _ParameterFetch:
    """Gets one node's parameters through its parameter services (polled, non-blocking)."""

    def __init__(self, node: Node, target: str) -> None:
        self.target = target
        self._node = node
        self._list = node.create_client(ListParameters, f"{target}/list_parameters")
        self._get = node.create_client(GetParameters, f"{target}/get_parameters")
        self._list_future: Future | None = None
        self._get_future: Future | None = None
        self._names: list[str] = []
        self._deadline = time.monotonic() + PARAMETER_TIMEOUT_S
        self.result: dict[str, str] | None = None

    def poll(self) -> bool:
        """Advance; True once finished (``result`` is None if it failed)."""
        if self._list_future is None:
            if self._list.service_is_ready():
                self._list_future = self._list.call_async(
                    ListParameters.Request(depth=ListParameters.Request.DEPTH_RECURSIVE))
        elif self._get_future is None:
            if self._list_future.done():
                self._names = list(self._list_future.result().result.names)
                self._get_future = self._get.call_async(
                    GetParameters.Request(names=self._names))
        elif self._get_future.done():
            values = self._get_future.result().values
            self.result = {
                name: _yaml_value(_python_value(parameter_value_to_python(value)))
                for name, value in zip(self._names, values, strict=False)
                if value.type != ParameterType.PARAMETER_NOT_SET
            }
        done = self.result is not None or time.monotonic() > self._deadline
        if done:
            self._node.destroy_client(self._list)
            self._node.destroy_client(self._get)
        return done


class Recorder(Node):
    """Subscribes (raw) to the session's topics and writes them to an MCAP file."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("recorder", **kwargs)
        read_only = {"read_only": True}
        self.declare_parameter("output", "session.mcap", ParameterDescriptor(
            description="Path of the .mcap file to write.", **read_only))
        self.declare_parameter("topics", DEFAULT_TOPICS, ParameterDescriptor(
            description="Topics to record; ready waits for each (except optional_topics).",
            **read_only))
        self.declare_parameter("optional_topics", DEFAULT_OPTIONAL_TOPICS, ParameterDescriptor(
            description="Topics recorded whenever they appear but never waited for.",
            **read_only))
        self.declare_parameter("parameter_nodes", Parameter.Type.STRING_ARRAY, ParameterDescriptor(
            description="Nodes whose parameters are saved; unset or empty: every node in the "
                        "graph when ready, except the recorder.", **read_only))
        self.declare_parameter("ready_timeout", 10.0, ParameterDescriptor(
            description="Seconds to wait for the topics before declaring ready anyway.",
            dynamic_typing=True, **read_only))
        optional = [self.resolve_topic_name(t) for t in self._strings("optional_topics")]
        wanted = [self.resolve_topic_name(t) for t in self._strings("topics")] + optional
        self._wanted = list(dict.fromkeys(wanted))
        self._required = [t for t in self._wanted if t not in optional]
        self._parameter_nodes = self._strings("parameter_nodes")
        self._ready_deadline = time.monotonic() + float(
            self.get_parameter("ready_timeout").value)

        self.declare_parameter("compression", "zstd", ParameterDescriptor(
            description=f"Chunk compression: {', '.join(COMPRESSIONS)}.", **read_only))
        refuse_undeclared(self)   # a misspelt name in a params file: refused, named
        self.output = Path(self.get_parameter("output").value).expanduser()
        self.writer = McapBagWriter(self.output, compression=self.get_parameter("compression").value)
        # The subscriptions live on a second, hidden node that no executor spins: messages
        # wait in the middleware's history (SUBSCRIPTION_HISTORY) until take_all() takes them
        # in one batch per slice, instead of waking this thread for every message.
        self._reader = Node("_recorder_reader", context=self.context, use_global_arguments=False,
                            start_parameter_services=False, enable_rosout=False)
        self._takers: list[tuple[Any, type, int]] = []
        #: Per taker: last publication sequence number seen, messages missed (gaps).
        self._last_sequence: list[int] = []
        self.missed: dict[str, int] = {}
        self._pending: list[tuple[int, int, bytes]] = []
        self._recorded: dict[str, Any] = {}
        self._ready = False
        self._warned_types: set[str] = set()
        self._fetches: list[_ParameterFetch] | None = None  # None: not started
        self._ready_pub = self.create_publisher(Bool, topics.RECORDER_READY, READY_QOS)
        self.get_logger().info(f"recording {', '.join(self._wanted)} to {self.output}")

    def _strings(self, name: str) -> list[str]:
        try:
            values = self.get_parameter(name).value
        except ParameterUninitializedException:
            values = None
        return [s for s in (values or []) if s]

    @property
    def ready(self) -> bool:
        """Ready was announced."""
        return self._ready

    # -- called between executor slices ----------------------------------------------
    def poll(self) -> None:
        """Subscribe to topics that appeared, save parameters, then announce readiness."""
        if len(self._recorded) < len(self._wanted):
            self._subscribe_new_topics()
        if self._fetches is None and self._topics_ready():
            self._fetches = self._start_parameter_fetches()
        if self._fetches:
            self._poll_parameters()
        if not self._ready and self._fetches == []:
            self._ready = True
            self._ready_pub.publish(Bool(data=True))
            self.get_logger().info(f"ready ({topics.RECORDER_READY})")

    def _subscribe_new_topics(self) -> None:
        """Subscribe to the wanted topics that have a publisher now.

        Not before: a topic is in the graph as soon as anyone subscribes to it (the plant
        to /joint_commands, the controller to /joint_states), and with no offer to adapt
        to the subscription would be best effort, i.e. lossy (request_qos).
        """
        graph = dict(self.get_topic_names_and_types())
        for name in self._wanted:
            if name in self._recorded or name not in graph or self.count_publishers(name) < 1:
                continue
            types = graph[name]
            if len(types) > 1 and name not in self._warned_types:
                self._warned_types.add(name)
                self.get_logger().warning(f"{name} has several types {types}; using {types[0]}")
            self._subscribe(name, types[0])

    def _subscribe(self, name: str, type_name: str) -> None:
        try:
            msg_class = _import_message(type_name)
            publishers = self.get_publishers_info_by_topic(name)
            offered = [p.qos_profile for p in publishers]
            type_hash = str(publishers[0].topic_type_hash) if publishers else ""
            channel = self.writer.add_topic(
                name, type_name, [qos_profile_dict(q) for q in offered], type_hash,
                _has_header(msg_class))
        except (ImportError, AttributeError, LookupError, ValueError) as exc:
            if name not in self._warned_types:
                self._warned_types.add(name)
                self.get_logger().error(f"cannot record {name} ({type_name}): {exc}")
            return
        # On the reader node, which no executor spins: take_all() takes what arrived.
        subscription = self._reader.create_subscription(
            msg_class, name, _never_called, request_qos(offered), raw=True)
        self._recorded[name] = subscription
        self._takers.append((subscription, msg_class, channel))
        self._last_sequence.append(0)
        if self._ready:
            self.get_logger().info(f"now recording {name}")

    def take_all(self, flush: bool = False) -> int:
        """Write the messages that arrived since the last call, in receive order; returns
        how many were taken. Log time: the middleware's receive time of each message.

        Messages received less than ``ORDER_MARGIN_NS`` before this call wait for the
        next one (unless ``flush``), so that messages of topics taken later in this call
        but received earlier are not written after them: the file stays in log-time order.
        """
        cut = time.time_ns() - ORDER_MARGIN_NS
        batch = self._pending
        append = batch.append
        taken_count = len(batch)
        for i, (subscription, msg_class, channel) in enumerate(self._takers):
            handle = subscription.handle
            take = handle.take_message
            # Sequence numbers count per publisher: gaps mean something only with one.
            last = self._last_sequence[i] if subscription.get_publisher_count() == 1 else -1
            missed = 0
            with handle:
                while (taken := take(msg_class, True)) is not None:
                    info = taken[1]
                    # 0 from a middleware without receive times: this call's time.
                    append((info["received_timestamp"] or cut, channel, taken[0]))
                    if last >= 0:
                        sequence = info["publication_sequence_number"] or 0
                        if sequence > last + 1 and last:
                            missed += sequence - last - 1
                        last = sequence
            self._last_sequence[i] = max(last, 0)
            if missed:
                name = self.writer.topic_name(channel)
                self.missed[name] = self.missed.get(name, 0) + missed
        taken_count = len(batch) - taken_count
        if not batch:
            return 0
        batch.sort(key=_first)
        if flush:
            self._pending = []
        else:
            k = bisect.bisect_right(batch, cut, key=_first)
            self._pending = batch[k:]
            del batch[k:]
        write = self.writer.write
        for stamp, channel, data in batch:
            write(channel, data, stamp)
        return taken_count

    def destroy_node(self) -> None:
        """Destroy the reader node too."""
        self._reader.destroy_node()
        super().destroy_node()

    def _topics_ready(self) -> bool:
        """Every required topic is subscribed and connected, or the ready timeout passed."""
        missing = [t for t in self._required if t not in self._recorded]
        unmatched = [t for t in self._required if t in self._recorded
                     and self._recorded[t].get_publisher_count() < 1]
        # Node names arrive separately from endpoints: wait until every publisher's node
        # is known, so that the parameter nodes found in the graph are complete.
        unnamed = [t for t in self._required if t in self._recorded and any(
            info.node_name == UNKNOWN_NODE for info in self.get_publishers_info_by_topic(t))]
        if not missing and not unmatched and not unnamed:
            return True
        if time.monotonic() < self._ready_deadline:
            return False
        problems = ([f"no publisher yet on {', '.join(missing)}"] if missing else []) + (
            [f"not yet connected to {', '.join(unmatched)}"] if unmatched else []) + (
            [f"publishers of unknown nodes on {', '.join(unnamed)}"] if unnamed else [])
        self.get_logger().warning(
            f"ready timeout: {'; '.join(problems)} (recording them when they appear)")
        return True

    def _start_parameter_fetches(self) -> list[_ParameterFetch]:
        targets = self._parameter_nodes
        if not targets:
            me = self.get_fully_qualified_name()
            targets = [f"{ns.rstrip('/')}/{name}"
                       for name, ns in self.get_node_names_and_namespaces()
                       if not name.startswith("_")]
            targets = [t for t in dict.fromkeys(targets) if t != me]
        return [_ParameterFetch(self, t if t.startswith("/") else f"/{t}") for t in targets]

    def _poll_parameters(self) -> None:
        pending = []
        for fetch in self._fetches or []:
            if not fetch.poll():
                pending.append(fetch)
            elif fetch.result is not None:
                self.writer.add_metadata(f"parameters/{fetch.target.lstrip('/')}", fetch.result)
                self.get_logger().info(f"saved {len(fetch.result)} parameters of {fetch.target}")
            else:
                self.get_logger().warning(f"could not get the parameters of {fetch.target}")
        self._fetches = pending


def _never_called(_data: bytes) -> None:
    """Callback of the reader node's subscriptions (never spun: take_all() takes)."""


def _first(item: tuple) -> Any:
    return item[0]


class _StopRequest:
    """Set by SIGINT/SIGTERM; a second signal also skips draining."""

    def __init__(self) -> None:
        self.count = 0

    def __call__(self, signum: int, frame: Any) -> None:
        self.count += 1


def _spin_slice(executor: Any, seconds: float) -> None:
    # EventsExecutor (rclpy 7.1.6) runs timers and callbacks only within a bounded wait.
    executor.spin_until_future_complete(Future(), timeout_sec=seconds)


def record(recorder: Recorder, executor: Any, stop: _StopRequest) -> None:
    """Record until ``stop`` is requested, then drain until the topics fall quiet."""
    while not stop.count:
        _spin_slice(executor, SLICE_S)
        recorder.take_all()
        recorder.poll()
    deadline = time.monotonic() + DRAIN_MAX_S
    recorder.take_all()
    while stop.count < 2 and time.monotonic() < deadline:
        _spin_slice(executor, DRAIN_QUIET_S)
        if not recorder.take_all():
            break
    recorder.take_all(flush=True)


def main(args: Iterable[str] | None = None) -> int:
    """Entry point of the ``recorder`` executable."""
    argv = list(args) if args is not None else sys.argv
    if refuse_empty_params_files("recorder", argv):
        return 1
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    stop = _StopRequest()
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    try:
        recorder = Recorder()
    except (OSError, ValueError) as exc:
        print(f"recorder: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 1
    executor = EventsExecutor()
    executor.add_node(recorder)
    # Start-up objects out of the collector's generations: no full collections that
    # rescan them while recording.
    gc.collect()
    gc.freeze()
    try:
        record(recorder, executor, stop)
    except ExternalShutdownException:
        pass
    finally:
        recorder.writer.close()
        count, path = recorder.writer.message_count, recorder.output
        executor.shutdown(timeout_sec=1.0)
        recorder.destroy_node()
        rclpy.try_shutdown()
    missed = sum(recorder.missed.values())
    detail = (f"; {missed} missed (gaps in the publishers' sequence numbers: "
              f"{', '.join(f'{t} {n}' for t, n in recorder.missed.items())})" if missed else "")
    print(f"recorder: wrote {count} messages to {path}{detail}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
