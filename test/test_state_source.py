"""Issue 25, items 2 and 3: a controller follows one /joint_states writer at the DDS level
(cr_control/nodes/state_source.py). A second publisher's states, a 10 MB one among them,
never reach the controller; it is reported; once the followed publisher has left, the
controller subscribes again and follows the other."""

from __future__ import annotations

import itertools
import subprocess
import sys
from types import SimpleNamespace

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_probe import RosProbe, next_domain, stop_node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from cr_control.core import topics
from cr_control.core.ros_env import (
    DDS_PROFILE_VARIABLE,
    LOCKSTEP_DDS_PROFILE,
    NODE_DDS_PROFILE,
    drop_node_dds_profile,
    isolated_env,
)
from cr_control.nodes import state_source
from cr_control.nodes.state_source import StateSourceWatch

NODE = "adaptive_impedance"
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
HUGE_ENTRIES = 640_000          # ~10 MB, as cr_fuzz's huge_joint_state


def state(stamp_ns: int, position=(3.0358, -2.4401), names=("joint1", "joint2")) -> JointState:
    msg = JointState(name=list(names), position=list(position), velocity=[0.0] * len(position))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return msg


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def diagnostic_value(arrays: list, key: str) -> str | None:
    """``key`` of the controller's last status on /diagnostics (None before one came)."""
    for array in reversed(arrays):
        for status in array.status:
            if status.name.startswith(f"{NODE}:"):
                return {kv.key: kv.value for kv in status.values}.get(key)
    return None


@pytest.mark.ros
def test_a_second_publisher_never_reaches_the_controller_and_takes_over_once_the_first_left():
    domain = next_domain()
    env = isolated_env(domain_id=domain)
    assert env.get(DDS_PROFILE_VARIABLE) == str(NODE_DDS_PROFILE)    # conftest: as in sessions
    proc = subprocess.Popen([sys.executable, "-m", "cr_control.nodes.controller_node", NODE],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    probe = RosProbe(domain)
    intruder = RosProbe(domain, "intruder")
    failure = None
    try:
        commands, status, diagnostics = [], [], []
        node = probe.node
        node.create_subscription(JointState, topics.JOINT_COMMANDS, commands.append, QOS)
        node.create_subscription(Float64MultiArray, topics.status_topic(NODE), status.append, QOS)
        node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, QOS)
        first = node.create_publisher(JointState, topics.JOINT_STATES, QOS)
        assert probe.spin_until(lambda: first.get_subscription_count() > 0, 60), "not subscribed"
        stamps = itertools.count(1_000_000_000, 1_000_000)

        def answered(pub, spin=probe) -> bool:
            """Publish one state; True once a command answers it (stamps are the states')."""
            stamp = next(stamps)
            pub.publish(state(stamp))
            spin.spin_until(lambda: any(stamp_ns(c) == stamp for c in commands), timeout=0.05)
            probe.spin_until(lambda: any(stamp_ns(c) == stamp for c in commands), timeout=0.05)
            return any(stamp_ns(c) == stamp for c in commands)

        assert probe.spin_until(lambda: answered(first), timeout=30), "the first is not answered"
        # A second publisher: one 10 MB state, then well-formed states of its own stamps.
        second = intruder.node.create_publisher(JointState, topics.JOINT_STATES, QOS)
        intruder.spin_until(lambda: second.get_subscription_count() > 0, timeout=5)
        n = HUGE_ENTRIES
        second.publish(JointState(name=[f"j{i:06d}" for i in range(n)], position=[0.0] * n,
                                  velocity=[0.0] * n))
        foreign = [next(stamps) for _ in range(50)]
        for stamp in foreign:
            second.publish(state(stamp))
        for _ in range(200):                             # the first goes on meanwhile
            assert answered(first), "the first publisher's state went unanswered"
        assert probe.spin_until(lambda: diagnostic_value(diagnostics, "unfollowed_publishers")
                                == "1", timeout=10), "the second publisher was not reported"
        assert not {stamp_ns(c) for c in commands} & set(foreign)
        last = status[-1]
        for field in ("inputs_oversized", "states_foreign", "source_handovers"):
            assert topics_field(last, field) == 0, field    # its states never came in
        # The first leaves: the controller subscribes again and follows the second.
        node.destroy_publisher(first)
        assert probe.spin_until(lambda: answered(second, intruder), timeout=30), \
            "the second publisher was not followed after the first left"
    except AssertionError as exc:
        failure = exc
    finally:
        intruder.close()
        probe.close()
        _, out = stop_node(proc)
    assert failure is None, f"{failure}; the node printed:\n{out[-3000:]}"
    assert out.count("publisher(s) on /joint_states not followed") == 1, out[-3000:]
    assert out.count("subscribing again") == 1, out[-3000:]


