"""Lockstep recording loses nothing to a slow reader, by construction.

A lockstep loop runs several times faster than real time; a recorder that falls behind
(starved of CPU on a 2-core machine) used to lose messages: the plant's KEEP_LAST writer
history overtook it, or its own reader history overflowed. Now the lockstep plant waits
for its readers' acknowledgements every ``LOCKSTEP_ACK_EVERY`` states (heartbeats every
10 ms, cr_control/core/fastdds_profile.xml, keep the wait short), and the recorder's
KEEP_ALL reader stops acknowledging when full, so the whole loop waits for it.

- The recorder process stopped (SIGSTOP) for 0.8 s in the middle of a lockstep session:
  every state, command and status is in the MCAP, the recorder reports none missed, and
  every loop topic was subscribed reliably. (Before: the recorder subscribed to
  /joint_commands and /joint_states as soon as the plant's or controller's subscription
  put them in the graph, with no offer to adapt to: best effort, lossy; and a 1.5 s stop
  lost 3300 messages of every topic once that was fixed, the writers' history overtaken.)
- A reader with the recorder's QoS that takes nothing for 4 s while the plant would
  publish 8000 states: the plant waits for it (Fast DDS holds 5000 for the reader), and in
  the end every state arrives, sequence numbers and stamps without a gap.
- The nodes' processes use the package's Fast DDS profile unless the user chose one.
"""

import os
import signal
import sys
import threading
import time

import numpy as np
import pytest
from rclpy.node import Node
from ros_probe import RosProbe, next_domain, start_node, stop_node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from cr_control.analysis.analyze import load_session
from cr_control.core import topics
from cr_control.core.ros_env import (
    DDS_PROFILE_IN_CWD,
    DDS_PROFILE_VARIABLE,
    NODE_DDS_PROFILE,
    use_node_dds_profile,
)
from cr_control.nodes.lockstep import ACK_EVERY, ReaderPacer
from cr_control.nodes.qos import PUBLISH_QOS, READY_QOS
from cr_control.recording.recorder import request_qos
from cr_control.tools.session import Session, SessionConfig

PLANT = [sys.executable, "-m", "cr_sim.plant_node"]
CONTROLLER = [sys.executable, "-m", "cr_control.nodes.controller_node"]


