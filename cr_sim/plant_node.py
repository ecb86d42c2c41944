"""The plant node: one simulated scenario on the topic contract, realtime or lockstep.

- ``realtime``: a wall-clock timer at ``rate_hz``; each tick integrates the wall time
  elapsed since the last one (:mod:`cr_sim.realtime_clock`) with the latest command
  held, then publishes the state stamped with the wall clock.
  A command that answers the latest state integrates its first period as soon as it
  arrives ("stepped ahead"): the tick then only publishes, so the state leaves on the
  tick, not a plant step later, and the controller's whole period is left for the round
  trip. The physics are the same (the command is held from the state it answers, as
  before); a second, different command for the same state takes effect a period later.
- ``lockstep``: publishes a state (and /clock) and steps one period only when the
  command computed from that state arrives: deterministic, faster than real time.
  Nothing is lost to a slow reader: every 250 states the plant waits until every
  reader of its topics (a recorder too) has acknowledged them, and the whole loop waits
  with it (:mod:`cr_control.nodes.lockstep`).

Publishes /joint_states, the force/torque sensor wrench (same stamp; force and torque, in
the plant's ``wrench_frame``), for plants that have one the true contact wrench on
/plant/contact_wrench (base frame, same stamp; analysis and tests only), per-second loop
statistics on /plant/timing, and stops by itself after ``duration`` seconds of
simulated time (0 = run until stopped). Its command interface ("effort" or "position",
:attr:`~cr_sim.plants.base.Plant.command_interface`) is advertised once, latched, on
/plant/command_interface: a controller node of the other kind refuses to drive it.

Safety: the node hands every command to a :class:`~cr_sim.supervisor.PlantSupervisor`
(no ROS; the offline loop steps through the same object) and steps the plant through it:
command checks and limits, one commander at a time (by the publisher GIDs of
:mod:`cr_control.nodes.sender_aware`), the driver's transport delay and late bursts
(``command_delay_cycles``, ``late_burst_*``: :mod:`cr_sim.transport_delay`, in plant steps,
so lockstep and real time delay alike), the watchdog (realtime), the reflexes, the safe stop
(``safe_stop`` = 1 and ``safe_stop_reason`` on /plant/timing, ERROR on /diagnostics) and the
run's early ends; see that module for the rules. A safe stop lasts until someone sets the
parameter ``resume`` to true (``cr_param set plant resume true``); the plant then resets it
to false. The node also counts the publishers on /joint_commands and /joint_states once a
second (another session on this domain, a rogue node): warned once and counted in
``command_publishers`` / ``state_publishers``, so the recording shows it. It ends with exit
code 0 after ``duration``, 1 after a non-finite state or output (one ERROR line,
``NON-FINITE: ...``; nothing non-finite is published) and 3 when the supervisor ends the run
early (one ERROR line, ``ENDED: ...``).

Hot path: the state, wrench, sensors and clock messages are built once as CDR
bytes and refilled in place each tick (:class:`cr_control.core.cdr.Writer`: numpy views
onto their numbers), published as bytes; commands are taken serialized, with their
publisher's GID (:mod:`cr_control.nodes.sender_aware`: 20-30 us more per command than a
``raw=True`` subscription on EventsExecutor, for the GID rclpy does not give), and read
from their bytes (:mod:`cr_control.nodes.raw_messages`): no ROS message object per tick.
The time spent building and publishing the state is reported as ``publish_time_us``.

Housekeeping (the once-a-second report) runs off the tick, in the idle slot after a
command was answered (:mod:`cr_sim.plant_report`).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, String

from cr_control.core import topics
from cr_control.nodes import sender_aware
from cr_control.nodes.diagnostics import PlantDiagnostics
from cr_control.nodes.lockstep import ReaderPacer, wait_for_readers
from cr_control.nodes.qos import CONTROL_QOS, PUBLISH_QOS, READY_QOS
from cr_control.nodes.raw_messages import JointStateReader
from cr_control.nodes.ros_parameters import declare, police_changes
from cr_control.nodes.spin import help_asked, node_usage, quiet_on_shutdown, spin_nodes, start_nodes
from cr_control.nodes.state_source import publisher_node
from cr_control.supervision.plant_commander import COMMANDER_PARAMETER
from cr_control.supervision.single_source import expected_names, full_node_name
from cr_sim.loop_stats import SAFE_STOP_REASONS, LoopStats
from cr_sim.plant_markers import PlantMarkers
from cr_sim.plant_messages import PlantMessages
from cr_sim.plant_report import PlantReport
from cr_sim.plant_setup import (  # noqa: F401 - plant_parameters: the tools' way in
    NODE_PARAMETERS,
    SCENARIO_PARAMETER,
    check_settings,
    command_limiter,
    initial_command,
    plant_parameters,
    transport_delay,
    unlimited_joints,
    unlimited_note,
    warm_up,
)
from cr_sim.plants.registry import SCENARIOS
from cr_sim.realtime_clock import CatchUp, PublishTimes
from cr_sim.supervisor import MAX_COMMAND_BYTES, PlantSupervisor

#: Realtime: a tick integrates at most this many periods of the wall time since the last
#: one (20 ms); a longer stall of the loop is dropped, not integrated with a stale command.
MAX_CATCH_UP_PERIODS = 20
#: Lockstep: a safe-stopped plant without a command for this many ``lockstep_resend_s``
#: ends (the controller stopped commanding: nothing would step the plant again).
IDLE_RESENDS = 2


class PlantNode(Node):
    """Runs a cr_sim scenario chosen by the ``scenario`` parameter."""

    def __init__(self, **kwargs):
        super().__init__("plant", **kwargs)
        scenario = declare(self, [SCENARIO_PARAMETER])
        specs, factory = SCENARIOS[scenario["scenario"]]
        self.settings = declare(self, NODE_PARAMETERS)
        check_settings(self.settings)
        values = declare(self, specs)
        commander = declare(self, [COMMANDER_PARAMETER])["commander"]
        self.plant = factory(values)
        police_changes(self, [SCENARIO_PARAMETER, *NODE_PARAMETERS, COMMANDER_PARAMETER, *specs],
                       self._on_parameter)
        self.period = 1.0 / self.settings["rate_hz"]
        self.plant.brake_frequency = self.settings["brake_frequency"]
        self.lockstep = self.settings["mode"] == "lockstep"
        # Realtime: this process runs at the real-time loop's CPU weight (spin_nodes;
        # cr_control.nodes.realtime_priority), and its first tick is not its first step.
        self.realtime_loop = not self.lockstep
        if self.realtime_loop:
            warm_up(factory(values), self.period)
        self.joint_names = list(self.plant.joint_names)
        self.command_names = tuple(self.plant.command_joints)
        self.limiter = command_limiter(self.plant, self.settings, self.period)
        if note := unlimited_note(self.plant, self.limiter):
            self.get_logger().warn(note)
        self.finished = Future()
        self.stats = LoopStats()
        self.scenario = scenario["scenario"]
        # First of our endpoints, so that whoever discovers the states discovers it too.
        self.interface_pub = self.create_publisher(String, topics.PLANT_COMMAND_INTERFACE, READY_QOS)
        self.interface_pub.publish(String(data=self.plant.command_interface))
        #: The plant's supervision (cr_sim.supervisor): what is held, checks, safe stop.
        self.supervisor = PlantSupervisor(
            self.plant, self.period, self.limiter, lockstep=self.lockstep,
            watchdog_missed_cycles=self.settings["watchdog_missed_cycles"],
            watchdog_reaction=self.settings["watchdog_reaction"],
            handover_cycles=self.settings["command_handover_cycles"],
            idle_s=IDLE_RESENDS * self.settings["lockstep_resend_s"], scenario=self.scenario,
            command=initial_command(self.plant), stats=self.stats,
            commanders=expected_names(commander),
            logger=lambda: self.get_logger(), name_of=self._publisher_node,
            on_safe_stop=lambda reason: self.diagnostics.safe_stop(reason),
            delay=transport_delay(self.settings))
        self.watchdog = self.supervisor.watchdog

        self.command_stamp: int | None = None            # stamps as integer nanoseconds
        self.state_stamp: int | None = None
        self._sent = PublishTimes()     # when the last states left, for the round trips
        self._resume_requested = False
        self._started = False
        self._recorder_ready = not self.settings["wait_for_recorder"]
        self._t0_wall = 0.0
        self._last_tick = 0.0
        self._catch_up = CatchUp(self.period, MAX_CATCH_UP_PERIODS)    # realtime
        # Realtime: seconds the step ahead of the next tick took (None: not stepped ahead).
        self._ahead_time: float | None = None
        self._last_publish_wall = 0.0

        self.state_pub = self.create_publisher(JointState, topics.JOINT_STATES, PUBLISH_QOS)
        self.wrench_pub = self.create_publisher(WrenchStamped, topics.WRENCH, PUBLISH_QOS)
        # Outgoing messages, built once as CDR bytes and refilled in place every state.
        self.messages = PlantMessages(self.plant, self.settings["contact_wrench_every"],
                                      clock=self.lockstep)
        # The true contact wrench (base frame), for analysis and tests (topics.CONTACT_WRENCH).
        self.contact_pub = (self.create_publisher(WrenchStamped, topics.CONTACT_WRENCH,
                                                  PUBLISH_QOS) if self.messages.truth is not None else None)
        self.sensors_pub = (self.create_publisher(Float64MultiArray, topics.PLANT_SENSORS,
                                                  PUBLISH_QOS) if self.messages.sensors is not None else None)
        self.timing_pub = self.create_publisher(Float64MultiArray, topics.PLANT_TIMING, PUBLISH_QOS)
        self.clock_pub = self.create_publisher(Clock, topics.CLOCK, PUBLISH_QOS) if self.lockstep else None
        # /diagnostics: judged from each timing report.
        self.diagnostics = PlantDiagnostics(self, self.scenario, self.settings["rate_hz"],
                                            not self.lockstep, SAFE_STOP_REASONS)
        self.markers = PlantMarkers(self, self.plant)    # /plant/markers, ~30 Hz
        self.markers.warm_up()
        self._pacer = ReaderPacer(self, [self.state_pub, self.wrench_pub, self.sensors_pub,
                                         self.clock_pub, self.contact_pub])   # used in lockstep
        #: The once-a-second report (/plant/timing, /diagnostics, a log line), as chores.
        self.report = PlantReport(self)
        self._publish_timing = self.report.publish
        self._read_command = JointStateReader()

        # Commands with their publisher's GID (rclpy 7.1 hands none to Python: sender_aware).
        self.command_sub = sender_aware.subscribe_or_raw(
            self, JointState, topics.JOINT_COMMANDS, quiet_on_shutdown(self, self._on_command),
            CONTROL_QOS, MAX_COMMAND_BYTES, CONTROL_QOS, "every one is obeyed: one commander "
            "is not enforced")
        if self.settings["wait_for_recorder"]:
            self.create_subscription(Bool, topics.RECORDER_READY, self._on_recorder_ready, READY_QOS)
        # Timers are made here and started later: EventsExecutor does not pick up timers
        # created inside callbacks.
        tick = self._resend_if_stalled if self.lockstep else self._tick
        self._tick_timer = self.create_timer(
            self.settings["lockstep_resend_s"] if self.lockstep else self.period,
            quiet_on_shutdown(self, tick), autostart=False)
        self._timing_timer = self.create_timer(1.0, quiet_on_shutdown(self, self._publish_timing),
                                               autostart=False)
        self._start_timer = self.create_timer(0.01, quiet_on_shutdown(self, self._try_start))
        self.get_logger().info(
            f"scenario {scenario['scenario']} ({self.plant.command_interface} commands), "
            f"{self.settings['mode']} at {self.settings['rate_hz']:g} Hz, "
            f"joints {self.joint_names}"
            + ("" if list(self.command_names) == self.joint_names
               else f" (commanded {list(self.command_names)})")
            + f", {self.supervisor.describe()}; waiting for a controller")

    # -- what the supervisor holds, as the node's ----------------------------------------
    @property
    def safe_stop(self) -> bool:
        """Whether the plant brakes (a safe stop is engaged)."""
        return self.supervisor.safe_stop

    @property
    def command(self) -> np.ndarray:
        """The command applied at the next step (the brakes' in a safe stop)."""
        return self.supervisor.command

    @property
    def exit_code(self) -> int:
        """The process's exit code once finished (see the module docstring)."""
        return self.supervisor.exit_code

    def destroy_node(self) -> None:
        if isinstance(self.command_sub, sender_aware.SenderAwareSubscription):
            self.command_sub.destroy()     # not one of the node's subscriptions: freed here
        super().destroy_node()

    # -- parameters -----------------------------------------------------------------
    def _on_parameter(self, name: str, value) -> None:
        self._resume_requested |= name == "resume" and bool(value)   # acted on by the next tick

    def _resume(self) -> None:
        self._resume_requested = False
        self.set_parameters([Parameter("resume", value=False)])
        self.supervisor.resume()

    # -- start and stop -------------------------------------------------------------
    def _on_recorder_ready(self, msg: Bool) -> None:
        self._recorder_ready = self._recorder_ready or msg.data

    def _try_start(self) -> None:
        """Start once a controller listens and answers (and the recorder is ready): a node
        that publishes commands and subscribes to the states (a real-time controller
        subscribes only once discovery has settled: cr_control.nodes.discovery_settle)."""
        if self._started or not self._recorder_ready:
            return
        if self.state_pub.get_subscription_count() < 1 or self.command_sub.get_publisher_count() < 1:
            return
        if not self._commander_listens():
            return
        self._started = True
        self._start_timer.cancel()
        self._t0_wall = self._last_tick = time.monotonic()
        self.stats.start(self._t0_wall)
        self.supervisor.start(self._t0_wall)
        self._timing_timer.reset()
        self._tick_timer.reset()
        self.get_logger().info("controller connected: starting")
        if self.lockstep:
            self._publish_state(*divmod(int(round(self.plant.time * 1e9)), 1_000_000_000))

    def _commander_listens(self) -> bool:
        """An expected commander (parameter ``commander``) publishes on the command topic and
        subscribes to the state topic: a node that merely sends commands never starts it."""
        def nodes(infos) -> set[tuple[str, str]]:
            return {(info.node_namespace, info.node_name) for info in infos}
        allows = self.supervisor.guard.allows          # only an expected commander starts it
        commanders = {node for node in nodes(self.get_publishers_info_by_topic(
            self.command_sub.topic_name)) if allows(full_node_name(*node))}
        return bool(commanders & nodes(self.get_subscriptions_info_by_topic(self.state_pub.topic_name)))

    def _finish(self) -> None:
        if self.finished.done():
            return
        self.report.chores.clear()           # superseded by the final report, made now
        self._publish_timing(at_once=True)
        self.get_logger().info(
            f"done: {self.plant.time:.3f} s simulated in {time.monotonic() - self._t0_wall:.3f} s wall, "
            f"{self.stats.total_cycles} cycles, {self.stats.commands_refused} commands refused, "
            f"{self.stats.commands_clipped} clipped"
            + (f", {self._catch_up.dropped_s:.3f} s of stalls not simulated"
               if self._catch_up.dropped_s else "")
            + (f", in safe stop ({SAFE_STOP_REASONS[self.stats.safe_stop_reason]})"
               if self.safe_stop else ""))
        wait_for_readers(list(self.publishers), 2.0)   # the last messages reach the recorder
        self.finished.set_result(True)

    def _out_of_time(self) -> bool:
        duration = self.settings["duration"]
        return duration > 0.0 and self.plant.time >= duration - 0.5 * self.period

    # -- state out ------------------------------------------------------------------
    def _publish_state(self, sec: int, nanosec: int) -> None:
        """Publish clock (lockstep), wrench, sensors, joint state and (when due) the true
        contact wrench stamped ``sec.nanosec``; nothing if a value is not finite."""
        start = time.perf_counter()
        out = self.messages
        bad = out.fill(sec, nanosec)
        if bad:
            self._stop_non_finite(bad)
            return
        if self.clock_pub is not None:
            self.clock_pub.publish(out.clock.message())
        self.wrench_pub.publish(out.wrench.message())
        if self.sensors_pub is not None:
            self.sensors_pub.publish(out.sensors.message())
        self.state_pub.publish(out.state.message())
        if out.contact_due:                 # after the state: the loop's messages go first
            bad = out.fill_contact(sec, nanosec)
            if bad:
                self._stop_non_finite(bad)
                return
            self.contact_pub.publish(out.contact.message())
        now = time.monotonic()
        key = sec * 1_000_000_000 + nanosec
        self.state_stamp = key
        self._last_publish_wall = now
        self._sent.sent(key, now)
        self.stats.published(time.perf_counter() - start)
        self.markers.tick(self.plant.time, sec, nanosec)

    # -- commands in ----------------------------------------------------------------
    def _publisher_node(self, gid: bytes) -> str | None:
        """The full node name of the publisher ``gid`` on /joint_commands, from the graph
        (a query: once per publisher, cached by the commander rule); None if the graph does
        not know it or its node yet (rmw's "_NODE_NAME_UNKNOWN_": asked again later, never
        taken for a name)."""
        try:
            return publisher_node(self, self.command_sub.topic_name, gid)
        except Exception:  # noqa: BLE001 - a graph query that fails names nobody
            return None

    def _on_command(self, data: bytes | None, gid: bytes = b"", length: int = 0) -> None:
        """A serialized command from the publisher ``gid`` (its GID; b"" if unknown);
        ``data`` None: a message of ``length`` bytes, too long to be read. The supervisor
        checks it; a valid one answering the latest state steps the plant (lockstep) or the
        coming tick's first period (realtime, when not braking)."""
        sup = self.supervisor
        now = time.monotonic()
        size = len(data) if data is not None else max(length, MAX_COMMAND_BYTES + 1)
        if not sup.admit(gid, size, now):
            return
        msg = self._read_command(data)
        if not sup.accept(msg, gid, now):
            return
        key = msg.sec * 1_000_000_000 + msg.nanosec
        sent = self._sent.answered(key)
        if sent is not None:
            self.stats.round_trip(now - sent)
        self.command_stamp = key
        if sup.safe_stop and not self.lockstep:
            return                          # braking (every tick) until resumed
        # lockstep in safe stop: the command still advances the plant, with the brakes
        if key != self.state_stamp or not self._started or self.finished.done():
            return
        if self.lockstep:
            self._lockstep_step()
        elif self._ahead_time is None:
            self._step_ahead()

    # -- stepping -------------------------------------------------------------------
    def _step(self) -> None:
        """One period through the supervisor; finish if it ended the run."""
        self.supervisor.step()
        if self.supervisor.ended is not None:
            self._finish()

    def _stop_non_finite(self, what: str) -> None:
        """``what`` (an outgoing message) is not finite: nothing of it is published, and the
        run ends (the supervisor says why, exit code 1)."""
        self.supervisor.non_finite(what)
        self._finish()

    def _lockstep_step(self) -> None:
        start = time.perf_counter()
        self._step()
        if self.finished.done():
            return
        self.stats.cycle(True, time.perf_counter() - start)
        if self._out_of_time():
            self._finish()
            return
        self._pacer.published()
        self._publish_state(*divmod(int(round(self.plant.time * 1e9)), 1_000_000_000))

    def _step_ahead(self) -> None:
        """Realtime: integrate the coming tick's first period with the command that just
        answered the latest state (the tick then publishes at once)."""
        start = time.perf_counter()
        self._step()
        self._ahead_time = time.perf_counter() - start
        self.report.run_chore()          # the idle slot until the next tick

    def _resend_if_stalled(self) -> None:
        """Lockstep, every lockstep_resend_s: a resume, the supervisor's ends (no command
        since the start; a safe stop nobody commands any more), the state sent again."""
        if self.finished.done() or self.state_stamp is None:
            return
        if self._resume_requested:
            self._resume()
        now = time.monotonic()
        self.supervisor.idle(now)
        if self.supervisor.ended is not None:
            self._finish()
            return
        if now - self._last_publish_wall > self.settings["lockstep_resend_s"]:
            self.get_logger().warn("no command for the last state: publishing it again")
            self._publish_state(*divmod(self.state_stamp, 1_000_000_000))

    def _tick(self) -> None:
        if self.finished.done():
            return
        now = time.monotonic()
        elapsed, self._last_tick = now - self._last_tick, now
        fresh = self.command_stamp is not None and self.command_stamp == self.state_stamp
        if self._resume_requested:
            self._resume()
        self.supervisor.tick(now)
        if self.supervisor.ended is not None:
            self._finish()
            return
        start = time.perf_counter()
        substeps = self._catch_up.periods(elapsed)   # whole periods, gaps clamped
        ahead, self._ahead_time = self._ahead_time, None
        for _ in range(substeps - (ahead is not None)):
            self._step()
            if self.finished.done():
                return
        self.stats.cycle(fresh, time.perf_counter() - start + (ahead or 0.0))
        if self._out_of_time():
            self._finish()
            return
        self._publish_state(*divmod(time.time_ns(), 1_000_000_000))
        if self.report.chores:           # if no step ahead came to run them (none, safe stop)
            self.report.run_waited_chore()


def main(args: list[str] | None = None) -> int:
    """Run the plant node (exit 1 with one line on stderr if it refuses to start)."""
    argv = list(sys.argv if args is None else args)
    if help_asked(argv):
        print(node_usage("plant", f"A simulated plant on the topic contract (scenario: one of "
                         f"{', '.join(sorted(SCENARIOS))}).",
                         "the params files config/plant_*.yaml (the thesis's scenarios) and "
                         "config/robots/ROBOT/plant.yaml list them with their defaults, bounds "
                         "and meanings."))
        return 0
    nodes = start_nodes("plant", argv, lambda: [PlantNode()])
    if nodes is None:
        return 1
    spin_nodes(nodes, until=nodes[0].finished)
    return nodes[0].exit_code


if __name__ == "__main__":
    sys.exit(main())
