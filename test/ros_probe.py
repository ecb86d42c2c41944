"""A test-side ROS participant on a given domain, with bounded waits."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import time
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from cr_control.core import topics
from cr_control.core.ros_env import DomainLock, claim_free_domain

#: Tests take domain ids in 51..100 (sessions 1..50: a test never meets a session).
TEST_FIRST_DOMAIN = 51
TEST_DOMAIN_SPAN = 50

_starts = itertools.count(os.getpid())
#: Domains this test process holds, in the order taken (see release_domains).
_claims: list[DomainLock] = []


def next_domain() -> int:
    """A ROS_DOMAIN_ID (51..100) no other process on this machine holds; this process
    holds it until :func:`release_domains` (conftest: at the end of the test, or of the
    module for module-scoped fixtures) so parallel test runs never meet."""
    lock = claim_free_domain(TEST_FIRST_DOMAIN, TEST_DOMAIN_SPAN,
                             start=TEST_FIRST_DOMAIN + next(_starts) % TEST_DOMAIN_SPAN)
    _claims.append(lock)
    return lock.domain_id


def domains_taken() -> int:
    """How many domains were taken so far (a mark for :func:`release_domains`)."""
    return len(_claims)


def release_domains(mark: int) -> None:
    """Release the domains taken after ``mark``."""
    while len(_claims) > mark:
        _claims.pop().release()


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


def recorded_arrays(mcap, topic: str) -> list[tuple[list[str], list[float]]]:
    """(field names, values) of every labelled array recorded on ``topic`` in ``mcap``."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(m.layout.dim[0].label.split(","), list(m.data))
                for _, _, _, m in reader.iter_decoded_messages(topics=[topic])]


def start_node(cmd: list[str], env: dict[str, str], *ros_args: str) -> subprocess.Popen:
    """A node process (``cmd``, then ``--ros-args`` and ``ros_args`` if any), output captured."""
    args = [*cmd, "--ros-args", *ros_args] if ros_args else cmd
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop_node(proc: subprocess.Popen, sig: int = signal.SIGINT, timeout: float = 15.0) -> tuple[int, str]:
    """Signal ``proc`` (if still running); its exit code and output (killed after ``timeout``)."""
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return proc.returncode, out


def timing_field(msg, name: str) -> float:
    """A field of a labelled timing/status array message, by name."""
    return msg.data[topics.fields_of(msg.layout.dim[0].label).index(name)]
