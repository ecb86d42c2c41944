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
(``raw=True`` subscriptions, ``publish(bytes)``): joint states, wrenches and plant
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
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from cr_control.core import cdr, topics
from cr_control.nodes.lockstep import ReaderPacer
from cr_control.nodes.qos import CONTROL_QOS, PUBLISH_QOS, READY_QOS, TARGET_QOS
from cr_control.nodes.raw_messages import (
    ArrayReader,
    JointStateFields,
    JointStateReader,
    WrenchReader,
)
from cr_control.nodes.ros_parameters import ParameterError, declare, police_changes
from cr_control.nodes.spin import RCLError, quiet_on_shutdown, spin_nodes, start_nodes
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


def wait_for_acks(node: Node, timeout_s: float = 2.0) -> None:
    """Block until every RELIABLE publisher of ``node`` had its messages acknowledged (each
    waits at most ``timeout_s``): call before a node is destroyed at the end of a run, or
    a recorder misses the last messages still in flight."""
    for publisher in list(node.publishers):
        with contextlib.suppress(RCLError, RuntimeError):
            publisher.wait_for_all_acked(Duration(seconds=timeout_s))


class ControllerNode(Node):
    """Runs the control scheme ``scheme`` on the topic contract of DESIGN.md."""

    def __init__(self, scheme: str, **kwargs):
        super().__init__(scheme, **kwargs)
        cls = controller_class(scheme)
        given = {name: p.value for name, p in self._parameter_overrides.items()}  # noqa: SLF001
        specs = cls.parameters(given)      # a task-space scheme sizes its gains to the robot
        values = declare(self, specs)
        if values["diagnostics_every"] < 1:
            raise ParameterError("parameter diagnostics_every must be >= 1")
        self.controller = cls(values)
        self.controller.warm_up()   # load the compiled kernels now, not in the first cycle
        self.controller.log_warning = self.get_logger().warn   # Controller rate-limits its own
        self.add_on_set_parameters_callback(self._check_counts)
        police_changes(self, specs, self._apply, self.controller.check_parameter)
        self.joint_names = list(self.controller.values["joint_names"])        # commanded
        self.state_joint_names = tuple(self.controller.state_joint_names)     # read
        n = len(self.joint_names)
        self._diagnostics_every = values["diagnostics_every"]
        self._cycle = 0
        self._out_time_us = 0.0
        self._index_cache: tuple[tuple[str, ...], list[int] | None] = ((), None)
        self.force = np.zeros(3)
        self._last_stamp: tuple[int, int] | None = None
        self._answered = False
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
        self.create_subscription(JointState, topics.JOINT_STATES,
                                 quiet_on_shutdown(self, self._on_joint_state), CONTROL_QOS,
                                 raw=True)
        if hasattr(self.controller, "set_target_pose"):    # task-space schemes: live targets
            self._base_link = self.controller.values["base_link"]
            self.create_subscription(PoseStamped, f"~/{topics.TARGET_POSE_SUFFIX}",
                                     quiet_on_shutdown(self, self._on_target_pose), TARGET_QOS)
            self.create_subscription(WrenchStamped, f"~/{topics.TARGET_WRENCH_SUFFIX}",
                                     quiet_on_shutdown(self, self._on_target_wrench), TARGET_QOS)
        self.get_logger().info(
            f"{scheme}: {len(specs)} parameters, commanding {self.joint_names} "
            f"({self.controller.command_interface})")

    # -- parameters -----------------------------------------------------------------
    @staticmethod
    def _check_counts(params) -> SetParametersResult:
        for p in params:
            if p.name == "diagnostics_every" and isinstance(p.value, int) and p.value < 1:
                return SetParametersResult(successful=False, reason="diagnostics_every must be >= 1")
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
            return
        if self._interface == "refused":
            return
        self._interface = "refused"     # from now on no state is answered
        self._plant_interface = interface
        self._refused_at = time.monotonic()
        if self._plant_parameters.service_is_ready():
            self._scenario_future = self._plant_parameters.call_async(
                GetParameters.Request(names=["scenario"]))
        self._refusal_timer.reset()

    def _refuse_when_ready(self) -> None:
        """Log the refusal (with the plant's scenario once known, or after SCENARIO_WAIT_S)
        and complete ``refused``: main() then exits with code 1."""
        future = self._scenario_future
        waited = time.monotonic() - self._refused_at
        if future is not None and not future.done() and waited < SCENARIO_WAIT_S:
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
    def _unreadable(self, topic: str) -> None:
        self.get_logger().error(f"a message on {topic} could not be read: ignored",
                                throttle_duration_sec=5.0)

    def _on_wrench(self, data: bytes) -> None:
        wrench = self._read_wrench(data)
        if wrench is None:
            self._unreadable(topics.WRENCH)
            return
        self.force[:] = wrench.force

    def _on_plant_sensors(self, data: bytes) -> None:
        """The plant's extra measurements the law reads (``plant_sensor_fields``), found by
        label; published just before the joint state they belong to."""
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
        if not np.linalg.norm(quaternion) > 0.0:
            self.get_logger().warn("~/target_pose with a zero quaternion ignored (an "
                                   "orientation of [0, 0, 0, 1] means none)",
                                   throttle_duration_sec=5.0)
            return
        self.controller.set_target_pose(np.array(position), np.array(quaternion))

    def _on_target_wrench(self, msg: WrenchStamped) -> None:
        f = msg.wrench.force
        force = [f.x, f.y, f.z]
        if self._target_usable(topics.TARGET_WRENCH_SUFFIX, msg.header.frame_id, force):
            self.controller.set_target_wrench(np.array(force))

    def _joint_order(self, names: tuple[str, ...]) -> list[int] | None:
        """Indices of our state joints in a JointState's name list (None if any is missing)."""
        if names != self._index_cache[0]:
            try:
                order = [names.index(n) for n in self.state_joint_names]
            except ValueError:
                order = None
            self._index_cache = (names, order)
        if self._index_cache[1] is None:
            self.get_logger().error(f"joint state lacks some of {list(self.state_joint_names)}: "
                                    f"{list(names)}", throttle_duration_sec=5.0)
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

    def _on_joint_state(self, data: bytes) -> None:
        entry = time.perf_counter()
        if self._interface != "ok" and (self._interface == "refused" or self._plant_advertises()):
            return      # refused, or the plant's interface is on its way: no command
        state = self._read_state(data)
        if state is None:
            self._unreadable(topics.JOINT_STATES)
            return
        stamp = (state.sec, state.nanosec)
        if stamp == self._last_stamp and self._answered:
            self.command_pub.publish(self._command_bytes)  # a repeated state: same answer
            return
        self._last_stamp = stamp
        position, velocity = self._joint_arrays(state)
        if not self._sensors_seen:
            self.get_logger().warn(
                f"{self.scheme} reads {list(self._sensor_fields)} from {topics.PLANT_SENSORS} "
                "but none has arrived: those inputs are NaN (the law holds its command, or "
                "uses its fallback where it has one)", throttle_duration_sec=5.0)
        t = stamp[0] + stamp[1] * 1e-9
        compute_start = time.perf_counter()
        out = self.controller.step(t, position, velocity, self.force)

        # -- messages out (timed; reported in the next published status) --
        out_start = time.perf_counter()
        self._command.set_stamp(*stamp)
        self._command_out[:] = out.command
        self._command_bytes = self._command.message()
        self.command_pub.publish(self._command_bytes)
        self._answered = True
        if self.forward_pub is not None:
            self._forward_out[:] = out.command
            self.forward_pub.publish(self._forward.message())
        self._cycle += 1
        if self._cycle >= self._diagnostics_every:
            self._cycle = 0
            reference, status = self._reference_out, self._status_out
            reference[0] = status[0] = t
            reference[1:] = out.reference
            status[1:self._n_status] = out.status
            status[-2] = (compute_start - entry) * 1e6
            status[-1] = self._out_time_us
            self.reference_pub.publish(self._reference.message())
            self.status_pub.publish(self._status.message())
        self._out_time_us = (time.perf_counter() - out_start) * 1e6
        if self._pacer is not None:
            self._pacer.published()


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
