"""The plant's guards on its command stream: one commander at a time, handover
after a stated silence, oversized commands refused unread.

The node tests drive the plant node callback by callback (no spinning, no clock waits) as
test_plant_realtime.py does, with the publisher GIDs given by hand; the last tests take
real messages from two publishers of another participant through the node's subscription
(:mod:`cr_control.nodes.sender_aware`), which reads the GIDs rmw reports.
"""

import os
import sys
import time

import numpy as np
import pytest
import rclpy
from plant_harness import PERIOD, tick
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from ros_probe import RosProbe, start_node, stop_node, timing_field
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from cr_control.core import topics
from cr_control.nodes import sender_aware
from cr_control.nodes.qos import PUBLISH_QOS
from cr_sim.plant_node import NODE_PARAMETERS, PlantNode
from cr_sim.supervisor import MAX_COMMAND_BYTES, MAX_COMMAND_JOINTS

A, B, C = b"A" * 16, b"B" * 16, b"C" * 16          # publisher GIDs (16 bytes, as rmw's)
DEFAULTS = {p.name: p.default for p in NODE_PARAMETERS}


def command(node: PlantNode, effort, names=None) -> bytes:
    """A serialized command answering the latest state."""
    msg = JointState(name=list(names or node.command_names), effort=list(effort))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(node.state_stamp or 0, 1_000_000_000)
    return serialize_message(msg)


def send(node: PlantNode, gid: bytes, effort, names=None) -> None:
    """Deliver a command of the publisher ``gid``, as the subscription does."""
    node._on_command(command(node, effort, names), gid)


def timing(node: PlantNode) -> dict[str, float]:
    """The node's /plant/timing values as it publishes them now, by name."""
    node._publish_timing(at_once=True)
    return dict(zip(topics.PLANT_TIMING_FIELDS, node.report.message.data, strict=True))


# -- one commander ---------------------------------------------------------------------------
def test_the_handover_default_is_stated_and_below_the_watchdog():
    assert DEFAULTS["command_handover_cycles"] == 50
    assert DEFAULTS["command_handover_cycles"] < DEFAULTS["watchdog_missed_cycles"]
    assert topics.PLANT_TIMING_FIELDS[-3:] == ["commands_foreign", "commands_oversized",
                                               "commander_handovers"]


@pytest.mark.ros
def test_a_second_publisher_is_refused_counted_and_logged_once(make_node):
    node = make_node()
    tick(node)
    send(node, A, [1.0, -1.0])                   # the first valid command: A commands
    np.testing.assert_array_equal(node.command, [1.0, -1.0])
    for k in range(5):                           # B's bang-bang, and a huge value: refused
        send(node, B, [20.0 * (-1) ** k, 1e308])
        tick(node)
        np.testing.assert_array_equal(node.command, [1.0, -1.0])
        send(node, A, [1.0, -1.0])               # A goes on, obeyed
    send(node, A, [1.5, -1.0])
    np.testing.assert_array_equal(node.command, [1.5, -1.0])
    t = timing(node)
    assert t["commands_foreign"] == 5 and t["commander_handovers"] == 0
    assert t["commands_refused"] == 0 and t["commands_oversized"] == 0
    assert node.log.count("refused unread: following") == 1
    assert node.log.count("another is followed only after 50 cycles without a valid message") == 1


@pytest.mark.ros
def test_handover_only_after_the_stated_silence(make_node):
    node = make_node(command_handover_cycles=5)
    tick(node)
    send(node, A, [1.0, 1.0])
    for _ in range(4):                           # A silent for 4 ticks: B still refused
        tick(node)
    send(node, B, [2.0, 2.0])
    np.testing.assert_array_equal(node.command, [1.0, 1.0])
    assert node.stats.commands_foreign == 1
    tick(node)                                   # 5 ticks of silence: B's next command takes over
    send(node, B, [2.0, 2.0])
    np.testing.assert_array_equal(node.command, [2.0, 2.0])
    assert node.stats.commander_handovers == 1 and node.log.count("handover:") == 1
    send(node, A, [3.0, 3.0])                    # A is now the other publisher
    np.testing.assert_array_equal(node.command, [2.0, 2.0])
    assert node.stats.commands_foreign == 2
    assert node.log.count("refused unread: following") == 1  # still logged once
    t = timing(node)
    assert (t["commands_foreign"], t["commander_handovers"]) == (2, 1)


