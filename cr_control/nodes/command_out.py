"""What a controller node sends on /joint_commands: the law's command, or its brake.

Messages are built once as CDR bytes and refilled in place (:class:`cr_control.core.cdr.Writer`),
stamped as the state they answer. A brake (the law gave up, or the node was deactivated)
goes out with ``header.frame_id`` :data:`~cr_control.core.topics.BRAKE_FRAME_ID`: it gives
way, and the plant follows another expected controller from that one's first command.

Deactivated (:meth:`CommandOut.brake_until_relieved`), a node with a brake answers every
state with it, as a real robot holds the last command it got forever (a
forward_command_controller, ros2_controllers #95), until a command that is no brake
appears on /joint_commands after its first brake: another controller has taken over, and
the node falls silent. (Not before that brake: the plant still follows this node, whose
last command was its law's, and refuses the other's; fallen silent then, it would leave
the plant waiting, in lockstep, for an answer nobody it follows sends.) Only while
deactivated does the node read /joint_commands (a subscription made at deactivation,
dropped at activation): while it commands, the loop's commands are no input of its.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from rclpy.node import Node
from rclpy.publisher import Publisher
from sensor_msgs.msg import JointState

from cr_control.core import cdr, topics
from cr_control.nodes.qos import CONTROL_QOS
from cr_control.nodes.raw_messages import joint_state_frame_id


class CommandOut:
    """The node's /joint_commands messages (module docstring)."""

    def __init__(self, node: Node, publisher: Publisher, joint_names: Sequence[str],
                 interface: str, relieved: Callable[[], None] = lambda: None) -> None:
        field = interface if interface in ("position", "velocity") else "effort"
        n = len(joint_names)
        self.node, self.publisher, self.relieved = node, publisher, relieved
        self._command = cdr.Writer(cdr.joint_state, name=list(joint_names), **{field: n})
        self._brake = cdr.Writer(cdr.joint_state, frame_id=topics.BRAKE_FRAME_ID,
                                 name=list(joint_names), **{field: n})
        self._values = {False: self._command.array(field), True: self._brake.array(field)}
        #: The last message published (a repeated state is answered with it again).
        self.last = b""
        #: Deactivated and braking until another controller commands.
        self.braking = False
        #: A brake has gone out since the deactivation.
        self.braked = False
        self._watch = None

    def publish(self, values: np.ndarray, stamp: tuple[int, int], brake: bool = False) -> None:
        """Publish ``values`` as the command (or, ``brake``, the brake) answering ``stamp``."""
        message = self._brake if brake else self._command
        self.braked = self.braked or (brake and self.braking)
        self._values[brake][:] = values
        message.set_stamp(*stamp)
        self.last = message.message()
        self.publisher.publish(self.last)

    def repeat(self) -> None:
        self.publisher.publish(self.last)

    def brake_until_relieved(self) -> None:
        """Deactivated: brake until a command that is no brake appears (module docstring)."""
        self.braking, self.braked = True, False
        self._watch = self.node.create_subscription(
            JointState, topics.JOINT_COMMANDS, self.seen, CONTROL_QOS, raw=True)

    def seen(self, data: bytes) -> None:
        """A message on /joint_commands while braking: another controller's command, once
        this node's brake has gone out, ends it."""
        other = joint_state_frame_id(data) not in (topics.BRAKE_FRAME_ID, None)
        if self.braking and self.braked and other:
            self.braking = False
            self.node.get_logger().info("another controller commands: brake released")
            self.relieved()

    def commanding(self) -> None:
        """Activated: the law's commands, /joint_commands no longer read."""
        self.braking = False
        if self._watch is not None:
            self.node.destroy_subscription(self._watch)
            self._watch = None
