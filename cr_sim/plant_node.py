"""The plant node: one simulated scenario on the topic contract, realtime or lockstep.

- ``realtime``: a wall-clock timer at ``rate_hz``; each tick integrates the wall time
  elapsed since the last one (in whole periods, the remainder carried to the next tick)
  with the latest command held, then publishes the state stamped with the wall clock.
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

Safety (issue 7), modelled on libfranka:

- Commands must name exactly the plant's joints, one finite value each, in the field of
  the plant's interface (``position`` for position plants, ``effort`` otherwise: an
  effort-only command to a position plant is refused, not read as zero positions);
  anything else is refused (counted in ``commands_refused``) and the last good command
  stays.
- Every command is clipped into the joint limits (``effort_limit``, by default the
  URDF's ``<limit effort>``) and the rate limit (``effort_rate_limit``, libfranka's
  1000 N m/s) before it reaches the simulation (counted in ``commands_clipped``).
  Position-interface plants get the URDF's position limits and velocity limit instead.
- Watchdog (realtime only; lockstep waits for commands and resends instead): a tick
  with no new command since the previous one reuses the last command; after
  ``watchdog_missed_cycles`` such ticks in a row, or twice that many periods of wall time
  over at least a tenth as many ticks (:mod:`cr_sim.watchdog`: ticks slowed down by publishes
  blocked on a dead reader), the reaction is a **safe stop** (the
  plant's brakes, :meth:`~cr_sim.plants.base.Plant.safe_stop_command`: gravity held,
  joints damped to rest and held), ``hold`` (keep the last command) or ``disabled``. The
  safe stop is logged once with its reason, shows as ``safe_stop`` = 1 in /plant/timing
  (``safe_stop_reason`` = 1) and lasts until someone sets the parameter ``resume`` to true
  (``cr_param set plant resume true``); the plant then resets ``resume`` to false and
  applies commands again.
- Reflexes (issue 20; libfranka's Cartesian and joint reflexes), realtime and lockstep:
  after every plant step, on the true state, a contact force above the scenario's
  ``max_contact_force`` (:meth:`~cr_sim.plants.base.Plant.contact_force_magnitude`) or a
  joint velocity above its URDF ``<limit velocity>``
  (:meth:`~cr_sim.plants.base.Plant.velocity_limits`) trips the same safe stop, logged once
  with the values (``REFLEX: ...``), ``safe_stop_reason`` 2 (force) or 3 (velocity), ended
  by ``resume`` as above. In lockstep each command still advances the plant one period (the
  loop and a recording go on deterministically) but the brakes' command is applied instead.
  The comparisons pass only a value inside its limit (:func:`reflex`): NaN trips them.
- No NaN leaves the plant: after every step the true state is checked
  (:meth:`~cr_sim.plants.base.Plant.state_is_finite`), and every message's values before it
  is published. A non-finite one cannot be braked: the node publishes nothing more (the last
  state out was finite), logs one ERROR line (``NON-FINITE: ...``) and finishes with exit
  code 1; a controller sees its states stop.
- One commander at a time (issue 25; ros2_control lets one controller claim an interface,
  libfranka takes one control connection): the publisher of the first valid command is
  the commander; commands from any other publisher on /joint_commands are refused unread
  (a bytes comparison of the publisher GIDs, :mod:`cr_control.nodes.sender_aware`),
  counted in ``commands_foreign`` and logged once. Another publisher takes over with a
  valid command only after the commander has sent nothing for ``command_handover_cycles``
  (50) cycles: a restarted or switched controller takes over before the watchdog's safe
  stop (100); a stalled one is not displaced by a stray publisher meanwhile. Lockstep has
  no ticks: there the silence is that many periods of wall time. Handovers are logged and
  counted (``commander_handovers``).
- A command longer than ``MAX_COMMAND_BYTES`` (64 joints' worth) is refused unread
  (counted in ``commands_oversized``, logged once).
- Another publisher on /joint_commands or /joint_states (a second session on this
  domain, a rogue node) is also checked once a second: warned once and counted in
  ``command_publishers`` / ``state_publishers``, so the recording shows it.

Hot path (issue 6): the state, wrench, sensors and clock messages are built once as CDR
bytes and refilled in place each tick (:class:`cr_control.core.cdr.Writer`: numpy views
onto their numbers), published as bytes; commands are taken serialized, with their
publisher's GID (:mod:`cr_control.nodes.sender_aware`: 20-30 us more per command than a
``raw=True`` subscription on EventsExecutor, for the GID rclpy does not give), and read
from their bytes (:mod:`cr_control.nodes.raw_messages`): no ROS message object per tick.
The time spent building and publishing the state is reported as ``publish_time_us``.

Housekeeping off the tick: the once-a-second report (publisher count, ``/plant/timing``,
``/diagnostics``, a log line) costs ~1.5 ms in all, more than a period, so done in one
callback it made the next tick late by a period every second (measured: 1.45-1.52 ms per
call, Panda session). In real time it is queued as chores, run one at a time in the idle
slot after a tick's command has been answered and stepped ahead (the most expensive piece
~0.4 ms); if no command is stepped ahead (none arrives, or a safe stop), the tick runs a
chore waited on for more than :data:`CHORE_WAIT_TICKS`. Lockstep and the final report run
them at once. Five Panda sessions each, alternating: ticks more than 1.5 ms apart 87 -> 64
per 10 s (medians), ticks 9887 -> 9903.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from math import isfinite

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, MultiArrayDimension, String

from cr_control.core import cdr, topics
from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.brake import MAX_BRAKE_STEP
from cr_control.nodes import sender_aware
from cr_control.nodes.diagnostics import PlantDiagnostics
from cr_control.nodes.lockstep import ReaderPacer, wait_for_readers
from cr_control.nodes.qos import CONTROL_QOS, PUBLISH_QOS, READY_QOS
from cr_control.nodes.raw_messages import JointStateFields, JointStateReader
from cr_control.nodes.ros_parameters import declare, police_changes
from cr_control.nodes.spin import quiet_on_shutdown, spin_nodes, start_nodes
from cr_sim.loop_stats import (
    SAFE_STOP_CONTACT_FORCE,
    SAFE_STOP_JOINT_VELOCITY,
    SAFE_STOP_NONE,
    SAFE_STOP_REASONS,
    SAFE_STOP_WATCHDOG,
    LoopStats,
)
from cr_sim.plant_markers import PlantMarkers
from cr_sim.plants.base import CommandLimiter, Plant
from cr_sim.plants.registry import SCENARIOS
from cr_sim.watchdog import Watchdog

NODE_PARAMETERS = [
    Param("mode", "realtime", "realtime: wall-clock timer; lockstep: step on each command.",
          "choice", choices=("realtime", "lockstep"), read_only=True),
    # 10 kHz: beyond the fastest robot interfaces (1-8 kHz).
    Param("rate_hz", 1000.0, "Control rate (Hz): ticks per second in realtime, 1/period in "
          "lockstep.", "positive", read_only=True, bound=1e4),
    Param("duration", 0.0, "Simulated seconds to run before stopping; 0 = until stopped.",
          "nonnegative", read_only=True, bound=Bound.TIME),
    Param("wait_for_recorder", False, "Start only after the recorder says it is ready "
          f"({topics.RECORDER_READY}), so a recording misses nothing.", "bool", read_only=True),
    Param("contact_wrench_every", 1, "Publish the true contact wrench (analysis only) every "
          "this many states (integer >= 1); cr_session sets 10 in real time, where each "
          "publish costs the 1 kHz loop (as the controllers' diagnostics_every).", "integer",
          read_only=True, bound=1000),
    Param("lockstep_resend_s", 1.0, "Lockstep: republish the state if no command came for "
          "this long (wall s).", "positive", read_only=True, bound=60.0),
    Param("watchdog_missed_cycles", 100, "Realtime watchdog: consecutive ticks without a new "
          "command (the last one is reused meanwhile) before watchdog_reaction, >= 1. 100 = "
          "0.1 s at 1 kHz (libfranka: 20 on a real-time kernel): controller stalls of 20-60 ms "
          "were seen on a loaded 2-core machine, and a false stop needs a manual resume. Also "
          "twice that many periods of wall time over at least a tenth of the ticks: a plant whose "
          "ticks slowed down stops in time too.",
          "integer", read_only=True, bound=10000),      # 10 s at 1 kHz
    Param("watchdog_reaction", "safe_stop", "What the watchdog does: safe_stop (brakes: "
          "gravity held, joints damped to rest and held there, until resume is set), hold "
          "(keep applying the last command, logged) or disabled (not 'off': YAML reads that as "
          "false).", "choice", choices=("safe_stop", "hold", "disabled"), read_only=True),
    Param("brake_frequency", 50.0, "Safe stop of effort plants: natural frequency w_b "
          "(rad/s) of the brakes tau = G(q) - M(q) (2 w_b q' + w_b^2 (q - q_stop)), q_stop = "
          "q + q'/w_b when braking began: every joint, whatever its inertia, slows as "
          "e^(-w_b t) and is held where it stops. At most "
          f"{MAX_BRAKE_STEP:g} x rate_hz (a torque held for a period brakes stably only so).",
          "positive", read_only=True, bound=Bound.BANDWIDTH),
    Param("resume", False, "Set to true to leave a safe stop (the plant applies commands "
          "again and sets this back to false). Never happens by itself.", "bool"),
    Param("effort_limit", [0.0], "Joint effort limits (N m): one value for every joint or "
          "one per joint; 0 = the URDF's <limit effort>. Commands beyond are clipped.",
          "nonnegative_vector", read_only=True, bound=Bound.EFFORT),
    # 1e9 N m/s (1e6 N m per 1 ms cycle): no limit in practice, which is how the
    # comparisons with the offline loop (which has none) open it up; fjr_robust_adaptive's
    # thesis runs need 1e5.
    Param("effort_rate_limit", 1000.0, "Torque-rate limit (N m/s) between consecutive "
          "commands (libfranka: 1000); commands beyond are clipped.", "positive",
          read_only=True, bound=1e9),
    Param("command_handover_cycles", 50, "One commander at a time (issue 25): commands from "
          "any other publisher on /joint_commands are refused (counted in commands_foreign) "
          "until the commander has sent nothing for this many cycles (realtime: ticks; "
          "lockstep: this many periods of wall time); then the next valid command's publisher "
          "takes over. >= 1. 50 = 50 ms at 1 kHz: below the watchdog's 100, so a restarted "
          "controller takes over before the safe stop; above the 20-60 ms stalls of a loaded "
          "controller, so a stalled one is not displaced by a stray publisher.", "integer",
          read_only=True, bound=10000),
]


SCENARIO_PARAMETER = Param("scenario", "compliant_plane", "Simulated scenario.", "choice",
                           choices=tuple(SCENARIOS), read_only=True)

#: Publish times kept for matching commands to the states they answer.
_RING = 64

#: The most joints a command may name: a command longer than such a JointState (names of
#: 63 characters, all three arrays filled, a 255-character frame_id: MAX_COMMAND_BYTES) is
#: refused unread, whatever the plant's joints (the Panda has 9, the largest URDF here).
MAX_COMMAND_JOINTS = 64
#: Realtime: a tick integrates at most this many periods of the wall time since the last
#: one (20 ms); a longer stall of the loop is dropped, not integrated with a stale command.
MAX_CATCH_UP_PERIODS = 20
#: Realtime: a queued chore (housekeeping) waits at most this many ticks for an idle slot.
CHORE_WAIT_TICKS = 2
MAX_COMMAND_BYTES = len(cdr.Writer(cdr.joint_state, frame_id="f" * 255,
                                   name=["n" * 63] * MAX_COMMAND_JOINTS,
                                   **dict.fromkeys(("position", "velocity", "effort"),
                                                   MAX_COMMAND_JOINTS)).message())


def plant_parameters(scenario: str) -> list[Param]:
    """Every parameter of the plant node running ``scenario``, in declaration order."""
    specs = SCENARIOS[scenario][0]
    return [replace(SCENARIO_PARAMETER, default=scenario), *NODE_PARAMETERS, *specs]


def command_limiter(plant: Plant, settings: dict, period: float) -> CommandLimiter:
    """The plant's command limits: effort bounds (``effort_limit``, else the URDF's) and
    the torque-rate limit; position plants: the URDF's position and velocity limits.

    A joint with no known effort limit (no URDF and none given) is left unbounded, with
    no rate limit either: the node warns at start (see :func:`unlimited_joints`).
    """
    limits = plant.joint_limits()
    n = len(plant.command_joints)
    if plant.command_interface == "position":
        return CommandLimiter(limits.lower, limits.upper, limits.velocity, period)
    given = list(settings["effort_limit"])
    if len(given) not in (1, n):
        raise ParameterError(f"effort_limit needs 1 or {n} values, got {len(given)}")
    effort = []
    for i in range(n):
        value = given[0] if len(given) == 1 else given[i]
        urdf = float(limits.effort[i])
        effort.append(value if value > 0.0 else (urdf if 0.0 < urdf < np.inf else np.inf))
    rate = [settings["effort_rate_limit"] if e < np.inf else np.inf for e in effort]
    return CommandLimiter([-e for e in effort], effort, rate, period)


def reflex(plant: Plant, max_force: float,
           velocity_limits: list[tuple[int, float, str]]) -> tuple[int, str] | None:
    """The reflex the plant's true state trips now, as (``safe_stop_reason``, the log line's
    start), or None: a contact force (:meth:`~cr_sim.plants.base.Plant.contact_force_magnitude`)
    above ``max_force``, else the first joint (index into ``true_velocity()``, limit, name
    of ``velocity_limits``) faster than its limit. Each comparison passes only a value
    inside its limit (``not abs(f) <= limit``): NaN and infinities trip it, as any value
    that is not a number must (with ``f > limit``, NaN passed)."""
    force = plant.contact_force_magnitude()
    if not abs(force) <= max_force:
        return (SAFE_STOP_CONTACT_FORCE,
                f"REFLEX: contact force {force:.4g} N > max_contact_force {max_force:g} N")
    if velocity_limits:
        velocity = plant.true_velocity()
        for i, limit, name in velocity_limits:
            if not abs(velocity[i]) <= limit:
                return (SAFE_STOP_JOINT_VELOCITY,
                        f"REFLEX: joint {name} velocity {velocity[i]:.4g} beyond its URDF "
                        f"<limit velocity> {limit:g}")
    return None


def unlimited_joints(plant: Plant, limiter: CommandLimiter) -> list[str]:
    """Joints whose commands the limiter does not bound."""
    return [name for name, lo, hi in zip(plant.command_joints, limiter.lower, limiter.upper, strict=True)
            if lo == -np.inf and hi == np.inf]


def warm_up(spare: Plant, period: float) -> None:
    """Run a spare plant of the node's scenario through what ticks and a safe stop call
    (steps, measurement, sensors, reflex checks, true contact wrench, brakes), so that the
    real plant's first tick does not pay for loading its compiled kernels: the Panda's
    first tick took 25-30 ms (numba's cache, and numpy.ma imported by numba's typeof), the
    largest of the late ticks that cost its first second ~20 ticks (2026-11-26)."""
    command = initial_command(spare)
    for _ in range(2):
        spare.step(command, period)
    spare.measurement()
    if spare.sensor_fields:                   # published only then (one plant keeps an array)
        spare.sensors()
    spare.contact_force_magnitude()
    spare.true_velocity()
    truth = getattr(spare, "contact_wrench", None)
    if callable(truth):
        truth()
    spare.begin_safe_stop()
    spare.step(np.asarray(spare.safe_stop_command(), dtype=float), period)


def initial_command(plant: Plant) -> np.ndarray:
    """What the plant holds before the first command: its own held input where it has one
    (``plant.held``; the ch. 4 plant starts in equilibrium with delta_c = delta), else the
    current positions for position plants (hold still), and for effort plants the gravity
    torque G(q) where the plant knows it (the arm is held as a real arm's brakes or its own
    gravity compensation hold it until a controller takes over), else zero efforts.
    A realtime plant steps with it until a controller answers (a few ms: a 20 kg arm under
    zero torque reached 0.84 rad/s at the Panda's elbow before the first command; zero
    positions would pull the ch. 4 end effector off the constraint)."""
    n = len(plant.command_joints)
    held = getattr(plant, "held", None)
    if held is not None and np.shape(held) == (n,) and np.all(np.isfinite(held)):
        return np.array(held, dtype=float)
    if plant.command_interface == "position":
        return np.array(plant.measurement().position, dtype=float)
    # a plant's noise-free position where it has one: no noise drawn (the offline loop draws
    # none here, so lockstep stays bit for bit with a noisy sensor)
    true_position = getattr(plant, "true_position", None)
    position = true_position() if callable(true_position) else plant.measurement().position
    gravity = plant.gravity_torque(np.asarray(position, dtype=float))
    if gravity is not None and gravity.shape == (n,) and np.all(np.isfinite(gravity)):
        return gravity
    return np.zeros(n)


class PlantNode(Node):
    """Runs a cr_sim scenario chosen by the ``scenario`` parameter."""

    def __init__(self, **kwargs):
        super().__init__("plant", **kwargs)
        scenario = declare(self, [SCENARIO_PARAMETER])
        specs, factory = SCENARIOS[scenario["scenario"]]
        self.settings = declare(self, NODE_PARAMETERS)
        for name in ("watchdog_missed_cycles", "command_handover_cycles", "contact_wrench_every"):
            if self.settings[name] < 1:
                raise ParameterError(f"parameter {name} must be >= 1")
        values = declare(self, specs)
        self.plant = factory(values)
        police_changes(self, [SCENARIO_PARAMETER, *NODE_PARAMETERS, *specs], self._on_parameter)
        self.period = 1.0 / self.settings["rate_hz"]
        brake_frequency = self.settings["brake_frequency"]
        if brake_frequency * self.period > MAX_BRAKE_STEP:
            raise ParameterError(
                f"brake_frequency {brake_frequency:g} rad/s is too high for rate_hz "
                f"{self.settings['rate_hz']:g}: a brake torque held for a period is stable only "
                f"up to brake_frequency = {MAX_BRAKE_STEP:g} x rate_hz "
                f"({MAX_BRAKE_STEP * self.settings['rate_hz']:g} rad/s here)")
        self.plant.brake_frequency = brake_frequency
        self.lockstep = self.settings["mode"] == "lockstep"
        # Realtime: this process runs at the real-time loop's CPU weight (spin_nodes;
        # cr_control.nodes.realtime_priority), and its first tick is not its first step.
        self.realtime_loop = not self.lockstep
        if self.realtime_loop:
            warm_up(factory(values), self.period)
        self.joint_names = list(self.plant.joint_names)
        self.command_names = tuple(self.plant.command_joints)
        self.limiter = command_limiter(self.plant, self.settings, self.period)
        if unbounded := unlimited_joints(self.plant, self.limiter):
            self.get_logger().warn(f"no command limit known for {unbounded} (no URDF limit): "
                                   "commands to them are not bounded" + ("; set effort_limit" if
                                   self.plant.command_interface == "effort" else ""))
        self.finished = Future()
        #: The process's exit code once finished: 1 after a non-finite state (:meth:`_stop_non_finite`).
        self.exit_code = 0
        self.stats = LoopStats()
        self.scenario = scenario["scenario"]
        # First of our endpoints, so that whoever discovers the states discovers it too.
        self.interface_pub = self.create_publisher(String, topics.PLANT_COMMAND_INTERFACE, READY_QOS)
        self.interface_pub.publish(String(data=self.plant.command_interface))

        n = len(self.joint_names)
        self.command = initial_command(self.plant)     # held until the first command
        self._command_list: list[float] | None = None   # last applied command, for the rate limit
        self.command_stamp: int | None = None            # stamps as integer nanoseconds
        self.state_stamp: int | None = None
        self._ring_stamps: list[int | None] = [None] * _RING
        self._ring_times = [0.0] * _RING
        self._ring_i = 0
        self._order_cache: tuple[tuple[str, ...], list[int] | None] = ((), None)
        self._position_interface = self.plant.command_interface == "position"
        # Watchdog (realtime): armed by the first command.
        self._watchdog_reaction = "disabled" if self.lockstep else self.settings["watchdog_reaction"]
        self.watchdog = Watchdog(self.settings["watchdog_missed_cycles"], self.period)
        self._new_command = False
        self.safe_stop = False
        # Reflexes (both modes): one comparison per step for the force, a short loop for
        # the joints with a URDF velocity limit.
        self._max_force = float(self.plant.max_contact_force)
        self._velocity_limits = [(i, limit, self.joint_names[i])
                                 for i, limit in self.plant.velocity_limits()]
        self._resume_requested = False
        # One commander at a time (issue 25): the GID of the publisher whose commands are
        # followed (None until the first valid command) and when it was last heard (realtime:
        # the tick count; lockstep: wall time).
        self._commander: bytes | None = None
        self._handover_cycles = self.settings["command_handover_cycles"]
        self._ticks = 0
        self._commander_tick = 0
        # Housekeeping queued for the idle slot after a tick's step ahead (realtime), and
        # the tick count when the oldest of it was queued or last ran.
        self._chores: deque[Callable[[], None]] = deque()
        self._chore_tick = 0
        self._commander_wall = 0.0
        self._warned: set[str] = set()
        self._started = False
        self._recorder_ready = not self.settings["wait_for_recorder"]
        self._t0_wall = 0.0
        self._last_tick = 0.0
        self._carry = 0.0          # realtime: wall time not yet simulated (s)
        self._dropped_s = 0.0      # realtime: wall time of stalls not simulated (s)
        self._contact_count = 0    # states since the last true contact wrench
        # Realtime: seconds the step ahead of the next tick took (None: not stepped ahead).
        self._ahead_time: float | None = None
        self._last_publish_wall = 0.0

        self.state_pub = self.create_publisher(JointState, topics.JOINT_STATES, PUBLISH_QOS)
        self.wrench_pub = self.create_publisher(WrenchStamped, topics.WRENCH, PUBLISH_QOS)
        # The true contact wrench (base frame), for analysis and tests (topics.CONTACT_WRENCH).
        truth = getattr(self.plant, "contact_wrench", None)
        self._truth = truth if callable(truth) else None
        self.contact_pub = (self.create_publisher(WrenchStamped, topics.CONTACT_WRENCH,
                                                  PUBLISH_QOS) if self._truth else None)
        sensor_fields = ["stamp", *self.plant.sensor_fields]
        self.sensors_pub = (self.create_publisher(Float64MultiArray, topics.PLANT_SENSORS,
                                                  PUBLISH_QOS) if len(sensor_fields) > 1 else None)
        self._sensors = topics.labelled_writer(sensor_fields)
        self._sensors_out = self._sensors.array("data")
        self.timing_pub = self.create_publisher(Float64MultiArray, topics.PLANT_TIMING, PUBLISH_QOS)
        self.clock_pub = self.create_publisher(Clock, topics.CLOCK, PUBLISH_QOS) if self.lockstep else None
        # /diagnostics (issue 22): judged from each timing report.
        self.diagnostics = PlantDiagnostics(self, self.scenario, self.settings["rate_hz"],
                                            not self.lockstep, SAFE_STOP_REASONS)
        self.markers = PlantMarkers(self, self.plant)    # /plant/markers, ~30 Hz (issue 22)
        self.markers.warm_up()
        self._pacer = ReaderPacer(self, [self.state_pub, self.wrench_pub, self.sensors_pub,
                                         self.clock_pub, self.contact_pub])   # used in lockstep
        self._timing_msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                                 topics.PLANT_TIMING_FIELDS)
        # Outgoing messages, built once as CDR bytes and refilled in place every tick.
        self._state = cdr.Writer(cdr.joint_state, name=self.joint_names, position=n, velocity=n,
                                 effort=n)
        self._q_out, self._v_out, self._e_out = (self._state.array(f) for f in
                                                 ("position", "velocity", "effort"))
        # frame_id: the frame the plant measures its wrench in (a URDF sensor link, its base).
        self._wrench = cdr.Writer(cdr.wrench_stamped,
                                  frame_id=self.plant.wrench_frame)
        self._wrench_out = self._wrench.array("wrench")       # force, torque
        self._contact = cdr.Writer(cdr.wrench_stamped,
                                   frame_id=getattr(self.plant, "base_frame", "world"))
        self._contact_out = self._contact.array("wrench")
        self._clock_out = cdr.Writer(cdr.clock)
        self._read_command = JointStateReader()

        # Commands with their publisher's GID (rclpy 7.1 hands none to Python: see
        # sender_aware); without rcl's take at hand, a plain raw subscription that cannot
        # tell publishers apart (one commander is then not enforced: warned).
        on_command = quiet_on_shutdown(self, self._on_command)
        if sender_aware.available():
            self.command_sub = sender_aware.subscribe(self, JointState, topics.JOINT_COMMANDS,
                                                      on_command, CONTROL_QOS, MAX_COMMAND_BYTES)
        else:
            self.get_logger().warn("rcl's take is not reachable through ctypes: publishers on "
                                   f"{topics.JOINT_COMMANDS} cannot be told apart, every one "
                                   "is obeyed")
            self.command_sub = self.create_subscription(
                JointState, topics.JOINT_COMMANDS, on_command, CONTROL_QOS, raw=True)
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
            + f", command limits {self.limiter.lower}..{self.limiter.upper}, "
            f"watchdog {self._watchdog_reaction}"
            + ("" if self._watchdog_reaction == "disabled"
               else f" after {self.watchdog.missed_limit} missed cycles")
            + f", reflexes at contact force > {self._max_force:g} N"
            + "".join(f", |{name}'| > {limit:g}" for _, limit, name in self._velocity_limits)
            + "; waiting for a controller")

    def destroy_node(self) -> None:
        if isinstance(self.command_sub, sender_aware.SenderAwareSubscription):
            self.command_sub.destroy()     # not one of the node's subscriptions: freed here
        super().destroy_node()

    # -- parameters -----------------------------------------------------------------
    def _on_parameter(self, name: str, value) -> None:
        if name == "resume" and value:
            self._resume_requested = True   # acted on (and reset) by the next tick

    def _resume(self) -> None:
        self._resume_requested = False
        self.set_parameters([Parameter("resume", value=False)])
        if not self.safe_stop:
            self.get_logger().info("resume requested, but no safe stop is engaged")
            return
        self.safe_stop = False
        self.stats.safe_stop = 0.0
        self.stats.safe_stop_reason = SAFE_STOP_NONE
        self.watchdog.disarm()   # re-armed by the next command; the brake torque is held till then
        self.get_logger().warn("resumed from safe stop on request: applying commands again")

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
        self._timing_timer.reset()
        self._tick_timer.reset()
        self.get_logger().info("controller connected: starting")
        if self.lockstep:
            self._publish_state(*divmod(int(round(self.plant.time * 1e9)), 1_000_000_000))

    def _commander_listens(self) -> bool:
        """Some node that publishes on the command topic subscribes to the state topic."""
        def nodes(infos) -> set[tuple[str, str]]:
            return {(info.node_namespace, info.node_name) for info in infos}
        commanders = nodes(self.get_publishers_info_by_topic(self.command_sub.topic_name))
        return bool(commanders & nodes(self.get_subscriptions_info_by_topic(self.state_pub.topic_name)))

    def _finish(self) -> None:
        if self.finished.done():
            return
        self._chores.clear()                 # superseded by the final report, made now
        self._publish_timing(at_once=True)
        self.get_logger().info(
            f"done: {self.plant.time:.3f} s simulated in {time.monotonic() - self._t0_wall:.3f} s wall, "
            f"{self.stats.total_cycles} cycles, {self.stats.commands_refused} commands refused, "
            f"{self.stats.commands_clipped} clipped"
            + (f", {self._dropped_s:.3f} s of stalls not simulated" if self._dropped_s else "")
            + (f", in safe stop ({SAFE_STOP_REASONS[self.stats.safe_stop_reason]})"
               if self.safe_stop else ""))
        wait_for_readers(list(self.publishers), 2.0)   # the last messages reach the recorder
        self.finished.set_result(True)

    def _out_of_time(self) -> bool:
        duration = self.settings["duration"]
        return duration > 0.0 and self.plant.time >= duration - 0.5 * self.period

    # -- state out ------------------------------------------------------------------
    def _publish_state(self, sec: int, nanosec: int) -> None:
        """Publish clock (lockstep), wrench and joint state stamped ``sec.nanosec``."""
        start = time.perf_counter()
        m = self.plant.measurement()
        state, wrench = self._state, self._wrench
        self._q_out[:] = m.position
        self._v_out[:] = m.velocity
        self._e_out[:] = m.effort
        self._wrench_out[:3] = m.force
        self._wrench_out[3:] = m.torque
        if not isfinite(self._q_out.sum() + self._v_out.sum() + self._e_out.sum()
                        + self._wrench_out.sum()):
            self._stop_non_finite("the joint state or wrench to publish")
            return
        state.set_stamp(sec, nanosec)
        wrench.set_stamp(sec, nanosec)
        if self.clock_pub is not None:
            self._clock_out.set_stamp(sec, nanosec)
            self.clock_pub.publish(self._clock_out.message())
        self.wrench_pub.publish(wrench.message())
        if self.sensors_pub is not None:
            self._sensors_out[0] = sec + nanosec * 1e-9
            self._sensors_out[1:] = self.plant.sensors()
            if not isfinite(self._sensors_out.sum()):
                self._stop_non_finite("a plant sensor to publish")
                return
            self.sensors_pub.publish(self._sensors.message())
        self.state_pub.publish(state.message())
        self._contact_count += 1
        if self._truth is not None and self._contact_count >= self.settings["contact_wrench_every"]:
            self._contact_count = 0         # after the state: the loop's messages go first
            truth = self._truth()
            self._contact.set_stamp(sec, nanosec)
            self._contact_out[:3] = truth.force
            self._contact_out[3:] = truth.torque
            if not isfinite(self._contact_out.sum()):
                self._stop_non_finite("the true contact wrench to publish")
                return
            self.contact_pub.publish(self._contact.message())
        now = time.monotonic()
        key = sec * 1_000_000_000 + nanosec
        self.state_stamp = key
        self._last_publish_wall = now
        i = self._ring_i = (self._ring_i + 1) % _RING
        self._ring_stamps[i], self._ring_times[i] = key, now
        self.stats.published(time.perf_counter() - start)
        self.markers.tick(self.plant.time, sec, nanosec)

    def _published_at(self, key: int) -> float | None:
        """Wall time the state stamped ``key`` was published (None if not among the last)."""
        stamps, i = self._ring_stamps, self._ring_i
        for k in range(_RING):
            j = (i - k) % _RING
            if stamps[j] == key:
                stamps[j] = None      # one round trip per state
                return self._ring_times[j]
        return None

    # -- commands in ----------------------------------------------------------------
    def _reorder(self, names: list[str], values) -> list[float] | None:
        """``values`` in our joint order if ``names`` are exactly our joints, else None."""
        key = tuple(names)
        if key != self._order_cache[0]:
            ours = self.command_names
            ok = len(names) == len(ours) and set(names) == set(ours)
            self._order_cache = (key, [names.index(n) for n in ours] if ok else None)
        order = self._order_cache[1]
        if order is None or len(values) != len(names):
            return None
        return [values[i] for i in order]

    def _refuse(self, why: str) -> None:
        self.stats.commands_refused += 1
        self.get_logger().warn(f"refused a command ({why}); {self.stats.commands_refused} so far; "
                               "holding the last good one", throttle_duration_sec=5.0)

    def _wrong_field(self, msg: JointStateFields) -> str:
        """Why ``msg`` is not a command of our interface ("" if it is one)."""
        ours, theirs = (("positions", "efforts") if self._position_interface
                        else ("efforts", "positions"))
        given = msg.position if self._position_interface else msg.effort
        other = msg.effort if self._position_interface else msg.position
        if len(given) == 0 and len(other) > 0:
            return (f"it carries {theirs} but this plant takes {ours} (scenario "
                    f"{self.scenario})")
        return ""

    def _publisher_name(self, gid: bytes) -> str:
        """``node 'name' (gid ...)`` of the publisher ``gid`` on /joint_commands, from the graph
        (a query: only for the rare log lines)."""
        gid_text = f"gid {gid.hex()}" if gid else "unknown gid"
        try:
            infos = self.get_publishers_info_by_topic(self.command_sub.topic_name)
        except Exception:  # noqa: BLE001 - a log line's detail, never worth failing for
            infos = []
        for info in infos:
            if gid and bytes(info.endpoint_gid) == gid:
                return f"node '{info.node_namespace.rstrip('/')}/{info.node_name}' ({gid_text})"
        return f"a publisher ({gid_text})"

    def _commander_silence(self) -> int:
        """Cycles since the commander's last valid command: ticks in realtime, periods of
        wall time in lockstep (which has no ticks)."""
        if self.lockstep:
            return int((time.monotonic() - self._commander_wall) * self.settings["rate_hz"])
        return self._ticks - self._commander_tick

    def _from_another(self, gid: bytes) -> bool:
        """True if a command of ``gid`` (not the commander) is refused unread: the commander
        has not been silent for command_handover_cycles (counted; logged the first time)."""
        if self._commander is None or self._commander_silence() >= self._handover_cycles:
            return False
        self.stats.commands_foreign += 1
        self._warn_once("foreign", lambda: (
            f"refused commands from {self._publisher_name(gid)} on "
            f"{self.command_sub.topic_name}: the plant follows one commander at a time, "
            f"{self._publisher_name(self._commander)}, until it has been silent for "
            f"{self._handover_cycles} cycles (command_handover_cycles); counted in "
            f"commands_foreign ({topics.PLANT_TIMING}), logged once"))
        return True

    def _warn_once(self, key: str, text: Callable[[], str]) -> None:
        """Log ``text()`` as a warning the first time ``key`` comes (the text is only built
        then: it may query the graph)."""
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warn(text())

    def _take_over(self, gid: bytes) -> None:
        """``gid``'s valid command makes it the commander (the first, or after the silence)."""
        previous, self._commander = self._commander, gid
        if previous is None:
            self.get_logger().info(f"commands from {self._publisher_name(gid)}")
            return
        self.stats.commander_handovers += 1
        self.get_logger().warn(
            f"handover: commands now from {self._publisher_name(gid)}; the previous commander "
            f"({self._publisher_name(previous)}) was silent for {self._commander_silence()} "
            f"cycles (command_handover_cycles {self._handover_cycles})")

    def _refuse_oversized(self, length: int) -> None:
        self.stats.commands_oversized += 1
        self._warn_once("oversized", lambda: (
            f"refused a {length}-byte command unread: more than {MAX_COMMAND_BYTES} bytes "
            f"({MAX_COMMAND_JOINTS} joints' worth); counted in commands_oversized, logged once"))

    def _on_command(self, data: bytes | None, gid: bytes = b"", length: int = 0) -> None:
        """A serialized command from the publisher ``gid`` (its GID; b"" if unknown);
        ``data`` None: a message of ``length`` bytes, too long to be read."""
        if data is None or len(data) > MAX_COMMAND_BYTES:
            self._refuse_oversized(length if data is None else len(data))
            return
        if gid != self._commander and self._from_another(gid):
            return
        msg = self._read_command(data)
        if msg is None:
            self._refuse("not a readable JointState")
            return
        values = msg.position if self._position_interface else msg.effort
        if msg.name != self.command_names or len(values) != len(self.command_names):
            values = self._reorder(msg.name, values)
            if values is None:
                self._refuse(self._wrong_field(msg) or
                             f"it names {list(msg.name)} with {len(msg.effort)} efforts and "
                             f"{len(msg.position)} positions; the plant's commanded joints are "
                             f"{list(self.command_names)}")
                return
        limited = self.limiter.limit(values, self._command_list)
        if limited is None:
            self._refuse("non-finite value")
            return
        self.stats.commands_clipped = self.limiter.clipped
        if gid != self._commander:
            self._take_over(gid)
        if self.lockstep:
            self._commander_wall = time.monotonic()
        else:
            self._commander_tick = self._ticks
        key = msg.sec * 1_000_000_000 + msg.nanosec
        sent = self._published_at(key)
        if sent is not None:
            self.stats.round_trip(time.monotonic() - sent)
        self.command_stamp = key
        self._new_command = True
        if not self.safe_stop:
            self._command_list = limited
            self.command = np.array(limited)
        elif not self.lockstep:
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
        """One period of the plant: with the held command, or the brakes' in a safe stop;
        then, on the new state, the finiteness check (a non-finite state stops the node:
        :meth:`_stop_non_finite`) and the reflexes (:func:`reflex`)."""
        if self.safe_stop:                               # brakes act on every step
            self._command_list = self.limiter.bound(self.plant.safe_stop_command())
            self.command = np.array(self._command_list)
            self.plant.step(self.command, self.period)
            if not self.plant.state_is_finite():
                self._stop_non_finite("the plant's state")
            return
        self.plant.step(self.command, self.period)
        if not self.plant.state_is_finite():
            self._stop_non_finite("the plant's state")
            return
        tripped = reflex(self.plant, self._max_force, self._velocity_limits)
        if tripped is not None:
            self._engage_safe_stop(*tripped)

    def _stop_non_finite(self, what: str) -> None:
        """``what`` became non-finite: no brake can act on a non-finite state and nothing
        non-finite may leave the plant, so publish nothing more, say so in one ERROR line and
        finish (the process exits with code 1). The last state published was finite."""
        if self.finished.done():
            return
        self.exit_code = 1
        self.get_logger().error(
            f"NON-FINITE: {what} is not finite at t = {self.plant.time:.3f} s: nothing more is "
            "published (the last state was finite) and the plant stops, exit code 1; a "
            "controller sees its states stop")
        self._finish()

    def _engage_safe_stop(self, reason: int, what: str) -> None:
        """Brake from the next step on until resumed; log it once with why (a safe stop
        already engaged keeps its reason)."""
        if self.safe_stop:
            return
        self.safe_stop = True
        self.stats.safe_stop = 1.0
        self.stats.safe_stop_reason = reason
        self.diagnostics.safe_stop(reason)       # ERROR on /diagnostics now, not at the next report
        self.plant.begin_safe_stop()
        self.get_logger().error(
            f"{what} at t = {self.plant.time:.3f} s: "
            f"{'braking' if reason == SAFE_STOP_WATCHDOG else 'safe stop, braking'} "
            f"({self.plant.describe_safe_stop()}). Commands are ignored until the parameter "
            "resume is set to true.")

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
        self._run_chore()                # the idle slot until the next tick

    def _resend_if_stalled(self) -> None:
        if self.finished.done() or self.state_stamp is None:
            return
        if self._resume_requested:
            self._resume()
        if time.monotonic() - self._last_publish_wall > self.settings["lockstep_resend_s"]:
            self.get_logger().warn("no command for the last state: publishing it again")
            self._publish_state(*divmod(self.state_stamp, 1_000_000_000))

    def _watch(self, now: float) -> None:
        """Tell the watchdog whether this tick saw a new command; react when it says so."""
        new, self._new_command = self._new_command, False
        reason = self.watchdog.tick(now, new)
        if self.watchdog.run > self.stats.window_max_missed_run:
            self.stats.window_max_missed_run = self.watchdog.run
        if reason is None or self._watchdog_reaction == "disabled":
            return
        if self._watchdog_reaction == "hold":
            self.get_logger().warn(f"watchdog: {reason}: holding the last command "
                                   "(watchdog_reaction hold)", throttle_duration_sec=5.0)
            return
        self._engage_safe_stop(SAFE_STOP_WATCHDOG, f"SAFE STOP: watchdog: {reason}")

    def _tick(self) -> None:
        if self.finished.done():
            return
        now = time.monotonic()
        elapsed, self._last_tick = now - self._last_tick, now
        self._ticks += 1
        fresh = self.command_stamp is not None and self.command_stamp == self.state_stamp
        if self._resume_requested:
            self._resume()
        self._watch(now)
        start = time.perf_counter()
        # Whole periods, the rest carried to the next tick: every step has the same dt
        # (an LTI plant's exact discretisation is then computed once, not every tick:
        # ~190 us -> ~4 us for the ch. 4 plant) and simulated time follows wall time to
        # within a period.
        # After a gap (a stalled tick) at most MAX_CATCH_UP_PERIODS are integrated: the rest
        # of the gap is dropped (simulated time falls behind wall time; said in the "done"
        # line) rather than integrated under a command held that long.
        due = elapsed + self._carry
        substeps = max(1, round(due / self.period))
        if substeps > MAX_CATCH_UP_PERIODS:
            self._dropped_s += (substeps - MAX_CATCH_UP_PERIODS) * self.period
            substeps, due = MAX_CATCH_UP_PERIODS, MAX_CATCH_UP_PERIODS * self.period
        self._carry = max(due - substeps * self.period, -self.period)
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
        if self._chores and self._ticks - self._chore_tick > CHORE_WAIT_TICKS:
            self._run_chore()            # no step ahead came to run it (no command, safe stop)

    def _check_publishers(self) -> None:
        """Warn once if anyone but the controller commands, or anyone but us publishes states."""
        commands = self.count_publishers(self.command_sub.topic_name)
        states = self.count_publishers(self.state_pub.topic_name)
        self.stats.command_publishers, self.stats.state_publishers = commands, states
        for topic, count, allowed in ((self.command_sub.topic_name, commands, 1),
                                      (self.state_pub.topic_name, states, 1)):
            if count > allowed:
                self._warn_once(topic, lambda count=count, topic=topic, allowed=allowed: (
                    f"{count} publishers on {topic} (expected {allowed}): another session on "
                    "this ROS_DOMAIN_ID or a rogue node is on the control loop; counted in "
                    f"{topics.PLANT_TIMING}"))

    def _run_chore(self) -> None:
        """Run the oldest queued chore, if any."""
        if self._chores:
            self._chores.popleft()()
        self._chore_tick = self._ticks

    def _publish_timing(self, at_once: bool = False) -> None:
        """The once-a-second report: queued as chores in real time (module docstring), done
        at once in lockstep and ``at_once``."""
        if not self._started:
            return
        chores = (self._check_publishers, self._report_timing, self._report_diagnostics,
                  self._log_timing)
        if at_once or self.lockstep:
            for chore in chores:
                chore()
            return
        if not self._chores:
            self._chore_tick = self._ticks
        self._chores.extend(chores)

    def _report_timing(self) -> None:
        now = time.monotonic()
        stamp = self.state_stamp * 1e-9 if self.state_stamp is not None else 0.0
        self._timing_msg.data = [stamp, *self.stats.report(now)]
        self.timing_pub.publish(self._timing_msg)

    def _window(self) -> dict[str, float]:
        """The last /plant/timing report's values by name."""
        return dict(zip(topics.PLANT_TIMING_FIELDS, self._timing_msg.data, strict=True))

    def _report_diagnostics(self) -> None:
        self.diagnostics.report(self._window())

    def _log_timing(self) -> None:
        d = self._window()
        self.get_logger().info(
            f"t={self.plant.time:.1f} s rate={d['rate_hz']:.0f} Hz "
            f"fresh={100 * d['window_fresh_share']:.2f}% "
            f"round trip p50/p99/max={d['window_age_p50_ms']:.3f}/{d['window_age_p99_ms']:.3f}/"
            f"{d['window_age_max_ms']:.3f} ms step={d['step_time_us']:.0f} us "
            f"publish={d['publish_time_us']:.0f} us"
            + (f" SAFE STOP ({SAFE_STOP_REASONS[self.stats.safe_stop_reason]})" if self.safe_stop
               else ""))


def main(args: list[str] | None = None) -> int:
    """Run the plant node (exit 1 with one line on stderr if it refuses to start)."""
    nodes = start_nodes("plant", list(sys.argv if args is None else args), lambda: [PlantNode()])
    if nodes is None:
        return 1
    spin_nodes(nodes, until=nodes[0].finished)
    return nodes[0].exit_code


if __name__ == "__main__":
    sys.exit(main())
