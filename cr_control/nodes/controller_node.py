"""The one generic controller node; each scheme's executable only chooses the scheme.

Subscribes to /joint_states and the force/torque sensor wrench, runs one control cycle
per joint state and publishes on /joint_commands (a JointState with the joint names and
efforts, or positions for command-displacement schemes, stamped with the state's stamp)
and its labelled ~/reference and ~/status (topics.py) every ``diagnostics_every``
cycles. Gains are ROS parameters (config/<scheme>.yaml), live-tunable through the
standard parameter services.

With ``lockstep`` set (the plant steps on this node's commands; ``cr_session --mode
lockstep`` sets it), the node waits every 250 cycles until the readers of its topics (a
recorder) acknowledged them, so a recording loses nothing (:mod:`cr_control.nodes.lockstep`).

Hot path (issue 6): the loop's messages are taken and published serialized
(``raw=True`` subscriptions, the joint states with their sender through
:mod:`cr_control.nodes.sender_aware`, ``publish(bytes)``): joint states, wrenches and plant
sensors are read straight from their CDR bytes (:mod:`cr_control.nodes.raw_messages`),
and the command, reference and status are built once as CDR bytes whose numbers are
refilled in place (:class:`cr_control.core.cdr.Writer`): no ROS message object is made
or converted per cycle. The status carries where a cycle's time goes: ``in_time_us``
(callback entry to compute start), ``compute_time_us`` and ``out_time_us`` (building
and publishing the previous cycle's messages). numpy's floating-point warnings are off
in the node process: :meth:`Controller.step` catches non-finite results itself and logs
them, rate-limited.

Command interface (issue 9): the plant advertises what it takes on the latched
``/plant/command_interface`` ("effort" or "position"). A scheme that commands the other
kind never publishes a command: the node logs one ERROR line (``adaptive_impedance commands
efforts but the plant takes positions (scenario dynamic_constraint): refusing to drive
it``) and exits with code 1. While a plant advertises but its value has not arrived yet,
states are not answered (a lockstep plant sends them again); a plant that advertises
nothing (another robot, a test probe) is driven as before.

Guards (issue 25; counted in the status, :data:`cr_control.core.topics.NODE_STATUS_FIELDS`):

- One source of states: the nodes' Fast DDS profile lets the state reader match one
  writer only, so a second publisher's states never reach this process (a 10 MB one costs
  the loop nothing); :mod:`cr_control.nodes.state_source` reports the publishers not
  followed and subscribes again once the followed one has left. Behind that, and alone
  where the profile is not in force, /joint_states is taken with each message's publisher GID
  (:mod:`cr_control.nodes.sender_aware`; rclpy 7.1.6 gives Python none). The node follows
  the first publisher whose state it answers; states of any other are ignored unread
  (``states_foreign``, one warning) until the followed one has been silent for
  SOURCE_SILENCE_S (a restarted plant, a switched driver): the next publisher is then
  followed (``source_handovers``, one info line).
- Newest state first (real time): a node that fell behind (several of its plant's states
  taken in one wake-up) answers only the newest, as the plant holds a command for its
  latest state only; the older are skipped (``states_skipped`` on the node, a rate-limited
  warning) and the law's next step is longer (its integration step is clamped after gaps).
  Lockstep answers every state.
- Size: a JointState longer than a 64-joint one (``raw_messages.joint_state_max_bytes``),
  or of another length than the last state and saying it has more than 64 names, and a
  wrench or plant sensor message beyond its bound, is dropped unread (``inputs_oversized``).
- Sensor sanity: a wrench whose force is above ``max_sensor_force`` or not finite is a
  sensor fault: the last sane force stays in use (``sensor_faults``, one warning); so is a
  wrench whose frame_id is not the controller's ``sensor_frame`` (when set).

Wrist sensor (issue 24, task-space schemes): the wrench's force and torque (sensor frame)
go to the law, which compensates them (:mod:`cr_control.schemes.blocks.wrist_sensor`);
``~/zero_ft`` (std_srvs/Trigger) starts zeroing the sensor's bias, or refuses with the
reason (no wrench yet, moving, in contact, a zeroing under way, a bias farther than
``zero_ft_max_change`` from the first one); ``~/zero_ft_force`` (std_srvs/Trigger) zeroes
with the operator vouching that the tool touches nothing (no contact or distance checks;
its bias becomes the first one). Refusals are logged at most one line every 5 s, with a
count; every call gets its reason in the response.
- A failing law: while :attr:`Controller.commanding` is False (its output failed for more
  than ``max_bad_cycles`` cycles in a row, or a failed start check) a scheme with a braking
  command publishes that every cycle (a real robot holds the last command forever); a
  scheme without one publishes nothing, so the plant's watchdog brakes;
  ``commands_stopped`` is 1.
"""

