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

Hot path: the loop's messages are taken and published serialized
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

Command interface: a scheme never drives a plant that takes the other kind of command
(:mod:`cr_control.nodes.plant_interface`: one ERROR line, exit code 1).

Input guards (:mod:`cr_control.supervision.controller_inputs`, counted in the status,
:data:`cr_control.core.topics.NODE_STATUS_FIELDS`): each state, wrench and plant-sensor
message is handed to a :class:`~cr_control.supervision.controller_inputs.ControllerInputs`
(sizes, one state source by rule, lifecycle, the plant's interface, readable, repeated,
newest first, joint order, sensor sanity) and the node acts on its verdict. States are
followed from one publisher only: the first that delivers a valid state and belongs to the
node named by ``state_source`` (``/plant`` by default; ``/joint_state_broadcaster`` on a
ros2_control robot): a silent or forged publisher is never followed
(:mod:`cr_control.supervision.single_source`; refusals in ``states_foreign``, on
/diagnostics and in the log, rate-limited).

Wrist sensor (task-space schemes): the wrench's force and torque (sensor frame)
go to the law, which compensates them (:mod:`cr_control.schemes.blocks.wrist_sensor`);
``~/zero_ft`` (std_srvs/Trigger) starts zeroing the sensor's bias, or refuses with the
reason (no wrench yet, moving, in contact, a zeroing under way, a bias farther than
``zero_ft_max_change`` from the first one); ``~/zero_ft_force`` (std_srvs/Trigger) zeroes
with the operator vouching that the tool touches nothing (no contact or distance checks;
its bias becomes the first one). Refusals are logged at most one line every 5 s, with a
count; every call gets its reason in the response.

