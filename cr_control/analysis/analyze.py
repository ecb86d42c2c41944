"""Analysis of recorded sessions (executable ``cr_analyze``): metrics, thesis figures, comparisons.

Reads any MCAP file the recorder wrote (or any ``ros2`` MCAP with this package's topics)
without ROS: messages are decoded with ``mcap_ros2``. A session gives what a control
engineer asks first: tracking metrics (RMS/max position and force error, settling time,
peak torque), controller compute time, loop timing, and the thesis's figures as PNG.
Metrics and figures cover the position axes the session has (x, y; and z on a spatial
arm); a robot session (``cr_session --robot``, wiping a table) also gets the wiping task's
metrics and figures of :mod:`cr_control.analysis.robot` (normal force, in-plane path error,
contact lost, orientation and posture error; 3-D and top-view path).

It also checks that the recording is one session's own: more than one publisher on a
control topic, or header stamps on /joint_states or /joint_commands that go backwards
or repeat, mean another run shared the ROS domain (cross-talk) or the plant restarted.
Such recordings get a ``WARNING`` line under the metrics and non-zero integrity fields.

Command line::

    cr_analyze FILE.mcap [FILE2.mcap ...] [--out DIR] [--no-plots] [--json]

prints the metrics table (one column per file) or JSON, and writes the figures (default:
``<stem>_plots/`` next to the first file; with several files, comparison figures there
and each session's own figures in a sub-directory per session). Exit status 2 on user
errors (missing, unreadable or non-MCAP files, no package topics).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import struct
import sys
from array import array
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory

from cr_control.analysis import chapter2, chapter4, chapter5, chapter6, robot
from cr_control.analysis.figures import save_figure as _save
from cr_control.core import ros_yaml, topics

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: What the MCAP readers raise on damaged or truncated data.
_READ_ERRORS = (McapError, ValueError, EOFError, struct.error)
PARAMETERS_PREFIX = "parameters/"

#: Settling: ||e|| stays within max(SETTLING_FRACTION * ||e(t0)||, SETTLING_BAND_M).
SETTLING_FRACTION = 0.02
SETTLING_BAND_M = 1e-3

#: Network-norm pairs of the NN schemes (true, estimate), thesis figs 3.12-3.14.
NORM_PAIRS = [("M_r_norm", "M_r_hat_norm"), ("C_r_norm", "C_r_hat_norm"),
              ("G_r_norm", "G_r_hat_norm")]
ESTIMATE_PREFIXES = ("A_hat", "B_hat", "c_hat")
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
    try:
        with open(path, "rb") as f:
            magic = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise SessionError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if magic != MCAP_MAGIC:
        raise SessionError(f"{path}: not an MCAP file")


def _iter_messages(path: Path, warnings: list[str], metadata: dict[str, dict[str, str]],
                   ) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """Messages in file order (filling ``metadata``); tolerates a file cut short."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        try:
            summary = reader.get_summary()
        except _READ_ERRORS:
            summary = None
        if summary is not None:
            metadata.update({m.name: dict(m.metadata) for m in reader.iter_metadata()})
            yield from reader.iter_messages(log_time_order=False)
            return
        # No summary (recording cut short): read linearly as far as the data goes.
        f.seek(0)
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        count = 0
        try:
            for record in StreamReader(f, skip_magic=False).records:
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
        except _READ_ERRORS as exc:
            warnings.append(f"file ends early ({exc}); read {count} messages")


def _stamp(msg: Any) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


class _Rows:
    """Fixed-width float rows stored compactly, with a time column to sort by.

    Counts, in the order rows are added, times that go backwards or repeat.
    """

    def __init__(self, width: int) -> None:
        self.width = width
        self.time = array("d")
        self.values = array("d")
        self.backwards = 0
        self.repeated = 0

    def add(self, time: float, row: Sequence[float]) -> None:
        if self.time:
            self.backwards += time < self.time[-1]
            self.repeated += time == self.time[-1]
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
        self.rows.add(_stamp(msg), row)

    def series(self) -> JointSeries:
        time, table = self.rows.sorted()
        n = len(self.names)
        return JointSeries(time, self.names,
                           *(table[:, k * n:(k + 1) * n] for k in range(len(self.KEYS))),
                           stamps_backwards=self.rows.backwards,
                           stamps_repeated=self.rows.repeated)


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