@pytest.mark.ros
def test_a_commander_that_keeps_commanding_is_never_displaced(make_node):
    """Every tick has A's command: however long B publishes, B is refused."""
    node = make_node(command_handover_cycles=5)
    tick(node)
    for _ in range(50):
        send(node, A, [0.5, 0.5])
        send(node, B, [-0.5, -0.5])
        tick(node)
    np.testing.assert_array_equal(node.command, [0.5, 0.5])
    assert node.stats.commands_foreign == 50 and node.stats.commander_handovers == 0


@pytest.mark.ros
def test_a_bad_command_does_not_take_over(make_node):
    """After the silence a publisher takes over with a valid command only: a command that is
    refused (wrong joints, NaN) leaves the commander as it was."""
    node = make_node(command_handover_cycles=3)
    tick(node)
    send(node, A, [1.0, 1.0])
    tick(node, 1)
    for _ in range(3):
        tick(node)
    send(node, B, [1.0, 2.0], names=["joint1", "elbow"])
    send(node, C, [float("nan"), 0.0])
    assert node.stats.commands_refused == 2 and node.stats.commands_foreign == 0
    assert node.stats.commander_handovers == 0
    send(node, A, [0.5, 0.5])                    # A is back: no handover
    np.testing.assert_array_equal(node.command, [0.5, 0.5])
    assert node.stats.commander_handovers == 0 and node.log.count("handover:") == 0


@pytest.mark.ros
def test_a_restarted_controller_takes_over_before_the_watchdog_stops(make_node):
    """Defaults: the old controller falls silent, the new one (another GID) answers every
    tick from then on: it is refused for 50 ticks, then obeyed, and the watchdog (100)
    never fires."""
    node = make_node()
    tick(node)
    send(node, A, [1.0, 1.0])
    refused_ticks = 0
    for _ in range(200):
        tick(node)
        before = node.stats.commands_foreign
        send(node, B, [2.0, 2.0])
        refused_ticks += node.stats.commands_foreign > before
    assert refused_ticks == DEFAULTS["command_handover_cycles"] - 1
    np.testing.assert_array_equal(node.command, [2.0, 2.0])
    assert not node.safe_stop and node.stats.commander_handovers == 1


@pytest.mark.ros
def test_lockstep_follows_the_same_rule_in_wall_time(make_node, monkeypatch):
    node = make_node(mode="lockstep", command_handover_cycles=20)
    now = time.monotonic()
    monkeypatch.setattr(time, "monotonic", lambda: now)   # the rule's wall clock, held
    node._publish_state(0, 0)                    # the first state
    send(node, A, [1.0, 1.0])                    # answers it: the plant steps
    assert node.plant.time == pytest.approx(PERIOD)
    send(node, B, [2.0, 2.0])                    # B answers the next state: refused, no step
    assert node.plant.time == pytest.approx(PERIOD) and node.stats.commands_foreign == 1
    node.supervisor.guard.last_heard = now / PERIOD - 19.5   # A silent 19 periods
    send(node, B, [2.0, 2.0])
    assert node.plant.time == pytest.approx(PERIOD) and node.stats.commands_foreign == 2
    node.supervisor.guard.last_heard = now / PERIOD - 20.5   # 20: B takes over
    send(node, B, [2.0, 2.0])
    assert node.plant.time == pytest.approx(2 * PERIOD)
    np.testing.assert_array_equal(node.command, [2.0, 2.0])
    assert node.stats.commander_handovers == 1
    send(node, A, [3.0, 3.0])
    assert node.plant.time == pytest.approx(2 * PERIOD) and node.stats.commands_foreign == 3


