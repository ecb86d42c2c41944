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


class _RawReader:
    """``reader(data)``: the fields of a serialized message of ``msg_type``, or None. Plain
    CDR is read by ``schema`` (:mod:`cr_control.core.cdr`); other bytes by rclpy."""

    schema: cdr.Schema
    msg_type: type

    def __init__(self) -> None:
        self._cdr = cdr.Reader(type(self).schema)

    def __call__(self, data: bytes) -> Any | None:
        items = self._cdr.read(data)
        if items is not None:
            return self._from_items(items, self._cdr.shape)
        try:
            msg = deserialize_message(data, self.msg_type)
        except Exception:  # noqa: BLE001 - rclpy raises several kinds for bytes it cannot read
            return None
        return self._from_message(msg)

    def _from_items(self, items: tuple, shape: cdr.Shape) -> Any:
        raise NotImplementedError

    def _from_message(self, msg: Any) -> Any:
        raise NotImplementedError


class JointStateReader(_RawReader):
    """The fields of a serialized sensor_msgs/JointState."""

    schema, msg_type = cdr.joint_state, JointState

    def _from_items(self, items: tuple, shape: cdr.Shape) -> JointStateFields:
        s = shape.slices
        return JointStateFields(items[0], items[1], shape.strings["name"], items[s["position"]],
                                items[s["velocity"]], items[s["effort"]])

    def _from_message(self, msg: JointState) -> JointStateFields:
        stamp = msg.header.stamp
        return JointStateFields(stamp.sec, stamp.nanosec, tuple(msg.name), tuple(msg.position),
                                tuple(msg.velocity), tuple(msg.effort))


class WrenchReader(_RawReader):
    """The fields of a serialized geometry_msgs/WrenchStamped."""

    schema, msg_type = cdr.wrench_stamped, WrenchStamped

    def _from_items(self, items: tuple, shape: cdr.Shape) -> WrenchFields:
        start = shape.slices["wrench"].start
        return WrenchFields(items[0], items[1], items[start:start + 3], items[start + 3:start + 6])

    def _from_message(self, msg: WrenchStamped) -> WrenchFields:
        f, t = msg.wrench.force, msg.wrench.torque
        return WrenchFields(msg.header.stamp.sec, msg.header.stamp.nanosec, (f.x, f.y, f.z),
                            (t.x, t.y, t.z))


class ArrayReader(_RawReader):
    """Labels and data of a serialized std_msgs/Float64MultiArray."""

    schema, msg_type = cdr.float64_multi_array, Float64MultiArray

    def _from_items(self, items: tuple, shape: cdr.Shape) -> ArrayFields:
        return ArrayFields(shape.strings["labels"], items[shape.slices["data"]])

    def _from_message(self, msg: Float64MultiArray) -> ArrayFields:
        return ArrayFields(tuple(d.label for d in msg.layout.dim), tuple(msg.data))