from __future__ import annotations

import contextlib
import sys
import time

import numpy as np
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import GetParameters
from rclpy.duration import Duration
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from cr_control.core import cdr, topics
from cr_control.nodes import discovery_settle, sender_aware
from cr_control.nodes.diagnostics import ControllerDiagnostics
from cr_control.nodes.lockstep import ReaderPacer
from cr_control.nodes.markers import ControllerMarkers
from cr_control.nodes.qos import CONTROL_QOS, PUBLISH_QOS, READY_QOS, STATE_QOS, TARGET_QOS
from cr_control.nodes.raw_messages import (
    ARRAY_MAX_BYTES,
    MAX_JOINTS,
    WRENCH_MAX_BYTES,
    ArrayReader,
    JointStateFields,
    JointStateReader,
    WrenchReader,
    joint_state_max_bytes,
    joint_state_names,
)
from cr_control.nodes.ros_parameters import ParameterError, declare, police_changes
from cr_control.nodes.spin import RCLError, quiet_on_shutdown, spin_nodes, start_nodes
from cr_control.nodes.state_source import StateSourceWatch
from cr_control.schemes.registry import SCHEMES, controller_class


def stamp_seconds(stamp) -> float:
    """A builtin_interfaces/Time as float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


#: What each command interface sends, for the refusal message.
INTERFACE_NOUNS = {"effort": "efforts", "position": "positions"}
#: How long a refusing node waits for the plant's scenario name (s) before it exits.
SCENARIO_WAIT_S = 1.0
#: A node with no plant interface yet looks for an advertising plant at most this often (s).
ADVERTISED_CHECK_S = 0.5
#: Another /joint_states publisher is followed only after the followed one has been silent
#: this long (s; 2000 cycles at 1 kHz): beyond the plant's watchdog (100 cycles) and its
#: lockstep resend (1 s), so a plant still alive behind a flood of foreign states has braked
#: or sent its state again first; a restarted plant takes longer to come back anyway.
SOURCE_SILENCE_S = 2.0
#: Integer parameters that must be >= 1.
COUNT_PARAMETERS = ("diagnostics_every", "max_bad_cycles")
#: A fault of the messages in (unreadable, oversized, ...) is logged at most this often (s).
LOG_EVERY_S = 5.0


def wait_for_acks(node: Node, timeout_s: float = 2.0) -> None:
    """Block until every RELIABLE publisher of ``node`` had its messages acknowledged (each
    waits at most ``timeout_s``): call before a node is destroyed at the end of a run, or
    a recorder misses the last messages still in flight."""
    for publisher in list(node.publishers):
        with contextlib.suppress(RCLError, RuntimeError):
            publisher.wait_for_all_acked(Duration(seconds=timeout_s))


class ControllerNode(LifecycleNode):
    """Runs the control scheme ``scheme`` on the topic contract of DESIGN.md, as a managed
    (lifecycle) node: it answers states only while active (module docstring, "Lifecycle")."""

    def __init__(self, scheme: str, **kwargs):
        super().__init__(scheme, **kwargs)
        cls = controller_class(scheme)
        given = {name: p.value for name, p in self._parameter_overrides.items()}  # noqa: SLF001
        specs = cls.parameters(given)      # a task-space scheme sizes its gains to the robot
        values = declare(self, specs)
        for name in COUNT_PARAMETERS:
            if values[name] < 1:
                raise ParameterError(f"parameter {name} must be >= 1")
        self.controller = cls(values)
        self.controller.warm_up()   # load the compiled kernels now, not in the first cycle
        self.controller.log_warning = self.get_logger().warn   # Controller rate-limits its own
        self.controller.log_error = self.get_logger().error
        self.controller.log_info = self.get_logger().info
        self.add_on_set_parameters_callback(self._check_counts)
        police_changes(self, specs, self._apply, self.controller.check_parameter)
        self.joint_names = list(self.controller.values["joint_names"])        # commanded
        self.state_joint_names = tuple(self.controller.state_joint_names)     # read
        n = len(self.joint_names)
        self._diagnostics_every = values["diagnostics_every"]
        self._cycle = 0
        self._out_time_us = 0.0
        self._index_cache: tuple[tuple[str, ...], list[int] | None] = ((), None)
        self.wrench = np.zeros(6)             # the last sane wrench: force, torque
        self.force = self.wrench[:3]
        self._wrench_seen = False
        self._sensor_frame = self.controller.values.get("sensor_frame", "")
        self._last_stamp: tuple[int, int] | None = None
        self._answered = False
        self.active = False                   # lifecycle state "active": states are answered
        self.activations = 0
        self._held_state: tuple[bytes, bytes | None] | None = None  # the last one seen inactive
        #: The last state that came before the plant's command interface did.
        self._awaiting_interface: tuple[bytes, bytes | None] | None = None
        # Guards (module docstring): counts, the followed publisher, size bounds.
        self.states_foreign = self.source_handovers = self.inputs_oversized = self.states_skipped = 0
        self.sensor_faults = 0
        self.source: bytes | None = None      # GID of the /joint_states publisher followed
        self._source_seen = -np.inf           # perf_counter of its last message
        self._max_joints = max(MAX_JOINTS, len(self.controller.state_joint_names))
        self._max_state_bytes = joint_state_max_bytes(self._max_joints)
        self._state_size = -1                 # length of the last state read
        self._sensor_fault = False            # the last wrench was a sensor fault
        self._logged_at: dict[str, float] = {}
        # Command interface check: "unknown" until the plant says, then "ok" or "refused".
        self.scheme = scheme
        self.command_interface = self.controller.command_interface
        self.refused = Future()         # done (True) once the node refused its plant
        self._interface = "unknown"
        self._plant_interface = ""
        self._advertised = False
        self._advertised_checked = -np.inf
        self._scenario_future: Future | None = None
        self._refused_at = 0.0

        publish = self.create_publisher
        self.command_pub = publish(JointState, topics.JOINT_COMMANDS, PUBLISH_QOS)
        self.reference_pub = publish(Float64MultiArray, f"~/{topics.REFERENCE_SUFFIX}", PUBLISH_QOS)
        self.status_pub = publish(Float64MultiArray, f"~/{topics.STATUS_SUFFIX}", PUBLISH_QOS)
        forward = self.controller.values["forward_command_topic"]
        self.forward_pub = publish(Float64MultiArray, forward, PUBLISH_QOS) if forward else None
        # Lockstep: every 250 cycles, wait until the readers (a recorder) acknowledged.
        self._pacer = (ReaderPacer(self, [self.command_pub, self.forward_pub, self.reference_pub,
                                          self.status_pub]) if values["lockstep"] else None)
        # Outgoing messages, built once as CDR bytes and refilled in place every cycle.
        field = "position" if self.controller.command_interface == "position" else "effort"
        self._command = cdr.Writer(cdr.joint_state, name=self.joint_names, **{field: n})
        self._command_out = self._command.array(field)
        self._command_bytes = b""                         # the last command published
        self._forward = cdr.Writer(cdr.float64_multi_array, data=n)
        self._forward_out = self._forward.array("data")
        self._reference = topics.labelled_writer(self.controller.reference_fields)
        self._status = topics.labelled_writer(self.controller.status_fields + topics.NODE_STATUS_FIELDS)
        self._reference_out = self._reference.array("data")
        self._status_out = self._status.array("data")
        self._read_state, self._read_wrench = JointStateReader(), WrenchReader()
        self._read_sensors = ArrayReader()
        self._n_status = len(self.controller.status_fields)
        self.diagnostics = ControllerDiagnostics(self, self.controller, scheme)   # /diagnostics
        self.markers = ControllerMarkers(self, self.controller.reference_fields,   # ~/markers
                                         self.controller.values.get("base_link", "world"))
        # Latched like the recorder's ready flag (READY_QOS: RELIABLE, TRANSIENT_LOCAL, 1).
        self.create_subscription(String, topics.PLANT_COMMAND_INTERFACE,
                                 quiet_on_shutdown(self, self._on_plant_interface), READY_QOS)
        # Made up front (EventsExecutor: see spin.py): the scenario for the refusal message.
        self._plant_parameters = self.create_client(GetParameters, "/plant/get_parameters")
        self._refusal_timer = self.create_timer(0.05, quiet_on_shutdown(self, self._refuse_when_ready),
                                                autostart=False)
        self.create_subscription(WrenchStamped, topics.WRENCH, self._on_wrench, CONTROL_QOS,
                                 raw=True)
        self._sensor_fields = tuple(self.controller.plant_sensor_fields)
        self._sensor_cache: tuple[str, list[int] | None] = ("", None)
        self._sensors_seen = not self._sensor_fields
        if self._sensor_fields:
            self.create_subscription(Float64MultiArray, topics.PLANT_SENSORS,
                                     self._on_plant_sensors, CONTROL_QOS, raw=True)
        self._state_sub = None
        settle = 0.0 if values["lockstep"] else discovery_settle.settle_s()
        if settle > 0:      # module docstring of discovery_settle; a timer made up front
            self._settle_timer = self.create_timer(settle, self._subscribe_once_settled)
            self.get_logger().info(
                f"subscribing to {topics.JOINT_STATES} in {settle:g} s, once every participant "
                f"already on the domain is discovered ({discovery_settle.SETTLE_VARIABLE})")
        else:
            self._subscribe_states()
        self.source_watch = StateSourceWatch(   # one writer matched (module docstring)
            self, lambda: self._state_sub, quiet_on_shutdown(self, self._resubscribe_states),
            lambda: self._source_seen, SOURCE_SILENCE_S)
        if hasattr(self.controller, "set_target_pose"):    # task-space schemes: live targets
            self._base_link = self.controller.values["base_link"]
            self.create_subscription(PoseStamped, f"~/{topics.TARGET_POSE_SUFFIX}",
                                     quiet_on_shutdown(self, self._on_target_pose), TARGET_QOS)
            self.create_subscription(WrenchStamped, f"~/{topics.TARGET_WRENCH_SUFFIX}",
                                     quiet_on_shutdown(self, self._on_target_wrench), TARGET_QOS)
        if hasattr(self.controller, "zero_ft"):            # task-space schemes: a wrist sensor
            self.create_service(Trigger, "~/zero_ft", quiet_on_shutdown(self, self._on_zero_ft))
            self.create_service(Trigger, "~/zero_ft_force",
                                quiet_on_shutdown(self, self._on_zero_ft_force))
        self.get_logger().info(
            f"{scheme}: {len(specs)} parameters, commanding {self.joint_names} "
            f"({self.controller.command_interface})"
            + ("" if values["autostart"] else "; unconfigured until told (autostart false)"))
        if values["autostart"]:
            self.trigger_configure()
            self.trigger_activate()

    # -- lifecycle (module docstring) ---------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Everything the law needs was made and checked at start-up: nothing to do."""
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Answer states from now on, the law started afresh from the current state
        (:meth:`Controller.reset`); the last state seen while inactive is answered at once
        (a lockstep plant is waiting for it)."""
        relative = bool(self.controller.values.get("reference_relative", False))
        self.controller.reset(keep_time=not relative)
        self._last_stamp, self._answered = None, False
        self.active = True
        self.activations += 1
        self.get_logger().info(f"{self.scheme}: active, the law starts from the current state"
                               + (" (its reference restarts here)" if relative else ""))
        held, self._held_state = self._held_state, None
        if held is not None:
            self._on_joint_state(*held)
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop answering states: no command is published while inactive."""
        self.active = False
        self.get_logger().info(f"{self.scheme}: inactive, no command is published")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        return TransitionCallbackReturn.SUCCESS

    # -- parameters -----------------------------------------------------------------
    @staticmethod
    def _check_counts(params) -> SetParametersResult:
        for p in params:
            if p.name in COUNT_PARAMETERS and isinstance(p.value, int) and p.value < 1:
                return SetParametersResult(successful=False, reason=f"{p.name} must be >= 1")
        return SetParametersResult(successful=True)

    def _apply(self, name: str, value) -> None:
        self.controller.set_parameter(name, value)
        if name == "diagnostics_every":
            self._diagnostics_every = value

    # -- the plant's command interface -------------------------------------------------
    def _on_plant_interface(self, msg: String) -> None:
        interface = msg.data
        if interface == self.command_interface:
            if self._interface == "unknown":
                self.get_logger().info(f"the plant takes {INTERFACE_NOUNS[interface]}, "
                                       f"as {self.scheme} commands")
                self._interface = "ok"
                waiting, self._awaiting_interface = self._awaiting_interface, None
                if waiting is not None:
                    self._on_joint_state(*waiting)
            return
        if self._interface == "refused":
            return
        self._interface = "refused"     # from now on no state is answered
        self._plant_interface = interface
        self._refused_at = time.monotonic()
        self._refusal_timer.reset()
        self._refuse_when_ready()

    def _refuse_when_ready(self) -> None:
        """Log the refusal (with the plant's scenario once known, or after SCENARIO_WAIT_S)
        and complete ``refused``: main() then exits with code 1. The plant's parameter
        service is asked as soon as it is discovered (it may come after its interface)."""
        waited = time.monotonic() - self._refused_at
        if self._scenario_future is None and self._plant_parameters.service_is_ready():
            self._scenario_future = self._plant_parameters.call_async(
                GetParameters.Request(names=["scenario"]))
        future = self._scenario_future
        if (future is None or not future.done()) and waited < SCENARIO_WAIT_S:
            return
        self._refusal_timer.cancel()
        scenario = ""
        if future is not None and future.done() and future.result() is not None:
            values = future.result().values
            if values and values[0].string_value:
                scenario = f" (scenario {values[0].string_value})"
        theirs = INTERFACE_NOUNS.get(self._plant_interface, repr(self._plant_interface))
        self.get_logger().error(
            f"{self.scheme} commands {INTERFACE_NOUNS[self.command_interface]} but the plant "
            f"takes {theirs}{scenario}: refusing to drive it")
        if not self.refused.done():
            self.refused.set_result(True)

    def _plant_advertises(self) -> bool:
        """True if a plant advertises its command interface (checked every ADVERTISED_CHECK_S)."""
        now = time.monotonic()
        if now - self._advertised_checked >= ADVERTISED_CHECK_S:
            self._advertised_checked = now
            self._advertised = self.count_publishers(topics.PLANT_COMMAND_INTERFACE) > 0
        return self._advertised

    # -- messages in (serialized: raw subscriptions) ------------------------------------
    def _log_limited(self, key: str, severity: str, message: str) -> None:
        """Log ``message`` at most every LOG_EVERY_S per ``key``. For faults that can come
        with every message: rclpy's logger (its throttle too) reads the caller's frame and
        source file on every call, ~0.5 ms here; this check costs a dict lookup."""
        now = time.monotonic()
        if now - self._logged_at.get(key, -np.inf) < LOG_EVERY_S:
            return
        self._logged_at[key] = now
        if severity == "error":
            self.get_logger().error(message)
        else:
            self.get_logger().warn(message)

    def _unreadable(self, topic: str) -> None:
        self._log_limited(f"unreadable {topic}", "error",
                          f"a message on {topic} could not be read: ignored")

    def _oversized(self, topic: str, size: int, why: str) -> None:
        """Count a message dropped unread for its size; log (rate-limited)."""
        self.inputs_oversized += 1
        self._log_limited(f"oversized {topic}", "error",
                          f"a message of {size} bytes on {topic} ({why}) dropped unread; "
                          "counted in inputs_oversized")

    def _on_wrench(self, data: bytes) -> None:
        if len(data) > WRENCH_MAX_BYTES:
            self._oversized(topics.WRENCH, len(data), f"a WrenchStamped has at most "
                            f"{WRENCH_MAX_BYTES}")
            return
        wrench = self._read_wrench(data)
        if wrench is None:
            self._unreadable(topics.WRENCH)
            return
        fx, fy, fz = wrench.force
        limit = self.controller.values["max_sensor_force"]
        if self._sensor_frame and wrench.frame_id != self._sensor_frame:
            self.sensor_faults += 1
            self._log_limited("sensor frame", "error",
                              f"a wrench in frame {wrench.frame_id!r}, not sensor_frame "
                              f"{self._sensor_frame!r}: ignored (counted in sensor_faults)")
            return
        if fx * fx + fy * fy + fz * fz <= limit * limit:     # False for NaN, inf, overflow
            self.force[:] = wrench.force
            self.wrench[3:] = wrench.torque
            self._wrench_seen = True
            self._sensor_fault = False
            return
        self.sensor_faults += 1
        if not self._sensor_fault:
            self._sensor_fault = True
            self._log_limited("sensor fault", "warn",
                              f"wrench force {list(wrench.force)} N: |f| above max_sensor_force "
                              f"{limit:g} N or not finite: a sensor fault; the last sane force "
                              f"{self.force.tolist()} N stays in use (counted in sensor_faults)")

    @property
    def controller_reads_wrench(self) -> bool:
        """Whether the law takes force and torque (a wrist sensor), else the force alone."""
        return getattr(self.controller, "reads_wrench", False)

    def _on_plant_sensors(self, data: bytes) -> None:
        """The plant's extra measurements the law reads (``plant_sensor_fields``), found by
        label; published just before the joint state they belong to."""
        if len(data) > ARRAY_MAX_BYTES:
            self._oversized(topics.PLANT_SENSORS, len(data), f"at most {ARRAY_MAX_BYTES} read")
            return
        sensors = self._read_sensors(data)
        if sensors is None:
            self._unreadable(topics.PLANT_SENSORS)
            return
        label = sensors.labels[0] if sensors.labels else ""
        if label != self._sensor_cache[0]:
            fields = topics.fields_of(label)
            missing = [f for f in self._sensor_fields if f not in fields]
            index = None if missing else [fields.index(f) for f in self._sensor_fields]
            if missing:
                self.get_logger().error(f"{topics.PLANT_SENSORS} lacks {missing} (it has "
                                        f"{fields[1:]}): {self.scheme} reads them as NaN")
            self._sensor_cache = (label, index)
        index = self._sensor_cache[1]
        values = sensors.data
        if index is not None and len(values) > max(index):
            self.controller.plant_sensors[:] = [values[i] for i in index]
            self._sensors_seen = True

    # -- targets (task-space schemes) ----------------------------------------------------
    def _target_usable(self, topic: str, frame_id: str, values: list[float]) -> bool:
        """A target is used if it is in the base frame (or names none) and finite."""
        if frame_id not in ("", self._base_link):
            self.get_logger().warn(f"~/{topic} in frame {frame_id!r} ignored: targets must be in "
                                   f"{self._base_link!r} (no tf here)", throttle_duration_sec=5.0)
            return False
        if not all(np.isfinite(values)):
            self.get_logger().warn(f"~/{topic} with a non-finite value ignored",
                                   throttle_duration_sec=5.0)
            return False
        return True

    def _on_target_pose(self, msg: PoseStamped) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        position, quaternion = [p.x, p.y, p.z], [o.w, o.x, o.y, o.z]
        if not self._target_usable(topics.TARGET_POSE_SUFFIX, msg.header.frame_id,
                                   position + quaternion):
            return
        if not np.max(np.abs(quaternion)) > 0.0:    # not its norm: 1e-200 squared is 0
            self.get_logger().warn("~/target_pose with a zero quaternion ignored (an "
                                   "orientation of [0, 0, 0, 1] means none)",
                                   throttle_duration_sec=5.0)
            return
        # normalised without overflow, a position beyond the reach moved onto it (logged)
        self.controller.set_target_pose(np.array(position), np.array(quaternion))

    def _on_target_wrench(self, msg: WrenchStamped) -> None:
        f = msg.wrench.force
        force = [f.x, f.y, f.z]
        if self._target_usable(topics.TARGET_WRENCH_SUFFIX, msg.header.frame_id, force):
            self.controller.set_target_wrench(np.array(force))   # above max_target_force: scaled

    def _on_zero_ft(self, request: Trigger.Request, response: Trigger.Response,
                    force: bool = False) -> Trigger.Response:
        """~/zero_ft: start zeroing the wrist sensor (the controller judges whether it can
        and logs its refusals, rate-limited)."""
        if not self._wrench_seen:
            response.success, response.message = self.controller.zero_ft_refused(
                f"no wrench on {topics.WRENCH} yet")
        else:
            response.success, response.message = self.controller.zero_ft(force)
        if response.success:
            self.get_logger().info(f"~/zero_ft{'_force' if force else ''}: {response.message}")
        return response

    def _on_zero_ft_force(self, request: Trigger.Request,
                          response: Trigger.Response) -> Trigger.Response:
        """~/zero_ft_force: zero with the operator vouching the tool touches nothing."""
        return self._on_zero_ft(request, response, force=True)

    def _joint_order(self, names: tuple[str, ...]) -> list[int] | None:
        """Indices of our state joints in a JointState's name list (None if any is missing)."""
        if names != self._index_cache[0]:
            try:
                order = [names.index(n) for n in self.state_joint_names]
            except ValueError:
                order = None
            self._index_cache = (names, order)
        if self._index_cache[1] is None:
            self._log_limited("joints", "error", f"joint state lacks some of "
                              f"{list(self.state_joint_names)}: {list(names)}")
        return self._index_cache[1]

    def _joint_arrays(self, state: JointStateFields) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities in our joint order (empty arrays if unusable: held)."""
        names, position, velocity = state.name, state.position, state.velocity
        n = len(names)
        if len(position) != n or len(velocity) != n:
            return np.empty(0), np.empty(0)
        if names != self.state_joint_names:
            order = self._joint_order(names)
            if order is None:
                return np.empty(0), np.empty(0)
            position, velocity = [position[i] for i in order], [velocity[i] for i in order]
        return np.array(position), np.array(velocity)

    def _subscribe_states(self) -> None:
        """/joint_states with each message's publisher GID (:mod:`sender_aware`), or, where
        rcl cannot be reached, a plain raw subscription that cannot tell publishers apart."""
        callback = quiet_on_shutdown(self, self._on_joint_state)
        if sender_aware.available():
            self._state_sub = sender_aware.subscribe(self, JointState, topics.JOINT_STATES,
                                                     callback, STATE_QOS, self._max_state_bytes)
            return
        self._state_sub = self.create_subscription(JointState, topics.JOINT_STATES, callback,
                                                   CONTROL_QOS, raw=True)
        self.get_logger().warn(f"rcl's take is out of reach here: states of every publisher on "
                               f"{topics.JOINT_STATES} are answered (they cannot be told apart)")

    def _subscribe_once_settled(self) -> None:
        self._settle_timer.cancel()
        self._subscribe_states()

    def _resubscribe_states(self) -> None:
        """Make the state subscription again (its writer left: :mod:`state_source`)."""
        if isinstance(self._state_sub, sender_aware.SenderAwareSubscription):
            self._state_sub.destroy()
        else:
            self.destroy_subscription(self._state_sub)
        self._subscribe_states()

    def _state_refused(self, data: bytes | None, length: int | None) -> bool:
        """True (counted, logged) for a state dropped unread for its size (module docstring):
        longer than ``_max_state_bytes`` (``data`` None: not even copied), or of another
        length than the last state read and saying it has more than ``_max_joints`` names."""
        size = len(data) if data is not None else length or 0
        if data is not None and size <= self._max_state_bytes:
            if size == self._state_size:
                return False
            names = joint_state_names(data)
            if names is None or names <= self._max_joints:
                return False
            why = f"{names} joint names, more than {self._max_joints}"
        else:
            why = f"a JointState of {self._max_joints} joints has at most {self._max_state_bytes}"
        self._oversized(topics.JOINT_STATES, size, why)
        return True

    def _foreign(self, sender: bytes) -> None:
        """Count a state of another publisher than the one followed; warn on the first."""
        self.states_foreign += 1
        if self.states_foreign == 1:
            self.get_logger().warn(
                f"states from another publisher on {topics.JOINT_STATES} (GID {sender.hex()}) "
                f"than the one followed ({self.source.hex()}): ignored, counted in "
                f"states_foreign; another is followed only after {SOURCE_SILENCE_S:g} s without "
                "a state from it")

    def _follow(self, sender: bytes, now: float) -> None:
        """Follow ``sender`` from now on (the first, or one after the followed one's silence)."""
        if self.source is not None:
            self.source_handovers += 1
            self.get_logger().info(
                f"{topics.JOINT_STATES}: no state from the publisher followed ({self.source.hex()}) "
                f"for {now - self._source_seen:.3f} s: following {sender.hex()} from now on")
        self.source = sender

    def _on_joint_state(self, data: bytes | None, sender: bytes | None = None,
                        length: int | None = None) -> None:
        """One state (serialized), from publisher ``sender`` (its GID; None if unknown);
        ``data`` None for a message of ``length`` bytes too long to be copied here."""
        entry = time.perf_counter()
        if (data is None or len(data) != self._state_size) and self._state_refused(data, length):
            return
        new_source = sender is not None and sender != self.source
        if new_source and entry - self._source_seen <= SOURCE_SILENCE_S:
            self._foreign(sender)
            return
        if not self.active and not new_source and self._held_state is not None:
            # Inactive with a state of this source already read (the law's time origin is
            # set): only the newest is answered, at activation, and read then; an inactive
            # node beside the active one costs the loop no deserialisation per cycle.
            self._held_state = (data, sender)
            self._source_seen = entry
            return
        if self._interface != "ok" and (self._interface == "refused" or self._plant_advertises()):
            if self._interface == "unknown" and self._pacer is not None:
                # Lockstep: the plant waits for this state's answer (and republished the
                # state only after lockstep_resend_s): answer it once the interface is known.
                # In real time the next state comes within a cycle anyway.
                self._awaiting_interface = (data, sender)
            return      # refused, or the plant's interface is on its way: no command yet
        state = self._read_state(data)
        if state is None:
            self._unreadable(topics.JOINT_STATES)
            return
        self._state_size = len(data)
        if new_source:
            self._follow(sender, entry)
        self._source_seen = entry
        stamp = (state.sec, state.nanosec)
        if not self.active:
            self.controller.observe(stamp[0] + stamp[1] * 1e-9)   # the law's time origin
            self._held_state = (data, sender)
            return
        if stamp == self._last_stamp and self._answered:
            if self._publishes:
                self.command_pub.publish(self._command_bytes)  # a repeated state: same answer
            return
        if self._pacer is None and getattr(self._state_sub, "newer_queued", False):
            # real time, fallen behind: a newer state of this plant is queued behind this
            # one, and the plant holds a command only for its latest state
            self.states_skipped += 1
            self._log_limited("skipped", "warn", (
                f"fell behind the plant: {self.states_skipped} states so far answered only by "
                "the newest one queued behind them (each skipped state lengthens the law's "
                "next step)"))
            return
        self._last_stamp = stamp
        position, velocity = self._joint_arrays(state)
        if not self._sensors_seen:
            self._log_limited(
                "sensors", "warn",
                f"{self.scheme} reads {list(self._sensor_fields)} from {topics.PLANT_SENSORS} "
                "but none has arrived: those inputs are NaN (the law holds its command, or "
                "uses its fallback where it has one)")
        t = stamp[0] + stamp[1] * 1e-9
        compute_start = time.perf_counter()
        out = self.controller.step(t, position, velocity,
                                   self.wrench if self.controller_reads_wrench else self.force)

        # -- messages out (timed; reported in the next published status) --
        out_start = time.perf_counter()
        self._command.set_stamp(*stamp)
        self._command_out[:] = out.command
        self._command_bytes = self._command.message()
        if self._publishes:     # else the plant's watchdog brakes (module docstring)
            self.command_pub.publish(self._command_bytes)
            if self.forward_pub is not None:
                self._forward_out[:] = out.command
                self.forward_pub.publish(self._forward.message())
        self._answered = True
        # after the command: the plant waits for it, diagnostics and markers do not
        self.diagnostics.cycle(t, out_start - compute_start)
        self.markers.cycle(t, out.reference)
        self._cycle += 1
        if self._cycle >= self._diagnostics_every:
            self._cycle = 0
            reference, status = self._reference_out, self._status_out
            reference[0] = status[0] = t
            reference[1:] = out.reference
            n = self._n_status
            status[1:n] = out.status
            status[n:] = ((compute_start - entry) * 1e6, self._out_time_us,
                          0.0 if self.controller.commanding else 1.0, self.states_foreign,
                          self.source_handovers, self.inputs_oversized, self.sensor_faults)
            self.reference_pub.publish(self._reference.message())
            self.status_pub.publish(self._status.message())
        self._out_time_us = (time.perf_counter() - out_start) * 1e6
        if self._pacer is not None:
            self._pacer.published()


    @property
    def _publishes(self) -> bool:
        """Whether this cycle's output is published: while the law commands, or while the
        controller brakes through the command interface (it gave up and has a brake)."""
        return self.controller.commanding or self.controller.brakes


def main(scheme: str | None = None, args: list[str] | None = None) -> int:
    """Run the controller node of ``scheme`` (first command-line argument if not given).

    Exit code 2 for an unknown scheme, 1 (with one line on stderr) if the node refuses
    to start (a params file that is not YAML, a refused or mistyped value, ...) or refuses
    a plant that takes another command interface (one ERROR line in its log).
    """
    argv = list(sys.argv if args is None else args)
    if scheme is None:
        if len(argv) < 2 or argv[1] not in SCHEMES:
            print(f"usage: controller_node SCHEME [--ros-args ...]; schemes: {sorted(SCHEMES)}",
                  file=sys.stderr)
            return 2
        scheme = argv.pop(1)
    np.seterr(all="ignore")     # Controller.step catches and logs non-finite results
    nodes = start_nodes(scheme, argv, lambda: [ControllerNode(scheme)])
    if nodes is None:
        return 1
    refused = nodes[0].refused
    spin_nodes(nodes, until=refused)
    return 1 if refused.done() and refused.result() is True else 0


def _scheme_main(scheme: str):
    def entry() -> int:
        return main(scheme)

    entry.__doc__ = f"Executable of the {scheme} controller."
    return entry


# One console-script entry per scheme (setup.py): main_<scheme>.
for _scheme in SCHEMES:
    globals()[f"main_{_scheme}"] = _scheme_main(_scheme)

if __name__ == "__main__":
    sys.exit(main())
