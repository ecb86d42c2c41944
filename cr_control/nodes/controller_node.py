"""The one generic controller node; each scheme's executable only chooses the scheme.

Subscribes to /joint_states and the force/torque sensor wrench, runs one control cycle
per joint state and publishes on /joint_commands (a JointState with the joint names and
efforts, or positions for command-displacement schemes, stamped with the state's stamp)
and its labelled ~/reference and ~/status (topics.py). Gains are ROS parameters
(config/<scheme>.yaml), live-tunable through the standard parameter services.
"""

from __future__ import annotations

import sys

import numpy as np
import rclpy
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control.core import topics
from cr_control.nodes.qos import CONTROL_QOS
from cr_control.nodes.ros_parameters import ParameterError, declare, police_changes
from cr_control.nodes.spin import spin_nodes
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
        self.controller = cls(declare(self, specs))
        police_changes(self, specs, self.controller.set_parameter)
        self.joint_names = list(self.controller.values["joint_names"])
        self._index_cache: tuple[tuple[str, ...], np.ndarray | None] = ((), None)
        self.force = np.zeros(3)
        self._last_stamp = None
        self._last_command: JointState | None = None

        publish = self.create_publisher
        self.command_pub = publish(JointState, topics.JOINT_COMMANDS, CONTROL_QOS)
        self.reference_pub = publish(Float64MultiArray, f"~/{topics.REFERENCE_SUFFIX}", CONTROL_QOS)
        self.status_pub = publish(Float64MultiArray, f"~/{topics.STATUS_SUFFIX}", CONTROL_QOS)
        forward = self.controller.values["forward_command_topic"]
        self.forward_pub = publish(Float64MultiArray, forward, CONTROL_QOS) if forward else None
        self._reference_msg = topics.labelled_array(
            Float64MultiArray, MultiArrayDimension, self.controller.reference_fields)
        self._status_msg = topics.labelled_array(
            Float64MultiArray, MultiArrayDimension, self.controller.status_fields)
        self.create_subscription(WrenchStamped, topics.WRENCH, self._on_wrench, CONTROL_QOS)
        self.create_subscription(JointState, topics.JOINT_STATES, self._on_joint_state, CONTROL_QOS)
        self.get_logger().info(
            f"{scheme}: {len(specs)} parameters, commanding {self.joint_names} "
            f"({self.controller.command_interface})")

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
                self.get_logger().error(f"joint state lacks some of {self.joint_names}: {names}")
            self._index_cache = (key, order)
        return self._index_cache[1]

    def _on_joint_state(self, msg: JointState) -> None:
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        if stamp == self._last_stamp and self._last_command is not None:
            self.command_pub.publish(self._last_command)  # a repeated state: same answer
            return
        self._last_stamp = stamp
        order = self._joint_order(list(msg.name))
        position, velocity = np.asarray(msg.position), np.asarray(msg.velocity)
        if order is None or len(position) != len(msg.name) or len(velocity) != len(msg.name):
            position = velocity = np.empty(0)  # the controller holds its last command
        else:
            position, velocity = position[order], velocity[order]
        t = stamp_seconds(msg.header.stamp)
        out = self.controller.step(t, position, velocity, self.force)

        command = JointState()
        command.header.stamp = msg.header.stamp
        command.name = self.joint_names
        values = out.command.tolist()
        if self.controller.command_interface == "position":
            command.position = values
        else:
            command.effort = values
        self.command_pub.publish(command)
        self._last_command = command
        if self.forward_pub is not None:
            self.forward_pub.publish(Float64MultiArray(data=values))
        self._reference_msg.data = [t, *out.reference.tolist()]
        self.reference_pub.publish(self._reference_msg)
        self._status_msg.data = [t, *out.status.tolist()]
        self.status_pub.publish(self._status_msg)


def main(scheme: str | None = None, args: list[str] | None = None) -> int:
    """Run the controller node of ``scheme`` (first command-line argument if not given)."""
    argv = list(sys.argv if args is None else args)
    if scheme is None:
        if len(argv) < 2 or argv[1] not in SCHEMES:
            print(f"usage: controller_node SCHEME [--ros-args ...]; schemes: {sorted(SCHEMES)}",
                  file=sys.stderr)
            return 2
        scheme = argv.pop(1)
    rclpy.init(args=argv)
    try:
        node = ControllerNode(scheme)
    except ParameterError as exc:
        print(f"{scheme}: refused to start: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 1
    spin_nodes([node])
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
