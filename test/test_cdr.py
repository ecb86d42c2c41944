"""The loop's messages read and written as CDR bytes (cr_control.core.cdr), checked against
rclpy's own serialization: every field read back, every message written deserializes to
the message meant, a change of shape is never misread, and bytes that are not such a
message give None, never an exception."""

import random
import struct

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control.core import cdr, topics
from cr_control.nodes.raw_messages import ArrayReader, JointStateReader, WrenchReader


def random_joint_state(rng: random.Random) -> JointState:
    msg = JointState()
    msg.header.stamp.sec = rng.randrange(-2**31, 2**31)
    msg.header.stamp.nanosec = rng.randrange(0, 10**9)
    msg.header.frame_id = "".join(rng.choice("abcdé_/") for _ in range(rng.randrange(0, 9)))
    n = rng.randrange(0, 5)
    msg.name = ["".join(rng.choice("jointé_12") for _ in range(rng.randrange(0, 11)))
                for _ in range(n)]
    for field in ("position", "velocity", "effort"):
        count = rng.choice([0, n, rng.randrange(0, 4)])
        setattr(msg, field, [rng.uniform(-1e3, 1e3) for _ in range(count)])
    return msg


def fields_of(msg: JointState) -> tuple:
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, tuple(msg.name), tuple(msg.position),
            tuple(msg.velocity), tuple(msg.effort), msg.header.frame_id)


def test_joint_states_of_every_shape_read_as_rclpy_reads_them():
    rng = random.Random(6)
    reader = JointStateReader()
    for _ in range(300):
        msg = random_joint_state(rng)
        data = serialize_message(msg)
        items = reader._cdr.read(data)
        assert items is not None, msg                   # plain CDR: never the fallback
        assert tuple(reader(data)) == fields_of(msg)
        assert reader._cdr.shape.strings["frame_id"] == (msg.header.frame_id,)


def test_a_change_of_shape_is_found_not_misread():
    reader = JointStateReader()

    def read(**kw) -> tuple:
        msg = JointState(**kw)
        assert reader._cdr.read(serialize_message(msg)) is not None
        return tuple(reader(serialize_message(msg)))[2:6]

    assert read(name=["a", "b"], velocity=[1.0, 2.0]) == (("a", "b"), (), (1.0, 2.0), ())
    # Same length in bytes, same names: the two doubles moved from velocity to effort.
    assert read(name=["a", "b"], effort=[1.0, 2.0]) == (("a", "b"), (), (), (1.0, 2.0))
    assert read(name=["b", "a"], effort=[1.0, 2.0]) == (("b", "a"), (), (), (1.0, 2.0))
    assert read(name=["b", "c"], effort=[3.0, 4.0]) == (("b", "c"), (), (), (3.0, 4.0))


def test_padding_bytes_do_not_matter():
    """Padding carries anything (rclpy's own serialization leaves garbage there): the shape
    check looks only at lengths, counts and characters."""
    msg = JointState(name=["joint1", "j2"], position=[0.5, 1.5], effort=[2.0, 3.0])
    msg.header.frame_id = "w"
    data = bytearray(serialize_message(msg))
    reader = cdr.Reader(cdr.joint_state)
    shape = cdr.find_shape(cdr.joint_state, bytes(data))
    pads = [i for i in range(4, shape.size) if not covered(shape, i)]
    assert pads, "this message has padding"
    reader.read(bytes(data))
    for i in pads:
        data[i] ^= 0xA5
    items = reader.read(bytes(data))
    assert reader.shape is not None and items[reader.shape.slices["effort"]] == (2.0, 3.0)


def covered(shape: cdr.Shape, offset: int) -> bool:
    """``offset`` holds an item of ``shape`` (not padding)."""
    position = cdr.HEADER
    for code in struct_codes(shape.struct.format):
        size = struct.calcsize("<" + code)
        if position <= offset < position + size:
            return not code.endswith("x")
        position += size
    return False


def struct_codes(fmt: str) -> list[str]:
    codes, number = [], ""
    for ch in fmt[1:]:
        if ch.isdigit():
            number += ch
        else:
            codes.append(number + ch)
            number = ""
    return codes


def test_big_endian_messages_are_read():
    walker = cdr._Walker(">", content={"frame_id": "base", "name": ["a", "bc"], "position": 2,
                                       "velocity": 0, "effort": 2})
    cdr.joint_state(walker)
    values = walker.values
    values[0:2] = [7, 8]
    s = walker.slices
    values[s["position"]] = [1.25, -2.5]
    values[s["effort"]] = [3.0, 4.0]
    data = b"\x00\x00\x00\x00" + struct.pack("".join(walker.fmt), *values)
    assert tuple(JointStateReader()(data)) == (7, 8, ("a", "bc"), (1.25, -2.5), (), (3.0, 4.0), "base")


def test_bytes_that_are_no_such_message_give_none():
    msg = JointState(name=["joint1", "joint2"], position=[1.0, 2.0], velocity=[3.0, 4.0])
    data = serialize_message(msg)
    size = cdr.find_shape(cdr.joint_state, data).size
    reader = cdr.Reader(cdr.joint_state)
    assert reader.read(data) is not None
    for cut in range(size):                       # every truncation of a known shape
        assert reader.read(data[:cut]) is None
        assert cdr.find_shape(cdr.joint_state, data[:cut]) is None
    assert reader.read(b"\x00\x07" + data[2:]) is None       # another encapsulation
    huge = bytearray(data)
    huge[20:24] = struct.pack("<I", 2**31)                     # absurd name count
    assert reader.read(bytes(huge)) is None
    rng = random.Random(1)
    for _ in range(300):                          # noise after a valid header: no exception
        noise = b"\x00\x01\x00\x00" + bytes(rng.randrange(256) for _ in range(rng.randrange(80)))
        reader.read(noise)


