"""A recorded session read from its MCAP file without ROS (:func:`load_session`): arrays
per topic (joint states and commands, wrench, the controller's status and reference, the
plant timing, every labelled array topic), the parameters saved by the recorder, message
and publisher counts, and the stamps that go backwards or repeat (another run on the same
ROS domain, or a restarted plant).
"""

from __future__ import annotations

import contextlib
import io
import math
from array import array
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap_ros2.decoder import DecoderFactory

from cr_control.core import ros_yaml, topics

MCAP_MAGIC = b"\x89MCAP0\r\n"
PARAMETERS_PREFIX = "parameters/"


#: Stamps this far (s) from a session's time zero are on another clock.
DIFFERENT_CLOCK_S = 86_400.0
#: Control topics (by role) that must have exactly one publisher, and the plant timing
#: fields that count their publishers as the plant sees them.
CONTROL_ROLES = ("joint_states", "joint_commands", "wrench")
PUBLISHER_FIELDS = {"joint_states": "state_publishers", "joint_commands": "command_publishers"}

_JOINT_STATE = "sensor_msgs/msg/JointState"
_WRENCH = "geometry_msgs/msg/WrenchStamped"
_ARRAY = "std_msgs/msg/Float64MultiArray"


class SessionError(Exception):
    """A file that cannot be analysed (missing, unreadable, not MCAP, no package topics)."""


@dataclass
class JointSeries:
    """Joint values over time; ``NaN`` where a message carried no value."""

    time: np.ndarray  #: header stamp (s), shape (n,)
    names: list[str]
    position: np.ndarray  #: shape (n, joints)
    velocity: np.ndarray
    effort: np.ndarray
    #: Messages, in the order recorded, stamped before (after) or at the previous one.
    stamps_backwards: int = 0
    stamps_repeated: int = 0
    #: The stamps of those messages (the first MAX_IRREGULAR), backwards then repeated.
    backwards_at: np.ndarray = field(default_factory=lambda: np.zeros(0))
    repeated_at: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def excuse(self, windows: list[tuple[float, float]]) -> None:
        """Stop counting the backwards or repeated stamps inside ``windows`` ([first, last]
        stamps, s): a live switch's, where both controllers answered the same states."""
        def inside(stamps: np.ndarray) -> int:
            return int(sum(np.count_nonzero((stamps >= lo) & (stamps <= hi)) for lo, hi in windows))
        self.stamps_backwards -= inside(self.backwards_at)
        self.stamps_repeated -= inside(self.repeated_at)


@dataclass
class WrenchSeries:
    """Measured contact wrench over time (world frame)."""

    time: np.ndarray  #: header stamp (s)
    force: np.ndarray  #: (n, 3) N
    torque: np.ndarray  #: (n, 3) N m


@dataclass
class Session:
    """One recording: arrays per topic, the controller's name and the saved parameters."""

    path: Path
    controller: str | None = None
    #: field -> values of the controller's status / reference and of the plant timing.
    status: dict[str, np.ndarray] = field(default_factory=dict)
    reference: dict[str, np.ndarray] = field(default_factory=dict)
    timing: dict[str, np.ndarray] = field(default_factory=dict)
    #: Every labelled array topic (topic -> field -> values).
    labelled: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    joint_states: JointSeries | None = None
    joint_commands: JointSeries | None = None
    wrench: WrenchSeries | None = None
    #: The plant's true contact wrench (topics.CONTACT_WRENCH, base frame), if recorded.
    contact_wrench: WrenchSeries | None = None
    #: node -> parameter -> value (from the ``parameters/<node>`` metadata records).
    parameters: dict[str, dict[str, Any]] = field(default_factory=dict)
    message_counts: dict[str, int] = field(default_factory=dict)
    #: Publishers per control topic role (CONTROL_ROLES) the recorder saw when it
    #: subscribed (the channels' ``offered_qos_profiles``), where the file says.
    publishers: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    #: Controllers in the order they ran; more than one: a live switch (cr_session
    #: --switch-to), whose status/reference are joined on their common fields.
    controllers: list[str] = field(default_factory=list)
    #: (stamp of its first status, controller) for each controller after the first.
    switches: list[tuple[float, str]] = field(default_factory=list)

    @property
    def name(self) -> str:
        """The controller's name, else the file stem."""
        return self.controller or self.path.stem

    @property
    def t0(self) -> float:
        """Time zero of the figures (s): the first stamp of the controller's status, else
        of its reference, the joint states, the wrench or the joint commands."""
        for stamps in (self.status.get("stamp"), self.reference.get("stamp"),
                       *(s.time for s in (self.joint_states, self.wrench, self.joint_commands)
                         if s is not None)):
            if stamps is not None and len(stamps):
                return float(stamps[0])
        return 0.0

    def relative_time(self, stamps: np.ndarray) -> np.ndarray:
        """``stamps`` on the figures' time axis: from t0, unless they are on another clock.

        (Stamps more than a day away from t0 are taken as already relative, e.g. a plant
        timing stamped with time since start in a wall-clock session.)
        """
        t0 = self.t0
        if len(stamps) and abs(float(stamps[0]) - t0) > DIFFERENT_CLOCK_S:
            return stamps
        return stamps - t0


