"""Target timeouts over ROS: a real publisher streams ``~/target_pose`` into a lockstep session,
answering the plant's states, and stops; ``target_timeout`` after the last target the controller
saw, it holds its pose and says so in its status (``target_stale`` = 1) and its log, once.

Judged on the simulated clock alone (the states' stamps, the clock the rule runs on): the
streamer sends a target for every tenth state it sees until the stamp ``STREAM_UNTIL``, then
nothing. The controller cannot have seen the last target before the state it answers, so it
may not go stale before that stamp plus the timeout; and the session runs long enough after it
for the target to have been delivered. The timeout is 5 s of simulated time here, so that a
streamer descheduled on a loaded machine leaves no gap the rule would rightly call stale: the
lockstep loop runs ~3x faster than real time, so 2 s (as before) was a stall of ~0.7 s of the
streamer's process (the offline tests in test_contact_guard.py check the rule at the shipped
0.5 s to the cycle).
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from ros_probe import RosProbe
from sensor_msgs.msg import JointState

from cr_control.analysis.analyze import load_session
from cr_control.schemes.blocks.contact_guard import POSE_STALE
from cr_control.tools.session import Session, SessionConfig

pytestmark = pytest.mark.ros   # every test here starts ROS (conftest.py)

SCHEME = "adaptive_impedance"
TIMEOUT = 5.0        # s of simulated time (target_timeout)
STREAM_UNTIL = 1.5   # the last target answers a state stamped before this (s, simulated)
DURATION = 9.5       # s simulated: the last target may reach the controller 3 s late (load)


def test_a_stream_that_stops_goes_stale_once(tmp_path):
    cfg = SessionConfig(scheme=SCHEME, duration=DURATION, mode="lockstep", out=tmp_path,
                        name="timeout", overrides=[f"{SCHEME}.target_timeout={TIMEOUT}"])
    session = Session(cfg, progress=lambda _: None)
    result: dict = {}

    def run() -> None:
        result["run"] = session.run()

    runner = threading.Thread(target=run)
    runner.start()
    answered: list[float] = []                 # stamps of the states answered with a target
    try:
        while session.domain is None and runner.is_alive():   # the session's domain, once held
            time.sleep(0.05)
        probe = RosProbe(session.domain.domain_id, "target_streamer")
        pub = probe.node.create_publisher(PoseStamped, f"/{SCHEME}/target_pose", 10)
        msg = PoseStamped()
        msg.pose.position.x, msg.pose.position.y = -0.05, 0.2    # the arm's start point
        msg.pose.orientation.w = 1.0
        seen = [0]

        def on_state(state: JointState) -> None:
            stamp = state.header.stamp.sec + 1e-9 * state.header.stamp.nanosec
            seen[0] += 1
            if stamp < STREAM_UNTIL and seen[0] % 10 == 1:
                pub.publish(msg)
                answered.append(stamp)

        probe.node.create_subscription(JointState, "/joint_states", on_state, 100)
        probe.spin_until(lambda: not runner.is_alive(), 300.0)
        probe.close()
    finally:
        runner.join(timeout=300)
    assert "run" in result, "the session did not finish"
    assert answered, "the streamer saw no state before the stream's end"
    last = max(answered)
    s = load_session(result["run"].mcap)
    stamp, stale = s.status["stamp"], s.status["target_stale"]
    assert stale.max() == POSE_STALE, f"never stale in {stamp[-1]:.1f} s (last target {last:.3f} s)"
    went = stamp[np.argmax(stale == POSE_STALE)]
    print(f"last target answers {last:.3f} s; stale at {went:.3f} s (timeout {TIMEOUT} s)")
    assert went > last + TIMEOUT               # it saw the last target at its stamp or later
    assert np.all(stale[stamp >= went] == POSE_STALE)             # and stays: no target since
    log = (result["run"].logs / f"{SCHEME}.log").read_text()
    assert log.count("~/target_pose stale") == 1
    assert "fresh again" not in log