def load_session(path: str | Path) -> Session:
    """Read a recorded session; raises :class:`SessionError` for files it cannot use."""
    path = Path(path)
    _check_readable(path)
    session = Session(path)
    metadata: dict[str, dict[str, str]] = {}
    factory = DecoderFactory()
    accumulators: dict[str, Any] = {}
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
            decoder = factory.decoder_for(channel.message_encoding, schema)
            if decoder is None:
                continue
            try:
                msg = decoder(message.data)
            except Exception as exc:  # a corrupt message must not end the analysis
                session.warnings.append(f"{topic}: undecodable message skipped ({exc})")
                continue
            if topic not in accumulators:
                accumulators[topic] = _accumulator(kind, msg)
            if accumulators[topic] is not None:
                accumulators[topic].add(msg)
    except (*_READ_ERRORS, OSError) as exc:
        raise SessionError(f"{path}: unreadable MCAP file ({exc})") from exc

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
        session.controller = controllers[0]
        session.status = session.labelled[topics.status_topic(controllers[0])]
        session.reference = session.labelled.get(topics.reference_topic(controllers[0]), {})
        if len(controllers) > 1:
            session.warnings.append(f"several controllers {controllers}; analysing "
                                    f"{controllers[0]}")
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


# -- metrics -----------------------------------------------------------------------------

def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else math.nan


def settling_time(t: np.ndarray, error_norm: np.ndarray) -> float:
    """Time from the first sample until ``error_norm`` stays within its settling band.

    The band is max(SETTLING_FRACTION * error_norm[0], SETTLING_BAND_M). Returns 0 if the
    error never leaves it and NaN if the last sample is outside it (not settled).
    """
    if not len(t):
        return math.nan
    band = max(SETTLING_FRACTION * float(error_norm[0]), SETTLING_BAND_M)
    outside = np.flatnonzero(error_norm > band)
    if not len(outside):
        return 0.0
    if outside[-1] == len(t) - 1:
        return math.nan
    return float(t[outside[-1] + 1] - t[0])


def _percentiles(prefix: str, values: np.ndarray, unit: str) -> dict[str, float]:
    values = values[np.isfinite(values)]
    if not len(values):
        return {}
    p50, p99 = np.percentile(values, [50, 99])
    return {f"{prefix}_p50_{unit}": float(p50), f"{prefix}_p99_{unit}": float(p99),
            f"{prefix}_max_{unit}": float(np.max(values))}


