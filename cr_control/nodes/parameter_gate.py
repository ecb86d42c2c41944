"""A node's parameter services taken off its control thread (parameter requests
never block the control cycle, whatever their size).

rclpy takes a service request on the executor's thread, holding the GIL, and converts all
of it to Python before any callback can look at it: an 8 MB ``SetParameters`` request
(10^6 values for ``Q_c``) held the controller's only thread for 10-25 ms (measured
2026-11-25, 64 ms of missed commands in the fuzz; 0.14-0.24 s and a safe stop before the
size screen of ros_parameters.py).

:class:`ParameterGate` takes the node's six parameter services (``<node>/set_parameters``,
``.../set_parameters_atomically``, ``get_parameters``, ``describe_parameters``,
``get_parameter_types``, ``list_parameters``) out of the executor and serves them from a
thread of their own:

1. it waits on the services and takes each request through rcl (ctypes, so the GIL is
   released while rmw copies it) into a C request;
2. it reads the request's size from the C struct without converting it
   (:func:`request_bytes`): more than ``MAX_ENTRIES`` parameters or names, or more than
   ``MAX_REQUEST_BYTES`` of names, strings and arrays, is refused there: a set request is
   answered "refused: ... bytes", a get/describe/list request is dropped (its reply has no
   room for a reason), both counted and logged at most once a second;
3. a request within the bounds is converted to Python and handed to the executor's thread
   (a queue it polls every ``ANSWER_PERIOD_S``), which runs the service's own callback
   (rclpy's handler behind the screen of ros_parameters.py, so every value is validated
   and applied on the control thread, between cycles, as before) and sends the answer.

So the control thread never copies or converts more than ``MAX_REQUEST_BYTES`` of a
request; the gate's thread holds the GIL only to read sizes and convert bounded
requests (the process's switch interval is set to ``SWITCH_INTERVAL_S`` so that such work
delays the control thread by at most that).

The C layouts are Jazzy's (rcl_interfaces/msg/detail/*__struct.h, rmw/types.h), checked
against the message's own conversion by test/test_parameter_gate.py.
"""

from __future__ import annotations

import atexit
import ctypes
import sys
import threading
from collections import deque
from collections.abc import Callable
from contextlib import ExitStack, suppress

from rcl_interfaces.msg import ParameterType, SetParametersResult
from rcl_interfaces.srv import (
    DescribeParameters,
    GetParameters,
    GetParameterTypes,
    ListParameters,
    SetParameters,
    SetParametersAtomically,
)
from rclpy.clock import Clock, ClockType
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.service import Service
from rclpy.type_support import check_is_valid_msg_type

from cr_control.core.rate_limited_log import RateLimitedLog, logger_emit

#: Parameters (set) or names (get, describe, types, list prefixes) per request at most;
#: also the elements of one string-array value.
MAX_ENTRIES = 1000
#: Names, strings and array elements of one request at most (bytes): a URDF fits.
MAX_REQUEST_BYTES = 1 << 20
#: The process's GIL switch interval once a gate runs (s; CPython's default is 5 ms).
SWITCH_INTERVAL_S = 0.001
#: The executor's thread answers the requests let through this often (s): a timer, since
#: rclpy's EventsExecutor takes no guard conditions; an idle poll costs a few microseconds.
ANSWER_PERIOD_S = 0.02
#: The gate's thread checks for a stop this often when nothing arrives (ns).
WAIT_NS = 100_000_000
RCL_RET_OK = 0

#: The services of rclpy's ParameterService: suffix -> (type, kind of its request).
SERVICES = {
    "set_parameters": (SetParameters, "parameters"),
    "set_parameters_atomically": (SetParametersAtomically, "parameters"),
    "get_parameters": (GetParameters, "names"),
    "describe_parameters": (DescribeParameters, "names"),
    "get_parameter_types": (GetParameterTypes, "names"),
    "list_parameters": (ListParameters, "names"),
}


class _Sequence(ctypes.Structure):          # rosidl_runtime_c__*__Sequence, __String
    _fields_ = [("data", ctypes.c_void_p), ("size", ctypes.c_size_t),
                ("capacity", ctypes.c_size_t)]


