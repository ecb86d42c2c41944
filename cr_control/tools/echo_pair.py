"""A bare rclpy echo pair: the floor under cr_control's real-time loop (no control math).

``source`` is plant-like: a wall-clock timer at ``--rate`` publishes a
sensor_msgs/JointState (``--joints`` joints, default 2: name, position, velocity, effort)
and a WrenchStamped with the same stamp, and counts its loop with the plant's
:class:`~cr_sim.loop_stats.LoopStats` (fresh share, state -> command round trip).
``echo`` answers every JointState with a JointState command carrying the same header
stamp (names and efforts of the state's first ``--command-joints`` joints: a robot's plant
also publishes joints nobody commands, e.g. the Panda's 9 = 7 arm + 2 locked fingers,
commanded 7). Same topics, message types, QoS
(RELIABLE, KEEP_LAST 10) and executor (EventsExecutor) as the plant and controller nodes,
so the difference to a session is what cr_control itself costs.

The source publishes the plant's labelled timing report on /plant/timing every second,
logs the plant's per-second line and "done:" line, and prints one final JSON line
(prefix ``ECHO_RESULT``) with the whole-run figures. With ``--wait-for-recorder`` it
starts only once the recorder announced it is ready (as the plant does in a recorded
session).

``synthetic`` is a recorder load, no loop: at ``--rate`` it publishes what a recorded
session carries at that rate (joint state, wrench, joint command, a controller's
reference and status arrays of ``--controller``'s topics) plus the timing report once a
second, for ``--duration`` seconds once the recorder is ready; it logs "published: N
messages" at the end. ``cr_benchmark`` measures the recorder's CPU per message with it.

    python -m cr_control.tools.echo_pair both --duration 10        # one process
    python -m cr_control.tools.echo_pair echo &                     # two processes
    python -m cr_control.tools.echo_pair source --duration 10
    python -m cr_control.tools.echo_pair synthetic --duration 3     # with a recorder running
    python -m cr_control.tools.echo_pair both --joints 9 --command-joints 7 --joint-prefix panda_
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import rclpy
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, MultiArrayDimension

from cr_control.core import topics
from cr_control.core.ros_env import isolate_this_process
from cr_control.nodes.qos import CONTROL_QOS, PUBLISH_QOS, READY_QOS
from cr_control.nodes.spin import spin_nodes
from cr_sim.loop_stats import LoopStats

JOINT_NAMES = ["joint1", "joint2"]
RESULT_PREFIX = "ECHO_RESULT "
#: Fields of the synthetic status array beyond topics.STATUS_FIELDS (a scheme's estimates).
SYNTHETIC_EXTRA_STATUS = 6


def joint_names(n: int, prefix: str = "") -> list[str]:
    """``n`` joint names: ``{prefix}joint1`` ... (2 without a prefix: :data:`JOINT_NAMES`)."""
    return [f"{prefix}joint{i + 1}" for i in range(n)]


def joint_state(names: list[str], stamp=None) -> JointState:
    """The source's state: every joint's name, position, velocity and effort."""
    n = len(names)
    state = JointState()
    if stamp is not None:
        state.header.stamp = stamp
    state.name = names
    state.position = [0.1 * (i + 1) for i in range(n)]
    state.velocity = [0.0] * n
    state.effort = [0.0] * n
    return state


def joint_command(names: list[str], stamp=None) -> JointState:
    """The echo's command: the commanded joints' names and efforts."""
    command = JointState()
    if stamp is not None:
        command.header.stamp = stamp
    command.name = names
    command.effort = [0.0] * len(names)
    return command


class EchoSource(Node):
    """Publishes plant-like state at ``rate_hz`` for ``duration`` wall seconds once an echo answers."""

    #: The floor runs with the real-time loop's process settings (its CPU weight, the
    #: pre-faulted heap, SCHED_FIFO when asked: cr_control.nodes.realtime_priority), so the
    #: benchmark compares the software, not the scheduling.
    realtime_loop = True

    def __init__(self, rate_hz: float = 1000.0, duration: float = 10.0,
                 wait_for_recorder: bool = False, timing_subscribers: int = 0,
                 names: list[str] | None = None, **kwargs):
        super().__init__("echo_source", **kwargs)
        self.names = JOINT_NAMES if names is None else names
        self.period = 1.0 / rate_hz
        self.duration = duration
        self.finished = Future()
        self.stats = LoopStats()
        self._published = getattr(self.stats, "published", None)  # LoopStats with publish times
        self.state_stamp: tuple[int, int] | None = None
        self.command_stamp: tuple[int, int] | None = None
        self._published_at: dict[tuple[int, int], float] = {}
        self._started = False
        self._t0 = 0.0
        self.last_report: dict[str, float] = {}
        self.recorder_ready = not wait_for_recorder
        self._timing_subscribers = timing_subscribers
        if wait_for_recorder:
            self.create_subscription(Bool, topics.RECORDER_READY, self._on_ready, READY_QOS)

        self.state_pub = self.create_publisher(JointState, topics.JOINT_STATES, PUBLISH_QOS)
        self.wrench_pub = self.create_publisher(WrenchStamped, topics.WRENCH, PUBLISH_QOS)
        self.timing_pub = self.create_publisher(Float64MultiArray, topics.PLANT_TIMING, PUBLISH_QOS)
        self._timing_msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                                 topics.PLANT_TIMING_FIELDS)
        self.command_sub = self.create_subscription(JointState, topics.JOINT_COMMANDS,
                                                    self._on_command, CONTROL_QOS)
        # Created here, started later: EventsExecutor misses timers created in callbacks.
        self._tick_timer = self.create_timer(self.period, self._tick, autostart=False)
        self._timing_timer = self.create_timer(1.0, self._publish_timing, autostart=False)
        self._start_timer = self.create_timer(0.01, self._try_start)
        self.get_logger().info(f"echo source at {rate_hz:g} Hz for {duration:g} s; waiting for an echo")

    def _on_ready(self, msg: Bool) -> None:
        self.recorder_ready = self.recorder_ready or msg.data

    def _try_start(self) -> None:
        if self._started or not self.recorder_ready:
            return
        if self.state_pub.get_subscription_count() < 1 or self.command_sub.get_publisher_count() < 1:
            return
        if self.timing_pub.get_subscription_count() < self._timing_subscribers:
            return
        self._started = True
        self._start_timer.cancel()
        self._t0 = time.monotonic()
        self.stats.start(self._t0)
        self._timing_timer.reset()
        self._tick_timer.reset()
        self.get_logger().info("echo connected: starting")

    def _on_command(self, msg: JointState) -> None:
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        sent = self._published_at.pop(key, None)
        if sent is not None:
            self.stats.round_trip(time.monotonic() - sent)
        self.command_stamp = key

    def _tick(self) -> None:
        if self.finished.done():
            return
        now = time.monotonic()
        self.stats.cycle(self.command_stamp is not None and self.command_stamp == self.state_stamp)
        if now - self._t0 >= self.duration - 0.5 * self.period:
            self._finish(now)
            return
        start = time.perf_counter()
        stamp = self.get_clock().now().to_msg()
        wrench = WrenchStamped()
        wrench.header.stamp = stamp
        wrench.header.frame_id = "world"
        wrench.wrench.force.x, wrench.wrench.force.y, wrench.wrench.force.z = 0.0, 1.0, 0.0
        state = joint_state(self.names, stamp)
        self.wrench_pub.publish(wrench)
        self.state_pub.publish(state)
        if self._published is not None:  # the plant's publish_time_us, as a baseline
            self._published(time.perf_counter() - start)
        key = (stamp.sec, stamp.nanosec)
        self.state_stamp = key
        self._published_at[key] = time.monotonic()
        if len(self._published_at) > 64:
            self._published_at.pop(next(iter(self._published_at)))

    def _publish_timing(self, now: float | None = None) -> None:
        if not self._started:
            return
        now = time.monotonic() if now is None else now
        values = [now - self._t0, *self.stats.report(now)]
        # The plant's timing fields may grow (instrumentation): what the echo has not got is nan.
        values += [math.nan] * (len(topics.PLANT_TIMING_FIELDS) - len(values))
        self._timing_msg.data = values[:len(topics.PLANT_TIMING_FIELDS)]
        self.timing_pub.publish(self._timing_msg)
        d = dict(zip(topics.PLANT_TIMING_FIELDS, self._timing_msg.data, strict=True))
        self.last_report = d
        self.get_logger().info(
            f"t={d['stamp']:.1f} s rate={d['rate_hz']:.0f} Hz fresh={100 * d['window_fresh_share']:.2f}% "
            f"round trip p50/p99/max={d['window_age_p50_ms']:.3f}/{d['window_age_p99_ms']:.3f}/"
            f"{d['window_age_max_ms']:.3f} ms")

    def _finish(self, now: float) -> None:
        self._publish_timing(now)
        wall = now - self._t0
        self.get_logger().info(f"done: {wall:.3f} s simulated in {wall:.3f} s wall, "
                               f"{self.stats.total_cycles} cycles, 0 commands refused")
        result = dict(self.last_report, wall_s=wall,
                      achieved_rate_hz=self.stats.total_cycles / wall if wall > 0 else 0.0)
        print(RESULT_PREFIX + json.dumps(result), flush=True)
        self.finished.set_result(True)


class Echo(Node):
    """Answers each JointState with a JointState command of the same stamp (no math)."""

    realtime_loop = True          # as EchoSource's

    def __init__(self, names: list[str] | None = None, **kwargs):
        super().__init__("echo", **kwargs)
        self.names = JOINT_NAMES if names is None else names
        self.force = (0.0, 0.0, 0.0)
        self.answered = 0
        self.command_pub = self.create_publisher(JointState, topics.JOINT_COMMANDS, PUBLISH_QOS)
        self.create_subscription(WrenchStamped, topics.WRENCH, self._on_wrench, CONTROL_QOS)
        self.create_subscription(JointState, topics.JOINT_STATES, self._on_state, CONTROL_QOS)

    def _on_wrench(self, msg: WrenchStamped) -> None:
        f = msg.wrench.force
        self.force = (f.x, f.y, f.z)

    def _on_state(self, msg: JointState) -> None:
        self.command_pub.publish(joint_command(self.names, msg.header.stamp))
        self.answered += 1


class SyntheticLoad(Node):
    """Publishes a recorded session's 1 kHz topics at ``rate_hz`` (no loop, no math)."""

    def __init__(self, rate_hz: float = 1000.0, duration: float = 3.0, controller: str = "synthetic",
                 **kwargs):
        super().__init__("synthetic_load", **kwargs)
        self.duration = duration
        self.finished = Future()
        self.published = 0
        self._started = False
        self._t0 = 0.0
        self.recorder_ready = False
        self.state_pub = self.create_publisher(JointState, topics.JOINT_STATES, PUBLISH_QOS)
        self.wrench_pub = self.create_publisher(WrenchStamped, topics.WRENCH, PUBLISH_QOS)
        self.command_pub = self.create_publisher(JointState, topics.JOINT_COMMANDS, PUBLISH_QOS)
        self.reference_pub = self.create_publisher(Float64MultiArray, topics.reference_topic(controller),
                                                   CONTROL_QOS)
        self.status_pub = self.create_publisher(Float64MultiArray, topics.status_topic(controller),
                                                CONTROL_QOS)
        self.timing_pub = self.create_publisher(Float64MultiArray, topics.PLANT_TIMING, PUBLISH_QOS)
        self._reference = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                                topics.REFERENCE_FIELDS)
        status_fields = topics.STATUS_FIELDS + [f"estimate_{i}" for i in range(SYNTHETIC_EXTRA_STATUS)]
        self._status = topics.labelled_array(Float64MultiArray, MultiArrayDimension, status_fields)
        self._timing = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                             topics.PLANT_TIMING_FIELDS)
        self._n_reference, self._n_status = len(topics.REFERENCE_FIELDS), len(status_fields)
        self.create_subscription(Bool, topics.RECORDER_READY, self._on_ready, READY_QOS)
        self._tick_timer = self.create_timer(1.0 / rate_hz, self._tick, autostart=False)
        self._timing_timer = self.create_timer(1.0, self._publish_timing, autostart=False)
        self._start_timer = self.create_timer(0.01, self._try_start)
        self.get_logger().info(f"synthetic load at {rate_hz:g} Hz for {duration:g} s; "
                               "waiting for the recorder")

    def _on_ready(self, msg: Bool) -> None:
        self.recorder_ready = self.recorder_ready or msg.data

    def _try_start(self) -> None:
        if self._started or not self.recorder_ready:
            return
        self._started = True
        self._start_timer.cancel()
        self._t0 = time.monotonic()
        self._tick_timer.reset()
        self._timing_timer.reset()
        self.get_logger().info("recorder ready: starting")

    def _tick(self) -> None:
        if self.finished.done():
            return
        now = time.monotonic()
        if now - self._t0 >= self.duration:
            self.get_logger().info(f"published: {self.published} messages in {now - self._t0:.3f} s")
            self.finished.set_result(True)
            return
        stamp = self.get_clock().now().to_msg()
        t = now - self._t0
        state = JointState()
        state.header.stamp = stamp
        state.name = JOINT_NAMES
        state.position = [0.1 + t, 0.2]
        state.velocity = [0.0, t]
        state.effort = [0.0, 0.0]
        wrench = WrenchStamped()
        wrench.header.stamp = stamp
        wrench.header.frame_id = "world"
        wrench.wrench.force.y = t
        command = JointState()
        command.header.stamp = stamp
        command.name = JOINT_NAMES
        command.effort = [t, -t]
        self._reference.data = [t] * self._n_reference
        self._status.data = [t] * self._n_status
        self.state_pub.publish(state)
        self.wrench_pub.publish(wrench)
        self.command_pub.publish(command)
        self.reference_pub.publish(self._reference)
        self.status_pub.publish(self._status)
        self.published += 5

    def _publish_timing(self) -> None:
        self._timing.data = [time.monotonic() - self._t0] + [0.0] * (len(topics.PLANT_TIMING_FIELDS) - 1)
        self.timing_pub.publish(self._timing)
        self.published += 1