A failing law: while :attr:`Controller.commanding` is False (its output failed for more
than ``max_bad_cycles`` cycles in a row, or a failed start check) a scheme with a braking
command publishes that every cycle (a real robot holds the last command forever); a
scheme without one publishes nothing, so the plant's watchdog brakes;
``commands_stopped`` is 1. Deactivated, a scheme with a braking command answers every state
with it (and publishes nothing else) until it is activated again. Brakes go out with
header.frame_id ``brake`` (:data:`cr_control.core.topics.BRAKE_FRAME_ID`): they give way,
and the plant follows another expected controller from its first command (a live switch
is then make before break: the first controller brakes until the second commands).
"""

from __future__ import annotations

import contextlib
import sys
import time

import numpy as np
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.duration import Duration
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from cr_control.core import cdr, topics
from cr_control.core.rate_limited_log import RateLimitedLog, logger_emit
from cr_control.nodes import discovery_settle, sender_aware
from cr_control.nodes.command_out import CommandOut
from cr_control.nodes.diagnostics import ControllerDiagnostics
from cr_control.nodes.lockstep import ReaderPacer
from cr_control.nodes.markers import ControllerMarkers
from cr_control.nodes.plant_interface import PlantInterfaceCheck
from cr_control.nodes.qos import CONTROL_QOS, PUBLISH_QOS, STATE_QOS, TARGET_QOS
from cr_control.nodes.raw_messages import (
    ARRAY_MAX_BYTES,
    MAX_JOINTS,
    WRENCH_MAX_BYTES,
    ArrayReader,
    JointStateReader,
    WrenchReader,
    joint_state_max_bytes,
    joint_state_names,
)
from cr_control.nodes.ros_parameters import ParameterError, declare, police_changes
from cr_control.nodes.spin import RCLError, help_asked, node_usage, quiet_on_shutdown, spin_nodes, start_nodes
from cr_control.nodes.state_source import StateSourceWatch, publisher_node
from cr_control.schemes.registry import SCHEMES, controller_class
from cr_control.supervision.controller_inputs import (
    ANSWER,
    OBSERVE,
    REPEAT,
    SOURCE_SILENCE_S,
    STATE_SOURCE_PARAMETER,
    ControllerInputs,
    Readers,
)
from cr_control.supervision.delay_watch import delay_watch_for
from cr_control.supervision.single_source import SingleSource, expected_names

__all__ = ["SOURCE_SILENCE_S", "ControllerNode", "main", "wait_for_acks"]

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
    """Runs the control scheme ``scheme`` on the loop's topics (module docstring), as a
    managed (lifecycle) node: it answers states only while active."""

    def __init__(self, scheme: str, **kwargs):
        super().__init__(scheme, **kwargs)
        cls = controller_class(scheme)
        given = {name: p.value for name, p in self._parameter_overrides.items()}  # noqa: SLF001
        specs = cls.parameters(given)      # a task-space scheme sizes its gains to the robot
        values = declare(self, specs)
        for name in COUNT_PARAMETERS:
            if values[name] < 1:
                raise ParameterError(f"parameter {name} must be >= 1")
        state_source = declare(self, [STATE_SOURCE_PARAMETER])["state_source"]
        self.controller = cls(values)
        self.controller.warm_up()   # load the compiled kernels now, not in the first cycle
        self.controller.log_warning = self.get_logger().warn   # Controller rate-limits its own
        self.controller.log_error = self.get_logger().error
        self.controller.log_info = self.get_logger().info
        self.add_on_set_parameters_callback(self._check_counts)
        police_changes(self, specs, self._apply, self.controller.check_parameter)
        self.joint_names = list(self.controller.values["joint_names"])        # commanded
        n = len(self.joint_names)
        self._diagnostics_every = values["diagnostics_every"]
        self._cycle = 0
        self._out_time_us = 0.0
        self.activations = 0
        # The input guards (module docstring): sizes, one state source by rule, sanity.
        self.log_limited = RateLimitedLog(logger_emit(self.get_logger()), LOG_EVERY_S)
        max_joints = max(MAX_JOINTS, len(self.controller.state_joint_names))
        readers = Readers(JointStateReader(), WrenchReader(), ArrayReader(), joint_state_names,
                          joint_state_max_bytes(max_joints), max_joints, WRENCH_MAX_BYTES,
                          ARRAY_MAX_BYTES)
        self.state_source = (SingleSource(
            topics.JOINT_STATES, expected_names(state_source), SOURCE_SILENCE_S,
            lambda gid: publisher_node(self, topics.JOINT_STATES, gid), self.log_limited,
            what="states", parameter="state_source", counter="states_foreign")
            if sender_aware.available() else None)
        self.inputs = ControllerInputs(
            readers, self.controller.state_joint_names, self.controller.values,
            self.controller.plant_sensors, self.controller.plant_sensor_fields,
            self.state_source, self.log_limited, bool(values["lockstep"]),
            lambda: self.plant_interface.plant_advertises(), scheme)
        self.scheme = scheme
        self.command_interface = self.controller.command_interface
        # The plant's command interface: "unknown" until the plant says, "ok" or "refused".
        self.plant_interface = PlantInterfaceCheck(self, scheme, self.command_interface,
                                                   self.inputs, self._on_joint_state)
        self.refused = self.plant_interface.refused   # done (True) once the plant is refused

        publish = self.create_publisher
        self.command_pub = publish(JointState, topics.JOINT_COMMANDS, PUBLISH_QOS)
        self.reference_pub = publish(Float64MultiArray, f"~/{topics.REFERENCE_SUFFIX}", PUBLISH_QOS)
        self.status_pub = publish(Float64MultiArray, f"~/{topics.STATUS_SUFFIX}", PUBLISH_QOS)
        forward = self.controller.values["forward_command_topic"]
        self.forward_pub = publish(Float64MultiArray, forward, PUBLISH_QOS) if forward else None
        # Lockstep: every 250 cycles, wait until the readers (a recorder) acknowledged.
        self._pacer = (ReaderPacer(self, [self.command_pub, self.forward_pub, self.reference_pub,
                                          self.status_pub]) if values["lockstep"] else None)
        # Real time: the answers' round trip, checked once against the delay the gains take.
        self._delay_watch = delay_watch_for(self.controller, bool(values["lockstep"]))
        # Outgoing messages, built once as CDR bytes and refilled in place every cycle.
        self.out = CommandOut(self, self.command_pub, self.joint_names,
                              self.controller.command_interface, self._relieved)
        self._law_active = False                          # the lifecycle state "active"
        self._forward = cdr.Writer(cdr.float64_multi_array, data=n)
        self._forward_out = self._forward.array("data")
        self._reference = topics.labelled_writer(self.controller.reference_fields)
        self._status = topics.labelled_writer(self.controller.status_fields + topics.NODE_STATUS_FIELDS)
        self._reference_out = self._reference.array("data")
        self._status_out = self._status.array("data")
        self._n_status = len(self.controller.status_fields)
        self.diagnostics = ControllerDiagnostics(self, self.controller, scheme)   # /diagnostics
        self.markers = ControllerMarkers(self, self.controller.reference_fields,   # ~/markers
                                         self.controller.values.get("base_link", "world"))
        self.create_subscription(WrenchStamped, topics.WRENCH, self.inputs.wrench_message,
                                 CONTROL_QOS, raw=True)
        if self.inputs.sensor_fields:
            self.create_subscription(Float64MultiArray, topics.PLANT_SENSORS,
                                     self.inputs.sensors_message, CONTROL_QOS, raw=True)
        self._state_sub = None
        settle = 0.0 if values["lockstep"] else discovery_settle.settle_s()
        if settle > 0:      # module docstring of discovery_settle; a timer made up front
            self._settle_timer = self.create_timer(settle, self._subscribe_once_settled)
            self.get_logger().info(
                f"subscribing to {topics.JOINT_STATES} in {settle:g} s, once every participant "
                f"already on the domain is discovered ({discovery_settle.SETTLE_VARIABLE})")
        else:
            self._subscribe_states()
        self.source_watch = StateSourceWatch(self, topics.JOINT_STATES, self.state_source,
                                             quiet_on_shutdown(self, self._on_named))
        if self.controller.TASK_SPACE:      # live targets and a wrist sensor to zero
            self._base_link = self.controller.values["base_link"]
            self.create_subscription(PoseStamped, f"~/{topics.TARGET_POSE_SUFFIX}",
                                     quiet_on_shutdown(self, self._on_target_pose), TARGET_QOS)
            self.create_subscription(WrenchStamped, f"~/{topics.TARGET_WRENCH_SUFFIX}",
                                     quiet_on_shutdown(self, self._on_target_wrench), TARGET_QOS)
            self.create_service(Trigger, "~/zero_ft", quiet_on_shutdown(self, self._on_zero_ft))
            self.create_service(Trigger, "~/zero_ft_force",
                                quiet_on_shutdown(self, self._on_zero_ft_force))
        self.get_logger().info(
            f"{scheme}: {len(specs)} parameters, commanding {self.joint_names} "
            f"({self.controller.command_interface}), states from "
            + (", ".join(sorted(expected_names(state_source))) or "the first valid publisher")
            + ("" if values["autostart"] else "; unconfigured until told (autostart false)"))
        if values["autostart"]:
            self.trigger_configure()
            self.trigger_activate()

    # -- lifecycle (module docstring) ---------------------------------------------------
    @property
    def active(self) -> bool:
        """Lifecycle state "active": states are answered by the law."""
        return self._law_active

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Everything the law needs was made and checked at start-up: nothing to do."""
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Answer states from now on, the law started afresh from the current state
        (:meth:`Controller.reset`); the last state seen while inactive is answered at once
        (a lockstep plant is waiting for it)."""
        relative = bool(self.controller.values.get("reference_relative", False))
        self.controller.reset(keep_time=not relative)
        self.activations += 1
        self.out.commanding()
        self._law_active = True
        self.get_logger().info(f"{self.scheme}: active, the law starts from the current state"
                               + (" (its reference restarts here)" if relative else ""))
        held = self.inputs.activate()
        if held is not None:
            self._on_joint_state(*held)
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """The law stops: its brake answers the states from now on, where the scheme has
        one; else no command is published (the plant's watchdog brakes)."""
        self._law_active = False
        braking = self.inputs.active = self.controller.brakes
        self.get_logger().info(f"{self.scheme}: inactive, " + (
            "braking until another controller commands" if braking else "no command is published"))
        if braking:
            self.out.brake_until_relieved()
        return super().on_deactivate(state)

    def _relieved(self) -> None:
        """Another controller commands: the deactivated node reads no more states."""
        self.inputs.active = False

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.inputs.active = self._law_active = self.out.braking = False
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

    # -- targets (task-space schemes) ----------------------------------------------------
    def _on_target_pose(self, msg: PoseStamped) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        position, quaternion = [p.x, p.y, p.z], [o.w, o.x, o.y, o.z]
        if (self.inputs.target_usable(topics.TARGET_POSE_SUFFIX, msg.header.frame_id,
                                      position + quaternion, self._base_link)
                and self.inputs.orientation_usable(quaternion)):
            # normalised without overflow, a position beyond the reach moved onto it (logged)
            self.controller.set_target_pose(np.array(position), np.array(quaternion))

    def _on_target_wrench(self, msg: WrenchStamped) -> None:
        f = msg.wrench.force
        force = [f.x, f.y, f.z]
        if self.inputs.target_usable(topics.TARGET_WRENCH_SUFFIX, msg.header.frame_id, force,
                                     self._base_link):
            self.controller.set_target_wrench(np.array(force))   # above max_target_force: scaled

    def _on_zero_ft(self, request: Trigger.Request, response: Trigger.Response,
                    force: bool = False) -> Trigger.Response:
        """~/zero_ft: start zeroing the wrist sensor (the controller judges whether it can
        and logs its refusals, rate-limited)."""
        if not self.inputs.wrench_seen:
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

    # -- states in ----------------------------------------------------------------------
    def _subscribe_states(self) -> None:
        """/joint_states with each message's publisher GID (:mod:`sender_aware`), or, where
        rcl cannot be reached, a plain raw subscription that cannot tell publishers apart."""
        self._state_sub = sender_aware.subscribe_or_raw(
            self, JointState, topics.JOINT_STATES, quiet_on_shutdown(self, self._on_joint_state),
            STATE_QOS, self.inputs.read.max_state_bytes, CONTROL_QOS,
            "the states of every one are answered")

    def _subscribe_once_settled(self) -> None:
        self._settle_timer.cancel()
        self.get_logger().info(f"subscribing to {topics.JOINT_STATES} now")   # before it exists
        self._subscribe_states()

    def _on_named(self) -> None:
        """The graph named the state publishers: a lockstep state refused before its
        publisher's node was known is judged again (its plant waits for the answer)."""
        held = self.inputs.named()
        if held is not None:
            self._on_joint_state(*held)

    def _on_joint_state(self, data: bytes | None, sender: bytes | None = None,
                        length: int | None = None) -> None:
        """One state (serialized), from publisher ``sender`` (its GID; None if unknown);
        ``data`` None for a message of ``length`` bytes too long to be copied here. The
        guards judge it (:meth:`ControllerInputs.state`); an answered one runs the law."""
        entry = time.perf_counter()
        inputs = self.inputs
        verdict = inputs.state(data, sender, length, entry,
                               getattr(self._state_sub, "newer_queued", False))
        if verdict != ANSWER:
            if verdict == REPEAT and self._publishes:
                self.out.repeat()                              # a repeated state: same answer
            elif verdict == OBSERVE:
                self.controller.observe(inputs.t)              # the law's time origin
            return
        t, stamp = inputs.t, inputs.stamp
        if not self._law_active:           # deactivated: the brake until relieved, nothing else
            brake = self.controller.braking(inputs.position, inputs.velocity)
            if brake is not None:
                self.out.publish(brake, stamp, brake=True)
            return
        compute_start = time.perf_counter()
        out = self.controller.step(t, inputs.position, inputs.velocity,
                                   inputs.wrench if self.controller_reads_wrench else inputs.force)

        # -- messages out (timed; reported in the next published status) --
        out_start = time.perf_counter()
        if self._publishes:     # else the plant's watchdog brakes (module docstring)
            self.out.publish(out.command, stamp, brake=not self.controller.commanding)
            if self.forward_pub is not None:
                self._forward_out[:] = out.command
                self.forward_pub.publish(self._forward.message())
        # after the command: the plant waits for it, diagnostics and markers do not
        if self._delay_watch is not None and not self._delay_watch.done:
            late = self._delay_watch.answered(t, time.time())
            if late is not None:
                self.get_logger().warn(f"{self.scheme}: {late}")
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
                          0.0 if self.controller.commanding else 1.0, inputs.states_foreign,
                          inputs.source_handovers, inputs.inputs_oversized, inputs.sensor_faults,
                          self.controller.gate.age, inputs.wrench_age_ms)
            self.reference_pub.publish(self._reference.message())
            self.status_pub.publish(self._status.message())
        self._out_time_us = (time.perf_counter() - out_start) * 1e6
        if self._pacer is not None:
            self._pacer.published()

    @property
    def controller_reads_wrench(self) -> bool:
        """Whether the law takes force and torque (a wrist sensor), else the force alone."""
        return getattr(self.controller, "reads_wrench", False)

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
        if len(argv) >= 2 and argv[1] in ("-h", "--help"):
            print(f"usage: controller_node SCHEME [--ros-args ...]; schemes: {sorted(SCHEMES)}")
            return 0
        if len(argv) < 2 or argv[1] not in SCHEMES:
            print(f"usage: controller_node SCHEME [--ros-args ...]; schemes: {sorted(SCHEMES)}",
                  file=sys.stderr)
            return 2
        scheme = argv.pop(1)
    if help_asked(argv):
        print(node_usage(scheme, f"The {scheme} controller: answers each state on "
                         f"{topics.JOINT_STATES} with a command on {topics.JOINT_COMMANDS}.",
                         f"config/{scheme}.yaml lists every one with its default, bound and "
                         f"meaning; a robot's: config/robots/ROBOT/{scheme}.yaml."))
        return 0
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
