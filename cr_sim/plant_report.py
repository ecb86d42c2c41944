"""The plant node's once-a-second report, off the tick: the publisher count on its topics,
/plant/timing, /diagnostics and a log line.

Done in one callback it cost ~1.5 ms, more than a period, and made the next tick late by a
period every second (measured: 1.45-1.52 ms per call, Panda session). In real time it is
queued as chores, run one at a time in the idle slot after a tick's command has been
answered and stepped ahead (the most expensive piece ~0.4 ms); if no command is stepped
ahead (none arrives, or a safe stop), the tick runs a chore waited on for more than
:data:`CHORE_WAIT_TICKS`. Lockstep and the final report run them at once. Five Panda
sessions each, alternating: ticks more than 1.5 ms apart 87 -> 64 per 10 s (medians),
ticks 9887 -> 9903.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from typing import Any

from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control.core import topics
from cr_sim.loop_stats import SAFE_STOP_REASONS

#: Realtime: a queued chore waits at most this many ticks for an idle slot.
CHORE_WAIT_TICKS = 2


class PlantReport:
    """The report of the plant node ``node`` (its publishers, statistics, supervisor)."""

    def __init__(self, node: Any) -> None:
        self.node = node
        #: Chores queued for the idle slot after a tick's step ahead (real time) ...
        self.chores: deque[Callable[[], None]] = deque()
        #: ... and the tick count when the oldest of them was queued or last ran.
        self.chore_tick = 0
        #: The last /plant/timing message.
        self.message = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                             topics.PLANT_TIMING_FIELDS)

    def publish(self, at_once: bool = False) -> None:
        """The once-a-second report: queued as chores in real time (module docstring), done
        at once in lockstep and ``at_once``."""
        node = self.node
        if not node._started:                                   # noqa: SLF001 - its node
            return
        chores = (self.check_publishers, self.report_timing, self.report_diagnostics,
                  self.log_timing)
        if at_once or node.lockstep:
            for chore in chores:
                chore()
            return
        if not self.chores:
            self.chore_tick = node.supervisor.ticks
        self.chores.extend(chores)

    def run_chore(self) -> None:
        """Run the oldest queued chore, if any."""
        if self.chores:
            self.chores.popleft()()
        self.chore_tick = self.node.supervisor.ticks

    def run_waited_chore(self) -> None:
        """Run the oldest chore if it waited more than CHORE_WAIT_TICKS ticks."""
        if self.chores and self.node.supervisor.ticks - self.chore_tick > CHORE_WAIT_TICKS:
            self.run_chore()

    def check_publishers(self) -> None:
        """Warn once if anyone but the controller commands, or anyone but us publishes states."""
        node = self.node
        commands = node.count_publishers(node.command_sub.topic_name)
        states = node.count_publishers(node.state_pub.topic_name)
        node.stats.command_publishers, node.stats.state_publishers = commands, states
        for topic, count in ((node.command_sub.topic_name, commands),
                             (node.state_pub.topic_name, states)):
            if count > 1:
                node.supervisor.warn_once(topic, lambda count=count, topic=topic: (
                    f"{count} publishers on {topic} (expected 1): another session on "
                    "this ROS_DOMAIN_ID or a rogue node is on the control loop; counted in "
                    f"{topics.PLANT_TIMING}"))

    def report_timing(self) -> None:
        node = self.node
        stamp = node.state_stamp * 1e-9 if node.state_stamp is not None else 0.0
        self.message.data = [stamp, *node.stats.report(time.monotonic())]
        node.timing_pub.publish(self.message)

    def window(self) -> dict[str, float]:
        """The last /plant/timing report's values by name."""
        return dict(zip(topics.PLANT_TIMING_FIELDS, self.message.data, strict=True))

    def report_diagnostics(self) -> None:
        self.node.diagnostics.report(self.window())

    def log_timing(self) -> None:
        node, d = self.node, self.window()
        node.get_logger().info(
            f"t={node.plant.time:.1f} s rate={d['rate_hz']:.0f} Hz "
            f"fresh={100 * d['window_fresh_share']:.2f}% "
            f"round trip p50/p99/max={d['window_age_p50_ms']:.3f}/{d['window_age_p99_ms']:.3f}/"
            f"{d['window_age_max_ms']:.3f} ms step={d['step_time_us']:.0f} us "
            f"publish={d['publish_time_us']:.0f} us"
            + (f" SAFE STOP ({SAFE_STOP_REASONS[node.stats.safe_stop_reason]})"
               if node.safe_stop else ""))