def _wait_for_line(path, text: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not (path.exists() and text in path.read_text(errors="replace")):
        assert time.monotonic() < deadline, f"no {text!r} in {path}"
        time.sleep(0.05)


def _offered_reliability(mcap) -> dict[str, list[str]]:
    """Reliability of every offer recorded per channel (rosbag2's offered_qos_profiles)."""
    from mcap.reader import make_reader

    from cr_control.core import ros_yaml

    with open(mcap, "rb") as f:
        channels = make_reader(f).get_summary().channels.values()
        return {c.topic: [q["reliability"] for q in ros_yaml.load(c.metadata["offered_qos_profiles"])
                          or []] for c in channels}


@pytest.mark.ros
def test_a_stopped_recorder_loses_nothing_in_lockstep(tmp_path):
    duration = 6.0
    cfg = SessionConfig(scheme="adaptive_impedance", duration=duration, mode="lockstep",
                        out=tmp_path, domain_id=next_domain(), name="run")
    session = Session(cfg, progress=lambda _: None)
    result: dict = {}
    runner = threading.Thread(target=lambda: result.setdefault("run", session.run()))
    runner.start()
    try:
        _wait_for_line(session.logs / "plant.log", "controller connected: starting")
        time.sleep(0.3)
        recorder = session.processes["recorder"].pid
        os.kill(recorder, signal.SIGSTOP)
        # ~1200 states' time at lockstep speed, well past the pacer's 250: without the waits
        # it loses hundreds per topic. Well under a second: Fast DDS (2.14.5) declares the
        # shared-memory port of a process frozen for longer dead (healthy_check_timeout_ms,
        # 1 s), and a writer that saw it so never delivers to that reader again; 0.8 s left
        # a descheduled test process 0.2 s before that.
        time.sleep(0.4)
        os.kill(recorder, signal.SIGCONT)
    finally:
        runner.join()
    s = load_session(result["run"].mcap)
    n = int(duration * 1000)
    # Every cycle's state and command, each stamp at least once: a state the plant sent
    # again (no answer within its lockstep_resend_s, 1 s, while the controller's pacer waited
    # for the thawed recorder on a loaded machine) is recorded again as sent, and answered
    # again: a repeat, not a loss (seen beside a busy core: the state of 1.956 s twice).
    for series in (s.joint_states, s.joint_commands):
        stamps = np.unique(np.rint(series.time * 1e3).astype(int))
        assert len(stamps) == n and stamps[0] == 0 and stamps[-1] == n - 1
        assert len(series.time) - n == series.stamps_repeated
    print(f"states sent again by the plant: {s.joint_states.stamps_repeated}")
    assert len(s.status["stamp"]) == n
    assert np.allclose(np.diff(s.status["stamp"]), 1e-3, atol=1e-9)
    log = (session.logs / "recorder.log").read_text()
    assert "missed" not in log and "wrote" in log
    # Every loop topic was subscribed once its publisher was there: reliable, offer known.
    offered = _offered_reliability(result["run"].mcap)
    for topic in (topics.JOINT_STATES, topics.WRENCH, topics.JOINT_COMMANDS, topics.CLOCK,
                  topics.status_topic("adaptive_impedance")):
        assert offered[topic] == ["reliable"], (topic, offered[topic])
    for node in ("plant", "adaptive_impedance"):
        assert "acknowledged nothing" not in (session.logs / f"{node}.log").read_text()


@pytest.mark.ros
def test_a_reader_that_takes_nothing_holds_the_plant_back(ros_env):
    states = 8000
    probe = RosProbe(int(ros_env["ROS_DOMAIN_ID"]))
    # Like the recorder: a subscription on a node nobody spins, taken by hand.
    reader = Node("_lossless_reader", context=probe.context)
    sub = reader.create_subscription(JointState, topics.JOINT_STATES, lambda _: None,
                                     request_qos([PUBLISH_QOS]), raw=True)
    ready = probe.node.create_publisher(Bool, topics.RECORDER_READY, READY_QOS)
    procs = [start_node([*CONTROLLER, "adaptive_impedance"], ros_env, "-p", "lockstep:=true"),
             start_node(PLANT, ros_env, "-p", "mode:=lockstep", "-p", f"duration:={states / 1000}",
                        "-p", "wait_for_recorder:=true")]
    taken: list[tuple[int, int]] = []   # (publication sequence number, stamp in ns)

    def take_all() -> int:
        before = len(taken)
        while (item := sub.handle.take_message(JointState, True)) is not None:
            data, info = item
            sec, nanosec = np.frombuffer(data, dtype="<i4", count=2, offset=4)
            taken.append((info["publication_sequence_number"], int(sec) * 10**9 + int(nanosec)))
        return len(taken) - before

    try:
        assert probe.spin_until(lambda: sub.get_publisher_count() == 1, 30.0), "no plant"
        ready.publish(Bool(data=True))      # the plant starts only now: we see its first state
        time.sleep(4.0)                     # ~12000 states' time at lockstep speed
        held = procs[1].poll() is None      # the plant waits for us
        deadline = time.monotonic() + 120.0
        while procs[1].poll() is None and time.monotonic() < deadline:
            take_all()
            time.sleep(0.05)
        time.sleep(0.5)
        take_all()
    finally:
        outputs = [stop_node(p)[1] for p in procs]
        reader.destroy_node()
        probe.close()
    assert procs[1].returncode == 0, outputs[1]
    assert held
    sequence = np.array([t[0] for t in taken])
    stamps = np.array([t[1] for t in taken])
    # Nothing lost between the plant's writer and us: every sample it published, in order.
    assert np.array_equal(sequence, np.arange(sequence[0], sequence[0] + len(taken)))
    # Every state once, except the plant's lockstep resends (lockstep_resend_s: a state
    # repeated when no command came for 1 s, as when the controller starts slowly).
    assert np.array_equal(np.unique(stamps), np.arange(states) * 1_000_000)
    assert set(np.diff(stamps)) <= {0, 1_000_000} and len(taken) - states <= 5, len(taken)
    assert "acknowledged nothing" not in outputs[1]


def test_nodes_use_the_package_dds_profile_unless_the_user_chose_one(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    env: dict[str, str] = {}
    assert use_node_dds_profile(env) and env[DDS_PROFILE_VARIABLE] == str(NODE_DDS_PROFILE)
    assert "<heartbeatPeriod>" in NODE_DDS_PROFILE.read_text()
    mine = {DDS_PROFILE_VARIABLE: "/etc/my_profile.xml"}
    assert not use_node_dds_profile(mine) and mine[DDS_PROFILE_VARIABLE] == "/etc/my_profile.xml"
    (tmp_path / DDS_PROFILE_IN_CWD).write_text("<dds/>")   # Fast DDS reads this one then
    env = {}
    assert not use_node_dds_profile(env) and env == {}


def test_tools_listen_on_udp_only_and_the_loop_on_shared_memory(tmp_path, monkeypatch):
    """A tool that joins (cr_param, cr_lifecycle) listens on UDP only, so the loop's nodes
    never run the shared-memory port check on it; the loop's nodes keep Fast DDS's
    transports (shared memory between them: UDP cost the Panda row 0.3 ms of CPU a cycle)."""
    from cr_control.core.ros_env import VISITOR_DDS_PROFILE, use_visitor_dds_profile

    monkeypatch.chdir(tmp_path)
    env: dict[str, str] = {}
    assert use_visitor_dds_profile(env) and env[DDS_PROFILE_VARIABLE] == str(VISITOR_DDS_PROFILE)
    visitor = VISITOR_DDS_PROFILE.read_text()
    assert "<udpv4>" in visitor and "<address>127.0.0.1</address>" in visitor
    assert "defaultUnicastLocatorList" not in NODE_DDS_PROFILE.read_text().split("-->")[1]
    mine = {DDS_PROFILE_VARIABLE: "/etc/my_profile.xml"}
    assert not use_visitor_dds_profile(mine) and mine[DDS_PROFILE_VARIABLE] == "/etc/my_profile.xml"


def _heartbeats_ns(profile) -> dict[str, int]:
    """Writer profile name -> heartbeat period (ns) of a Fast DDS profile file."""
    import xml.etree.ElementTree as ET

    ns = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"
    out = {}
    for w in ET.parse(profile).getroot().iter(f"{ns}data_writer"):
        period = w.find(f"{ns}times/{ns}heartbeatPeriod")
        out[w.get("profile_name")] = (int(period.find(f"{ns}sec").text) * 1_000_000_000
                                      + int(period.find(f"{ns}nanosec").text))
    return out


def test_lockstep_nodes_take_the_lockstep_profile(tmp_path, monkeypatch):
    """Real time: 10 ms heartbeats on the loop's writers only (100 ms on the others: the
    heartbeat traffic of the Panda session's ~10 writers cost 1.57x the echo pair's CPU);
    lockstep: 10 ms on every writer (the pacing waits for acks). A node asked for lockstep by
    -p or by a params file takes the lockstep profile."""
    from cr_control.core.ros_env import LOCKSTEP_DDS_PROFILE
    from cr_control.nodes.spin import lockstep_requested

    realtime, lockstep = _heartbeats_ns(NODE_DDS_PROFILE), _heartbeats_ns(LOCKSTEP_DDS_PROFILE)
    loop = {topics.JOINT_STATES, topics.JOINT_COMMANDS, topics.WRENCH, topics.CLOCK,
            topics.PLANT_SENSORS}
    assert realtime == {"cr_control_writer": 100_000_000, **{t: 10_000_000 for t in loop}}
    assert lockstep == {"cr_control_writer": 10_000_000}
    monkeypatch.chdir(tmp_path)
    env: dict[str, str] = {}
    assert use_node_dds_profile(env, lockstep=True) and env[DDS_PROFILE_VARIABLE] == str(LOCKSTEP_DDS_PROFILE)
    assert lockstep_requested(["x", "--ros-args", "-p", "lockstep:=true"])
    assert lockstep_requested(["x", "--ros-args", "-p", "mode:=lockstep"])
    assert not lockstep_requested(["x", "--ros-args", "-p", "mode:=realtime", "-p", "lockstep:=false"])
    params = tmp_path / "p.yaml"
    params.write_text("plant:\n  ros__parameters:\n    mode: lockstep\n")
    assert lockstep_requested(["x", "--ros-args", "--params-file", str(params)])
    params.write_text("plant:\n  ros__parameters:\n    mode: realtime\n")
    assert not lockstep_requested(["x", "--ros-args", "--params-file", str(params)])


class _Publisher:
    def __init__(self, topic_name: str, acks: bool):
        self.topic_name, self.acks, self.waits = topic_name, acks, 0

    def wait_for_all_acked(self, timeout) -> bool:
        self.waits += 1
        return self.acks


class _Node:
    def __init__(self):
        self.warnings: list[str] = []

    def get_logger(self):
        return self

    def warn(self, text: str) -> None:
        self.warnings.append(text)


def test_the_pacer_stops_waiting_for_a_topic_whose_readers_never_answer(monkeypatch):
    """One 10 s wait for a reader that is gone, then none: not 10 s every 250 cycles (a
    lockstep session crawled at 25 Hz for minutes behind a dead shared-memory port). The
    wait itself (spin.wait_for_readers, in slices) is replaced by one call per wait."""
    import cr_control.nodes.lockstep as lockstep

    def wait_once(publishers, timeout_s):
        assert timeout_s == lockstep.ACK_TIMEOUT_S
        return all(p.wait_for_all_acked(timeout_s) for p in publishers)

    monkeypatch.setattr(lockstep, "wait_for_readers", wait_once)
    node, good, stuck = _Node(), _Publisher("/status", True), _Publisher("/joint_commands", False)
    pacer = ReaderPacer(node, [good, None, stuck])
    for _ in range(3 * ACK_EVERY):
        pacer.published()
    assert (good.waits, stuck.waits) == (3, 1)
    assert len(node.warnings) == 1 and "/joint_commands" in node.warnings[0]