class _ParameterValue(ctypes.Structure):    # rcl_interfaces__msg__ParameterValue
    _fields_ = [("type", ctypes.c_uint8), ("bool_value", ctypes.c_bool),
                ("integer_value", ctypes.c_int64), ("double_value", ctypes.c_double),
                ("string_value", _Sequence), ("byte_array_value", _Sequence),
                ("bool_array_value", _Sequence), ("integer_array_value", _Sequence),
                ("double_array_value", _Sequence), ("string_array_value", _Sequence)]


class _Parameter(ctypes.Structure):         # rcl_interfaces__msg__Parameter
    _fields_ = [("name", _Sequence), ("value", _ParameterValue)]


class _RequestId(ctypes.Structure):         # rmw_request_id_t
    _fields_ = [("writer_guid", ctypes.c_uint8 * 16), ("sequence_number", ctypes.c_int64)]


class _ServiceInfo(ctypes.Structure):       # rmw_service_info_t
    _fields_ = [("source_timestamp", ctypes.c_int64), ("received_timestamp", ctypes.c_int64),
                ("request_id", _RequestId)]


def _string_bytes(sequence: _Sequence) -> int | None:
    """Bytes of a string sequence's strings (None: more than MAX_ENTRIES strings)."""
    if sequence.size > MAX_ENTRIES:
        return None
    if sequence.size == 0:
        return 0
    strings = (_Sequence * sequence.size).from_address(sequence.data)
    return sum(s.size for s in strings) + 8 * sequence.size


def _parameters(address: int):
    """The C Parameters of the request at ``address`` (its first field)."""
    entries = _Sequence.from_address(address)
    return (_Parameter * entries.size).from_address(entries.data) if entries.size else ()


def _parameter_bytes(parameter: _Parameter) -> int | None:
    value = parameter.value
    strings = _string_bytes(value.string_array_value)
    if strings is None:
        return None
    return (parameter.name.size + value.string_value.size + value.byte_array_value.size
            + value.bool_array_value.size + 8 * value.integer_array_value.size
            + 8 * value.double_array_value.size + strings)


def request_bytes(kind: str, address: int) -> int | None:
    """What converting the C request at ``address`` would copy (bytes), read from its
    struct; None if it has more than MAX_ENTRIES entries. ``kind``: "parameters" (its first
    field is a Parameter sequence) or "names" (a string sequence)."""
    entries = _Sequence.from_address(address)
    if kind == "names":
        return _string_bytes(entries)
    if entries.size > MAX_ENTRIES:
        return None
    total = 0
    for parameter in _parameters(address):
        size = _parameter_bytes(parameter)
        if size is None:
            return None
        total += size
    return total


#: The array field of a ParameterValue of each array type (also read by ros_parameters).
ARRAY_FIELDS = {
    ParameterType.PARAMETER_BYTE_ARRAY: "byte_array_value",
    ParameterType.PARAMETER_BOOL_ARRAY: "bool_array_value",
    ParameterType.PARAMETER_INTEGER_ARRAY: "integer_array_value",
    ParameterType.PARAMETER_DOUBLE_ARRAY: "double_array_value",
    ParameterType.PARAMETER_STRING_ARRAY: "string_array_value",
}


def refusals(address: int, size: int | None,
             explain: Callable[[str, int], str | None] | None = None) -> list[str]:
    """One reason per parameter of the SetParameters(Atomically) request at ``address``,
    refused whole (``size`` from :func:`request_bytes`): ``explain(name, elements)``'s
    reason for a parameter it refuses from its name and size (the node's own: unknown
    name, too many values), else the request's size."""
    limit = f"at most {MAX_REQUEST_BYTES} bytes and {MAX_ENTRIES} entries are read"
    what = f"more than {MAX_ENTRIES} entries" if size is None else f"{size} bytes"
    whole = f"a request of {what} refused unread ({limit})"
    if size is None:
        return [whole] * min(_Sequence.from_address(address).size, MAX_ENTRIES)
    reasons = []
    for parameter in _parameters(address):
        name = ctypes.string_at(parameter.name.data, min(parameter.name.size, 256))
        field = ARRAY_FIELDS.get(parameter.value.type)
        count = getattr(parameter.value, field).size if field else 0
        reason = explain(name.decode(errors="replace"), count) if explain else None
        reasons.append(reason or whole)
    return reasons


