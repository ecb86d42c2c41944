"""One node's parameters through its standard ``list_parameters``/``get_parameters``
services, polled without blocking (:class:`ParameterFetch`), each value YAML-encoded as
the recorder saves it (metadata records ``parameters/<node>``).
"""

from __future__ import annotations

import time
from typing import Any

import yaml
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.task import Future

#: Give up on a node's parameters after this long.
PARAMETER_TIMEOUT_S = 5.0


def _yaml_value(value: Any) -> str:
    """A parameter value as a one-line YAML string."""
    text = yaml.safe_dump(value, default_flow_style=True, width=1 << 30)
    return text.removesuffix("\n...\n").rstrip("\n")


def _python_value(value: Any) -> Any:
    """A parameter value as plain YAML-serializable Python (arrays become lists)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, bytes | bytearray):
        return list(value)
    if isinstance(value, list | tuple):
        return [_python_value(v) for v in value]
    return value


class ParameterFetch:
    """Gets one node's parameters through its parameter services (polled, non-blocking)."""

    def __init__(self, node: Node, target: str) -> None:
        self.target = target
        self._node = node
        self._list = node.create_client(ListParameters, f"{target}/list_parameters")
        self._get = node.create_client(GetParameters, f"{target}/get_parameters")
        self._list_future: Future | None = None
        self._get_future: Future | None = None
        self._names: list[str] = []
        self._deadline = time.monotonic() + PARAMETER_TIMEOUT_S
        self.result: dict[str, str] | None = None

    def poll(self) -> bool:
        """Advance; True once finished (``result`` is None if it failed)."""
        if self._list_future is None:
            if self._list.service_is_ready():
                self._list_future = self._list.call_async(
                    ListParameters.Request(depth=ListParameters.Request.DEPTH_RECURSIVE))
        elif self._get_future is None:
            if self._list_future.done():
                self._names = list(self._list_future.result().result.names)
                self._get_future = self._get.call_async(
                    GetParameters.Request(names=self._names))
        elif self._get_future.done():
            values = self._get_future.result().values
            self.result = {
                name: _yaml_value(_python_value(parameter_value_to_python(value)))
                for name, value in zip(self._names, values, strict=False)
                if value.type != ParameterType.PARAMETER_NOT_SET
            }
        done = self.result is not None or time.monotonic() > self._deadline
        if done:
            self._node.destroy_client(self._list)
            self._node.destroy_client(self._get)
        return done
