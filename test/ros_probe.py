"""A test-side ROS participant on a given domain, with bounded waits."""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

_domains = (51 + i % 50 for i in itertools.count(os.getpid()))


def next_domain() -> int:
    """A ROS_DOMAIN_ID for one test (51..100, pid-offset so parallel runs rarely meet)."""
    return next(_domains)


class RosProbe:
    """One node in its own context on ``domain_id`` (localhost discovery from conftest)."""

    def __init__(self, domain_id: int, name: str = "test_probe"):
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, done: Callable[[], bool], timeout: float = 20.0) -> bool:
        """Spin until ``done()`` or ``timeout`` seconds; True if done."""
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def call(self, srv_type, name: str, request, timeout: float = 20.0):
        """Call a service, waiting for it to appear; the response (AssertionError on timeout)."""
        client = self.node.create_client(srv_type, name)
        assert self.spin_until(client.service_is_ready, timeout), f"service {name} never appeared"
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), f"no answer from {name}"
        self.node.destroy_client(client)
        return future.result()

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
