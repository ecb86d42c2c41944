"""The control loop's messages taken as bytes: subscriptions made with ``raw=True`` hand
their callbacks the serialized message, read here by :mod:`cr_control.core.cdr` (one
``struct`` call instead of building ROS message objects: ~2 µs instead of ~23 µs per
JointState, ~1.5 µs instead of ~46 µs per WrenchStamped). Bytes that are not plain CDR
(another encapsulation) go through rclpy's own deserialization, so any sender is read.

Size bounds (measured: a 10 MB JointState of 640 000 names took the reader 1.8 s): a node
compares a message's length with the largest message it reads (:func:`joint_state_max_bytes`,
:data:`WRENCH_MAX_BYTES`, :data:`ARRAY_MAX_BYTES`) before reading it, and drops a longer
one unread.
"""

from __future__ import annotations

import struct
from typing import Any, NamedTuple

from geometry_msgs.msg import WrenchStamped
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from cr_control.core import cdr

#: The largest JointState a controller reads has this many joints (more than any arm here,
#: its gripper included, and more than the state of two arms)...
MAX_JOINTS = 64
#: ... with joint names and frame_id of at most this many bytes each (ROS names of 255
#: characters and the NUL).
MAX_NAME_BYTES = 256


def _string_bytes(name_bytes: int) -> int:
    return 4 + name_bytes + 3            # length, bytes (NUL included), padding to 4


def joint_state_max_bytes(joints: int = MAX_JOINTS, name_bytes: int = MAX_NAME_BYTES) -> int:
    """Bytes of the largest plain-CDR sensor_msgs/JointState of ``joints`` joints whose names
    and frame_id have ``name_bytes`` bytes each, padding included (18 675 bytes for the
    defaults)."""
    doubles = 4 + 4 + 8 * joints         # count, padding to 8, values
    return (cdr.HEADER + 8 + _string_bytes(name_bytes) + 4 + joints * _string_bytes(name_bytes)
            + 3 * doubles + 4)


def _frame_id_span(data: bytes) -> tuple[str, int] | None:
    """(byte order, length with its NUL) of a plain-CDR JointState's header.frame_id, one
    uint32 read; None if ``data`` cannot say (too short, or not plain CDR). Its bytes start
    at HEADER + 12."""
    endian = cdr.ENDIAN.get(bytes(data[:2]))
    if endian is None or len(data) < cdr.HEADER + 12:
        return None
    return endian, struct.unpack_from(endian + "I", data, cdr.HEADER + 8)[0]


def joint_state_names(data: bytes) -> int | None:
    """How many names a plain-CDR JointState says it has (two uint32 read: frame_id's length
    and the name count), without reading the message; None if ``data`` cannot say (too
    short, or not plain CDR)."""
    span = _frame_id_span(data)
    if span is None:
        return None
    endian, frame_id = span
    at = cdr.HEADER + 12 + frame_id
    at += -(at - cdr.HEADER) % 4
    if at + 4 > len(data):
        return None
    return struct.unpack_from(endian + "I", data, at)[0]


def joint_state_frame_id(data: bytes) -> str | None:
    """A plain-CDR JointState's header.frame_id, read without the rest of the message; None
    if ``data`` cannot say."""
    span = _frame_id_span(data)
    if span is None or span[1] < 1 or cdr.HEADER + 12 + span[1] > len(data):
        return None
    return bytes(data[cdr.HEADER + 12:cdr.HEADER + 11 + span[1]]).decode("utf-8", "replace")


#: The largest geometry_msgs/WrenchStamped (frame_id of MAX_NAME_BYTES).
WRENCH_MAX_BYTES = cdr.HEADER + 8 + _string_bytes(MAX_NAME_BYTES) + 4 + 6 * 8 + 4
#: The largest std_msgs/Float64MultiArray a node reads (the plant's labelled sensors: a
#: label of every field name and a few values): 64 KiB.
ARRAY_MAX_BYTES = 65536


class JointStateFields(NamedTuple):
    sec: int
    nanosec: int
    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]
    frame_id: str = ""


class WrenchFields(NamedTuple):
    sec: int
    nanosec: int
    force: tuple[float, float, float]
    torque: tuple[float, float, float]
    frame_id: str = ""


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
                                items[s["velocity"]], items[s["effort"]],
                                shape.strings["frame_id"][0])

    def _from_message(self, msg: JointState) -> JointStateFields:
        stamp = msg.header.stamp
        return JointStateFields(stamp.sec, stamp.nanosec, tuple(msg.name), tuple(msg.position),
                                tuple(msg.velocity), tuple(msg.effort), msg.header.frame_id)


class WrenchReader(_RawReader):
    """The fields of a serialized geometry_msgs/WrenchStamped."""

    schema, msg_type = cdr.wrench_stamped, WrenchStamped

    def _from_items(self, items: tuple, shape: cdr.Shape) -> WrenchFields:
        start = shape.slices["wrench"].start
        return WrenchFields(items[0], items[1], items[start:start + 3], items[start + 3:start + 6],
                            shape.strings["frame_id"][0])

    def _from_message(self, msg: WrenchStamped) -> WrenchFields:
        f, t = msg.wrench.force, msg.wrench.torque
        return WrenchFields(msg.header.stamp.sec, msg.header.stamp.nanosec, (f.x, f.y, f.z),
                            (t.x, t.y, t.z), msg.header.frame_id)


class ArrayReader(_RawReader):
    """Labels and data of a serialized std_msgs/Float64MultiArray."""

    schema, msg_type = cdr.float64_multi_array, Float64MultiArray

    def _from_items(self, items: tuple, shape: cdr.Shape) -> ArrayFields:
        return ArrayFields(shape.strings["labels"], items[shape.slices["data"]])

    def _from_message(self, msg: Float64MultiArray) -> ArrayFields:
        return ArrayFields(tuple(d.label for d in msg.layout.dim), tuple(msg.data))
