"""The control loop's messages read and written as CDR bytes, without ROS message objects.

rclpy turns every message a subscription takes into Python objects (measured here:
~23 µs per sensor_msgs/JointState, ~46 µs per geometry_msgs/WrenchStamped, back to
back; more after an idle spell) and every message it publishes back into C structures.
A control loop's messages keep one shape for the whole run (the same joint names and
array lengths every cycle), so the nodes take and publish them serialized (rclpy's
``raw=True`` subscriptions and ``publish(bytes)``) and touch only the stamp and the
numbers: one ``struct`` call reads a whole message, a few write one.

The format is CDR as rmw_fastrtps and rmw_cyclonedds send it (XCDR1, "plain CDR"):
a 4-byte encapsulation header (0x0000 big-endian, 0x0001 little-endian; two option
bytes), then the fields in declaration order, each aligned to its own size counted
from the end of that header; a string is a uint32 length (the terminating NUL
included) and its bytes; a sequence is a uint32 count and its elements (doubles
aligned to 8 when there is at least one). Padding bytes carry anything.

A :class:`Shape` is found by walking one message field by field (:class:`_Walker`);
it holds one :class:`struct.Struct` that reads the whole message and the items that
fix the shape (lengths, counts, names, labels). :class:`Reader` keeps the last shape
and checks those items on every message, so a message of another shape (other names,
another length, another byte order) is walked again, never misread; bytes that are not
such a message give None (the node then uses rclpy's own deserialization).
:class:`Writer` builds a message of one shape once and refills its stamp and numbers.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import itemgetter
from typing import Any

import numpy as np

#: Encapsulation kinds (first two bytes) this module reads, and their byte order.
ENDIAN = {b"\x00\x00": ">", b"\x00\x01": "<"}
HEADER = 4       # encapsulation bytes before the payload


class _Walker:
    """Walks a message's fields in CDR order and builds the struct format that reads or
    writes the whole payload at once: one item per number, count or length and per
    string (its bytes with the NUL); padding skipped.

    Reading (``data`` given), counts and strings come from the bytes; writing
    (``content`` given), from ``content`` by field name, and ``values`` collects the
    items to pack (numbers zero).
    """

    def __init__(self, endian: str, data: bytes | None = None,
                 content: dict[str, Any] | None = None):
        self.endian, self.data, self.content = endian, data, content or {}
        self.fmt: list[str] = [endian]
        self.offset = 0                          # in the payload (alignment counts from it)
        self.n_items = 0
        self.fixed: list[int] = []               # items that fix the shape
        self.values: list[Any] = []              # writing: every item, in order
        self.slices: dict[str, slice] = {}       # the numbers of each named field
        self.offsets: dict[str, int] = {}        # byte offset (whole message) of each
        self.strings: dict[str, tuple[str, ...]] = {}

    def _align(self, size: int) -> None:
        pad = -self.offset % size
        if pad:
            self.fmt.append(f"{pad}x")
            self.offset += pad
            if self.data is not None and HEADER + self.offset > len(self.data):
                raise ValueError("truncated")

    def _item(self, code: str, size: int, count: int, fixed: bool, value: Any = 0) -> None:
        if self.data is not None and HEADER + self.offset + size > len(self.data):
            raise ValueError("truncated")
        self.fmt.append(code)
        if fixed:
            self.fixed.append(self.n_items)
        self.values.extend([value] * count)
        self.n_items += count
        self.offset += size

    def _read(self, code: str) -> int:
        return struct.unpack_from(self.endian + code, self.data, HEADER + self.offset)[0]

    def uint32(self, value: int = 0) -> int:
        """A length, count or size: it fixes the shape."""
        self._align(4)
        if self.data is not None:
            value = self._read("I")             # struct.error past the end
        self._item("I", 4, 1, True, value)
        return value

    def string(self, value: str = "") -> str:
        raw = value.encode() + b"\0"
        n = self.uint32(len(raw))
        if self.data is not None:
            start = HEADER + self.offset
            raw = bytes(self.data[start:start + n])
            if n == 0 or len(raw) < n or raw[-1] != 0:
                raise ValueError("bad string")
        self._item(f"{n}s", n, 1, True, raw)
        return raw[:-1].decode()

    def stamp(self, name: str = "stamp") -> None:
        """builtin_interfaces/Time: int32 sec, uint32 nanosec (the two items of ``name``)."""
        self._align(4)
        self.offsets[name] = HEADER + self.offset
        self.slices[name] = slice(self.n_items, self.n_items + 2)
        self._item("i", 4, 1, False)
        self._item("I", 4, 1, False)

    def header(self) -> None:
        """std_msgs/Header: stamp, frame_id."""
        self.stamp()
        self.strings["frame_id"] = (self.string(self.content.get("frame_id", "")),)

    def string_sequence(self, name: str) -> None:
        given = list(self.content.get(name, []))
        count = self.uint32(len(given))
        self.strings[name] = tuple(self.string(given[i] if i < len(given) else "")
                                   for i in range(count))

    def _doubles(self, name: str, count: int) -> None:
        if count:
            self._align(8)
        self.offsets[name] = HEADER + self.offset
        self.slices[name] = slice(self.n_items, self.n_items + count)
        if count:
            self._item(f"{count}d", 8 * count, count, False, 0.0)

    def double_sequence(self, name: str) -> None:
        """float64[]: its count fixes the shape, its numbers are the values of ``name``."""
        self._doubles(name, self.uint32(int(self.content.get(name, 0))))

    def double_array(self, name: str, count: int) -> None:
        """float64[count] (or a message of ``count`` float64 fields)."""
        self._doubles(name, count)


# -- the loop's message types, field by field ------------------------------------------------
def joint_state(w: _Walker) -> None:
    """sensor_msgs/JointState: header, name[], position[], velocity[], effort[]."""
    w.header()
    w.string_sequence("name")
    for field in ("position", "velocity", "effort"):
        w.double_sequence(field)


def wrench_stamped(w: _Walker) -> None:
    """geometry_msgs/WrenchStamped: header, wrench (force x y z, torque x y z)."""
    w.header()
    w.double_array("wrench", 6)


def float64_multi_array(w: _Walker) -> None:
    """std_msgs/Float64MultiArray: layout (dim[]: label, size, stride; data_offset), data[]."""
    dims = list(w.content.get("dim", []))        # writing: (label, size, stride) each
    count = w.uint32(len(dims))
    labels = []
    for i in range(count):
        label, size, stride = dims[i] if i < len(dims) else ("", 0, 0)
        labels.append(w.string(label))
        w.uint32(size)
        w.uint32(stride)
    w.strings["labels"] = tuple(labels)
    w.uint32(int(w.content.get("data_offset", 0)))
    w.double_sequence("data")


def clock(w: _Walker) -> None:
    """rosgraph_msgs/Clock: clock (builtin_interfaces/Time)."""
    w.stamp()


Schema = Callable[[_Walker], None]


@dataclass(frozen=True)
class Shape:
    """One message shape: ``struct`` reads the payload (from byte 4) into items;
    ``fixed(items) == expected`` holds exactly for messages of this shape."""

    encapsulation: bytes
    struct: struct.Struct
    fixed: Callable[[tuple], Any]
    expected: Any
    slices: dict[str, slice]
    offsets: dict[str, int]
    strings: dict[str, tuple[str, ...]]

    @property
    def size(self) -> int:
        """Bytes of a message of this shape (senders may append padding)."""
        return HEADER + self.struct.size


def _shape(walker: _Walker, encapsulation: bytes, items: Sequence[Any]) -> Shape:
    """The shape ``walker`` walked; ``items``: a message's items (what fixes the shape)."""
    fixed = walker.fixed
    # itemgetter of one index returns the item, of several a tuple; of none: an empty tuple.
    getter = itemgetter(*fixed) if fixed else (lambda items: ())
    return Shape(encapsulation, struct.Struct("".join(walker.fmt)), getter, getter(items),
                 walker.slices, walker.offsets, walker.strings)


