"""Declare :class:`~cr_control.core.parameters.Param` specs on an rclpy node and police changes.

Modelled on ros2_controllers' generated parameter handling: every parameter declared
with its type, description and read-only flag; values from a params file checked at
start-up (a bad file stops the node with the reason); live changes through the standard
parameter services validated and refused with a reason, leaving the old value in force.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from cr_control.core.parameters import (
    MATRIX_KINDS,
    SCALAR_KINDS,
    VECTOR_KINDS,
    Param,
    ParameterError,
    validate,
)

_ROS_TYPES = {
    **dict.fromkeys(SCALAR_KINDS, ParameterType.PARAMETER_DOUBLE),
    **dict.fromkeys(VECTOR_KINDS + MATRIX_KINDS, ParameterType.PARAMETER_DOUBLE_ARRAY),
    "string": ParameterType.PARAMETER_STRING,
    "choice": ParameterType.PARAMETER_STRING,
    "bool": ParameterType.PARAMETER_BOOL,
    "integer": ParameterType.PARAMETER_INTEGER,
    "string_list": ParameterType.PARAMETER_STRING_ARRAY,
}


def _description(param: Param) -> str:
    text = param.description
    if param.kind in MATRIX_KINDS:
        text += f" {param.size} values (diagonal) or {param.size ** 2} (full, row-major)."
    if param.choices:
        text += f" One of {list(param.choices)}."
    return text


def declare(node: Node, specs: Sequence[Param]) -> dict[str, Any]:
    """Declare ``specs`` on ``node``; return their validated, converted values.

    Raises ParameterError naming the parameter and the reason if a given value is refused.
    """
    values = {}
    for param in specs:
        descriptor = ParameterDescriptor(
            name=param.name, type=_ROS_TYPES[param.kind], description=_description(param),
            read_only=param.read_only)
        value = node.declare_parameter(param.name, param.ros_default, descriptor).value
        ok, reason, converted = validate(param, value)
        if not ok:
            raise ParameterError(f"parameter {param.name}: {reason}")
        values[param.name] = converted
    return values


def police_changes(node: Node, specs: Sequence[Param], apply: Callable[[str, Any], None]) -> None:
    """Validate live changes of ``specs`` on ``node`` and hand accepted ones to ``apply``.

    A change set with any refused value is refused whole (nothing applied), with the
    reason in the service response. ``apply`` runs after rclpy stored the new values,
    so the value is in force from the next control cycle on.
    """
    by_name = {p.name: p for p in specs}

    def check(params: list[Parameter]) -> SetParametersResult:
        for p in params:
            spec = by_name.get(p.name)
            if spec is None:
                continue
            ok, reason, _ = validate(spec, p.value)
            if not ok:
                node.get_logger().warn(f"refused {p.name}: {reason}")
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def commit(params: list[Parameter]) -> None:
        for p in params:
            if p.name in by_name:
                apply(p.name, validate(by_name[p.name], p.value)[2])
                node.get_logger().info(f"{p.name} set to {p.value!r}")

    node.add_on_set_parameters_callback(check)
    node.add_post_set_parameters_callback(commit)


__all__ = ["ParameterError", "declare", "police_changes"]