def metrics(session: Session) -> dict[str, Any]:
    """Tracking, torque, compute-time and loop-timing figures of merit (flat, SI units).

    Keys end with their unit. RMS and max are over samples; "last half" is the second
    half of the run in time. ``pos_err_*`` and settling are of the error norm over all
    position axes (x, y and, on a spatial arm, z); force errors and forces per axis.
    Settling: see :func:`settling_time`. A robot session adds the wiping task's metrics
    (:func:`cr_control.analysis.robot.robot_metrics`). Loop timing comes from the last
    plant timing message (whole-run totals) plus the mean of the per-second rates. Parts
    missing from the recording are absent from the result.
    """
    out: dict[str, Any] = {"controller": session.controller or "-"}
    status = session.status
    if len(status.get("stamp", ())):
        t = status["stamp"]
        out["duration_s"] = float(t[-1] - t[0])
        out["samples"] = len(t)
        if "e_x" in status and "e_y" in status:
            e = robot.error_norm(status)
            last = t >= t[0] + 0.5 * (t[-1] - t[0])
            out["pos_err_rms_m"] = _rms(e)
            out["pos_err_max_m"] = float(np.max(e))
            out["pos_err_rms_last_half_m"] = _rms(e[last])
            out["pos_err_max_last_half_m"] = float(np.max(e[last]))
            out["settling_time_s"] = settling_time(t, e)
        for axis in robot.AXES:
            name = f"f_err_{axis}"
            if name in status:
                err = status[name]
                out[f"{name}_rms_N"] = _rms(err)
                out[f"{name}_max_N"] = float(np.max(err))
                out[f"{name}_min_N"] = float(np.min(err))
        for axis in robot.AXES:
            if f"f_{axis}" in status:
                out[f"f_{axis}_min_N"] = float(np.min(status[f"f_{axis}"]))
                out[f"f_{axis}_max_N"] = float(np.max(status[f"f_{axis}"]))
        out.update(robot.robot_metrics(session))
        if "compute_time_us" in status:
            out.update(_percentiles("compute_time", status["compute_time_us"], "us"))
    commands = session.joint_commands
    if commands is not None and np.isfinite(commands.effort).any():
        for j, name in enumerate(commands.names):
            column = np.abs(commands.effort[:, j])
            if np.isfinite(column).any():
                out[f"tau_peak_{name}_Nm"] = float(np.nanmax(column))
    else:
        for name in sorted(k for k in status if k.startswith("tau_")):
            out[f"{name}_peak_Nm"] = float(np.max(np.abs(status[name])))
    timing = session.timing
    if len(timing.get("stamp", ())):
        last = {name: float(values[-1]) for name, values in timing.items()}
        if "rate_hz" in timing:
            out["loop_rate_hz"] = last["rate_hz"]
            out["loop_rate_mean_hz"] = float(np.mean(timing["rate_hz"]))
        for source, key in (("total_cycles", "loop_cycles"),
                            ("total_fresh_share", "loop_fresh_share"),
                            ("total_missed_cycles", "loop_missed_cycles"),
                            ("total_age_p50_ms", "loop_age_p50_ms"),
                            ("total_age_p99_ms", "loop_age_p99_ms"),
                            ("total_age_max_ms", "loop_age_max_ms")):
            if source in last:
                value = last[source]
                out[key] = int(value) if key.endswith("cycles") else value
    out.update(integrity(session))
    return out


def integrity(session: Session) -> dict[str, int]:
    """Is the recording one session's own? Publishers per control topic (where known),
    stamps going backwards or repeating on the joint topics, and ``data_warnings``: how
    many of those look wrong (see :func:`integrity_warnings`)."""
    out = {f"publishers_{role}": session.publishers[role]
           for role in CONTROL_ROLES if role in session.publishers}
    for role in ("joint_states", "joint_commands"):
        series = getattr(session, role)
        if series is not None:
            out[f"stamps_backwards_{role}"] = series.stamps_backwards
            out[f"stamps_repeated_{role}"] = series.stamps_repeated
    out["data_warnings"] = len(integrity_warnings(out))
    return out


def integrity_warnings(values: dict[str, Any]) -> list[str]:
    """One sentence per integrity problem in metrics ``values`` (see :func:`integrity`)."""
    found = []
    for role in CONTROL_ROLES:
        count = values.get(f"publishers_{role}", 1)
        if count > 1:
            found.append(f"{count} publishers on /{role}: another run shares this "
                         "ROS_DOMAIN_ID (cross-talk); its data is mixed in")
    for role in ("joint_states", "joint_commands"):
        backwards = values.get(f"stamps_backwards_{role}", 0)
        repeated = values.get(f"stamps_repeated_{role}", 0)
        if backwards:
            found.append(f"stamps on /{role} went backwards {backwards} times: a second "
                         "publisher (cross-talk) or a restarted plant")
        if repeated:
            found.append(f"stamps on /{role} repeated {repeated} times: a second publisher, "
                         "or states resent by a stalled lockstep loop")
    return found


#: A real-time loop "fell behind" below these (docs/benchmark.md's targets for this machine).
BEHIND_FRESH_SHARE = 0.95
BEHIND_RATE_HZ = 990.0