@pytest.mark.ros
@pytest.mark.parametrize("name", ["watchdog_missed_cycles", "command_handover_cycles"])
def test_cycle_counts_below_one_are_refused(make_node, name):
    from cr_control.core.parameters import ParameterError
    with pytest.raises(ParameterError, match=name):
        make_node(**{name: 0})


# -- oversized --------------------------------------------------------------------------------
def test_the_size_limit_is_64_joints_worth():
    names = [f"panda_joint{i}" for i in range(MAX_COMMAND_JOINTS)]
    big = JointState(name=names, position=[0.0] * 64, velocity=[0.0] * 64, effort=[0.0] * 64)
    big.header.frame_id = "f" * 200
    assert len(serialize_message(big)) <= MAX_COMMAND_BYTES
    assert MAX_COMMAND_BYTES < 8192
    assert len(serialize_message(JointState(name=["j"] * 1000, effort=[0.0] * 1000))) > MAX_COMMAND_BYTES


@pytest.mark.ros
def test_an_oversized_command_is_refused_unread_and_counted(make_node):
    node = make_node()
    tick(node)
    send(node, A, [1.0, 1.0])

    def never(data):
        raise AssertionError("an oversized command was parsed")

    node._read_command = never
    node._on_command(None, A, 10_000_000)        # as the subscription hands it: not copied
    huge = JointState(name=["joint1"] * 2000, effort=[1e308] * 2000)
    node._on_command(serialize_message(huge), A)  # as bytes (a plain subscription)
    np.testing.assert_array_equal(node.command, [1.0, 1.0])
    t = timing(node)
    assert t["commands_oversized"] == 2 and t["commands_refused"] == 0
    assert node.log.count("unread") == 1


# -- over ROS: the GIDs rmw reports ----------------------------------------------------------
def _probe_and_subscriber(probe_name: str, topic: str):
    """A probe (publishers' participant) and, in a context of its own, a node with a
    sender-aware JointState subscription on ``topic`` that appends each callback's
    arguments to ``got``: (probe, context, node, subscription, got)."""
    probe = RosProbe(int(os.environ["ROS_DOMAIN_ID"]), probe_name)
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    node = rclpy.create_node(f"{probe_name}_sub", context=context)
    got: list = []
    sub = sender_aware.subscribe(node, JointState, topic, lambda *a: got.append(a), PUBLISH_QOS, 1000)
    return probe, context, node, sub, got


@pytest.mark.ros
@pytest.mark.parametrize("executor", [EventsExecutor, SingleThreadedExecutor])
def test_sender_aware_subscription_reports_each_publishers_gid(executor):
    """Two publishers of another participant: each message comes with its publisher's GID
    (the graph's endpoint GID), an oversized one with its length only."""
    probe, context, node, sub, got = _probe_and_subscriber("guards_probe", "/guards_test")
    spin = executor(context=context)
    spin.add_node(node)
    try:
        p1 = probe.node.create_publisher(JointState, "/guards_test", PUBLISH_QOS)
        p2 = probe.node.create_publisher(JointState, "/guards_test", PUBLISH_QOS)

        def spin_until(done, timeout=20.0):
            deadline = time.monotonic() + timeout
            while not done() and time.monotonic() < deadline:
                spin.spin_once(timeout_sec=0.05)
            return done()

        assert spin_until(lambda: sub.get_publisher_count() == 2
                          and p1.get_subscription_count() == p2.get_subscription_count() == 1)
        p1.publish(JointState(name=["a"], effort=[1.0]))
        p2.publish(JointState(name=["b"], effort=[2.0]))
        p2.publish(JointState(name=["c"] * 200, effort=[0.0] * 200))
        assert spin_until(lambda: len(got) == 3), got
        gids = {bytes(i.endpoint_gid): i for i in node.get_publishers_info_by_topic("/guards_test")}
        (d1, g1), (d2, g2), (d3, g3, length) = got
        assert g1 in gids and g2 in gids and g1 != g2 and g3 == g2
        m1, m2 = deserialize_message(d1, JointState), deserialize_message(d2, JointState)
        assert (m1.name, list(m1.effort), m2.name, list(m2.effort)) == (["a"], [1.0], ["b"], [2.0])
        assert d3 is None and length > 1000
    finally:
        spin.shutdown()
        sub.destroy()
        node.destroy_node()
        rclpy.shutdown(context=context)
        probe.close()


