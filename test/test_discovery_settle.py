"""A real-time controller subscribes to /joint_states only once every
participant already on the domain has been discovered (cr_control/nodes/discovery_settle.py),
and the plant starts its loop only once a commander subscribes to its states."""

from __future__ import annotations

import math
import re
import sys
import time

import pytest
from ros_probe import RosProbe, next_domain, start_node, stop_node

from cr_control.core import topics
from cr_control.core.ros_env import NODE_DDS_PROFILE, isolated_env
from cr_control.nodes.discovery_settle import (
    DEFAULT_SETTLE_S,
    MAX_SETTLE_S,
    SETTLE_VARIABLE,
    settle_s,
)

NODE = "adaptive_impedance"
SETTLE = 2.0


@pytest.mark.parametrize(("text", "expected"), [
    (None, DEFAULT_SETTLE_S), ("", DEFAULT_SETTLE_S), ("0", 0.0), ("2.5", 2.5),
    ("-1", 0.0), ("1e9", MAX_SETTLE_S), ("soon", DEFAULT_SETTLE_S), ("nan", DEFAULT_SETTLE_S),
    ("inf", DEFAULT_SETTLE_S)])
def test_the_wait_is_read_from_the_environment(text, expected):
    env = {} if text is None else {SETTLE_VARIABLE: text}
    assert settle_s(env) == expected
    assert math.isfinite(settle_s(env))


def _subscribed_after(env: dict[str, str], *ros_args: str) -> tuple[float, str]:
    """Seconds from the controller's command publisher appearing to its state subscription
    (as this process discovers them), and the controller's output."""
    proc = start_node([sys.executable, "-m", "cr_control.nodes.controller_node", NODE], env,
                      *ros_args)
    probe = RosProbe(int(env["ROS_DOMAIN_ID"]))
    try:
        node = probe.node
        assert probe.spin_until(lambda: node.count_publishers(topics.JOINT_COMMANDS) > 0, 60)
        commanding = time.monotonic()
        assert probe.spin_until(lambda: node.count_subscribers(topics.JOINT_STATES) > 0, 30)
        waited = time.monotonic() - commanding
    finally:
        probe.close()
        _, out = stop_node(proc)
    return waited, out


@pytest.mark.ros
def test_a_realtime_controller_subscribes_to_the_states_only_after_the_wait():
    env = isolated_env(next_domain())
    env[SETTLE_VARIABLE] = str(SETTLE)
    waited, out = _subscribed_after(env)
    # Its publishers exist from its start; the subscription comes SETTLE s after the node
    # was made, by the node's own clock (its log lines' stamps, the first written just after
    # the timer was made: measured 1.968 s for 2). How much of that this process sees
    # depends on when it discovers each: not judged.
    announced = _log_stamp(out, "subscribing to /joint_states in")
    subscribed = _log_stamp(out, "subscribing to /joint_states now")
    print(f"subscribed {subscribed - announced:.3f} s after it said so; seen {waited:.3f} s "
          "after its publisher here")
    assert subscribed - announced >= SETTLE - 0.25
    assert waited < SETTLE + 5.0


@pytest.mark.ros
def test_a_lockstep_controller_subscribes_at_once():
    env = isolated_env(next_domain())
    env[SETTLE_VARIABLE] = "30"
    waited, _ = _subscribed_after(env, "-p", "lockstep:=true")
    assert waited < 5.0          # not the 30 s asked for real time


def _log_stamp(text: str, pattern: str) -> float:
    match = re.search(r"\[(\d+\.\d+)\] \[[^\]]+\]: [^\n]*" + pattern, text)
    assert match, f"no line matching {pattern!r} in:\n{text[-3000:]}"
    return float(match.group(1))


@pytest.mark.ros
def test_the_plant_starts_only_once_the_controller_listens(tmp_path, monkeypatch):
    """A real-time session: the recorder subscribes to the states at once (the plant's
    other condition), yet the plant starts only after the controller's subscription (its
    line is logged before the subscription exists: an order of events, not a duration),
    and no safe stop follows."""
    from cr_control.tools.session import Session, SessionConfig

    monkeypatch.setenv(SETTLE_VARIABLE, str(SETTLE))
    # the plant's watchdog at 2 s: this test is about the start's order, not about holding
    # 1 kHz on a loaded machine (the shipped 0.1 s fires at a 0.1 s stall of any process)
    cfg = SessionConfig(scheme=NODE, duration=1.0, out=tmp_path, domain_id=next_domain(),
                        name="settle", overrides=["plant.watchdog_missed_cycles=2000"])
    Session(cfg, progress=lambda *_: None).run()
    logs = tmp_path / "settle" / "logs"
    controller = (logs / f"{NODE}.log").read_text()
    plant = (logs / "plant.log").read_text()
    waiting = _log_stamp(controller, "subscribing to /joint_states in")
    subscribing = _log_stamp(controller, "subscribing to /joint_states now")
    started = _log_stamp(plant, "controller connected: starting")
    print(f"the plant started {started - waiting:.2f} s after the controller's {SETTLE:g} s wait began")
    assert started > subscribing
    assert "SAFE STOP" not in plant


def test_the_nodes_announce_themselves_every_quarter_second():
    """A participant joining a running session is sent to within ~0.6 s of its start, while
    Fast DDS's check of its new shared-memory port passes at once (fastdds_profile.xml)."""
    import xml.etree.ElementTree as ET

    ns = {"d": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    root = ET.parse(NODE_DDS_PROFILE).getroot()
    participants = [p for p in root.iterfind(".//d:participant", ns)
                    if p.get("is_default_profile") == "true"]
    assert len(participants) == 1
    period = participants[0].find("d:rtps/d:builtin/d:discovery_config/d:leaseAnnouncement", ns)
    seconds = int(period.find("d:sec", ns).text) + int(period.find("d:nanosec", ns).text) * 1e-9
    assert 0 < seconds <= 0.5