def loop_summary(values: dict[str, Any], realtime: bool = True) -> list[str]:
    """The plant loop in one line, then a plain warning if a real-time loop fell behind
    (rate below BEHIND_RATE_HZ or fewer than BEHIND_FRESH_SHARE of the cycles with a command
    computed from the state before). Empty without plant timing."""
    if "loop_fresh_share" not in values:
        return []
    rate = values.get("loop_rate_mean_hz", values.get("loop_rate_hz", math.nan))
    fresh = values["loop_fresh_share"]
    lines = [f"loop: {rate:.1f} Hz, {100 * fresh:.2f} % of cycles with a fresh command, "
             f"round trip p50/p99 {values.get('loop_age_p50_ms', math.nan):.3f}/"
             f"{values.get('loop_age_p99_ms', math.nan):.3f} ms"]
    if realtime and (fresh < BEHIND_FRESH_SHARE or rate < BEHIND_RATE_HZ):
        lines.append(f"WARNING: the real-time loop fell behind ({rate:.0f} Hz, "
                     f"{100 * (1 - fresh):.1f} % of cycles applied a stale command): the "
                     "machine was too busy for 1 kHz; see the timing plot and `make benchmark`")
    return lines


def _format_value(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool | int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return "n/a" if math.isnan(value) else f"{value:.4g}"
    return str(value)


def format_metrics(rows: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """An aligned text table: one row per metric, one column per (name, metrics) pair."""
    keys: list[str] = []
    for _, values in rows:
        keys += [k for k in values if k not in keys]
    table = [["metric", *(name for name, _ in rows)]]
    table += [[key, *(_format_value(values.get(key)) for _, values in rows)] for key in keys]
    widths = [max(len(line[i]) for line in table) for i in range(len(table[0]))]
    lines = ["  ".join(cell.ljust(w) if i == 0 else cell.rjust(w)
                       for i, (cell, w) in enumerate(zip(line, widths, strict=True))).rstrip()
             for line in table]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines += [f"WARNING: {name}: {text}" for name, values in rows
              for text in integrity_warnings(values)]
    return "\n".join(lines)


# -- figures -----------------------------------------------------------------------------

def _figure(rows: int, cols: int = 1, height: float = 2.4):
    from matplotlib.figure import Figure  # lazy: no plotting cost for --no-plots

    fig = Figure(figsize=(7.5 if cols == 1 else 4.5 * cols, 0.8 + height * rows),
                 layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
    return fig, axes


def _has(series: dict[str, np.ndarray], *names: str) -> bool:
    return all(name in series for name in names) and len(series.get("stamp", ())) > 0


def _torques(session: Session) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(label, time, torque) per joint: commanded efforts, else status tau_*."""
    commands = session.joint_commands
    if commands is not None and np.isfinite(commands.effort).any():
        return [(name, commands.time, commands.effort[:, j])
                for j, name in enumerate(commands.names)
                if np.isfinite(commands.effort[:, j]).any()]
    return [(name, session.status["stamp"], session.status[name])
            for name in sorted(k for k in session.status if k.startswith("tau_"))]


def plot_session(session: Session, out_dir: str | Path) -> list[Path]:
    """Write the session's figures (thesis style) as PNG into ``out_dir``; returns paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    rel, status, ref = session.relative_time, session.status, session.reference
    title = session.name

    position_axes = robot.position_axes(status)
    if _has(status, "r_x", "r_y"):
        fig, axes = _figure(len(position_axes))
        for ax, axis in zip(axes[:, 0], position_axes, strict=True):
            ax.plot(rel(status["stamp"]), status[f"r_{axis}"], label=f"{axis} (actual)")
            if _has(ref, f"r_d_{axis}"):
                ax.plot(rel(ref["stamp"]), ref[f"r_d_{axis}"], "k--", label=f"{axis}_d (desired)")
            ax.set_ylabel(f"{axis} [m]")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: position tracking (cf. thesis figs 3.2, 3.5, 3.8)")
        _save(fig, out / "position.png", written)

    if _has(status, "e_x", "e_y"):
        fig, axes = _figure(2)
        t = rel(status["stamp"])
        axes[0, 0].plot(t, robot.error_norm(status) * 1e3, label="‖e‖")
        for axis in position_axes:
            axes[0, 0].plot(t, status[f"e_{axis}"] * 1e3, lw=0.8, label=f"e_{axis}")
            if f"f_err_{axis}" in status:
                axes[1, 0].plot(t, status[f"f_err_{axis}"], label=f"f_err_{axis}")
        axes[0, 0].set_ylabel("position error [mm]")
        axes[1, 0].set_ylabel("force error [N]")
        axes[1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: tracking errors")
        _save(fig, out / "errors.png", written)

    force = session.wrench
    if _has(status, "f_x", "f_y") or force is not None:
        fig, axes = _figure(len(position_axes))
        for i, (ax, axis) in enumerate(zip(axes[:, 0], position_axes, strict=True)):
            if _has(status, f"f_{axis}"):
                ax.plot(rel(status["stamp"]), status[f"f_{axis}"], label=f"f_{axis} (measured)")
            elif force is not None:
                ax.plot(rel(force.time), force.force[:, i], label=f"f_{axis} (measured)")
            if _has(ref, f"f_d_{axis}"):
                ax.plot(rel(ref["stamp"]), ref[f"f_d_{axis}"], "k--", label=f"f_d{axis} (desired)")
            ax.set_ylabel(f"f_{axis} [N]")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: contact force (cf. thesis figs 3.3, 3.6, 3.9)")
        _save(fig, out / "force.png", written)

    torques = _torques(session)
    if torques:
        fig, axes = _figure(len(torques), height=1.9)
        for ax, (name, t, tau) in zip(axes[:, 0], torques, strict=True):
            ax.plot(rel(t), tau, label=name)
            ax.set_ylabel(f"{name} [N m]")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: joint torques (cf. thesis figs 3.4, 3.7, 3.11)")
        _save(fig, out / "torques.png", written)

    groups = [(prefix, [k for k in status if k.startswith(prefix)])
              for prefix in ESTIMATE_PREFIXES]
    groups = [(prefix, names) for prefix, names in groups if names]
    if groups and _has(status):
        fig, axes = _figure(len(groups), height=2.0)
        for ax, (prefix, names) in zip(axes[:, 0], groups, strict=True):
            for name in names:
                ax.plot(rel(status["stamp"]), status[name], label=name)
            ax.set_ylabel(prefix)
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: adaptive impedance estimates")
        _save(fig, out / "estimates.png", written)

    if _has(status, "s_x", "s_y"):
        fig, axes = _figure(1)
        for axis in (a for a in robot.AXES if f"s_{a}" in status):
            axes[0, 0].plot(rel(status["stamp"]), status[f"s_{axis}"], label=f"s_{axis}")
        axes[0, 0].set_ylabel("s [m/s]")
        axes[0, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: sliding variable")
        _save(fig, out / "sliding.png", written)

    pairs = [(true, est) for true, est in NORM_PAIRS if _has(status, true, est)]
    if pairs:
        fig, axes = _figure(len(pairs), height=2.0)
        for ax, (true, est) in zip(axes[:, 0], pairs, strict=True):
            t = rel(status["stamp"])
            ax.plot(t, status[true], "k--", label=f"‖{true.removesuffix('_norm')}‖ (true)")
            ax.plot(t, status[est], label=f"‖{est.removesuffix('_norm')}‖ (network)")
            ax.set_ylabel("norm")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: network estimates (cf. thesis figs 3.12-3.14)")
        _save(fig, out / "network_norms.png", written)

    timing = session.timing
    compute = _has(status, "compute_time_us")
    if _has(timing, "rate_hz") or compute:
        panels = [p for p, ok in (("rate", _has(timing, "rate_hz")),
                                  ("age", _has(timing, "window_age_p99_ms")),
                                  ("compute", compute)) if ok]
        fig, axes = _figure(len(panels), height=1.9)
        for ax, panel in zip(axes[:, 0], panels, strict=True):
            if panel == "rate":
                ax.plot(rel(timing["stamp"]), timing["rate_hz"], ".-", label="rate")
                ax.set_ylabel("loop rate [Hz]")
            elif panel == "age":
                for key in ("window_age_p50_ms", "window_age_p99_ms", "window_age_max_ms"):
                    if key in timing:
                        ax.plot(rel(timing["stamp"]), timing[key], ".-",
                                label=key.removeprefix("window_age_").removesuffix("_ms"))
                ax.set_ylabel("state→command [ms]")
            else:
                ax.plot(rel(status["stamp"]), status["compute_time_us"], lw=0.6,
                        label="compute time")
                ax.set_ylabel("compute [µs]")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: loop timing")
        _save(fig, out / "loop_timing.png", written)
    written += chapter5.session_figures(session, out)   # figs. 5.3-5.9 for chapter 5 runs
    written += chapter2.session_figures(session, out)   # figs. 2.4-2.12 for chapter 2 runs
    written += chapter4.session_figures(session, out)   # figs. 4.2-4.11, appendix C
    written += chapter6.session_figures(session, out)   # figs. 6.2-6.18 for chapter 6 runs
    written += robot.session_figures(session, out)      # a URDF arm wiping a table
    return written


def session_labels(sessions: Sequence[Session]) -> list[str]:
    """A distinct label per session: controller name, with the file stem when needed."""
    names = [s.name for s in sessions]
    labels = [f"{s.name} ({s.path.stem})" if names.count(s.name) > 1 and s.controller
              else s.name for s in sessions]
    return [f"{label} #{i + 1}" if labels.count(label) > 1 else label
            for i, label in enumerate(labels)]


def _overlay(sessions: Sequence[Session], labels: Sequence[str], path: Path, title: str,
             panels: Sequence[tuple[str, Callable[[Session], list[tuple[np.ndarray,
                                                                          np.ndarray, str]]]]],
             written: list[Path]) -> None:
    """One figure, a panel per quantity, one line per session (plus dashed references)."""
    panels = [(ylabel, get) for ylabel, get in panels if any(get(s) for s in sessions)]
    if not panels:
        return
    fig, axes = _figure(len(panels), height=2.2)
    for ax, (ylabel, get) in zip(axes[:, 0], panels, strict=True):
        for i, (session, label) in enumerate(zip(sessions, labels, strict=True)):
            for t, y, style in get(session):
                if style == "desired":
                    ax.plot(session.relative_time(t), y, "--", color=f"C{i}", lw=0.8, alpha=0.7)
                else:
                    ax.plot(session.relative_time(t), y, color=f"C{i}", lw=1.0,
                            label=label if style == "first" else None)
        ax.set_ylabel(ylabel)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    _save(fig, path, written)


def compare(sessions: Sequence[Session], out_dir: str | Path) -> list[Path]:
    """Side-by-side figures (one line per session) and the metrics table of ``sessions``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    labels = session_labels(sessions)
    written: list[Path] = []

    def status_line(name: str, scale: float = 1.0):
        def get(s: Session) -> list:
            return [(s.status["stamp"], scale * s.status[name], "first")] if _has(
                s.status, name) else []
        return get

    def tracked(actual: str, desired: str):
        def get(s: Session) -> list:
            lines = status_line(actual)(s)
            if lines and _has(s.reference, desired):
                lines.append((s.reference["stamp"], s.reference[desired], "desired"))
            return lines
        return get

    def error_norm(s: Session) -> list:
        if not _has(s.status, "e_x", "e_y"):
            return []
        return [(s.status["stamp"], 1e3 * robot.error_norm(s.status), "first")]

    _overlay(sessions, labels, out / "compare_position.png",
             "Position tracking (dashed: desired)",
             [("x [m]", tracked("r_x", "r_d_x")), ("y [m]", tracked("r_y", "r_d_y")),
              ("z [m]", tracked("r_z", "r_d_z")), ("‖e‖ [mm]", error_norm)], written)
    forces = [(f"f_{a} [N]", tracked(f"f_{a}", f"f_d_{a}")) for a in robot.AXES]
    forces += [(f"f_err_{a} [N]", status_line(f"f_err_{a}")) for a in robot.AXES]
    _overlay(sessions, labels, out / "compare_force.png", "Contact force (dashed: desired)",
             forces, written)
    _overlay(sessions, labels, out / "compare_robot.png", "Wiping the table (dashed: desired)",
             robot.compare_panels(), written)
    joints: list[str] = []
    for s in sessions:
        joints += [name for name, _, _ in _torques(s) if name not in joints]

    def torque(joint: str):
        def get(s: Session) -> list:
            return [(t, tau, "first") for name, t, tau in _torques(s) if name == joint]
        return get

    _overlay(sessions, labels, out / "compare_torques.png", "Joint torques",
             [(f"{j} [N m]", torque(j)) for j in joints], written)

    def timing_line(name: str):
        def get(s: Session) -> list:
            return [(s.timing["stamp"], s.timing[name], "first")] if _has(s.timing, name) else []
        return get

    _overlay(sessions, labels, out / "compare_loop_timing.png", "Loop timing",
             [("loop rate [Hz]", timing_line("rate_hz")),
              ("age p99 [ms]", timing_line("window_age_p99_ms")),
              ("compute [µs]", status_line("compute_time_us"))], written)

    rows = [(label, metrics(s)) for label, s in zip(labels, sessions, strict=True)]
    table = out / "comparison.txt"
    table.write_text(format_metrics(rows) + "\n")
    written.append(table)
    table_csv = out / "comparison.csv"
    with open(table_csv, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["metric", *labels])
        keys: list[str] = []
        for _, values in rows:
            keys += [k for k in values if k not in keys]
        for key in keys:
            writer.writerow([key, *(values.get(key, "") for _, values in rows)])
    written.append(table_csv)
    written += chapter5.compare_sessions(sessions, labels, out)   # chapter 5 runs: one table
    written += chapter2.compare_sessions(sessions, labels, out)   # chapter 2 runs: one table
    written += chapter4.compare_sessions(sessions, labels, out)   # chapter 4 / appendix C
    written += chapter6.compare_sessions(sessions, labels, out)   # chapter 6 runs: one table
    return written


# -- command line ------------------------------------------------------------------------

def _json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _folder_name(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in label).strip("_") or "session"


def _write_plots(sessions: Sequence[Session], out: Path) -> list[Path]:
    """Each session's own figures (in a sub-folder named by its label when several)."""
    if len(sessions) == 1:
        return plot_session(sessions[0], out)
    written = compare(sessions, out)
    for session, label in zip(sessions, session_labels(sessions), strict=True):
        written += plot_session(session, out / _folder_name(label))
    return written


def main(argv: Iterable[str] | None = None) -> int:
    """Entry point of ``cr_analyze``; returns the exit status."""
    parser = argparse.ArgumentParser(
        prog="cr_analyze",
        description="Metrics and thesis-style figures of recorded cr_control sessions.")
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE.mcap",
                        help="recorded sessions; several are compared side by side")
    parser.add_argument("--out", type=Path, metavar="DIR",
                        help="where to write figures (default: <first stem>_plots/ "
                             "next to the first file)")
    parser.add_argument("--no-plots", action="store_true", help="only print the metrics")
    parser.add_argument("--json", action="store_true",
                        help="print the metrics as JSON (one object per session)")
    args = parser.parse_args(None if argv is None else list(argv))

    def error(message: str) -> int:
        print(f"cr_analyze: error: {message}", file=sys.stderr)
        return 2

    sessions = []
    for path in args.files:
        try:
            sessions.append(load_session(path))
        except SessionError as exc:
            return error(str(exc))
    for session in sessions:
        for warning in session.warnings:
            print(f"cr_analyze: warning: {session.path}: {warning}", file=sys.stderr)

    labels = session_labels(sessions)
    rows = [(label, metrics(s)) for label, s in zip(labels, sessions, strict=True)]
    info = sys.stderr if args.json else sys.stdout
    if args.json:
        print(json.dumps({label: {k: _json_safe(v) for k, v in values.items()}
                          for label, values in rows}, indent=2))
        for label, values in rows:
            for text in integrity_warnings(values):
                print(f"WARNING: {label}: {text}", file=sys.stderr)
    else:
        print(format_metrics(rows))
    if not args.no_plots:
        first = args.files[0]
        out = args.out if args.out is not None else first.parent / f"{first.stem}_plots"
        try:
            written = _write_plots(sessions, out)
        except OSError as exc:
            return error(f"cannot write figures to {out}: {exc.strerror or exc}")
        print(f"wrote {len(written)} files to {out}", file=info)
    return 0


if __name__ == "__main__":
    sys.exit(main())
