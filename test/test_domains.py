"""No silent cross-talk: machine-wide domain-id locks, sessions refusing an
occupied domain, and cr_analyze flagging recordings that mixed two runs."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message
from ros_probe import TEST_DOMAIN_SPAN, TEST_FIRST_DOMAIN, next_domain
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control.analysis import analyze
from cr_control.core import topics
from cr_control.core.ros_env import (
    DOMAIN_SPAN,
    FIRST_DOMAIN,
    DomainBusyError,
    claim_consecutive_domains,
    claim_domain,
    claim_free_domain,
    domain_in_use,
)
from cr_control.recording.recorder import McapBagWriter

HOLD = ("import sys, time\nfrom cr_control.core.ros_env import claim_domain, claim_free_domain\n"
        "arg = sys.argv[1]\n"
        f"lock = claim_free_domain({TEST_FIRST_DOMAIN}, {TEST_DOMAIN_SPAN}) if arg == 'free' "
        "else claim_domain(int(arg))\n"
        "print('held', lock.domain_id, flush=True)\ntime.sleep(600)\n")


#: Ids no test or session of the suite claims (they take 1..100): the run-of-ids test's
#: neighbours of the held id are then free whatever the other worker holds.
UNUSED_DOMAIN = 210


def holder(domain: str = "free") -> tuple[subprocess.Popen, int]:
    """Another process holding a free test domain, or ``domain`` (until killed), and the id."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, domain], stdout=subprocess.PIPE, text=True)
    word, domain = proc.stdout.readline().split()
    assert word == "held"
    return proc, int(domain)


# -- the lock ----------------------------------------------------------------------------

def test_next_domain_ids_are_test_ids_and_distinct():
    ids = [next_domain() for _ in range(3)]
    assert len(set(ids)) == 3
    assert all(TEST_FIRST_DOMAIN <= i < TEST_FIRST_DOMAIN + TEST_DOMAIN_SPAN for i in ids)


def test_a_held_domain_is_refused_and_freed_when_its_holder_dies():
    # ids no other test claims: the id freed by the kill is not taken by another worker first
    proc, domain = holder(str(UNUSED_DOMAIN + 1))
    try:
        assert domain_in_use(domain)
        with pytest.raises(DomainBusyError, match=rf"ROS_DOMAIN_ID {domain} is in use .*pid {proc.pid}"):
            claim_domain(domain)
        taken = claim_free_domain(domain, 2, start=domain)
        assert taken.domain_id == domain + 1                # skips the held one
        taken.release()
    finally:
        proc.send_signal(signal.SIGKILL)                    # no clean-up: the kernel frees it
        proc.wait()
    claim_domain(domain).release()


