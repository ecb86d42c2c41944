"""The recorder node as a separate process: a complete rosbag2-style MCAP after SIGTERM/SIGINT."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import rclpy
import yaml
from geometry_msgs.msg import WrenchStamped
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, MultiArrayDimension

from cr_control.core import topics

REPO = Path(__file__).resolve().parents[1]
WAIT_S = 30.0  # bound on every wait; a healthy run needs a few seconds in all
#: The test publishers keep every sample until the recorder has it (KEEP_ALL, reliable):
#: a burst then measures the recorder, not the writer's history (with KEEP_LAST 10 a
#: no-pause burst of 1500 lost up to 53 samples at the writer on a busy machine).
QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
READY_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATUS = topics.status_topic("test_ctrl")
RECORDED = [topics.JOINT_STATES, topics.WRENCH, STATUS]


class SyntheticSession:
    """An in-test node (own context and domain) publishing plant-like messages."""

    def __init__(self, domain_id: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node("synthetic_plant", context=self.context)
        self.node.declare_parameter("gains", [1.5, 2.5])
        self.node.declare_parameter("mode", "test")
        self.joint_pub = self.node.create_publisher(JointState, topics.JOINT_STATES, QOS)
        self.wrench_pub = self.node.create_publisher(WrenchStamped, topics.WRENCH, QOS)
        self.status_pub = self.node.create_publisher(Float64MultiArray, STATUS, QOS)
        self.ready = False
        self.node.create_subscription(Bool, topics.RECORDER_READY, self._on_ready, READY_QOS)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _on_ready(self, msg: Bool) -> None:
        self.ready = self.ready or msg.data

    def spin_until(self, done: Callable[[], bool], what: str,
                   proc: subprocess.Popen | None = None) -> None:
        """Spin until ``done()``; fail after WAIT_S or if ``proc`` died."""
        deadline = time.monotonic() + WAIT_S
        while not done():
            if proc is not None and proc.poll() is not None:
                pytest.fail(f"recorder exited ({proc.returncode}) while waiting for {what}:\n"
                            f"{proc.stderr.read() if proc.stderr else ''}")
            if time.monotonic() > deadline:
                pytest.fail(f"timed out waiting for {what}")
            self.executor.spin_until_future_complete(Future(), timeout_sec=0.05)

    def publish(self, n: int, pause: float = 0.001) -> dict[str, list]:
        """Publish ``n`` messages on each recorded topic, ``pause`` s apart; returns what was sent."""
        sent: dict[str, list] = {name: [] for name in RECORDED}
        status = topics.labelled_array(Float64MultiArray, MultiArrayDimension,
                                       topics.STATUS_FIELDS)
        for i in range(n):
            joint = JointState(name=["j1", "j2"], position=[0.001 * i, -0.5 * i],
                               velocity=[1.0, float(i)], effort=[0.25 * i, 3.0])
            joint.header.stamp.sec, joint.header.stamp.nanosec = 1000 + i, 1000 * i
            wrench = WrenchStamped()
            wrench.header.stamp = joint.header.stamp
            wrench.wrench.force.x, wrench.wrench.force.y = float(i), -float(i)
            status.data = [1000.0 + i] + [float(i * k) for k in range(1, len(
                topics.STATUS_FIELDS))]
            self.joint_pub.publish(joint)
            self.wrench_pub.publish(wrench)
            self.status_pub.publish(status)
            sent[topics.JOINT_STATES].append(joint)
            sent[topics.WRENCH].append(wrench)
            sent[STATUS].append(list(status.data))
            if pause:
                time.sleep(pause)
        for pub in (self.joint_pub, self.wrench_pub, self.status_pub):
            assert pub.wait_for_all_acked(Duration(seconds=WAIT_S)), "recorder did not ack"
        return sent

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()


def run_session(tmp_path: Path, ros_env: dict[str, str], sig: int, n: int,
                extra_topics: tuple[str, ...] = (), ready_timeout: float = 20.0,
                pause: float = 0.001, compression: str = "zstd", parameter_nodes: tuple[str, ...] = (),
                ) -> tuple[Path, dict[str, list], str]:
    """Record a synthetic session, end the recorder with ``sig``; (file, sent, stderr)."""
    output = tmp_path / "session.mcap"
    env = {**ros_env, "PYTHONPATH": os.pathsep.join(
        p for p in (str(REPO), ros_env.get("PYTHONPATH", "")) if p)}
    session = SyntheticSession(int(env["ROS_DOMAIN_ID"]))
    proc = None
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "cr_control.recording.recorder", "--ros-args",
             "-p", f"output:={output}",
             "-p", f"topics:=[{', '.join(RECORDED + list(extra_topics))}]",
             "-p", f"ready_timeout:={ready_timeout}", "-p", f"compression:={compression}"]
            + (["-p", f"parameter_nodes:=[{', '.join(parameter_nodes)}]"] if parameter_nodes else []),
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        session.spin_until(lambda: session.ready, "the recorder's ready message", proc)
        # Ready after a (short) ready timeout need not mean connected on a loaded machine.
        pubs = (session.joint_pub, session.wrench_pub, session.status_pub)
        session.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in pubs),
                           "the recorder's subscriptions", proc)
        sent = session.publish(n, pause)
        proc.send_signal(sig)
        # Keep spinning while the recorder drains (nothing more is published).
        session.spin_until(lambda: proc.poll() is not None, "the recorder to exit")
        stderr = proc.stderr.read() if proc.stderr else ""
        assert proc.returncode == 0, stderr
        return output, sent, stderr
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(timeout=WAIT_S)
        session.close()


def read_file(path: Path) -> dict:
    """Everything the assertions need from a recorded file (strict, summary-based reader),
    after checking that a streaming reader (no summary, chunk CRCs checked) reads it too."""
    check_streaming(path)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        decoded: dict[str, list] = {}
        times: dict[str, list[tuple[int, int]]] = {}
        for _, channel, message, ros_msg in reader.iter_decoded_messages(log_time_order=False):
            decoded.setdefault(channel.topic, []).append(ros_msg)
            times.setdefault(channel.topic, []).append((message.log_time, message.publish_time))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        return {"header": reader.get_header(), "summary": summary, "decoded": decoded,
                "times": times, "metadata": metadata}


def check_streaming(path: Path) -> None:
    """Read the file front to back as a stream (no summary): every record parses, chunk
    CRCs match, the message count equals the summary's, log times are in order."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as f:
        records = list(StreamReader(f, skip_magic=False, emit_chunks=False, validate_crcs=True).records)
    messages = [r for r in records if isinstance(r, Message)]
    with open(path, "rb") as f:
        summary = make_reader(f, validate_crcs=True).get_summary()
    assert len(messages) == summary.statistics.message_count
    times = [m.log_time for m in messages]
    for channel in {m.channel_id for m in messages}:
        own = [m.log_time for m in messages if m.channel_id == channel]
        assert own == sorted(own)
    # Written in receive order across topics too (up to a middleware thread descheduled
    # between stamping a message and storing it: far less than a batch of 0.1 s).
    assert all(b - a > -100_000_000 for a, b in zip(times, times[1:], strict=False))
    with open(path, "rb") as f:
        ordered = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=True)]
    assert ordered == sorted(times)