def topics_field(msg, name: str) -> float:
    return msg.data[topics.fields_of(msg.layout.dim[0].label).index(name)]


# -- the watch alone (no graph: a node and a subscription of its own) -------------------
class FakeNode:
    def __init__(self):
        self.publishers, self.logged = 0, []
        self.timer = None

    def create_timer(self, period, callback):
        self.timer = callback
        return callback

    def count_publishers(self, topic):
        return self.publishers

    def get_logger(self):
        return SimpleNamespace(warn=lambda m: self.logged.append(("warn", m)),
                               info=lambda m: self.logged.append(("info", m)))


def test_the_watch_reports_unfollowed_publishers_and_resubscribes_only_when_orphaned(monkeypatch):
    clock = [100.0]
    monkeypatch.setattr(state_source.time, "perf_counter", lambda: clock[0])
    node, sub = FakeNode(), SimpleNamespace(matched=1, topic_name="/joint_states")
    sub.get_publisher_count = lambda: sub.matched
    last_state, made = [100.0], []
    watch = StateSourceWatch(node, lambda: sub, lambda: made.append(clock[0]),
                             lambda: last_state[0], silence_s=2.0)

    def tick(dt=0.5, state_too=False):
        clock[0] += dt
        if state_too:
            last_state[0] = clock[0]
        watch.tick()

    node.publishers = 1
    tick(state_too=True)
    assert watch.unfollowed == 0 and not node.logged
    node.publishers = 3                                  # two others appear: one warning
    for _ in range(4):
        tick(state_too=True)
    assert watch.unfollowed == 2 and [level for level, _ in node.logged] == ["warn"]
    assert "2 publisher(s) on /joint_states not followed" in node.logged[0][1]
    sub.matched, node.publishers = 0, 2                  # the followed one left
    tick(1.0)                                            # 1 s without a state: not yet
    tick(0.5)
    assert not made
    tick(0.5)                                            # 2 s silent, orphaned 1 s: again
    assert made == [clock[0]] and watch.resubscriptions == 1
    tick(0.5)
    assert len(made) == 1                                # orphaned again: wait ORPHANED_S
    tick(state_source.ORPHANED_S)
    assert len(made) == 2
    sub.matched = 1                                      # matched: never while one is
    for _ in range(10):
        tick()
    assert len(made) == 2
    sub.matched, node.publishers = 0, 0                  # nobody there: nothing to match
    for _ in range(10):
        tick()
    assert len(made) == 2


def test_the_recorder_drops_only_our_own_profiles():
    for ours in (NODE_DDS_PROFILE, LOCKSTEP_DDS_PROFILE):
        env = {DDS_PROFILE_VARIABLE: str(ours), "X": "1"}
        assert drop_node_dds_profile(env) and env == {"X": "1"}
    mine = {DDS_PROFILE_VARIABLE: "/etc/my_profile.xml"}
    assert not drop_node_dds_profile(mine) and mine[DDS_PROFILE_VARIABLE] == "/etc/my_profile.xml"