def test_claims_in_one_process_are_counted():
    domain = next_domain()                                  # held for this test
    again = claim_domain(domain)                            # e.g. an in-process Session
    again.release()
    assert again.held                                       # the test's claim remains
    proc = subprocess.run([sys.executable, "-c", HOLD, str(domain)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode != 0 and "is in use" in proc.stderr


def test_free_domain_id_skips_held_ids():
    lock = claim_free_domain()
    try:
        assert FIRST_DOMAIN <= lock.domain_id < FIRST_DOMAIN + DOMAIN_SPAN
        proc = subprocess.run([sys.executable, "-c", "from cr_control.core.ros_env import "
                               f"free_domain_id; print(free_domain_id({lock.domain_id}))"],
                              capture_output=True, text=True, timeout=60)
        assert int(proc.stdout) != lock.domain_id
    finally:
        lock.release()


def test_consecutive_domains_skip_a_run_broken_by_a_holder():
    proc, domain = holder(str(UNUSED_DOMAIN))               # another process holds one id
    try:
        locks = claim_consecutive_domains(3, first=domain - 1, span=8)
        ids = [lock.domain_id for lock in locks]
        assert ids == list(range(ids[0], ids[0] + 3)) and ids[0] > domain   # a run that avoids it
        assert not domain_in_use(ids[0])                    # ours (counted claims)
        with pytest.raises(DomainBusyError, match="no 3 consecutive"):
            claim_consecutive_domains(3, first=domain - 1, span=4)   # domain-1 .. domain+2
        for lock in locks:
            lock.release()
        assert all(not lock.held for lock in locks)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()


# -- two sessions ------------------------------------------------------------------------

@pytest.mark.ros
def test_second_session_on_the_same_domain_refuses(tmp_path):
    """Session A takes a free domain; B asked for it (option or environment) refuses to
    start with one line and creates nothing; A is not disturbed."""
    env = {k: v for k, v in os.environ.items() if k != "ROS_DOMAIN_ID"}
    env["PYTHONUNBUFFERED"] = "1"
    cmd = [sys.executable, "-m", "cr_control.tools.session", "--no-record"]
    # A runs until it is interrupted: it still holds its domain however long B takes to start
    # on a loaded machine (with a 3 s session, B once came after A had ended, and started)
    first = subprocess.Popen([*cmd, "--duration", "600", "--out", str(tmp_path / "a")], env=env,
                             text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        line = first.stdout.readline()
        assert "ROS_DOMAIN_ID=" in line, line + first.stderr.read()
        domain = int(line.split("ROS_DOMAIN_ID=")[1].split(",")[0])
        assert FIRST_DOMAIN <= domain < FIRST_DOMAIN + DOMAIN_SPAN
        for extra, extra_env in ((["--domain-id", str(domain)], {}), ([], {"ROS_DOMAIN_ID": str(domain)})):
            second = subprocess.run([*cmd, "--duration", "3", "--out", str(tmp_path / "b"), *extra],
                                    env={**env, **extra_env}, capture_output=True, text=True, timeout=60)
            assert second.returncode == 1 and "Traceback" not in second.stderr
            assert second.stderr.strip().splitlines() == [
                second.stderr.strip()], second.stderr                         # one line
            assert f"ROS_DOMAIN_ID {domain} is in use by another run" in second.stderr
            assert "refusing to start" in second.stderr
            assert not (tmp_path / "b").exists()
        assert first.poll() is None, first.stderr.read()               # A runs on, undisturbed
        first.send_signal(signal.SIGINT)
        out, err = first.communicate(timeout=120)
        assert first.returncode == 130 and "interrupted; processes stopped" in err, err
    finally:
        if first.poll() is None:
            first.kill()


# -- analysis ----------------------------------------------------------------------------

JOINTS = ["joint1", "joint2"]
TIMING_FIELDS = [*topics.PLANT_TIMING_FIELDS] + [
    f for f in ("command_publishers", "state_publishers") if f not in topics.PLANT_TIMING_FIELDS]


def joint_state(t: float, effort: float = 0.0) -> bytes:
    msg = JointState(name=JOINTS, position=[t, -t], velocity=[1.0, -1.0], effort=[effort, 0.0])
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))
    return serialize_message(msg)


def record(path: Path, state_stamps: list[float], command_stamps: list[float],
           command_publishers: int = 1, timing: dict[str, float] | None = None) -> Path:
    """A recording with the given stamp sequences (in recorded order)."""
    writer = McapBagWriter(path)
    qos = [{"history": "keep_last", "depth": 10}]
    states = writer.add_topic(topics.JOINT_STATES, "sensor_msgs/msg/JointState", qos, has_header=True)
    commands = writer.add_topic(topics.JOINT_COMMANDS, "sensor_msgs/msg/JointState",
                                qos * command_publishers, has_header=True)
    for i, t in enumerate(state_stamps):
        writer.write(states, joint_state(t), 1_000_000 + i)
    for i, t in enumerate(command_stamps):
        writer.write(commands, joint_state(t, effort=1.0), 1_000_000 + i)
    if timing is not None:
        channel = writer.add_topic(topics.PLANT_TIMING, "std_msgs/msg/Float64MultiArray")
        msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension, TIMING_FIELDS)
        values = {**dict.fromkeys(TIMING_FIELDS, 0.0), "stamp": state_stamps[-1], **timing}
        msg.data = [float(values[f]) for f in TIMING_FIELDS]
        writer.write(channel, serialize_message(msg), 2_000_000)
    writer.close()
    return path


