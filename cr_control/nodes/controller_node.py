"""The one generic controller node; each scheme's executable only chooses the scheme.

Subscribes to /joint_states and the force/torque sensor wrench, runs one control cycle
per joint state and publishes on /joint_commands (a JointState with the joint names and
efforts, or positions for command-displacement schemes, stamped with the state's stamp)
and its labelled ~/reference and ~/status (topics.py) every ``diagnostics_every``
cycles. Gains are ROS parameters (config/<scheme>.yaml), live-tunable through the
standard parameter services.

Hot path (issue 6): outgoing messages are built once and refilled in place (numpy
views onto the messages' own ``array.array`` fields: no message construction, no
per-element conversion); incoming arrays are read without copies. The status carries where a cycle's
time goes: ``in_time_us`` (callback entry to compute start), ``compute_time_us`` and
``out_time_us`` (building and publishing the previous cycle's messages). numpy's
floating-point warnings are off in the node process: :meth:`Controller.step` catches
non-finite results itself and logs them, rate-limited.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control.core import topics
from cr_control.nodes.qos import CONTROL_QOS, PUBLISH_QOS
from cr_control.nodes.ros_parameters import ParameterError, declare, police_changes
from cr_control.nodes.spin import quiet_on_shutdown, spin_nodes, start_nodes
from cr_control.schemes.registry import SCHEMES, controller_class


def stamp_seconds(stamp) -> float:
    """A builtin_interfaces/Time as float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


class ControllerNode(Node):
    """Runs the control scheme ``scheme`` on the topic contract of DESIGN.md."""

    def __init__(self, scheme: str, **kwargs):
        super().__init__(scheme, **kwargs)
        cls = controller_class(scheme)
        specs = cls.parameters()
        values = declare(self, specs)
        if values["diagnostics_every"] < 1:
            raise ParameterError("parameter diagnostics_every must be >= 1")
        self.controller = cls(values)
        self.controller.warm_up()   # load the compiled kernels now, not in the first cycle
        self.controller.log_warning = self.get_logger().warn   # Controller rate-limits its own
        self.add_on_set_parameters_callback(self._check_counts)
        police_changes(self, specs, self._apply)
        self.joint_names = list(self.controller.values["joint_names"])
        n = len(self.joint_names)
        self._diagnostics_every = values["diagnostics_every"]
        self._cycle = 0
        self._out_time_us = 0.0
        self._index_cache: tuple[tuple[str, ...], np.ndarray | None] = ((), None)
        self.force = np.zeros(3)
        self._last_stamp: tuple[int, int] | None = None
        self._answered = False

        publish = self.create_publisher
        self.command_pub = publish(JointState, topics.JOINT_COMMANDS, PUBLISH_QOS)
        self.reference_pub = publish(Float64MultiArray, f"~/{topics.REFERENCE_SUFFIX}", PUBLISH_QOS)
        self.status_pub = publish(Float64MultiArray, f"~/{topics.STATUS_SUFFIX}", PUBLISH_QOS)
        forward = self.controller.values["forward_command_topic"]
        self.forward_pub = publish(Float64MultiArray, forward, PUBLISH_QOS) if forward else None
        # Outgoing messages, built once and refilled in place every cycle.
        self._command_msg = JointState(name=list(self.joint_names))
        field = "position" if self.controller.command_interface == "position" else "effort"
        self._command_out = topics.array_field(self._command_msg, field, n)
        self._forward_msg = Float64MultiArray()
        self._forward_out = topics.array_field(self._forward_msg, "data", n)
        reference_fields = self.controller.reference_fields
        status_fields = self.controller.status_fields + topics.NODE_STATUS_FIELDS
        self._reference_msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                                    reference_fields)
        self._status_msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension, status_fields)
        self._reference_out = topics.array_field(self._reference_msg, "data", len(reference_fields))
        self._status_out = topics.array_field(self._status_msg, "data", len(status_fields))
        self._n_status = len(self.controller.status_fields)
        self.create_subscription(WrenchStamped, topics.WRENCH, self._on_wrench, CONTROL_QOS)
        self.create_subscription(JointState, topics.JOINT_STATES,
                                 quiet_on_shutdown(self, self._on_joint_state), CONTROL_QOS)
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

    # -- messages in ------------------------------------------------------------------
    def _on_wrench(self, msg: WrenchStamped) -> None:
        f = msg.wrench.force
        self.force[:] = (f.x, f.y, f.z)

    def _joint_order(self, names: list[str]) -> np.ndarray | None:
        """Indices of our joints in a JointState's name list (None if any is missing)."""
        key = tuple(names)
        if key != self._index_cache[0]:
            try:
                order = np.array([names.index(n) for n in self.joint_names])
            except ValueError:
                order = None
            self._index_cache = (key, order)
        if self._index_cache[1] is None:
            self.get_logger().error(f"joint state lacks some of {self.joint_names}: {names}",
                                    throttle_duration_sec=5.0)
        return self._index_cache[1]

    def _joint_arrays(self, msg: JointState) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities in our joint order (empty arrays if unusable: held)."""
        names, position, velocity = msg.name, msg.position, msg.velocity
        n = len(names)
        if len(position) != n or len(velocity) != n:
            return np.empty(0), np.empty(0)
        position = np.frombuffer(position, dtype=np.float64)    # rclpy gives array.array: no copy
        velocity = np.frombuffer(velocity, dtype=np.float64)
        if names == self.joint_names:
            return position, velocity
        order = self._joint_order(names)
        if order is None:
            return np.empty(0), np.empty(0)
        return position[order], velocity[order]

    def _on_joint_state(self, msg: JointState) -> None:
        entry = time.perf_counter()
        header_stamp = msg.header.stamp
        stamp = (header_stamp.sec, header_stamp.nanosec)
        if stamp == self._last_stamp and self._answered:
            self.command_pub.publish(self._command_msg)  # a repeated state: same answer
            return
        self._last_stamp = stamp
        position, velocity = self._joint_arrays(msg)
        t = stamp[0] + stamp[1] * 1e-9
        compute_start = time.perf_counter()
        out = self.controller.step(t, position, velocity, self.force)

        # -- messages out (timed; reported in the next published status) --
        out_start = time.perf_counter()
        command = self._command_msg
        command.header.stamp.sec, command.header.stamp.nanosec = stamp
        self._command_out[:] = out.command
        self.command_pub.publish(command)
        self._answered = True
        if self.forward_pub is not None:
            self._forward_out[:] = out.command
            self.forward_pub.publish(self._forward_msg)
        self._cycle += 1
        if self._cycle >= self._diagnostics_every:
            self._cycle = 0
            reference, status = self._reference_out, self._status_out
            reference[0] = status[0] = t
            reference[1:] = out.reference
            status[1:self._n_status] = out.status
            status[-2] = (compute_start - entry) * 1e6
            status[-1] = self._out_time_us
            self.reference_pub.publish(self._reference_msg)
            self.status_pub.publish(self._status_msg)
        self._out_time_us = (time.perf_counter() - out_start) * 1e6


def main(scheme: str | None = None, args: list[str] | None = None) -> int:
    """Run the controller node of ``scheme`` (first command-line argument if not given).

    Exit code 2 for an unknown scheme, 1 (with one line on stderr) if the node refuses
    to start (a params file that is not YAML, a refused or mistyped value, ...).
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
    spin_nodes(nodes)
    return 0


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