def parse_result(text: str) -> dict[str, float] | None:
    """The source's final figures from its output (the last ``ECHO_RESULT`` line), or None."""
    for line in reversed(text.splitlines()):
        if line.startswith(RESULT_PREFIX):
            return json.loads(line[len(RESULT_PREFIX):])
    return None


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface of the echo pair."""
    p = argparse.ArgumentParser(prog="echo_pair", description=__doc__.split("\n\n")[0])
    p.add_argument("role", choices=["source", "echo", "both", "synthetic"])
    p.add_argument("--duration", type=float, default=10.0,
                   help="source: wall seconds of loop after the echo answers (default 10)")
    p.add_argument("--rate", type=float, default=1000.0, help="source rate (Hz, default 1000)")
    p.add_argument("--wait-for-recorder", action="store_true",
                   help="source: start only after the recorder announced it is ready")
    p.add_argument("--timing-subscribers", type=int, default=0,
                   help=f"source: start only once this many subscribe to {topics.PLANT_TIMING} "
                        "(cr_benchmark's listener, the recorder: they see every report)")
    p.add_argument("--controller", default="synthetic",
                   help="synthetic: controller name of the reference/status topics")
    p.add_argument("--joints", type=int, default=len(JOINT_NAMES),
                   help=f"joints in the state (default {len(JOINT_NAMES)})")
    p.add_argument("--command-joints", type=int,
                   help="joints in the command: the state's first ones (default: all)")
    p.add_argument("--joint-prefix", default="",
                   help="prefix of the joint names (joint1, joint2, ... without one)")
    return p


def message_names(args: argparse.Namespace) -> tuple[list[str], list[str]]:
    """The joint names of the state and of the command from the command line."""
    state = joint_names(args.joints, args.joint_prefix)
    n = args.joints if args.command_joints is None else args.command_joints
    if not 0 < n <= args.joints:
        raise ValueError(f"--command-joints must be in 1..{args.joints} (--joints), not {n}")
    return state, state[:n]


def main(argv: list[str] | None = None) -> int:
    """Run the source, the echo, or both in one process."""
    p = build_parser()
    args = p.parse_args(argv)
    try:
        state_names, command_names = message_names(args)
    except ValueError as exc:
        p.error(str(exc))
    isolate_this_process()  # localhost discovery; keeps a ROS_DOMAIN_ID already set
    rclpy.init(args=[sys.argv[0]])
    nodes: list[Node] = []
    if args.role == "synthetic":
        load = SyntheticLoad(args.rate, args.duration, args.controller)
        spin_nodes([load], until=load.finished)
        return 0
    if args.role in ("echo", "both"):
        nodes.append(Echo(command_names))
    source = None
    if args.role in ("source", "both"):
        source = EchoSource(args.rate, args.duration, args.wait_for_recorder,
                            args.timing_subscribers, state_names)
        nodes.append(source)
    spin_nodes(nodes, until=source.finished if source is not None else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
