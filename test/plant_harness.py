"""Drive a PlantNode callback by callback in tests (no spinning, no clock waits): a logger
that keeps every line, a fixture making started nodes in contexts of their own, a tick."""

import os
import time
from unittest import mock

import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from cr_sim import plant_node
from cr_sim.plant_node import PlantNode

PERIOD = 1e-3


class Log:
    """Stands in for the node's logger: keeps every line by level."""

    def __init__(self):
        self.lines: list[tuple[str, str]] = []

    def info(self, message, **_):
        self.lines.append(("info", message))

    def warn(self, message, **_):
        self.lines.append(("warn", message))

    def error(self, message, **_):
        self.lines.append(("error", message))

    def count(self, text: str) -> int:
        return sum(text in message for _, message in self.lines)


@pytest.fixture
def make_node():
    """``make(**parameters)``: a started PlantNode (its logger a :class:`Log`) on this
    test's domain, destroyed at the end of the test."""
    made = []

    def make(**parameters) -> PlantNode:
        context = Context()
        rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
        parameters.setdefault("commander", "")      # the tests' own GIDs: no graph behind them
        node = PlantNode(context=context, parameter_overrides=[
            Parameter(name, value=value) for name, value in parameters.items()])
        node.log = Log()
        node.get_logger = lambda: node.log
        node._started = True
        made.append((node, context))
        return node

    yield make
    for node, context in made:
        node.destroy_node()
        rclpy.shutdown(context=context)


def tick(node: PlantNode, periods: int = 1) -> None:
    """Run the realtime node's tick as if exactly ``periods`` periods of wall time had passed
    since its last: the tick reads a clock of the node's own (the plant node's
    ``time.monotonic`` for this call), which only ticks advance, so a test process
    descheduled between ticks adds no time (the watchdog's wall-time rule, 200 ms, and the
    catch-up's periods see the ticks alone)."""
    last = getattr(node, "_harness_clock", None)
    last = time.monotonic() if last is None else last
    now = last + periods * PERIOD
    node._last_tick, node._harness_clock = last, now
    with mock.patch.object(plant_node.time, "monotonic", lambda: now):
        node._tick()