def check_complete_file(path: Path, sent: dict[str, list], n: int) -> dict:
    """Assert the rosbag2-style structure and that every sent message was recorded."""
    content = read_file(path)
    summary = content["summary"]
    assert content["header"].profile == "ros2"
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(RECORDED) <= set(channels)
    for topic in RECORDED:
        channel = channels[topic]
        schema = summary.schemas[channel.schema_id]
        assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
        offered = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        assert offered[0]["reliability"] == "reliable"
        assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
        assert summary.statistics.channel_message_counts[channel.id] == n, topic
        assert len(content["decoded"][topic]) == n, topic
    joint_schema = summary.schemas[channels[topics.JOINT_STATES].schema_id]
    assert joint_schema.name == "sensor_msgs/msg/JointState"
    text = joint_schema.data.decode()
    separator = "\n" + "=" * 80 + "\n"
    assert text.index("std_msgs/Header header") < text.index(separator + "MSG: std_msgs/Header\n")
    assert separator + "MSG: builtin_interfaces/Time\n" in text
    assert text.count("MSG: std_msgs/Header") == 1

    # Values survive the round trip, in order; publish time is the header stamp.
    for got, want in zip(content["decoded"][topics.JOINT_STATES], sent[topics.JOINT_STATES],
                         strict=True):
        assert list(got.name) == want.name and list(got.position) == list(want.position)
        assert list(got.effort) == list(want.effort)
        assert (got.header.stamp.sec, got.header.stamp.nanosec) == (
            want.header.stamp.sec, want.header.stamp.nanosec)
    for (log_time, publish_time), want in zip(content["times"][topics.JOINT_STATES],
                                              sent[topics.JOINT_STATES], strict=True):
        assert publish_time == want.header.stamp.sec * 10**9 + want.header.stamp.nanosec
        assert log_time > 1_600_000_000 * 10**9  # receive time, wall clock
    for got, want in zip(content["decoded"][topics.WRENCH], sent[topics.WRENCH], strict=True):
        assert (got.wrench.force.x, got.wrench.force.y) == (want.wrench.force.x,
                                                            want.wrench.force.y)
    for got, want in zip(content["decoded"][STATUS], sent[STATUS], strict=True):
        assert topics.fields_of(got.layout.dim[0].label) == topics.STATUS_FIELDS
        assert list(got.data) == want

    # rosbag2's metadata record, as ros2 bag reads it.
    bag = yaml.safe_load(content["metadata"]["rosbag2"]["serialized_metadata"])
    assert bag["storage_identifier"] == "mcap" and bag["version"] >= 9
    assert bag["message_count"] == summary.statistics.message_count
    counts = {t["topic_metadata"]["name"]: t["message_count"]
              for t in bag["topics_with_message_count"]}
    assert all(counts[topic] == n for topic in RECORDED)
    assert bag["duration"]["nanoseconds"] == (summary.statistics.message_end_time
                                              - summary.statistics.message_start_time)

    # The synthetic node's parameters, saved before ready.
    params = content["metadata"]["parameters/synthetic_plant"]
    assert yaml.safe_load(params["gains"]) == [1.5, 2.5]
    assert yaml.safe_load(params["mode"]) == "test"
    return content