def test_writers_give_what_rclpy_deserializes_to_the_message_meant():
    state = cdr.Writer(cdr.joint_state, name=["joint1", "joint2"], position=2, velocity=2, effort=2)
    state.set_stamp(12, 345)
    state.array("position")[:] = [0.1, 0.2]
    state.array("velocity")[:] = np.array([-1.0, 1.0])
    state.array("effort")[:] = [5.0, 6.0]
    msg = deserialize_message(state.message(), JointState)
    assert fields_of(msg) == (12, 345, ("joint1", "joint2"), (0.1, 0.2), (-1.0, 1.0), (5.0, 6.0), "")

    command = cdr.Writer(cdr.joint_state, name=["a"], effort=1)
    command.array("effort")[0] = -7.5
    assert fields_of(deserialize_message(command.message(), JointState)) == (
        0, 0, ("a",), (), (), (-7.5,), "")

    wrench = cdr.Writer(cdr.wrench_stamped, frame_id="world")
    wrench.set_stamp(1, 2)
    wrench.array("wrench")[:3] = [1.0, 2.0, 3.0]
    w = deserialize_message(wrench.message(), WrenchStamped)
    assert (w.header.frame_id, w.header.stamp.sec, w.header.stamp.nanosec) == ("world", 1, 2)
    assert (w.wrench.force.x, w.wrench.force.y, w.wrench.force.z, w.wrench.torque.z) == (1, 2, 3, 0)

    clock = cdr.Writer(cdr.clock)
    clock.set_stamp(3, 999_999_999)
    c = deserialize_message(clock.message(), Clock).clock
    assert (c.sec, c.nanosec) == (3, 999_999_999)

    fields = ["stamp", "x", "y"]
    status = topics.labelled_writer(fields)
    status.array("data")[:] = [0.5, 1.5, 2.5]
    theirs = topics.labelled_array(Float64MultiArray, MultiArrayDimension, fields)
    theirs.data = [0.5, 1.5, 2.5]
    assert deserialize_message(status.message(), Float64MultiArray) == theirs
    # Byte for byte what rclpy writes, padding aside (rclpy's padding is not zeroed).
    ours, rclpys = status.message(), serialize_message(theirs)
    shape = status.shape
    assert all(ours[i] == rclpys[i] for i in range(shape.size) if covered(shape, i))


def test_wrench_and_array_readers_against_rclpy():
    rng = random.Random(3)
    wrench_reader, array_reader = WrenchReader(), ArrayReader()
    for _ in range(100):
        w = WrenchStamped()
        w.header.frame_id = "f" * rng.randrange(0, 12)
        w.header.stamp.sec = rng.randrange(0, 100)
        values = [rng.uniform(-10, 10) for _ in range(6)]
        f, t = w.wrench.force, w.wrench.torque
        f.x, f.y, f.z, t.x, t.y, t.z = values
        assert tuple(wrench_reader(serialize_message(w))) == (
            w.header.stamp.sec, 0, tuple(values[:3]), tuple(values[3:]), w.header.frame_id)
        a = Float64MultiArray()
        a.layout.dim = [MultiArrayDimension(label="l" * rng.randrange(0, 7), size=rng.randrange(9),
                                            stride=3) for _ in range(rng.randrange(3))]
        a.layout.data_offset = rng.randrange(5)
        a.data = [rng.uniform(-1, 1) for _ in range(rng.randrange(6))]
        assert array_reader._cdr.read(serialize_message(a)) is not None
        assert tuple(array_reader(serialize_message(a))) == (
            tuple(d.label for d in a.layout.dim), tuple(a.data))


def test_the_fallback_reads_what_plain_cdr_does_not():
    """Bytes the CDR reader refuses go through rclpy's deserialization; unreadable: None."""
    reader = JointStateReader()
    msg = JointState(name=["a"], effort=[2.0])
    data = serialize_message(msg)
    reader._cdr.read = lambda data: None          # as for an encapsulation cdr does not read
    assert tuple(reader(data)) == fields_of(msg)
    assert reader(b"\x00\x07\x00\x00garbage") is None


@pytest.mark.parametrize("schema", [cdr.joint_state, cdr.wrench_stamped, cdr.float64_multi_array,
                                    cdr.clock])
def test_a_writer_reads_back_through_a_reader(schema):
    content = {"name": ["x", "yy"], "position": 2, "effort": 1, "frame_id": "w",
               "dim": [("a,b", 2, 2)], "data": 2}
    writer = cdr.Writer(schema, **content)
    for name, s in writer.shape.slices.items():
        if name != "stamp":
            writer.array(name)[:] = np.arange(1, s.stop - s.start + 1)
    stamped = "stamp" in writer.shape.slices
    if stamped:
        writer.set_stamp(4, 5)
    else:
        with pytest.raises(TypeError):
            writer.set_stamp(4, 5)
    reader = cdr.Reader(schema)
    items = reader.read(writer.message())
    assert not stamped or items[reader.shape.slices["stamp"]] == (4, 5)
    for name, s in writer.shape.slices.items():
        if name != "stamp":
            assert items[reader.shape.slices[name]] == tuple(range(1, s.stop - s.start + 1))
