"""Spinning nodes the way these machines hold 1 kHz: rclpy's EventsExecutor.

(SingleThreadedExecutor costs ~5x the CPU with 20-30 ms garbage-collector stalls;
MultiThreadedExecutor runs at 5-10 Hz, ros2/rclpy#1452.)
"""

from __future__ import annotations

import gc
from collections.abc import Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.task import Future


def spin_nodes(nodes: Sequence[Node], until: Future | None = None) -> None:
    """Spin ``nodes`` on one EventsExecutor until Ctrl-C, shutdown or ``until`` completes."""
    # Long-lived nodes allocate little garbage that cycles; keep the collector from
    # stalling the loop by freezing start-up objects out of its generations.
    gc.collect()
    gc.freeze()
    executor = EventsExecutor()
    for node in nodes:
        executor.add_node(node)
    until = Future() if until is None else until
    try:
        # Without a timeout, EventsExecutor's spin() and spin_until_future_complete()
        # never deliver anything here (rclpy 7.1.6): wait in bounded slices instead.
        while rclpy.ok() and not until.done():
            executor.spin_until_future_complete(until, timeout_sec=1.0)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
