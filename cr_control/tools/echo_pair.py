"""A bare rclpy echo pair: the floor under cr_control's real-time loop (no control math).

``source`` is plant-like: a wall-clock timer at ``--rate`` publishes a
sensor_msgs/JointState (2 joints: position, velocity, effort) and a WrenchStamped with
the same stamp, and counts its loop with the plant's :class:`~cr_sim.loop_stats.LoopStats`
(fresh share, state -> command round trip). ``echo`` answers every JointState with a
JointState command carrying the same header stamp. Same topics, message types, QoS
(RELIABLE, KEEP_LAST 10) and executor (EventsExecutor) as the plant and controller nodes,
so the difference to a session is what cr_control itself costs.

The source publishes the plant's labelled timing report on /plant/timing every second,
logs the plant's per-second line and "done:" line, and prints one final JSON line
(prefix ``ECHO_RESULT``) with the whole-run figures.

    python -m cr_control.tools.echo_pair both --duration 10        # one process
    python -m cr_control.tools.echo_pair echo &                     # two processes
    python -m cr_control.tools.echo_pair source --duration 10
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import rclpy
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control.core import topics
from cr_control.core.ros_env import isolate_this_process
from cr_control.nodes.qos import CONTROL_QOS
from cr_control.nodes.spin import spin_nodes
from cr_sim.loop_stats import LoopStats

JOINT_NAMES = ["joint1", "joint2"]
RESULT_PREFIX = "ECHO_RESULT "


class EchoSource(Node):
    """Publishes plant-like state at ``rate_hz`` for ``duration`` wall seconds once an echo answers."""

    def __init__(self, rate_hz: float = 1000.0, duration: float = 10.0, **kwargs):
        super().__init__("echo_source", **kwargs)
        self.period = 1.0 / rate_hz
        self.duration = duration
        self.finished = Future()
        self.stats = LoopStats()
        self.state_stamp: tuple[int, int] | None = None
        self.command_stamp: tuple[int, int] | None = None
        self._published_at: dict[tuple[int, int], float] = {}
        self._started = False
        self._t0 = 0.0
        self.last_report: dict[str, float] = {}

        self.state_pub = self.create_publisher(JointState, topics.JOINT_STATES, CONTROL_QOS)
        self.wrench_pub = self.create_publisher(WrenchStamped, topics.WRENCH, CONTROL_QOS)
        self.timing_pub = self.create_publisher(Float64MultiArray, topics.PLANT_TIMING, CONTROL_QOS)
        self._timing_msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                                 topics.PLANT_TIMING_FIELDS)
        self.command_sub = self.create_subscription(JointState, topics.JOINT_COMMANDS,
                                                    self._on_command, CONTROL_QOS)
        # Created here, started later: EventsExecutor misses timers created in callbacks.
        self._tick_timer = self.create_timer(self.period, self._tick, autostart=False)
        self._timing_timer = self.create_timer(1.0, self._publish_timing, autostart=False)
        self._start_timer = self.create_timer(0.01, self._try_start)
        self.get_logger().info(f"echo source at {rate_hz:g} Hz for {duration:g} s; waiting for an echo")

    def _try_start(self) -> None:
        if self._started:
            return
        if self.state_pub.get_subscription_count() < 1 or self.command_sub.get_publisher_count() < 1:
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
        stamp = self.get_clock().now().to_msg()
        wrench = WrenchStamped()
        wrench.header.stamp = stamp
        wrench.header.frame_id = "world"
        wrench.wrench.force.x, wrench.wrench.force.y, wrench.wrench.force.z = 0.0, 1.0, 0.0
        state = JointState()
        state.header.stamp = stamp
        state.name = JOINT_NAMES
        state.position = [0.1, 0.2]
        state.velocity = [0.0, 0.0]
        state.effort = [0.0, 0.0]
        self.wrench_pub.publish(wrench)
        self.state_pub.publish(state)
        key = (stamp.sec, stamp.nanosec)
        self.state_stamp = key
        self._published_at[key] = time.monotonic()
        if len(self._published_at) > 64:
            self._published_at.pop(next(iter(self._published_at)))

    def _publish_timing(self, now: float | None = None) -> None:
        if not self._started:
            return
        now = time.monotonic() if now is None else now
        self._timing_msg.data = [now - self._t0, *self.stats.report(now)]
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

    def __init__(self, **kwargs):
        super().__init__("echo", **kwargs)
        self.force = (0.0, 0.0, 0.0)
        self.answered = 0
        self.command_pub = self.create_publisher(JointState, topics.JOINT_COMMANDS, CONTROL_QOS)
        self.create_subscription(WrenchStamped, topics.WRENCH, self._on_wrench, CONTROL_QOS)
        self.create_subscription(JointState, topics.JOINT_STATES, self._on_state, CONTROL_QOS)

    def _on_wrench(self, msg: WrenchStamped) -> None:
        f = msg.wrench.force
        self.force = (f.x, f.y, f.z)

    def _on_state(self, msg: JointState) -> None:
        command = JointState()
        command.header.stamp = msg.header.stamp
        command.name = JOINT_NAMES
        command.effort = [0.0, 0.0]
        self.command_pub.publish(command)
        self.answered += 1


def parse_result(text: str) -> dict[str, float] | None:
    """The source's final figures from its output (the last ``ECHO_RESULT`` line), or None."""
    for line in reversed(text.splitlines()):
        if line.startswith(RESULT_PREFIX):
            return json.loads(line[len(RESULT_PREFIX):])
    return None


def main(argv: list[str] | None = None) -> int:
    """Run the source, the echo, or both in one process."""
    p = argparse.ArgumentParser(prog="echo_pair", description=__doc__.split("\n\n")[0])
    p.add_argument("role", choices=["source", "echo", "both"])
    p.add_argument("--duration", type=float, default=10.0,
                   help="source: wall seconds of loop after the echo answers (default 10)")
    p.add_argument("--rate", type=float, default=1000.0, help="source rate (Hz, default 1000)")
    args = p.parse_args(argv)
    isolate_this_process()  # localhost discovery; keeps a ROS_DOMAIN_ID already set
    rclpy.init(args=[sys.argv[0]])
    nodes: list[Node] = []
    if args.role in ("echo", "both"):
        nodes.append(Echo())
    source = None
    if args.role in ("source", "both"):
        source = EchoSource(args.rate, args.duration)
        nodes.append(source)
    spin_nodes(nodes, until=source.finished if source is not None else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
