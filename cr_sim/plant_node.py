"""The plant node: one simulated scenario on the topic contract, realtime or lockstep.

- ``realtime``: a wall-clock timer at ``rate_hz``; each tick integrates the wall time
  elapsed since the last one with the latest command held, then publishes the state.
- ``lockstep``: publishes a state (and /clock) and steps one period only when the
  command computed from that state arrives: deterministic, faster than real time.

Publishes /joint_states, the force/torque sensor wrench (same stamp), per-second loop
statistics on /plant/timing, and stops by itself after ``duration`` seconds of
simulated time (0 = run until stopped).
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, MultiArrayDimension

from cr_control.core import topics
from cr_control.core.parameters import Param
from cr_control.nodes.qos import CONTROL_QOS, READY_QOS
from cr_control.nodes.ros_parameters import ParameterError, declare
from cr_control.nodes.spin import spin_nodes
from cr_sim.loop_stats import LoopStats
from cr_sim.plants.registry import SCENARIOS

NODE_PARAMETERS = [
    Param("mode", "realtime", "realtime: wall-clock timer; lockstep: step on each command.",
          "choice", choices=("realtime", "lockstep"), read_only=True),
    Param("rate_hz", 1000.0, "Control rate (Hz): ticks per second in realtime, 1/period in "
          "lockstep.", "positive", read_only=True),
    Param("duration", 0.0, "Simulated seconds to run before stopping; 0 = until stopped.",
          "nonnegative", read_only=True),
    Param("wait_for_recorder", False, "Start only after the recorder says it is ready "
          f"({topics.RECORDER_READY}), so a recording misses nothing.", "bool", read_only=True),
    Param("lockstep_resend_s", 1.0, "Lockstep: republish the state if no command came for "
          "this long (wall s).", "positive", read_only=True),
]


SCENARIO_PARAMETER = Param("scenario", "compliant_plane", "Simulated scenario.", "choice",
                           choices=tuple(SCENARIOS), read_only=True)


def plant_parameters(scenario: str) -> list[Param]:
    """Every parameter of the plant node running ``scenario``, in declaration order."""
    specs = SCENARIOS[scenario][0]
    return [replace(SCENARIO_PARAMETER, default=scenario), *NODE_PARAMETERS, *specs]


def to_time(seconds: float) -> Time:
    """builtin_interfaces/Time of ``seconds``."""
    ns = int(round(seconds * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class PlantNode(Node):
    """Runs a cr_sim scenario chosen by the ``scenario`` parameter."""

    def __init__(self, **kwargs):
        super().__init__("plant", **kwargs)
        scenario = declare(self, [SCENARIO_PARAMETER])
        specs, factory = SCENARIOS[scenario["scenario"]]
        self.settings = declare(self, NODE_PARAMETERS)
        self.plant = factory(declare(self, specs))
        self.period = 1.0 / self.settings["rate_hz"]
        self.lockstep = self.settings["mode"] == "lockstep"
        self.joint_names = list(self.plant.joint_names)
        self.finished = Future()
        self.stats = LoopStats()

        self.command = np.zeros(len(self.joint_names))
        self.command_stamp: tuple[int, int] | None = None
        self.state_stamp: tuple[int, int] | None = None
        self._published_at: dict[tuple[int, int], float] = {}
        self._rejected_commands = 0
        self._started = False
        self._recorder_ready = not self.settings["wait_for_recorder"]
        self._t0_wall = 0.0
        self._last_tick = 0.0
        self._last_publish_wall = 0.0

        self.state_pub = self.create_publisher(JointState, topics.JOINT_STATES, CONTROL_QOS)
        self.wrench_pub = self.create_publisher(WrenchStamped, topics.WRENCH, CONTROL_QOS)
        self.timing_pub = self.create_publisher(Float64MultiArray, topics.PLANT_TIMING, CONTROL_QOS)
        self.clock_pub = self.create_publisher(Clock, topics.CLOCK, CONTROL_QOS) if self.lockstep else None
        self._timing_msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                                 topics.PLANT_TIMING_FIELDS)
        self.command_sub = self.create_subscription(JointState, topics.JOINT_COMMANDS,
                                                    self._on_command, CONTROL_QOS)
        if self.settings["wait_for_recorder"]:
            self.create_subscription(Bool, topics.RECORDER_READY, self._on_recorder_ready, READY_QOS)
        # Timers are made here and started later: EventsExecutor does not pick up timers
        # created inside callbacks.
        self._tick_timer = self.create_timer(
            self.settings["lockstep_resend_s"] if self.lockstep else self.period,
            self._resend_if_stalled if self.lockstep else self._tick, autostart=False)
        self._timing_timer = self.create_timer(1.0, self._publish_timing, autostart=False)
        self._start_timer = self.create_timer(0.01, self._try_start)
        self.get_logger().info(
            f"scenario {scenario['scenario']}, {self.settings['mode']} at {self.settings['rate_hz']:g} Hz, "
            f"joints {self.joint_names}; waiting for a controller")

    # -- start and stop -------------------------------------------------------------
    def _on_recorder_ready(self, msg: Bool) -> None:
        self._recorder_ready = self._recorder_ready or msg.data

    def _try_start(self) -> None:
        """Start once a controller listens and answers (and the recorder is ready)."""
        if self._started or not self._recorder_ready:
            return
        if self.state_pub.get_subscription_count() < 1 or self.command_sub.get_publisher_count() < 1:
            return
        self._started = True
        self._start_timer.cancel()
        self._t0_wall = self._last_tick = time.monotonic()
        self.stats.start(self._t0_wall)
        self._timing_timer.reset()
        self._tick_timer.reset()
        self.get_logger().info("controller connected: starting")
        if self.lockstep:
            self._publish_state(self._sim_stamp())

    def _finish(self) -> None:
        if self.finished.done():
            return
        self._publish_timing()
        self.get_logger().info(
            f"done: {self.plant.time:.3f} s simulated in {time.monotonic() - self._t0_wall:.3f} s wall, "
            f"{self.stats.total_cycles} cycles, {self._rejected_commands} commands refused")
        self.finished.set_result(True)

    def _out_of_time(self) -> bool:
        duration = self.settings["duration"]
        return duration > 0.0 and self.plant.time >= duration - 0.5 * self.period

    # -- state out ------------------------------------------------------------------
    def _sim_stamp(self) -> Time:
        return to_time(self.plant.time)

    def _publish_state(self, stamp: Time) -> None:
        m = self.plant.measurement()
        wrench = WrenchStamped()
        wrench.header.stamp = stamp
        wrench.header.frame_id = "world"
        wrench.wrench.force.x, wrench.wrench.force.y, wrench.wrench.force.z = m.force.tolist()
        state = JointState()
        state.header.stamp = stamp
        state.name = self.joint_names
        state.position = m.position.tolist()
        state.velocity = m.velocity.tolist()
        state.effort = m.effort.tolist()
        if self.clock_pub is not None:
            self.clock_pub.publish(Clock(clock=stamp))
        self.wrench_pub.publish(wrench)
        self.state_pub.publish(state)
        key = (stamp.sec, stamp.nanosec)
        now = time.monotonic()
        self.state_stamp = key
        self._last_publish_wall = now
        self._published_at[key] = now
        if len(self._published_at) > 64:
            self._published_at.pop(next(iter(self._published_at)))

    # -- commands in ----------------------------------------------------------------
    def _command_values(self, msg: JointState) -> np.ndarray | None:
        values = msg.position if self.plant.command_interface == "position" else msg.effort
        if list(msg.name) == self.joint_names and len(values) == len(self.joint_names):
            command = np.asarray(values, dtype=float)
        else:
            try:
                command = np.array([values[list(msg.name).index(n)] for n in self.joint_names])
            except (ValueError, IndexError):
                return None
        return command if self.plant.accept(command) else None

    def _on_command(self, msg: JointState) -> None:
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        command = self._command_values(msg)
        if command is None:
            self._rejected_commands += 1
            if self._rejected_commands in (1, 10, 100, 1000):
                self.get_logger().warn(f"refused {self._rejected_commands} commands (wrong names, "
                                       f"sizes or non-finite values); holding the last good one")
            return
        sent = self._published_at.pop(key, None)
        if sent is not None:
            self.stats.round_trip(time.monotonic() - sent)
        self.command, self.command_stamp = command, key
        if self.lockstep and self._started and key == self.state_stamp and not self.finished.done():
            self._lockstep_step()

    # -- stepping -------------------------------------------------------------------
    def _lockstep_step(self) -> None:
        start = time.perf_counter()
        self.plant.step(self.command, self.period)
        self.stats.cycle(True, time.perf_counter() - start)
        if self._out_of_time():
            self._finish()
            return
        self._publish_state(self._sim_stamp())

    def _resend_if_stalled(self) -> None:
        if self.finished.done() or self.state_stamp is None:
            return
        if time.monotonic() - self._last_publish_wall > self.settings["lockstep_resend_s"]:
            self.get_logger().warn("no command for the last state: publishing it again")
            stamp = Time(sec=self.state_stamp[0], nanosec=self.state_stamp[1])
            self._publish_state(stamp)

    def _tick(self) -> None:
        if self.finished.done():
            return
        now = time.monotonic()
        elapsed, self._last_tick = now - self._last_tick, now
        fresh = self.command_stamp is not None and self.command_stamp == self.state_stamp
        start = time.perf_counter()
        substeps = max(1, round(elapsed / self.period))  # steps of at most ~1.5 periods
        for _ in range(substeps):
            self.plant.step(self.command, elapsed / substeps)
        self.stats.cycle(fresh, time.perf_counter() - start)
        if self._out_of_time():
            self._finish()
            return
        self._publish_state(self.get_clock().now().to_msg())

    def _publish_timing(self) -> None:
        if not self._started:
            return
        now = time.monotonic()
        stamp = self.state_stamp[0] + self.state_stamp[1] * 1e-9 if self.state_stamp else 0.0
        self._timing_msg.data = [stamp, *self.stats.report(now)]
        self.timing_pub.publish(self._timing_msg)
        d = dict(zip(topics.PLANT_TIMING_FIELDS, self._timing_msg.data, strict=True))
        self.get_logger().info(
            f"t={self.plant.time:.1f} s rate={d['rate_hz']:.0f} Hz "
            f"fresh={100 * d['window_fresh_share']:.2f}% "
            f"round trip p50/p99/max={d['window_age_p50_ms']:.3f}/{d['window_age_p99_ms']:.3f}/"
            f"{d['window_age_max_ms']:.3f} ms step={d['step_time_us']:.0f} us")


def main(args: list[str] | None = None) -> int:
    """Run the plant node."""
    rclpy.init(args=sys.argv if args is None else args)
    try:
        node = PlantNode()
    except ParameterError as exc:
        print(f"plant: refused to start: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 1
    spin_nodes([node], until=node.finished)
    return 0


if __name__ == "__main__":
    sys.exit(main())