# -- reading -----------------------------------------------------------------------------

def _type_name(schema: Schema | None) -> str:
    """``pkg/msg/Type`` of a schema (also for ``pkg/Type`` names)."""
    if schema is None:
        return ""
    parts = schema.name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else schema.name


def _check_readable(path: Path) -> None:
    if not path.exists():
        raise SessionError(f"{path}: no such file")
    if path.is_dir():
        raise SessionError(f"{path}: is a directory, not an MCAP file")
    if not path.is_file():  # opening a named pipe would wait for a writer for ever
        raise SessionError(f"{path}: not a regular file (a pipe, device or socket), not an "
                           "MCAP file")
    try:
        with open(path, "rb") as f:
            magic = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise SessionError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if magic != MCAP_MAGIC:
        raise SessionError(f"{path}: not an MCAP file")


def _reason(exc: BaseException) -> str:
    """An exception in a short line: its type (when the text alone says little) and text."""
    text = (str(exc).splitlines() or [""])[0]
    if len(text) > 120:
        text = text[:117] + "..."
    known = isinstance(exc, (McapError, ValueError, EOFError)) and text
    return text if known else f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _iter_messages(path: Path, warnings: list[str], metadata: dict[str, dict[str, str]],
                   ) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """Messages in file order (filling ``metadata``); tolerates a file cut short.

    The one place the mcap reader reads the file. Every chunk's data is checked against the
    CRC-32 its writer stored (the MCAP format's ``uncompressed_crc``; 0: none stored), so a
    flipped bit in a chunk is a SessionError, never decoded as values. On damaged data the
    reader raises more than its own errors (a corrupt chunk: a decompression error, a
    KeyError for a channel id the summary lacks, an OverflowError for a length too large to
    read, ...): whatever it raises ends the reading, as a SessionError if the file has a
    summary (it claims to be complete), as a warning if it was cut short (read as far as
    the data goes).
    """
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        try:
            summary = reader.get_summary()
        except Exception:
            summary = None
        if summary is not None:
            try:
                metadata.update({m.name: dict(m.metadata) for m in reader.iter_metadata()})
                yield from reader.iter_messages(log_time_order=False)
            except CRCValidationError as exc:
                raise SessionError(_crc_failure(path, exc)) from None
            except Exception as exc:
                raise SessionError(f"{path}: damaged MCAP file, stopped at a corrupt record "
                                   f"({_reason(exc)})") from exc
            return
        # No summary (recording cut short): read linearly as far as the data goes.
        f.seek(0)
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        count = 0
        try:
            for record in StreamReader(f, skip_magic=False, validate_crcs=True).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message) and record.channel_id in channels:
                    channel = channels[record.channel_id]
                    count += 1
                    yield schemas.get(channel.schema_id), channel, record
                elif isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
        except CRCValidationError as exc:
            raise SessionError(_crc_failure(path, exc)) from None
        except Exception as exc:
            warnings.append(f"file ends early ({_reason(exc)}); read {count} messages")


def _crc_failure(path: Path, exc: CRCValidationError) -> str:
    """The one line for a record whose data does not match the CRC stored with it."""
    what = "a chunk's data" if type(exc.record).__name__ == "Chunk" else "its data section"
    return (f"{path}: damaged MCAP file, {what} fails its CRC-32 check (stored "
            f"{exc.expected:#010x}, computed {exc.actual:#010x}): changed since it was written")