@pytest.mark.ros
def test_one_wake_up_takes_what_is_queued():
    """A flood (50 000 states from a second publisher) costs one take per message,
    not one executor wake-up: take_data() takes every queued message, up to its bound."""
    from rclpy.duration import Duration

    probe, context, node, sub, got = _probe_and_subscriber("guards_flood", "/guards_flood")
    try:
        pub = probe.node.create_publisher(JointState, "/guards_flood", PUBLISH_QOS)
        deadline = time.monotonic() + 20.0
        while sub.get_publisher_count() != 1 or pub.get_subscription_count() != 1:
            assert time.monotonic() < deadline, "no match"
            time.sleep(0.02)
        for k in range(8):
            pub.publish(JointState(name=["a"], effort=[float(k)]))
        assert pub.wait_for_all_acked(Duration(seconds=10))     # all 8 in the reader's history
        sub.take_data()
        assert [list(deserialize_message(d, JointState).effort) for d, _ in got] == \
            [[float(k)] for k in range(8)]
        for _ in range(sender_aware.MAX_TAKES_PER_WAKE + 5):
            pub.publish(JointState(name=["a"], effort=[1.0]))
        assert pub.wait_for_all_acked(Duration(seconds=10))
        got.clear()
        sub.take_data()
        assert len(got) == min(sender_aware.MAX_TAKES_PER_WAKE, PUBLISH_QOS.depth)
    finally:
        sub.destroy()
        node.destroy_node()
        rclpy.shutdown(context=context)
        probe.close()


@pytest.mark.ros
def test_the_plant_refuses_a_second_publisher_over_ros(make_node):
    """The plant's own subscription: the first publisher's valid command makes it the
    commander; a second publisher's commands are refused and counted, its oversized one too."""
    node = make_node(mode="lockstep")
    node._started = False                        # no state goes out: commands are only held
    probe = RosProbe(int(os.environ["ROS_DOMAIN_ID"]), "guards_rogue")
    spin = EventsExecutor(context=node.context)
    spin.add_node(node)
    try:
        controller = probe.node.create_publisher(JointState, topics.JOINT_COMMANDS, PUBLISH_QOS)
        rogue = probe.node.create_publisher(JointState, topics.JOINT_COMMANDS, PUBLISH_QOS)

        def spin_until(done, timeout=20.0):
            deadline = time.monotonic() + timeout
            while not done() and time.monotonic() < deadline:
                spin.spin_once(timeout_sec=0.05)
            return done()

        assert spin_until(lambda: node.command_sub.get_publisher_count() == 2
                          and controller.get_subscription_count() == rogue.get_subscription_count() == 1)
        # the publishers' node names reach the graph after their endpoints (ROS discovery info)
        assert spin_until(lambda: [i.node_name for i in node.get_publishers_info_by_topic(
            topics.JOINT_COMMANDS)] == ["guards_rogue"] * 2)
        controller.publish(JointState(name=list(node.command_names), effort=[1.0, -1.0]))
        assert spin_until(lambda: node.supervisor.commander is not None)
        for k in range(10):          # one at a time: the subscription keeps the last 10
            rogue.publish(JointState(name=list(node.command_names), effort=[20.0 * (-1) ** k, 1e308]))
            assert spin_until(lambda k=k: node.stats.commands_foreign == k + 1), vars(node.stats)
        rogue.publish(JointState(name=["j"] * 1000, effort=[0.0] * 1000))
        assert spin_until(lambda: node.stats.commands_oversized == 1), vars(node.stats)
        np.testing.assert_array_equal(node.command, [1.0, -1.0])
        assert node.log.count("refused unread: following") == 1
        assert node.log.count("guards_rogue") >= 1          # the log names the nodes
    finally:
        spin.shutdown()
        probe.close()


