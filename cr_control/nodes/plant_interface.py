"""The controller's check of the plant's command interface.

The plant advertises what it takes on the latched ``/plant/command_interface`` ("effort",
"position" or "velocity"). A scheme that commands the other kind never publishes a command: the
controller logs one ERROR line (``adaptive_impedance commands efforts but the plant takes
positions (scenario dynamic_constraint): refusing to drive it``) and exits with code 1.
While a plant advertises but its value has not arrived yet, states are not answered (a
lockstep plant sends them again); a plant that advertises nothing (another robot, a test
probe) is driven as before. The verdict lives in the node's input guards
(:attr:`ControllerInputs.interface`); this module does the ROS side.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from rcl_interfaces.srv import GetParameters
from rclpy.node import Node
from rclpy.task import Future
from std_msgs.msg import String

from cr_control.core import topics
from cr_control.nodes.qos import READY_QOS
from cr_control.nodes.spin import quiet_on_shutdown
from cr_control.supervision.controller_inputs import ControllerInputs

#: What each command interface sends, for the refusal message.
INTERFACE_NOUNS = {"effort": "efforts", "position": "positions", "velocity": "velocities"}
#: How long a refusing node waits for the plant's scenario name (s) before it exits.
SCENARIO_WAIT_S = 1.0
#: A node with no plant interface yet looks for an advertising plant at most this often (s).
ADVERTISED_CHECK_S = 0.5


class PlantInterfaceCheck:
    """Subscribes to the plant's interface for ``node`` (commanding ``interface`` for
    ``scheme``); tells ``inputs``; ``answer(held)`` answers a state that waited for it;
    ``refused`` is done (True) once the node refused its plant (main() then exits 1)."""

    def __init__(self, node: Node, scheme: str, interface: str, inputs: ControllerInputs,
                 answer: Callable[..., None]) -> None:
        self.node, self.scheme, self.interface = node, scheme, interface
        self.inputs, self.answer = inputs, answer
        self.refused = Future()
        self._plant_interface = ""
        self._advertised = False
        self._advertised_checked = -np.inf
        self._scenario_future: Future | None = None
        self._refused_at = 0.0
        # Latched like the recorder's ready flag (READY_QOS: RELIABLE, TRANSIENT_LOCAL, 1).
        node.create_subscription(String, topics.PLANT_COMMAND_INTERFACE,
                                 quiet_on_shutdown(node, self.on_interface), READY_QOS)
        # Made up front (EventsExecutor: see spin.py): the scenario for the refusal message.
        self._plant_parameters = node.create_client(GetParameters, "/plant/get_parameters")
        self._timer = node.create_timer(0.05, quiet_on_shutdown(node, self._refuse_when_ready),
                                        autostart=False)

    def on_interface(self, msg: String) -> None:
        interface = msg.data
        if interface == self.interface:
            if self.inputs.interface == "unknown":
                self.node.get_logger().info(f"the plant takes {INTERFACE_NOUNS[interface]}, "
                                            f"as {self.scheme} commands")
            waiting = self.inputs.interface_known(True)
            if waiting is not None:
                self.answer(*waiting)
            return
        if self.inputs.interface == "refused":
            return
        self.inputs.interface_known(False)     # from now on no state is answered
        self._plant_interface = interface
        self._refused_at = time.monotonic()
        self._timer.reset()
        self._refuse_when_ready()

    def _refuse_when_ready(self) -> None:
        """Log the refusal (with the plant's scenario once known, or after SCENARIO_WAIT_S)
        and complete ``refused``. The plant's parameter service is asked as soon as it is
        discovered (it may come after its interface)."""
        waited = time.monotonic() - self._refused_at
        if self._scenario_future is None and self._plant_parameters.service_is_ready():
            self._scenario_future = self._plant_parameters.call_async(
                GetParameters.Request(names=["scenario"]))
        future = self._scenario_future
        if (future is None or not future.done()) and waited < SCENARIO_WAIT_S:
            return
        self._timer.cancel()
        scenario = ""
        if future is not None and future.done() and future.result() is not None:
            values = future.result().values
            if values and values[0].string_value:
                scenario = f" (scenario {values[0].string_value})"
        theirs = INTERFACE_NOUNS.get(self._plant_interface, repr(self._plant_interface))
        self.node.get_logger().error(
            f"{self.scheme} commands {INTERFACE_NOUNS[self.interface]} but the plant "
            f"takes {theirs}{scenario}: refusing to drive it")
        if not self.refused.done():
            self.refused.set_result(True)

    def plant_advertises(self) -> bool:
        """True if a plant advertises its command interface (checked every ADVERTISED_CHECK_S)."""
        now = time.monotonic()
        if now - self._advertised_checked >= ADVERTISED_CHECK_S:
            self._advertised_checked = now
            self._advertised = self.node.count_publishers(topics.PLANT_COMMAND_INTERFACE) > 0
        return self._advertised
