"""The controller node's raw input path, callback by callback (no spinning): states are
read from their CDR bytes, reordered by name, refused when unusable, and bytes that are no
JointState are ignored (the node answers the next good state)."""

import os
import subprocess
import sys

import numpy as np
import pytest
import rclpy
import rclpy.parameter
from geometry_msgs.msg import WrenchStamped
from rclpy.context import Context
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from cr_control.nodes.controller_node import ControllerNode
from cr_control.nodes.raw_messages import JointStateFields
from cr_control.schemes.registry import SCHEMES


@pytest.fixture
def node():
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    controller = ControllerNode("adaptive_impedance", context=context)
    yield controller
    controller.destroy_node()
    rclpy.shutdown(context=context)


def fields(names, position, velocity) -> JointStateFields:
    return JointStateFields(1, 0, tuple(names), tuple(position), tuple(velocity), ())


@pytest.mark.ros
def test_joint_arrays_in_our_order_or_empty_when_unusable(node):
    q, v = node.inputs.joint_arrays(fields(["joint2", "joint1"], [2.0, 1.0], [20.0, 10.0]))
    np.testing.assert_array_equal(q, [1.0, 2.0])
    np.testing.assert_array_equal(v, [10.0, 20.0])
    q, v = node.inputs.joint_arrays(fields(["joint1", "joint2", "extra"], [1.0, 2.0, 3.0], [0.0] * 3))
    np.testing.assert_array_equal(q, [1.0, 2.0])
    for bad in (fields(["joint1", "elbow"], [1.0, 2.0], [0.0, 0.0]),       # a joint missing
                fields(["joint1", "joint2"], [1.0, 2.0], [0.0])):          # lengths differ
        q, v = node.inputs.joint_arrays(bad)
        assert q.size == 0 and v.size == 0


@pytest.mark.ros
def test_unreadable_bytes_are_ignored_and_the_next_state_answered(node):
    node._on_joint_state(b"\x00\x01\x00\x00 not a joint state")
    node._on_joint_state(b"")
    assert not node.inputs.answered
    msg = JointState(name=["joint1", "joint2"], position=[3.0358, -2.4401], velocity=[0.0, 0.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 7, 5_000_000
    node._on_joint_state(serialize_message(msg))
    assert node.inputs.answered
    command = deserialize_message(node.out.last, JointState)
    assert (command.header.stamp.sec, command.header.stamp.nanosec) == (7, 5_000_000)
    assert list(command.name) == ["joint1", "joint2"] and len(command.effort) == 2
    assert np.isfinite(command.effort).all() and not command.position


WARM_UP_CHECK = """
import sys
import numpy as np
from numba.core.registry import CPUDispatcher
from cr_control.schemes.registry import SCHEMES, make_controller

def signatures():
    return {f"{name}.{attr}": len(obj.signatures)
            for name, mod in list(sys.modules.items()) if name.startswith(("cr_control", "cr_sim"))
            for attr, obj in vars(mod).items() if isinstance(obj, CPUDispatcher)}

for scheme in sorted(SCHEMES):
    controller = make_controller(scheme)
    controller.warm_up()
    before = signatures()
    n = controller.n_state
    for stamp in (0.0, 1e-3):      # as the node passes them: np.array of the message's tuples
        controller.step(stamp, np.array((0.1,) * n), np.array((0.0,) * n), np.zeros(3))
    after = signatures()
    print(scheme, sorted(k for k in after if after[k] != before.get(k, 0)))
"""


@pytest.fixture
def lockstep_node():
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    controller = ControllerNode("adaptive_impedance", context=context,
                                parameter_overrides=[rclpy.parameter.Parameter("lockstep", value=True)])
    yield controller
    controller.destroy_node()
    rclpy.shutdown(context=context)


@pytest.mark.ros
def test_a_lockstep_state_before_the_plants_interface_is_answered_once_it_comes(lockstep_node):
    """The plant's first state can come before its latched command interface: the lockstep
    plant waits for that state's answer, so the controller answers it when the interface
    arrives (before: only the plant's republication 1 s later, one extra state recorded)."""
    from std_msgs.msg import String

    node = lockstep_node
    assert node._pacer is not None and node.inputs.interface == "unknown"
    node.inputs.plant_advertises = lambda: True                   # the interface is on its way
    msg = JointState(name=["joint1", "joint2"], position=[3.0358, -2.4401], velocity=[0.0, 0.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 0
    node._on_joint_state(serialize_message(msg))
    assert not node.inputs.answered
    node.plant_interface.on_interface(String(data="effort"))
    assert node.inputs.answered
    command = deserialize_message(node.out.last, JointState)
    assert (command.header.stamp.sec, command.header.stamp.nanosec) == (0, 0)


def test_warm_up_leaves_nothing_to_compile_in_the_first_cycles():
    """In a fresh install (a colcon install tree has no kernel cache) a kernel first met in
    the loop is compiled there: ~1 s of stalled cycles. A fresh process, so nothing an
    earlier test compiled hides it."""
    out = subprocess.run([sys.executable, "-c", WARM_UP_CHECK], capture_output=True, text=True,
                         timeout=300, check=True).stdout
    lines = out.splitlines()
    assert len(lines) == len(SCHEMES) and all(line.endswith(" []") for line in lines), out


def _state(sec: int, nanosec: int) -> bytes:
    msg = JointState(name=["joint1", "joint2"], position=[3.0358, -2.4401], velocity=[0.0, 0.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return serialize_message(msg)


def _wrench(sec: int, nanosec: int, f_x: float) -> bytes:
    msg = WrenchStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    msg.wrench.force.x = f_x
    return serialize_message(msg)


@pytest.mark.ros
def test_the_node_reports_the_age_of_the_wrench_it_read(node):
    """The state's own wrench first: age 0; the wrench of the state before: 1 ms, and the law
    read that one; no wrench yet: -1."""
    assert node.inputs.wrench_age_ms == -1.0
    node.inputs.wrench_message(_wrench(7, 4_000_000, 1.5))
    node._on_joint_state(_state(7, 5_000_000))
    assert node.inputs.wrench_age_ms == pytest.approx(1.0) and node._status_out[-1] == pytest.approx(1.0)
    assert node.inputs.force[0] == 1.5
    node.inputs.wrench_message(_wrench(7, 6_000_000, 2.5))
    node._on_joint_state(_state(7, 6_000_000))
    assert node._status_out[-1] == 0.0 and node.inputs.force[0] == 2.5