def _stamp(msg: Any) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


#: How many backwards or repeated stamps a topic keeps, each (the counts go on).
MAX_IRREGULAR = 10_000


class _Rows:
    """Fixed-width float rows stored compactly, with a time column to sort by.

    Counts, in the order rows are added, times that go backwards or repeat (and keeps the
    first :data:`MAX_IRREGULAR` of each).
    """

    def __init__(self, width: int) -> None:
        self.width = width
        self.time = array("d")
        self.values = array("d")
        self.backwards = 0
        self.repeated = 0
        self.backwards_at: list[float] = []
        self.repeated_at: list[float] = []
        self._last: float | None = None      # the last counted time

    def add(self, time: float, row: Sequence[float], counted: bool = True) -> None:
        """A row; ``counted`` False: its time is neither judged nor judged against."""
        if counted:
            if self._last is not None and time <= self._last:
                backwards = time < self._last
                self.backwards += backwards
                self.repeated += not backwards
                kept = self.backwards_at if backwards else self.repeated_at
                if len(kept) < MAX_IRREGULAR:
                    kept.append(time)
            self._last = time
        self.time.append(time)
        self.values.extend(row)

    def sorted(self) -> tuple[np.ndarray, np.ndarray]:
        """(time, rows) in time order (stable)."""
        time = np.array(self.time)
        rows = np.array(self.values).reshape(len(time), self.width)
        order = np.argsort(time, kind="stable")
        return time[order], rows[order]