class _TypeSupport:
    """The C functions of a Python message class (its rosidl capsules)."""

    _pointer = ctypes.pythonapi.PyCapsule_GetPointer
    _pointer.argtypes, _pointer.restype = [ctypes.py_object, ctypes.c_char_p], ctypes.c_void_p

    def __init__(self, msg_class):
        check_is_valid_msg_type(msg_class)          # imports its type support (the capsules)
        get = self._pointer
        self.create = ctypes.CFUNCTYPE(ctypes.c_void_p)(get(msg_class._CREATE_ROS_MESSAGE, None))
        self.destroy = ctypes.CFUNCTYPE(None, ctypes.c_void_p)(get(msg_class._DESTROY_ROS_MESSAGE, None))
        # The conversions touch Python objects: PYFUNCTYPE keeps the GIL.
        self.to_py = ctypes.PYFUNCTYPE(ctypes.py_object, ctypes.c_void_p)(
            get(msg_class._CONVERT_TO_PY, None))
        self.from_py = ctypes.PYFUNCTYPE(ctypes.c_bool, ctypes.py_object, ctypes.c_void_p)(
            get(msg_class._CONVERT_FROM_PY, None))


_rcl: tuple | None = None


def _rcl_functions() -> tuple:
    """(rcl_take_request_with_info, rcl_send_response) of the librcl rclpy loaded."""
    global _rcl
    if _rcl is None:
        rcl = ctypes.CDLL("librcl.so")              # the library rclpy loaded
        take, send = rcl.rcl_take_request_with_info, rcl.rcl_send_response
        take.argtypes = [ctypes.c_void_p, ctypes.POINTER(_ServiceInfo), ctypes.c_void_p]
        send.argtypes = [ctypes.c_void_p, ctypes.POINTER(_RequestId), ctypes.c_void_p]
        take.restype = send.restype = ctypes.c_int
        _rcl = (take, send)
    return _rcl


class _Gated:
    """One parameter service served by the gate."""

    def __init__(self, service: Service, kind: str):
        self.service, self.kind = service, kind
        self.request = _TypeSupport(service.srv_type.Request)
        self.response = _TypeSupport(service.srv_type.Response)


