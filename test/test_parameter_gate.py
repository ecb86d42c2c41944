"""The parameter gate: a node's parameter services are taken off its executor's
thread, requests are sized from their C struct and refused unread beyond the bounds, and
the ones let through are answered by the service's own callback on the executor's thread.

The C layouts the gate reads are checked against the messages' own conversion (the
rosidl capsule that rclpy uses), so a layout that drifted from Jazzy's fails here.
"""

from __future__ import annotations

import threading
import time

import pytest
import rclpy
import rclpy.parameter
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node

from cr_control.nodes import parameter_gate
from cr_control.nodes.parameter_gate import (
    MAX_ENTRIES,
    MAX_REQUEST_BYTES,
    _TypeSupport,
    refusals,
    request_bytes,
)


class _CRequest:
    """A Python request converted to its C struct (the gate's view of it)."""

    def __init__(self, request):
        self.support = _TypeSupport(type(request))
        self.address = self.support.create()
        assert self.support.from_py(request, self.address)

    def __enter__(self) -> int:
        return self.address

    def __exit__(self, *exc) -> None:
        self.support.destroy(self.address)


def _parameter(name: str, **value) -> ParameterMsg:
    return ParameterMsg(name=name, value=ParameterValue(**value))


def test_request_bytes_reads_the_c_struct_as_the_message_says():
    request = SetParameters.Request(parameters=[
        _parameter("Q_c", type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[1.0] * 5),
        _parameter("names", type=ParameterType.PARAMETER_STRING_ARRAY, string_array_value=["a", "bcd"]),
        _parameter("frame", type=ParameterType.PARAMETER_STRING, string_value="xyz"),
        _parameter("k", type=ParameterType.PARAMETER_INTEGER_ARRAY, integer_array_value=[1, 2, 3]),
        _parameter("flags", type=ParameterType.PARAMETER_BOOL_ARRAY, bool_array_value=[True] * 4),
        _parameter("blob", type=ParameterType.PARAMETER_BYTE_ARRAY, byte_array_value=[b"\x01"] * 6),
    ])
    expected = (3 + 8 * 5) + (5 + (1 + 3) + 8 * 2) + (5 + 3) + (1 + 8 * 3) + (5 + 4) + (4 + 6)
    with _CRequest(request) as address:
        assert request_bytes("parameters", address) == expected
        # explain() sees each parameter's name and element count as the node would
        seen = []
        reasons = refusals(address, expected, lambda name, n: seen.append((name, n)) or None)
    assert seen == [("Q_c", 5), ("names", 2), ("frame", 0), ("k", 3), ("flags", 4), ("blob", 6)]
    assert len(reasons) == 6 and all("refused unread" in r for r in reasons)

    names = GetParameters.Request(names=["a", "bb", "ccc"])
    with _CRequest(names) as address:
        assert request_bytes("names", address) == 6 + 8 * 3
    prefixes = ListParameters.Request(prefixes=["x"] * (MAX_ENTRIES + 1), depth=0)
    with _CRequest(prefixes) as address:
        assert request_bytes("names", address) is None      # too many entries: not walked


@pytest.fixture(params=[False, True], ids=["wall_time", "sim_time"])
def gated_node(request):
    """A node with one parameter, its services behind a gate, spun by an EventsExecutor on
    a thread (as spin_nodes does); a client node in the same context. With use_sim_time
    and no /clock, as a lockstep node before its plant runs: the gate answers all the same."""
    context = Context()
    rclpy.init(context=context)
    node = Node("crgate", context=context, parameter_overrides=[
        rclpy.parameter.Parameter("use_sim_time", value=request.param)])
    node.declare_parameter("gain", 1.0)
    callback_threads = []
    for service in node.services:                       # record where callbacks run
        if service.srv_type is SetParameters:
            handle = service.callback

            def on_thread(request, response, handle=handle):
                callback_threads.append(threading.get_ident())
                return handle(request, response)

            service.callback = on_thread
    gate = parameter_gate.install(node)
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    executor_thread = []
    stop = threading.Event()

    def spin() -> None:
        executor_thread.append(threading.get_ident())
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    client_node = Node("crgate_client", context=context)
    client_executor = SingleThreadedExecutor(context=context)
    client_executor.add_node(client_node)
    try:
        yield node, gate, (client_node, client_executor), callback_threads, executor_thread
    finally:
        stop.set()
        spinner.join(timeout=5)
        client_executor.shutdown()
        client_node.destroy_node()
        node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)


def _call(client, srv_type, name: str, request, timeout: float = 10.0):
    """The answer to ``request``, or None if there was none within ``timeout``."""
    client_node, client_executor = client
    service = client_node.create_client(srv_type, name)
    try:
        assert service.wait_for_service(timeout_sec=10.0)
        future = service.call_async(request)
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            client_executor.spin_once(timeout_sec=0.02)
        return future.result() if future.done() else None
    finally:
        client_node.destroy_client(service)


@pytest.mark.ros
def test_the_gate_serves_and_refuses_without_the_executor_taking(gated_node):
    node, gate, client, callback_threads, executor_thread = gated_node
    assert {s.srv_name for s in gate.services} == {
        f"crgate/{suffix}" for suffix in parameter_gate.SERVICES}
    assert not [s for s in node.services if s in gate.services]    # the executor has none

    # within the bounds: answered by the service's own callback, on the executor's thread
    accepted = _call(client, SetParameters, "/crgate/set_parameters", SetParameters.Request(
        parameters=[_parameter("gain", type=ParameterType.PARAMETER_DOUBLE, double_value=2.5)]))
    assert accepted is not None and accepted.results[0].successful
    assert node.get_parameter("gain").value == 2.5
    assert callback_threads == executor_thread                  # applied between cycles
    got = _call(client, GetParameters, "/crgate/get_parameters",
                GetParameters.Request(names=["gain"]))
    assert got is not None and got.values[0].double_value == 2.5

    # beyond them: a set is answered with the reason, never reaching the callback
    huge = SetParameters.Request(parameters=[_parameter(
        "gain", type=ParameterType.PARAMETER_DOUBLE_ARRAY,
        double_array_value=[1.0] * (MAX_REQUEST_BYTES // 8 + 1))])
    refused = _call(client, SetParameters, "/crgate/set_parameters", huge)
    assert refused is not None and not refused.results[0].successful
    assert "refused unread" in refused.results[0].reason
    assert node.get_parameter("gain").value == 2.5 and len(callback_threads) == 1
    # a get with a 2 MB name has no room for a reason: dropped, counted, and the gate serves on
    dropped = _call(client, GetParameters, "/crgate/get_parameters",
                    GetParameters.Request(names=["g" * (2 * MAX_REQUEST_BYTES)]), timeout=1.0)
    assert dropped is None and gate.refused == 2
    again = _call(client, GetParameters, "/crgate/get_parameters",
                  GetParameters.Request(names=["gain"]))
    assert again is not None and again.values[0].double_value == 2.5


@pytest.mark.ros
def test_destroying_the_node_ends_the_gate(gated_node):
    """destroy_node stops the gate's thread first, then destroys the node as rclpy does."""
    node, gate, *_ = gated_node
    assert gate._thread.is_alive()                              # noqa: SLF001
    assert node.destroy_node is not Node.destroy_node.__get__(node)
    gate.stop()
    assert not gate._thread.is_alive()                          # noqa: SLF001
    assert all(s.handle is not None for s in gate.services)
