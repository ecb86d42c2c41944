"""Declare :class:`~cr_control.core.parameters.Param` specs on an rclpy node and police changes.

Modelled on ros2_controllers' generated parameter handling: every parameter declared
with its type, description and read-only flag; values from a params file checked at
start-up (a bad file stops the node with the reason: a refused value, a value of the
wrong type, a parameter the node does not have); live changes through the standard
parameter services validated and refused with a reason, leaving the old value in force.

A parameter request is handled in the executor that runs the control cycle, so it must
cost next to nothing whatever it carries: a value with more elements than its parameter
takes, or a parameter the node does not have, is refused from the request itself, before
rclpy turns it into a Parameter (rclpy 7.1.6 type-checks an array element by element in
Python: 47 ms for 10^6 doubles). Refusals are logged at most every REFUSED_WARN_EVERY_S per
parameter, with the count of the ones in between.
"""

from __future__ import annotations

import difflib
import math
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rcl_interfaces.srv import SetParameters, SetParametersAtomically
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.node import Node
from rclpy.parameter import Parameter

from cr_control.core.parameters import (
    MATRIX_KINDS,
    MAX_VALUES,
    SCALAR_KINDS,
    VECTOR_KINDS,
    Param,
    ParameterError,
    describe,
    size_refusal,
    validate,
)
from cr_control.nodes import parameter_gate

_ROS_TYPES = {
    **dict.fromkeys(SCALAR_KINDS, ParameterType.PARAMETER_DOUBLE),
    **dict.fromkeys(VECTOR_KINDS + MATRIX_KINDS, ParameterType.PARAMETER_DOUBLE_ARRAY),
    "string": ParameterType.PARAMETER_STRING,
    "choice": ParameterType.PARAMETER_STRING,
    "bool": ParameterType.PARAMETER_BOOL,
    "integer": ParameterType.PARAMETER_INTEGER,
    "string_list": ParameterType.PARAMETER_STRING_ARRAY,
}

#: ROS types of list parameters (an empty one needs its type spelt out for rclpy).
_LISTS = (ParameterType.PARAMETER_DOUBLE_ARRAY, ParameterType.PARAMETER_STRING_ARRAY)

#: Parameters every rclpy node declares by itself (and ``qos_overrides.*`` ones).
BUILTIN_PARAMETERS = ("use_sim_time", "start_type_description_service")
_BUILTIN_PREFIX = "qos_overrides."

#: Refused changes of one parameter are logged at most this often (s), as the controller's
#: held cycles (Controller._warn); the count in between is reported.
REFUSED_WARN_EVERY_S = 5.0

def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def coerce(value: Any, ros_type: int) -> Any:
    """Make a value fit a declared type where no information is lost: ``5`` for a
    double, ``[1, 2]`` for a double array. Anything else is returned unchanged."""
    if ros_type == ParameterType.PARAMETER_DOUBLE and _is_int(value):
        return float(value)
    if (ros_type == ParameterType.PARAMETER_DOUBLE_ARRAY and isinstance(value, list | tuple)
            and all(_is_int(v) or isinstance(v, float) for v in value)):
        return [float(v) for v in value]
    return value


def type_name(ros_type: int) -> str:
    """``double array`` for PARAMETER_DOUBLE_ARRAY, and so on."""
    return Parameter.Type(ros_type).name.lower().replace("_", " ")


def unknown_reason(owner: str, given: Iterable[str], known: Iterable[str]) -> str | None:
    """The reason naming every name of ``given`` that ``owner`` does not have (with the
    closest known name as a hint), or None; rclpy's own parameters always count as known."""
    known = set(known) | set(BUILTIN_PARAMETERS)
    unknown = [n for n in given if n not in known and not n.startswith(_BUILTIN_PREFIX)]
    if not unknown:
        return None
    hints = []
    for name in unknown:
        close = difflib.get_close_matches(name, sorted(known), n=1)
        hints.append(f"{name} (did you mean {close[0]}?)" if close else name)
    plural = "s" if len(unknown) > 1 else ""
    return f"unknown parameter{plural} for {owner}: {', '.join(hints)}"


def refuse_unknown(owner: str, given: Iterable[str], known: Iterable[str]) -> None:
    """ParameterError with :func:`unknown_reason` if ``given`` names a parameter ``owner``
    does not have."""
    if (reason := unknown_reason(owner, given, known)) is not None:
        raise ParameterError(reason)