class ParameterGate:
    """Serves ``node``'s parameter services from a thread of its own (module docstring).
    Install with :func:`install` before the node spins (``node.parameter_gate``); stopped
    with the node."""

    def __init__(self, node: Node, gated: list[_Gated],
                 explain: Callable[[str, int], str | None] | None = None):
        self._node, self._gated, self._explain = node, gated, explain
        self._take, self._send = _rcl_functions()
        self._queue: deque = deque()
        # EventsExecutor takes no guard conditions ("Guard conditions not supported"): a
        # timer made now (it picks up no timer made later) polls the queue instead.
        # On the steady clock: a node on simulated time (use_sim_time) answers before its
        # clock runs too.
        self._answer = node.create_timer(ANSWER_PERIOD_S, self._answer_queued,
                                         clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._wake = GuardCondition(None, None, context=node.context)
        self._stopping = False
        #: Requests refused or dropped on their size (logged one line a second at most).
        self.refused = 0
        self._log = RateLimitedLog(logger_emit(node.get_logger()), 1.0)
        self._thread = threading.Thread(target=self._run, name=f"{node.get_name()}_parameters",
                                        daemon=True)
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        self._thread.start()
        # A process that ends without destroying the node: the thread must not be inside
        # rcl_wait while the interpreter finalizes (std::terminate, "Aborted").
        atexit.register(self.stop)

    # -- the gate's thread ---------------------------------------------------------------
    def _run(self) -> None:
        try:
            wait_set = _rclpy.WaitSet(0, 1, 0, 0, len(self._gated), 0, self._node.context.handle)
            while not self._stopping:
                with ExitStack() as held:           # none of them destroyed while waited on
                    held.enter_context(self._node.context.handle)
                    held.enter_context(self._wake.handle)
                    for gated in self._gated:
                        held.enter_context(gated.service.handle)
                    wait_set.clear_entities()
                    for gated in self._gated:
                        wait_set.add_service(gated.service.handle)
                    wait_set.add_guard_condition(self._wake.handle)
                    wait_set.wait(WAIT_NS)
                    ready = set(wait_set.get_ready_entities("service"))
                    for gated in self._gated:
                        if gated.service.handle.pointer in ready and not self._stopping:
                            self._take_all(gated)
        except Exception:  # noqa: BLE001 - a context shut down or a handle destroyed: end
            return

    def _take_all(self, gated: _Gated) -> None:
        info = _ServiceInfo()
        while not self._stopping:
            request = gated.request.create()
            try:
                ret = self._take(gated.service.handle.pointer, ctypes.byref(info), request)
                if ret != RCL_RET_OK:
                    return
                size = request_bytes(gated.kind, request)
                if size is not None and size <= MAX_REQUEST_BYTES:
                    self._queue.append((gated, gated.request.to_py(request), _copy(info.request_id)))
                else:
                    self._refuse(gated, request, info.request_id, size)
            finally:
                gated.request.destroy(request)

    def _refuse(self, gated: _Gated, request: int, request_id: _RequestId, size: int | None) -> None:
        if gated.kind == "parameters":
            reasons = refusals(request, size, self._explain)
        else:
            reasons = [f"a request of {size} bytes refused unread" if size is not None
                       else f"a request of more than {MAX_ENTRIES} names refused unread"]
        reason = reasons[0] if reasons else "an empty request"
        self.refused += 1
        self._log("refused", "warn", lambda: f"{gated.service.srv_name}: {reason} "
                  f"({self.refused} so far)")
        srv_type = gated.service.srv_type
        if srv_type is SetParameters:
            response = SetParameters.Response(results=[
                SetParametersResult(successful=False, reason=text) for text in reasons])
        elif srv_type is SetParametersAtomically:
            response = SetParametersAtomically.Response(
                result=SetParametersResult(successful=False, reason=reason))
        else:
            return                                  # its reply has no room for a reason
        self._respond(gated, response, request_id)

    # -- both threads ------------------------------------------------------------------
    def _respond(self, gated: _Gated, response, request_id: _RequestId) -> None:
        message = gated.response.create()
        try:
            if gated.response.from_py(response, message):
                with gated.service.handle:
                    self._send(gated.service.handle.pointer, ctypes.byref(request_id), message)
        finally:
            gated.response.destroy(message)

    # -- the executor's thread ---------------------------------------------------------
    def _answer_queued(self) -> None:
        """Answer the requests the gate let through: the service's own callback."""
        while self._queue:
            gated, request, request_id = self._queue.popleft()
            response = gated.service.callback(request, gated.service.srv_type.Response())
            self._respond(gated, response, request_id)

    @property
    def services(self) -> list[Service]:
        """The services the gate serves (no longer in ``node.services``)."""
        return [gated.service for gated in self._gated]

    def stop(self) -> None:
        """End the gate's thread and destroy the services it served."""
        if self._stopping:
            return
        self._stopping = True
        with suppress(Exception):                   # the context is already gone
            self._wake.trigger()
        self._thread.join(timeout=2.0)
        atexit.unregister(self.stop)
        for gated in self._gated:
            with suppress(Exception):               # already gone with its context
                gated.service.destroy()
        with suppress(Exception):
            self._wake.destroy()


def _copy(request_id: _RequestId) -> _RequestId:
    copy = _RequestId()
    ctypes.memmove(ctypes.byref(copy), ctypes.byref(request_id), ctypes.sizeof(_RequestId))
    return copy


def install(node: Node, explain: Callable[[str, int], str | None] | None = None
            ) -> ParameterGate | None:
    """Serve ``node``'s parameter services from a gate (None: it has none, e.g. a node
    made with ``start_parameter_services=False``). The node's ``destroy_node`` stops it.
    ``explain(name, elements)``: the node's reason to refuse a parameter from its name and
    size alone, used in the answer to a request refused unread."""
    gated = []
    for service in list(node.services):       # rclpy's ParameterService: "<node>/<suffix>"
        for suffix, (srv_type, kind) in SERVICES.items():
            if service.srv_type is srv_type and service.srv_name == f"{node.get_name()}/{suffix}":
                gated.append(_Gated(service, kind))
                node._services.remove(service)       # the executor no longer takes it
    if not gated:
        return None
    gate = ParameterGate(node, gated, explain)
    node.parameter_gate = gate
    destroy = node.destroy_node

    def destroy_node() -> bool:
        gate.stop()
        return destroy()

    node.destroy_node = destroy_node
    return gate


__all__ = ["ARRAY_FIELDS", "MAX_ENTRIES", "MAX_REQUEST_BYTES", "ParameterGate", "install", "refusals",
           "request_bytes"]