@pytest.mark.ros
def test_sigterm_leaves_complete_rosbag2_style_file(tmp_path, ros_env):
    n = 300
    path, sent, _ = run_session(tmp_path, ros_env, signal.SIGTERM, n)
    check_complete_file(path, sent, n)


@pytest.mark.ros
def test_sigint_and_missing_topic_still_complete(tmp_path, ros_env):
    n = 50
    # Named parameter nodes: after a 1 s ready timeout the graph may not show the node yet.
    path, sent, stderr = run_session(tmp_path, ros_env, signal.SIGINT, n,
                                     extra_topics=("/never_published",), ready_timeout=1.0,
                                     parameter_nodes=("synthetic_plant",))
    assert "/never_published" in stderr  # the ready timeout names the missing topic
    content = check_complete_file(path, sent, n)
    assert "/never_published" not in {c.topic for c in content["summary"].channels.values()}


@pytest.mark.ros
def test_burst_is_recorded_whole_uncompressed(tmp_path, ros_env):
    """A burst (no pause) of 1500 messages per topic: taken in batches, nothing lost."""
    n = 1500
    path, sent, _ = run_session(tmp_path, ros_env, signal.SIGTERM, n, pause=0.0, compression="none")
    content = check_complete_file(path, sent, n)
    chunk_compression = {c.compression for c in content["summary"].chunk_indexes}
    assert chunk_compression == {""}


