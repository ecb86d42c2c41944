"""The control loop's messages taken as bytes: subscriptions made with ``raw=True`` hand
their callbacks the serialized message, read here by :mod:`cr_control.core.cdr` (one
``struct`` call instead of building ROS message objects: ~2 µs instead of ~23 µs per
JointState, ~1.5 µs instead of ~46 µs per WrenchStamped). Bytes that are not plain CDR
(another encapsulation) go through rclpy's own deserialization, so any sender is read.
"""

from __future__ import annotations

from typing import Any, NamedTuple

from geometry_msgs.msg import WrenchStamped
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from cr_control.core import cdr


class JointStateFields(NamedTuple):
    sec: int
    nanosec: int
    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]


class WrenchFields(NamedTuple):
    sec: int
    nanosec: int
    force: tuple[float, float, float]
    torque: tuple[float, float, float]


class ArrayFields(NamedTuple):
    labels: tuple[str, ...]      # the layout's dimension labels
    data: tuple[float, ...]


def _deserialize(data: bytes, msg_type: type) -> Any | None:
    try:
        return deserialize_message(data, msg_type)
    except Exception:  # noqa: BLE001 - rclpy raises several kinds for bytes it cannot read
        return None


class JointStateReader:
    """``reader(data)``: the fields of a serialized sensor_msgs/JointState, or None."""

    def __init__(self) -> None:
        self._cdr = cdr.Reader(cdr.joint_state)

    def __call__(self, data: bytes) -> JointStateFields | None:
        items = self._cdr.read(data)
        if items is not None:
            shape = self._cdr.shape
            s = shape.slices
            return JointStateFields(items[0], items[1], shape.strings["name"], items[s["position"]],
                                    items[s["velocity"]], items[s["effort"]])
        msg = _deserialize(data, JointState)
        if msg is None:
            return None
        stamp = msg.header.stamp
        return JointStateFields(stamp.sec, stamp.nanosec, tuple(msg.name), tuple(msg.position),
                                tuple(msg.velocity), tuple(msg.effort))


class WrenchReader:
    """``reader(data)``: the fields of a serialized geometry_msgs/WrenchStamped, or None."""

    def __init__(self) -> None:
        self._cdr = cdr.Reader(cdr.wrench_stamped)

    def __call__(self, data: bytes) -> WrenchFields | None:
        items = self._cdr.read(data)
        if items is not None:
            start = self._cdr.shape.slices["wrench"].start
            return WrenchFields(items[0], items[1], items[start:start + 3], items[start + 3:start + 6])
        msg = _deserialize(data, WrenchStamped)
        if msg is None:
            return None
        f, t = msg.wrench.force, msg.wrench.torque
        return WrenchFields(msg.header.stamp.sec, msg.header.stamp.nanosec, (f.x, f.y, f.z),
                            (t.x, t.y, t.z))


class ArrayReader:
    """``reader(data)``: labels and data of a serialized std_msgs/Float64MultiArray, or None."""

    def __init__(self) -> None:
        self._cdr = cdr.Reader(cdr.float64_multi_array)

    def __call__(self, data: bytes) -> ArrayFields | None:
        items = self._cdr.read(data)
        if items is not None:
            shape = self._cdr.shape
            return ArrayFields(shape.strings["labels"], items[shape.slices["data"]])
        msg = _deserialize(data, Float64MultiArray)
        if msg is None:
            return None
        return ArrayFields(tuple(d.label for d in msg.layout.dim), tuple(msg.data))