def find_shape(schema: Schema, data: bytes) -> Shape | None:
    """The shape of ``data`` (a serialized message of ``schema``'s type), or None if it is
    not plain CDR or not such a message."""
    endian = ENDIAN.get(bytes(data[:2]))
    if endian is None or len(data) < HEADER:
        return None
    walker = _Walker(endian, data=data)
    try:
        schema(walker)
        items = struct.Struct("".join(walker.fmt)).unpack_from(data, HEADER)
    except (ValueError, struct.error, UnicodeDecodeError):
        return None
    return _shape(walker, bytes(data[:2]), items)


class Reader:
    """Reads the messages of one subscription: ``read(data)`` gives the items of the
    payload (``shape.slices`` names them), or None for bytes it cannot read."""

    def __init__(self, schema: Schema):
        self.schema = schema
        self.shape: Shape | None = None

    def read(self, data: bytes) -> tuple | None:
        shape = self.shape
        if shape is not None and len(data) >= shape.size and data[:2] == shape.encapsulation:
            items = shape.struct.unpack_from(data, HEADER)
            if shape.fixed(items) == shape.expected:
                return items
        shape = find_shape(self.schema, data)
        if shape is None:
            return None
        self.shape = shape
        return shape.struct.unpack_from(data, HEADER)


class Writer:
    """A message of one shape, built once (little-endian), refilled in place: ``array(name)``
    is a numpy view on a field's numbers inside the message bytes, ``set_stamp`` writes the
    stamp, ``message()`` gives the bytes to publish.

    ``content`` names the strings and counts: ``frame_id``, ``name`` (joint names),
    ``position``/``velocity``/``effort``/``data`` (counts), ``dim`` ((label, size,
    stride) tuples) as the schema reads them.
    """

    def __init__(self, schema: Schema, **content: Any):
        walker = _Walker("<", content=content)
        schema(walker)
        self.shape = _shape(walker, b"\x00\x01", walker.values)
        self._buffer = bytearray(b"\x00\x01\x00\x00") + bytearray(self.shape.struct.size)
        self.shape.struct.pack_into(self._buffer, HEADER, *walker.values)
        self._stamp = struct.Struct("<iI")
        self._stamp_offset = walker.offsets.get("stamp")

    def array(self, name: str) -> np.ndarray:
        """The numbers of field ``name``, written in place into the message."""
        s = self.shape.slices[name]
        return np.frombuffer(self._buffer, dtype="<f8", count=s.stop - s.start,
                             offset=self.shape.offsets[name])

    def set_stamp(self, sec: int, nanosec: int) -> None:
        if self._stamp_offset is None:
            raise TypeError("this message type has no stamp")
        self._stamp.pack_into(self._buffer, self._stamp_offset, sec, nanosec)

    def message(self) -> bytes:
        return bytes(self._buffer)