CLEAN = [0.001 * i for i in range(1, 200)]


def cr_analyze(path: Path, capsys) -> tuple[int, str]:
    code = analyze.main([str(path), "--no-plots"])
    return code, capsys.readouterr().out


def test_clean_recording_has_no_warning(tmp_path, capsys):
    path = record(tmp_path / "clean.mcap", CLEAN, CLEAN, timing={"state_publishers": 1,
                                                                 "command_publishers": 1})
    m = analyze.metrics(analyze.load_session(path))
    assert m["data_warnings"] == 0 and m["publishers_joint_commands"] == 1
    assert m["publishers_joint_states"] == 1 and m["stamps_backwards_joint_states"] == 0
    code, out = cr_analyze(path, capsys)
    assert code == 0 and "WARNING" not in out


def test_interleaved_sessions_are_flagged(tmp_path, capsys):
    """Two plants on one domain: their stamp sequences interleave."""
    other = [100.0 + t for t in CLEAN]
    mixed = [t for pair in zip(CLEAN, other, strict=True) for t in pair]
    path = record(tmp_path / "mixed.mcap", mixed, CLEAN)
    m = analyze.metrics(analyze.load_session(path))
    assert m["stamps_backwards_joint_states"] == len(CLEAN) - 1
    assert m["stamps_backwards_joint_commands"] == 0 and m["data_warnings"] == 1
    code, out = cr_analyze(path, capsys)
    assert code == 0
    assert f"WARNING: mixed: stamps on /joint_states went backwards {len(CLEAN) - 1} times" in out


def test_repeated_stamps_are_flagged(tmp_path, capsys):
    path = record(tmp_path / "repeat.mcap", CLEAN, CLEAN[:50] + CLEAN[49:])
    m = analyze.metrics(analyze.load_session(path))
    assert m["stamps_repeated_joint_commands"] == 1 and m["data_warnings"] == 1
    assert "stamps on /joint_commands repeated 1 times" in cr_analyze(path, capsys)[1]


@pytest.mark.parametrize("source", ["mcap", "plant_timing"])
def test_second_publisher_is_flagged(tmp_path, capsys, source):
    """Publisher counts from the recording's channel metadata or the plant's timing."""
    if source == "mcap":
        path = record(tmp_path / "two.mcap", CLEAN, CLEAN, command_publishers=2)
    else:
        path = record(tmp_path / "two.mcap", CLEAN, CLEAN,
                      timing={"command_publishers": 2, "state_publishers": 1})
    m = analyze.metrics(analyze.load_session(path))
    assert m["publishers_joint_commands"] == 2 and m["data_warnings"] == 1
    out = cr_analyze(path, capsys)[1]
    assert "WARNING: two: 2 publishers on /joint_commands: another run shares this ROS_DOMAIN_ID" in out


def test_integrity_fields_reach_the_csv(tmp_path):
    session = analyze.load_session(record(tmp_path / "two.mcap", CLEAN, CLEAN, command_publishers=2))
    written = analyze.compare([session, session], tmp_path / "cmp")
    csv = (tmp_path / "cmp" / "comparison.csv").read_text().splitlines()
    rows = {line.split(",")[0]: line for line in csv}
    assert rows["publishers_joint_commands"].endswith(",2,2") and rows["data_warnings"].endswith(",1,1")
    assert "WARNING" in (tmp_path / "cmp" / "comparison.txt").read_text()
    assert written
