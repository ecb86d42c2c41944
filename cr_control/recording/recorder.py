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
footer, and exits with status 0. If the file cannot be written (the disk full, an I/O
error), the recorder stops: one ERROR line names the file and the reason, the file keeps
what was written before (cut back to its last whole record, without a summary: readers
read it as a recording cut short) and the exit status is 1.

ROS parameters (all read-only, read at start):

- ``output`` (string): path of the ``.mcap`` file. Default ``session.mcap``.
- ``topics`` (string array): topics to record. Default: joint states, wrench, joint
  commands, ``/clock``, plant timing, ``/parameter_events``.
- ``optional_topics`` (string array): topics recorded whenever they appear but never
  waited for. Default ``/clock`` (published only in lockstep mode), ``/plant/sensors``,
  ``/plant/contact_wrench`` (published by the plants that have them), ``/diagnostics`` and
  ``/plant/markers``.
- ``parameter_nodes`` (string array): nodes whose parameters are saved. Default empty:
  every node in the graph when ready, except this one.
- ``ready_timeout`` (double, s): how long to wait for the topics before declaring ready
  anyway (with a warning). Default 10.
- ``compression`` (string): chunk compression, ``zstd`` (default), ``lz4`` or ``none``
  (zstd costs ~0.2 µs per message here, a small share of the per-message cost).

The node is here; the file format is :mod:`cr_control.recording.mcap_writer`, message
definitions and QoS :mod:`cr_control.recording.definitions`, the parameter services'
client :mod:`cr_control.recording.parameter_fetch`.
"""

from __future__ import annotations

import bisect
import errno
import gc
import signal
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from std_msgs.msg import Bool

from cr_control.core import topics
from cr_control.core.ros_env import drop_node_dds_profile
from cr_control.nodes.qos import READY_QOS
from cr_control.nodes.ros_parameters import refuse_undeclared
from cr_control.nodes.spin import refuse_empty_params_files
from cr_control.recording.definitions import (
    UNKNOWN_NODE,
    DefinitionNotFoundError,
    has_header,
    import_message,
    message_definition,
    qos_profile_dict,
    qos_profiles_yaml,
    request_qos,
)
from cr_control.recording.mcap_writer import COMPRESSIONS, McapBagWriter, header_stamp_ns
from cr_control.recording.parameter_fetch import ParameterFetch

#: Names other modules and the tests import from here (their code lives in the modules above).
__all__ = [
    "COMPRESSIONS", "DefinitionNotFoundError", "McapBagWriter", "header_stamp_ns", "message_definition",
    "qos_profile_dict", "qos_profiles_yaml", "request_qos",
]

DEFAULT_TOPICS = [
    topics.JOINT_STATES,
    topics.WRENCH,
    topics.JOINT_COMMANDS,
    topics.CLOCK,
    topics.PLANT_TIMING,
    topics.PARAMETER_EVENTS,
]
DEFAULT_OPTIONAL_TOPICS = [topics.CLOCK, topics.PLANT_SENSORS, topics.CONTACT_WRENCH,
                           topics.DIAGNOSTICS, topics.PLANT_MARKERS]

#: The executor runs in slices of this length; between slices the recorder discovers
#: topics, checks readiness and parameter requests, and notices a stop request.
SLICE_S = 0.1
#: After a stop request: keep recording until no message arrives for DRAIN_QUIET_S,
#: but no longer than DRAIN_MAX_S.
DRAIN_QUIET_S = 0.25
DRAIN_MAX_S = 3.0
#: Messages received this recently wait for the next batch (see Recorder.take_all).
ORDER_MARGIN_NS = 2_000_000


# -- the node --------------------------------------------------------------------------


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
        #: Per taker: last publication sequence number seen (0: not tracking), and
        #: whether the topic had one publisher at the end of the last take.
        self._last_sequence: list[int] = []
        self._was_single: list[bool] = []
        self.missed: dict[str, int] = {}
        self._pending: list[tuple[int, int, bytes]] = []
        self._recorded: dict[str, Any] = {}
        self._ready = False
        self._warned_types: set[str] = set()
        self._fetches: list[ParameterFetch] | None = None  # None: not started
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
            msg_class = import_message(type_name)
            publishers = self.get_publishers_info_by_topic(name)
            offered = [p.qos_profile for p in publishers]
            type_hash = str(publishers[0].topic_type_hash) if publishers else ""
            channel = self.writer.add_topic(
                name, type_name, [qos_profile_dict(q) for q in offered], type_hash,
                has_header(msg_class))
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
        self._was_single.append(False)
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
            # Sequence numbers count per publisher, and a message does not say whose it
            # is: gaps mean something only while the topic has had one publisher since
            # the last take and until after this one (a second publisher's messages can
            # still be queued just after it left, or arrive just after it matched).
            single = subscription.get_publisher_count() == 1
            last = self._last_sequence[i] if single and self._was_single[i] else -1
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
            single = single and subscription.get_publisher_count() == 1
            self._was_single[i] = single
            self._last_sequence[i] = max(last, 0) if single else 0
            if missed and single:
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

    def _start_parameter_fetches(self) -> list[ParameterFetch]:
        targets = self._parameter_nodes
        if not targets:
            me = self.get_fully_qualified_name()
            targets = [f"{ns.rstrip('/')}/{name}"
                       for name, ns in self.get_node_names_and_namespaces()
                       if not name.startswith("_")]
            targets = [t for t in dict.fromkeys(targets) if t != me]
        return [ParameterFetch(self, t if t.startswith("/") else f"/{t}") for t in targets]

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


def record_to_file(recorder: Recorder, executor: Any, stop: _StopRequest) -> OSError | None:
    """:func:`record`, then close the file; the OSError that stopped the writing (the disk
    full, ...), if any: the file is then closed as far as it was written (McapBagWriter)."""
    failure = None
    try:
        record(recorder, executor, stop)
    except ExternalShutdownException:
        pass
    except OSError as exc:
        failure = exc
    try:
        recorder.writer.close()
    except OSError as exc:
        failure = failure or exc
    return failure


def write_failure(path: Path, exc: OSError) -> str:
    """The one line logged when the file cannot be written."""
    full = exc.errno in (errno.ENOSPC, errno.EDQUOT)
    reason = "the disk is full" if full else f"cannot write ({exc.strerror or exc})"
    return (f"stopped recording to {path}: {reason}; the file keeps what was written before, "
            "without its summary (readers read it as a recording cut short)")


def main(args: Iterable[str] | None = None) -> int:
    """Entry point of the ``recorder`` executable."""
    argv = list(args) if args is not None else sys.argv
    if refuse_empty_params_files("recorder", argv):
        return 1
    drop_node_dds_profile()     # it records every writer; Fast DDS's defaults (ros_env)
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
    failure = None
    try:
        failure = record_to_file(recorder, executor, stop)
        if failure is not None:
            recorder.get_logger().error(write_failure(recorder.output, failure))
    finally:
        recorder.writer.close()   # after an exception other than OSError
        count, path = recorder.writer.message_count, recorder.output
        executor.shutdown(timeout_sec=1.0)
        recorder.destroy_node()
        rclpy.try_shutdown()
    if failure is not None:
        return 1
    missed = sum(recorder.missed.values())
    detail = (f"; {missed} missed (gaps in the publishers' sequence numbers: "
              f"{', '.join(f'{t} {n}' for t, n in recorder.missed.items())})" if missed else "")
    print(f"recorder: wrote {count} messages to {path}{detail}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