def refuse_undeclared(node: Node) -> None:
    """Call once every parameter is declared: ParameterError if the node was given a
    parameter it does not have (a misspelt name in a params file or a ``-p``), which
    rclpy would otherwise keep unused without a word."""
    # rclpy 7.1.6 has no public accessor for the overrides (params files, -p arguments).
    given = node._parameter_overrides  # noqa: SLF001
    refuse_unknown(node.get_name(), given, node.list_parameters([], 0).names)


def declare(node: Node, specs: Sequence[Param]) -> dict[str, Any]:
    """Declare ``specs`` on ``node``; return their validated, converted values.

    Given values of a compatible type are converted (``150`` for a double). Raises
    ParameterError naming the parameter and the reason if a given value is refused or
    of the wrong type. (Call :func:`refuse_undeclared` after the last ``declare``.)
    """
    values = {}
    overrides = node._parameter_overrides  # noqa: SLF001 - see refuse_undeclared
    for param in specs:
        ros_type = _ROS_TYPES[param.kind]
        given = overrides.get(param.name)
        # rclpy types an empty list as a byte array whatever was declared (rclpy 7.1.6), and
        # rcl's YAML parser hands it NOT_SET (``posture: []`` in a params file, as every
        # session's params.yaml writes it): a list parameter that is, or is given, empty is
        # declared with dynamic typing (``validate`` still refuses anything but numbers).
        empty_default = isinstance(param.ros_default, list) and not param.ros_default
        empty_given = given is not None and (given.type_ == Parameter.Type.NOT_SET or (
            isinstance(given.value, list | tuple) and len(given.value) == 0))
        dynamic = ros_type in _LISTS and (empty_default or empty_given)
        if dynamic and given is not None and given.type_ == Parameter.Type.NOT_SET:
            overrides[param.name] = given = Parameter(param.name, value=[])
        descriptor = ParameterDescriptor(
            name=param.name, type=ros_type, description=describe(param),
            read_only=param.read_only, dynamic_typing=dynamic)
        if given is not None and (fitted := coerce(given.value, ros_type)) is not given.value:
            overrides[param.name] = Parameter(param.name, value=fitted)
        try:
            value = node.declare_parameter(param.name, param.ros_default, descriptor).value
        except InvalidParameterTypeException:
            got = overrides[param.name]
            raise ParameterError(f"parameter {param.name} must be a {type_name(ros_type)}, got "
                                 f"a {type_name(got.type_.value)} ({got.value!r})") from None
        value = list(value) if dynamic and value is not None else value
        ok, reason, converted = validate(param, value)
        if not ok:
            raise ParameterError(f"parameter {param.name}: {reason}")
        values[param.name] = converted
    return values


class Throttle:
    """Log a line per key at most every ``every`` s; the next line logged for that key says
    how many were held back in between."""

    def __init__(self, log: Callable[[str], None], every: float = REFUSED_WARN_EVERY_S):
        self.log = log
        self.every = every
        self._last: dict[str, tuple[float, int]] = {}    # key -> (logged at, held back since)

    def __call__(self, key: str, text: str) -> None:
        now = time.monotonic()
        at, held = self._last.get(key, (-math.inf, 0))
        if now - at < self.every:
            self._last[key] = (at, held + 1)
            return
        self._last[key] = (now, 0)
        self.log(text + (f" ({held} more refused since the last warning)" if held else ""))