def test_writer_file_opens_in_strict_readers(tmp_path):
    """McapBagWriter alone (no ROS): many small chunks, schemas/channels, metadata, a
    channel with no messages; the summary, indexes, CRCs and rosbag2 record agree."""
    from rclpy.serialization import serialize_message

    from cr_control.recording.recorder import McapBagWriter

    path = tmp_path / "w.mcap"
    writer = McapBagWriter(path, compression="lz4", chunk_size=4096)
    joints = writer.add_topic(topics.JOINT_STATES, "sensor_msgs/msg/JointState", has_header=True)
    status = writer.add_topic(STATUS, "std_msgs/msg/Float64MultiArray")
    writer.add_topic("/never", "std_msgs/msg/Float64MultiArray")
    writer.add_metadata("parameters/x", {"a": "1"})
    n = 500
    for i in range(n):
        joint = JointState(name=["j1"], position=[float(i)])
        joint.header.stamp.sec, joint.header.stamp.nanosec = 7, i
        writer.write(joints, serialize_message(joint), 1_000_000 + 2 * i)
        writer.write(status, serialize_message(Float64MultiArray(data=[float(i)])), 1_000_001 + 2 * i)
    writer.close()
    check_streaming(path)
    content = read_file(path)
    summary = content["summary"]
    assert len(summary.chunk_indexes) > 5 and {c.compression for c in summary.chunk_indexes} == {"lz4"}
    assert summary.statistics.message_count == 2 * n
    assert summary.statistics.message_start_time == 1_000_000
    assert summary.statistics.message_end_time == 1_000_000 + 2 * n - 1
    assert [m.position[0] for m in content["decoded"][topics.JOINT_STATES]] == [float(i) for i in range(n)]
    assert content["times"][topics.JOINT_STATES][3] == (1_000_006, 7 * 10**9 + 3)
    assert content["times"][STATUS][3] == (1_000_007, 1_000_007)
    assert content["metadata"]["parameters/x"] == {"a": "1"}
    bag = yaml.safe_load(content["metadata"]["rosbag2"]["serialized_metadata"])
    assert bag["message_count"] == 2 * n
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in bag["topics_with_message_count"]}
    assert counts == {topics.JOINT_STATES: n, STATUS: n, "/never": 0}


@pytest.mark.ros
def test_a_topic_first_seen_through_a_subscriber_is_recorded_reliably(tmp_path, ros_env):
    """A topic is in the graph as soon as anyone subscribes (the plant to /joint_commands
    before the controller publishes): the recorder waits for a publisher and adapts to
    its offer (reliable) instead of subscribing at once, best effort, with nothing to
    adapt to (which lost messages in lockstep sessions)."""
    n, late = 200, "/late_topic"
    output = tmp_path / "late.mcap"
    env = {**ros_env, "PYTHONPATH": os.pathsep.join(
        p for p in (str(REPO), ros_env.get("PYTHONPATH", "")) if p)}
    session = SyntheticSession(int(env["ROS_DOMAIN_ID"]))
    session.node.create_subscription(Float64MultiArray, late, lambda _: None, QOS)
    proc = subprocess.Popen(
        [sys.executable, "-m", "cr_control.recording.recorder", "--ros-args",
         "-p", f"output:={output}", "-p", f"topics:=[{late}]", "-p", "ready_timeout:=1.0"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        session.spin_until(lambda: session.ready, "the recorder's ready message", proc)
        publisher = session.node.create_publisher(Float64MultiArray, late, QOS)
        session.spin_until(lambda: publisher.get_subscription_count() >= 2,
                           "the recorder's subscription", proc)
        for i in range(n):
            publisher.publish(Float64MultiArray(data=[float(i)]))
        assert publisher.wait_for_all_acked(Duration(seconds=WAIT_S))
        proc.send_signal(signal.SIGINT)
        session.spin_until(lambda: proc.poll() is not None, "the recorder to exit")
        assert proc.returncode == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=WAIT_S)
        session.close()
    content = read_file(output)
    assert [m.data[0] for m in content["decoded"][late]] == [float(i) for i in range(n)]
    channel = next(c for c in content["summary"].channels.values() if c.topic == late)
    offered = yaml.safe_load(channel.metadata["offered_qos_profiles"])
    assert [q["reliability"] for q in offered] == ["reliable"]