@pytest.mark.ros
def test_a_rogue_beside_a_running_controller_is_refused(ros_env):
    """The fuzz: beside plant and adaptive_impedance, a second publisher sends a +-20 N m
    bang-bang for 1 s, then 1e308. Before: obeyed, 5 rad/s and 18-32 rad/s. Now every rogue
    command is refused (counted), the arm moves as under control alone (< 2 rad/s; ~0.9
    rad/s is the task's) and nothing stops. In lockstep, so that the arm's motion is the
    controller's alone however late a loaded machine runs it (in real time a controller
    descheduled for a few tenths of a second leaves its last torque applied meanwhile, and
    the arm speeds up with no rogue obeyed)."""
    probe = RosProbe(int(ros_env["ROS_DOMAIN_ID"]), "guards_fuzz")
    states, timing = [], []
    deep = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
    probe.node.create_subscription(JointState, topics.JOINT_STATES, states.append, deep, raw=True)
    probe.node.create_subscription(Float64MultiArray, topics.PLANT_TIMING, timing.append, 100)
    rogue = probe.node.create_publisher(JointState, topics.JOINT_COMMANDS, PUBLISH_QOS)
    controller = start_node([sys.executable, "-m", "cr_control.nodes.controller_node",
                             "adaptive_impedance"], ros_env, "-p", "lockstep:=true")
    # long enough in lockstep (~3x real time) to outlast the rogue's 1.2 s of wall time
    plant = start_node([sys.executable, "-m", "cr_sim.plant_node"], ros_env,
                       "-p", "mode:=lockstep", "-p", "duration:=20.0")
    try:
        assert probe.spin_until(lambda: len(timing) >= 2, timeout=90), "the session never ran"
        assert probe.spin_until(lambda: rogue.get_subscription_count() >= 1, timeout=10)
        start = len(states)
        msg = JointState(name=["joint1", "joint2"])
        end = time.monotonic() + 1.0
        k = 0
        while time.monotonic() < end:
            msg.effort = [20.0 * (-1) ** (k // 50), -20.0 * (-1) ** (k // 50)]
            rogue.publish(msg)
            k += 1
            probe.spin_until(lambda: False, timeout=0.001)
        for _ in range(200):
            msg.effort = [1e308, -1e308]
            rogue.publish(msg)
            probe.spin_until(lambda: False, timeout=0.001)
        stop = len(states)
        assert plant.poll() is None, "the run ended before the rogue did"
        assert probe.spin_until(lambda: plant.poll() is not None, timeout=120)
        probe.spin_until(lambda: False, timeout=0.5)
    finally:
        _, out = stop_node(plant)
        stop_node(controller)
        probe.close()
    speeds = [max(abs(v) for v in deserialize_message(s, JointState).velocity)
              for s in states[start:stop + 200]]
    last = timing[-1]
    print(f"{k + 200} rogue commands, {timing_field(last, 'commands_foreign'):.0f} refused; "
          f"fastest joint while they came: {max(speeds):.2f} rad/s")
    # each one the plant reads is refused and counted; how many it reads is the middleware's
    # (its reader keeps the last 10: a stall of the plant's process drops the older ones)
    assert timing_field(last, "commands_foreign") >= 1
    assert timing_field(last, "commander_handovers") == 0
    assert max(speeds) < 2.0
    assert not any(timing_field(m, "safe_stop") for m in timing)
    # logged once per reason: "following" the controller, or, where the controller had been
    # silent for the rule's 50 cycles (a loaded machine), "only ... is followed"
    following, unexpected = (out.count(f"refused unread: {why}") for why in ("following", "only"))
    assert following <= 1 and unexpected <= 1 and following + unexpected >= 1, out[-3000:]
    assert "guards_fuzz" in out, out[-3000:]