def police_changes(node: Node, specs: Sequence[Param], apply: Callable[[str, Any], None],
                   check_change: Callable[[str, Any], str | None] | None = None) -> None:
    """Validate live changes of ``specs`` on ``node`` and hand accepted ones to ``apply``.

    Call it after declaring every parameter: it first refuses parameters given at start
    that the node does not have (:func:`refuse_undeclared`).

    What is refused follows ROS semantics: a ``SetParametersAtomically`` request with
    any refused value is refused whole (nothing applied); a ``SetParameters`` request
    (what ``ros2 param set`` and ``cr_param set`` send) is handled parameter by
    parameter, each with its own result, so in a mixed request the valid values are
    applied and the refused ones keep their old value. The reason is in the service
    response. ``check_change(name, value)`` (optional) refuses a value its spec allows but
    the other current values do not (e.g. gamma_1 > gamma_2), returning the reason; each
    value of a request is checked against the values in force. ``apply`` runs after rclpy
    stored the new values, so a value is in force from the next control cycle on.

    The node's parameter services are served off the control thread, and a request larger
    than parameter_gate.MAX_REQUEST_BYTES is refused unread there (:mod:`parameter_gate`).
    They then screen each request (:func:`_screen_requests`): a
    name the node does not have is refused with a reason naming it (rclpy 7.1.6 answers
    "Invalid access to undeclared parameter(s): []"), and a value with more elements than its
    parameter takes is refused without being read. Refusals are logged through a
    :class:`Throttle` (per parameter; one key for every unknown name).
    """
    refuse_undeclared(node)
    by_name = {p.name: p for p in specs}
    warn = Throttle(node.get_logger().warn)

    def check(params: list[Parameter]) -> SetParametersResult:
        for p in params:
            spec = by_name.get(p.name)
            if spec is None:
                continue
            ok, reason, value = validate(spec, p.value)
            if ok and check_change is not None:
                reason = check_change(p.name, value)
                ok = reason is None
            if not ok:
                warn(p.name, f"refused {p.name}: {reason}")
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def commit(params: list[Parameter]) -> None:
        for p in params:
            if p.name in by_name:
                apply(p.name, validate(by_name[p.name], p.value)[2])
                node.get_logger().info(f"{p.name} set to {p.value!r}")

    def explain(name: str, n: int) -> str | None:
        """Why a value of ``n`` elements for ``name`` is refused from its size and name alone
        (None: let rclpy handle it)."""
        spec = by_name.get(name)
        if spec is None and not node.has_parameter(name):
            owner = node.get_name()
            return (unknown_reason(owner, [name], node.list_parameters([], 0).names)
                    or f"unknown parameter for {owner}: {name}")   # an undeclared qos_overrides.*
        if n <= (MAX_VALUES if spec is None else spec.max_values):
            return None
        return (f"{name} takes at most {MAX_VALUES} values, got {n}" if spec is None
                else size_refusal(spec, n))

    def screen(msg: ParameterMsg) -> str | None:
        """Why ``msg`` is refused from what the request says (None: let rclpy handle it)."""
        field = parameter_gate.ARRAY_FIELDS.get(msg.value.type)
        reason = explain(msg.name, 0 if field is None else len(getattr(msg.value, field)))
        if reason is not None:
            known = msg.name in by_name or node.has_parameter(msg.name)
            warn(msg.name if known else "(unknown)", f"refused {reason}" if not known
                 else f"refused {msg.name}: {reason}")
        return reason

    node.add_on_set_parameters_callback(check)
    node.add_post_set_parameters_callback(commit)
    _screen_requests(node, screen)
    parameter_gate.install(node, explain)   # requests taken and sized off the control thread


def _screen_requests(node: Node, screen: Callable[[ParameterMsg], str | None]) -> None:
    """Put ``screen`` in front of the node's SetParameters and SetParametersAtomically
    services: a parameter it refuses is answered with its reason and never reaches rclpy
    (which converts a whole request before anything else looks at it); the others are handled
    by rclpy as before. No-op for a node started without parameter services."""
    base = node.get_name()      # rclpy's ParameterService names them <node>/set_parameters...
    for service in node.services:
        handle = service.callback
        if service.srv_type is SetParameters and service.srv_name == f"{base}/set_parameters":

            def set_parameters(request, response, handle=handle):
                reasons = [screen(p) for p in request.parameters]
                if not any(reasons):
                    return handle(request, response)
                for p, reason in zip(request.parameters, reasons, strict=True):
                    response.results.append(
                        SetParametersResult(successful=False, reason=reason) if reason else
                        handle(SetParameters.Request(parameters=[p]), SetParameters.Response()).results[0])
                return response

            service.callback = set_parameters
        elif (service.srv_type is SetParametersAtomically
              and service.srv_name == f"{base}/set_parameters_atomically"):

            def set_atomically(request, response, handle=handle):
                for p in request.parameters:
                    if reason := screen(p):
                        response.result = SetParametersResult(successful=False, reason=reason)
                        return response
                return handle(request, response)

            service.callback = set_atomically


__all__ = ["BUILTIN_PARAMETERS", "ParameterError", "Throttle", "coerce", "declare", "police_changes",
           "refuse_undeclared", "refuse_unknown", "type_name", "unknown_reason"]