class _LabelledTopic:
    """A labelled Float64MultiArray topic: the rows that carry its first label."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.fields = topics.fields_of(label)
        self.rows = _Rows(len(self.fields))

    def add(self, msg: Any) -> None:
        if msg.layout.dim and msg.layout.dim[0].label == self.label and len(
                msg.data) == len(self.fields):
            self.rows.add(msg.data[0], msg.data)

    def columns(self) -> dict[str, np.ndarray]:
        _, table = self.rows.sorted()
        return {name: table[:, i] for i, name in enumerate(self.fields)}


class _JointTopic:
    """A JointState topic; joints named by its first message, NaN where values are absent."""

    KEYS = ("position", "velocity", "effort")

    def __init__(self, names: Sequence[str]) -> None:
        self.names = list(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.rows = _Rows(3 * len(self.names))

    def add(self, msg: Any) -> None:
        n = len(self.names)
        row = [math.nan] * (3 * n)
        same = list(msg.name) == self.names
        columns = range(n) if same else [self.index.get(name) for name in msg.name]
        for k, key in enumerate(self.KEYS):
            values = getattr(msg, key)
            if len(values) == len(columns):
                for column, value in zip(columns, values, strict=True):
                    if column is not None:
                        row[k * n + column] = value
        # a brake that gave way (a controller deactivated in a live switch) answers the
        # same states as the controller that took over: not a second loop's stamps
        self.rows.add(_stamp(msg), row, msg.header.frame_id != topics.BRAKE_FRAME_ID)

    def series(self) -> JointSeries:
        time, table = self.rows.sorted()
        n = len(self.names)
        return JointSeries(time, self.names,
                           *(table[:, k * n:(k + 1) * n] for k in range(len(self.KEYS))),
                           stamps_backwards=self.rows.backwards,
                           stamps_repeated=self.rows.repeated,
                           backwards_at=np.array(self.rows.backwards_at),
                           repeated_at=np.array(self.rows.repeated_at))


class _WrenchTopic:
    def __init__(self) -> None:
        self.rows = _Rows(6)

    def add(self, msg: Any) -> None:
        f, t = msg.wrench.force, msg.wrench.torque
        self.rows.add(_stamp(msg), (f.x, f.y, f.z, t.x, t.y, t.z))

    def series(self) -> WrenchSeries:
        time, table = self.rows.sorted()
        return WrenchSeries(time, table[:, :3], table[:, 3:])


def _accumulator(kind: str, msg: Any) -> Any:
    """The accumulator for a topic, from its type and first message (None: not used)."""
    if kind == _JOINT_STATE:
        return _JointTopic(msg.name)
    if kind == _WRENCH:
        return _WrenchTopic()
    if msg.layout.dim and topics.fields_of(msg.layout.dim[0].label)[:1] == ["stamp"]:
        return _LabelledTopic(msg.layout.dim[0].label)
    return None


def _parse_value(text: str) -> Any:
    try:
        return ros_yaml.load(text)
    except yaml.YAMLError:
        return text


def _publisher_count(channel: Channel) -> int | None:
    """Publishers of a recorded channel: entries of its ``offered_qos_profiles`` (rosbag2
    writes one per publisher it matched), None if the file does not say."""
    text = channel.metadata.get("offered_qos_profiles", "")
    try:
        offered = ros_yaml.load(text) if text.strip() else None
    except yaml.YAMLError:
        return None
    return len(offered) if isinstance(offered, list) and offered else None


def _decoder(path: Path, factory: DecoderFactory, channel: Channel, schema: Schema | None) -> Any:
    """The decoder of a channel's messages (None: not ROS 2 CDR); SessionError if its schema
    does not parse (the parser's own complaint on stderr is dropped: the error says it)."""
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            return factory.decoder_for(channel.message_encoding, schema)
    except Exception as exc:
        name = schema.name if schema is not None else "?"
        raise SessionError(f"{path}: {channel.topic}: its schema {name} does not parse "
                           f"({_reason(exc)})") from None


def load_session(path: str | Path) -> Session:
    """Read a recorded session; raises :class:`SessionError` for files it cannot use."""
    path = Path(path)
    _check_readable(path)
    session = Session(path)
    metadata: dict[str, dict[str, str]] = {}
    factory = DecoderFactory()
    decoders: dict[int, Any] = {}  # channel id -> decoder (None: not decoded)
    accumulators: dict[str, Any] = {}
    kinds: dict[str, str] = {}  # topic -> the type its accumulator reads
    publishers: dict[str, int] = {}  # topic -> publishers over its channels
    channels_seen: set[int] = set()
    try:
        for schema, channel, message in _iter_messages(path, session.warnings, metadata):
            topic = channel.topic
            session.message_counts[topic] = session.message_counts.get(topic, 0) + 1
            if channel.id not in channels_seen:
                channels_seen.add(channel.id)
                count = _publisher_count(channel)
                if count is not None:
                    publishers[topic] = publishers.get(topic, 0) + count
            kind = _type_name(schema)
            if kind not in (_JOINT_STATE, _WRENCH, _ARRAY) or accumulators.get(
                    topic, True) is None:
                continue
            if kinds.setdefault(topic, kind) != kind:
                raise SessionError(f"{path}: {topic} was recorded with two types, "
                                   f"{kinds[topic]} and {kind}")
            if channel.id not in decoders:
                decoders[channel.id] = _decoder(path, factory, channel, schema)
            decoder = decoders[channel.id]
            if decoder is None:
                continue
            try:
                msg = decoder(message.data)
            except Exception as exc:  # a corrupt message must not end the analysis
                session.warnings.append(f"{topic}: undecodable message skipped ({exc})")
                continue
            try:
                if topic not in accumulators:
                    accumulators[topic] = _accumulator(kind, msg)
                if accumulators[topic] is not None:
                    accumulators[topic].add(msg)
            except (AttributeError, TypeError, IndexError) as exc:
                raise SessionError(f"{path}: {topic}: the recording's {kind} schema is not "
                                   f"ROS's ({exc})") from None
    except OSError as exc:
        raise SessionError(f"{path}: unreadable MCAP file ({exc.strerror or exc})") from exc

    for topic, acc in accumulators.items():
        if isinstance(acc, _LabelledTopic):
            session.labelled[topic] = acc.columns()
        elif isinstance(acc, _WrenchTopic):
            if topic == topics.CONTACT_WRENCH:
                session.contact_wrench = acc.series()
            elif session.wrench is None or topic == topics.WRENCH:
                session.wrench = acc.series()
                _note_publishers(session, "wrench", publishers.get(topic))
        elif isinstance(acc, _JointTopic):
            for role in ("joint_commands", "joint_states"):
                if topic == f"/{role}" or topic.endswith(f"/{role}"):
                    setattr(session, role, acc.series())
                    _note_publishers(session, role, publishers.get(topic))
                    break

    session.timing = session.labelled.get(topics.PLANT_TIMING, {})
    for role, name in PUBLISHER_FIELDS.items():
        counts = session.timing.get(name)
        if counts is not None and np.isfinite(counts).any():
            _note_publishers(session, role, int(np.nanmax(counts)))
    suffix = f"/{topics.STATUS_SUFFIX}"
    controllers = sorted(t[1:-len(suffix)] for t in session.labelled
                         if t.endswith(suffix) and t != topics.PLANT_TIMING)
    if controllers:
        _pick_controllers(session, controllers)
    for name, values in metadata.items():
        if name.startswith(PARAMETERS_PREFIX):
            session.parameters[name[len(PARAMETERS_PREFIX):]] = {
                key: _parse_value(text) for key, text in values.items()}

    if not (session.labelled or session.joint_states or session.joint_commands
            or session.wrench):
        found = ", ".join(sorted(session.message_counts)) or "no messages"
        raise SessionError(f"{path}: none of cr_control's topics in this recording ({found})")
    return session


def _note_publishers(session: Session, role: str, count: int | None) -> None:
    """Keep the largest publisher count known for ``role``."""
    if count is not None:
        session.publishers[role] = max(count, session.publishers.get(role, 0))


def _join(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Labelled arrays of consecutive controllers as one: their common fields, in time order.
    States both answered (:data:`SWITCH_OVERLAP_S`: the plant stepped with the earlier's
    answers) keep the earlier's rows."""
    common = [f for f in parts[0] if all(f in part for part in parts[1:])]
    kept, last = [], -np.inf
    for part in parts:
        stamps = part.get("stamp", np.zeros(0))
        rows = stamps > last
        kept.append({f: part[f][rows] for f in common})
        if len(stamps):
            last = max(last, float(stamps[-1]))
    return {f: np.concatenate([part[f] for part in kept]) for f in common}


#: A live switch: how long (s of stamps) the second controller's first statuses may precede
#: the first's last. Activated, it answers the states it held and had queued; in lockstep,
#: where the deactivation races the plant's next state, the first's law may have answered
#: them just before (a busy machine leaves a few queued); the plant stepped with those
#: answers and drops the second's, stamped for states gone.
SWITCH_OVERLAP_S = 0.1


def _pick_controllers(session: Session, names: list[str]) -> None:
    """The controller(s) whose status is analysed. Several whose statuses follow one another
    in time (a live switch: each one's first status at most :data:`SWITCH_OVERLAP_S` before
    the previous one's last, its last after it) are joined, and the commands' stamps both
    answered are not counted as going backwards or repeating; several at once (a rogue
    second controller) are warned about, the first kept."""
    statuses = {n: session.labelled[topics.status_topic(n)] for n in names}
    ordered = sorted(names, key=lambda n: statuses[n]["stamp"][0] if len(statuses[n]["stamp"])
                     else np.inf)
    spans = [(statuses[n]["stamp"][0], statuses[n]["stamp"][-1]) for n in ordered
             if len(statuses[n]["stamp"])]
    pairs = list(zip(spans, spans[1:], strict=False))
    switched = len(spans) == len(ordered) > 1 and all(
        earlier[1] - later[0] <= SWITCH_OVERLAP_S and later[1] > earlier[1]
        for earlier, later in pairs)
    session.controller = ordered[0] if switched else names[0]
    if not switched:
        session.controllers = [names[0]]
        session.status = statuses[names[0]]
        session.reference = session.labelled.get(topics.reference_topic(names[0]), {})
        if len(names) > 1:
            session.warnings.append(f"several controllers {names}; analysing {names[0]}")
        return
    session.controllers = ordered
    if session.joint_commands is not None:
        session.joint_commands.excuse([(later[0], earlier[1]) for earlier, later in pairs
                                       if earlier[1] >= later[0]])
    session.switches = [(float(statuses[n]["stamp"][0]), n) for n in ordered[1:]]
    session.status = _join([statuses[n] for n in ordered])
    session.reference = _join([session.labelled.get(topics.reference_topic(n), {"stamp": np.zeros(0)})
                               for n in ordered])
