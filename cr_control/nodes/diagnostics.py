"""/diagnostics from a node: the rules of :mod:`cr_control.core.diagnostics` as
``diagnostic_msgs/DiagnosticArray`` messages, once a second (what diagnostic_updater does).

:class:`PlantDiagnostics` is fed the plant's per-second /plant/timing figures as they are
published, and publishes at once when a safe stop engages; :class:`ControllerDiagnostics`
counts a controller's cycles (one call per cycle: an append and two stores) and publishes
from a 1 Hz timer of its own.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from cr_control.core import topics
from cr_control.core.diagnostics import ControllerRules, ControllerWindow, PlantRules, Status

#: diagnostic_updater's publisher: RELIABLE, depth 10.
DIAGNOSTICS_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: Seconds between two statuses (diagnostic_updater's default period).
PERIOD_S = 1.0


def to_message(status: Status, stamp) -> DiagnosticArray:
    """One status as a DiagnosticArray stamped ``stamp`` (builtin_interfaces/Time)."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = [DiagnosticStatus(
        level=bytes([status.level]), name=status.name, message=status.message,
        hardware_id=status.hardware_id,
        values=[KeyValue(key=k, value=v) for k, v in status.values.items()])]
    return msg


class _Publisher:
    def __init__(self, node: Node) -> None:
        self.node = node
        self.pub = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, DIAGNOSTICS_QOS)
        self.last: Status | None = None      #: the last status published (tests, logs)

    def publish(self, status: Status) -> None:
        self.last = status
        self.pub.publish(to_message(status, self.node.get_clock().now().to_msg()))


class PlantDiagnostics(_Publisher):
    """The plant's status, published with each /plant/timing report."""

    def __init__(self, node: Node, hardware_id: str, rate_hz: float, realtime: bool,
                 safe_stop_reasons: Mapping[int, str]) -> None:
        super().__init__(node)
        self.rules = PlantRules(f"{node.get_name()}: loop", hardware_id, rate_hz, realtime,
                                safe_stop_reasons)

        self.figures: dict[str, float] | None = None     #: the last timing report's

    def report(self, figures: Mapping[str, float]) -> None:
        """Judge one timing report (field -> value) and publish the status."""
        self.figures = dict(figures)
        self.publish(self.rules.status(figures))

    def safe_stop(self, reason: int) -> None:
        """A safe stop was just engaged: publish ERROR now (diagnostic_updater's
        force_update), with the last report's figures and ``reason``; nothing before the
        first report."""
        if self.figures is not None:
            self.publish(self.rules.status({**self.figures, "safe_stop": 1.0,
                                            "safe_stop_reason": float(reason)}))


class ControllerDiagnostics(_Publisher):
    """A controller's status, published by a 1 Hz timer from what :meth:`cycle` counted.

    ``controller``: the :class:`cr_control.schemes.controller.Controller` (held, restored
    and stop counts, ``commanding``); ``guards``: the node (its input-guard counts)."""

    def __init__(self, node: Node, controller, hardware_id: str) -> None:
        super().__init__(node)
        self.controller = controller
        self.rules = ControllerRules(f"{node.get_name()}: control loop", hardware_id)
        self.compute_s: list[float] = []
        self._first = self._last = math.nan
        self._seen = False
        self.timer = node.create_timer(PERIOD_S, self.tick)

    def cycle(self, stamp: float, compute_s: float) -> None:
        """Count one answered state (its stamp, s) and its compute time (s). Hot path."""
        if not self.compute_s:              # the window's first state
            self._first = stamp
        self.compute_s.append(compute_s)
        self._last = stamp

    def tick(self) -> None:
        """Publish the window's status and start a new window."""
        times, self.compute_s = self.compute_s, []
        n = len(times)
        period = (self._last - self._first) / (n - 1) if n > 1 else math.nan
        self._first = self._last = math.nan
        self._seen = self._seen or n > 0
        c, node = self.controller, self.node
        self.publish(self.rules.status(ControllerWindow(
            cycles=n, compute_s=times, period_s=period, held_cycles=c.held_cycles,
            restored_cycles=c.restored_cycles, commanding=c.commanding, stops=c.stops,
            states_foreign=node.inputs.states_foreign, inputs_oversized=node.inputs.inputs_oversized,
            sensor_faults=node.inputs.sensor_faults, states_seen=self._seen,
            active=getattr(node, "active", True),
            unfollowed_publishers=node.source_watch.unfollowed)))
