"""cr_fuzz: hostile and careless input against the tools and running real-time sessions.

Seven suites (``--suite``), each printing a table:

- ``inputs``: robot descriptions, files and command lines (:mod:`cr_control.tools.fuzz_inputs`):
  each tool run as a process of its own under resource limits; no ROS session. CI runs
  these (``test/test_fuzz_inputs.py``).
- ``session``: on the scheme's thesis plant (or ``--robot``): parameters beyond their bounds,
  a second commander, a second source of joint states, a 10 MB JointState, a 10^6-element
  parameter request, a 10^12 N wrench, processes joining the domain.
- ``robot``: on the Panda with a wrist sensor (``panda_ft``): pose targets out of reach (10 m,
  1e300 m, a quaternion of norm 1e200, NaN), along the table, into it and diagonally down
  (judged by the force: within the baseline's 1.2 x + 2 N), wrench targets (1e6 N, pulled away then
  pressing), ~/zero_ft called over and over while pressing, and a node with a silent
  /joint_states publisher and a /joint_commands publisher on the domain before the session
  starts that then commands 1e308 N m.
- ``delay`` (:mod:`~cr_control.tools.fuzz_delay`): panda_ft behind a slow driver, the
  session's plant given a transport delay of 3 cycles and late bursts (~1 % and ~5 % of the
  cycles late); no joint above half its velocity limit, the force within the baseline's.
- ``position`` (:mod:`~cr_control.tools.fuzz_position`): a UR5 taking joint positions
  (``ur5_position``; ``--robot xarm7`` or ``panda_position`` too): absurd gains set live,
  far and NaN pose targets, a 1e12 N wrench, the controller's process stopped for 0.5 s;
  every commanded position finite and within one period of its velocity limit of the last.
- ``gains`` and ``gains_impedance`` (:mod:`~cr_control.tools.fuzz_gains`): the Panda wiping
  with adaptive_impedance and impedance, a gain set live to its accepted extreme (found by
  bisection through the controller's parameter service); no reflex, every joint below its
  velocity limit, the force at most 1.5 x the 10 N target.

Each session case runs a recorded real-time session (plant, controller, recorder:
``cr_session``'s processes on a domain of their own) while this process's own node, which
joined the domain before the session started, sends one kind of bad input two
plant-timing messages (~2 s) after the plant began. The recording then says what
happened, one row per case:

- alive: every process ran to the end (none died, the plant finished its run);
- finite: every recorded joint position and velocity is finite;
- max |q'|: the largest joint speed after the first second (rad/s or m/s);
- max |f|: the largest true contact force after the first second (N; robot plants);
- safe stop: the plant's safe stop engaged (``/plant/timing``);
- resumed: the controller commands at the end (none of its commands stopped, and the
  last timing window's share of fresh commands at least RESUMED_SHARE of the baseline
  run's median window: a stopped controller gives ~0 %, a loaded 2-core machine 55-95 %
  window to window; how well the loop runs is the miss column's);
- q'/lim: the largest joint speed after the first second as a share of the joint's URDF
  velocity limit (robot plants);
- miss: the longest run of plant ticks without a new command (ms at 1 kHz);
- jump: on a position interface, the largest step between consecutive commanded positions,
  in control periods of the joint's velocity limit (at most 1);
- verdict: ``survived`` when alive, finite, no safe stop, resumed, max |q'| within the
  suite's baseline run's (same scheme and robot, nothing sent) times SPEED_MARGIN plus
  SPEED_FLOOR (not for a target that moves the arm on purpose), for the force-judged
  cases max |f| within the baseline's times FORCE_MARGIN plus FORCE_FLOOR, and, for the
  cases held to it, the miss within the baseline's plus the case's margin; and, where
  the case says (:class:`~cr_control.tools.fuzz_case.Case`), against the robot's own
  limits: q'/lim, max |f| and the commanded positions (finite, jump at most 1); else
  ``FAILED`` with the first reason (a safe stop with the plant's reason and by when).

A case may change its session rather than send a message: ``Case.session_args`` are
cr_session's ``-p NODE.PARAM=VALUE`` overrides (the delay suite's plant parameters). A
suite (:class:`~cr_control.tools.fuzz_case.Suite`) names its baseline, robot and scheme
(``--robot`` and, where the suite names none, ``--scheme`` choose). The row's "seen" says
when the input began (s after the first state) and what the case noted.

Each session suite's baseline runs first. Exit status 0 if every case survived (or was
refused, for the inputs), 1 if one did not, 2 on a usage error.

    cr_fuzz                       # every case, adaptive_impedance, 8 s sessions
    cr_fuzz --suite inputs        # the tools alone, ~1 min
    cr_fuzz --suite position --robot xarm7
    cr_fuzz --cases second_commander,huge_joint_state --duration 6
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

from cr_control.core.ros_env import claim_free_domain, isolated_env
from cr_control.robots import ROBOTS, home_tip
from cr_control.tools import fuzz_delay, fuzz_gains, fuzz_position
from cr_control.tools.fuzz_case import Case, Suite, nothing
from cr_control.tools.fuzz_verdict import SETTLE_S, Row, judge, verdict


class Intruder:
    """This process's node on the session's domain: sets parameters, publishes."""

    def __init__(self, domain_id: int, controller: str):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        from cr_control.core import topics
        from cr_control.nodes.qos import CONTROL_QOS

        self.topics, self.qos = topics, CONTROL_QOS
        self.controller = f"/{controller}"
        #: The session's robot profile (None: a thesis plant) and the session itself (its
        #: processes, its configuration); run_case sets them.
        self.robot: str | None = None
        self.session = None
        #: What the case did, in words, for the row's "seen" (e.g. the value a gain reached).
        self.notes: list[str] = []
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node("cr_fuzz", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.joint_names: list[str] = []
        self.timing_messages = 0
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        self.node.create_subscription(Float64MultiArray, topics.PLANT_TIMING, self._on_timing, 10)
        self._state_sub = self.node.create_subscription(JointState, topics.JOINT_STATES,
                                                        self._on_state, CONTROL_QOS)
        self.publishers: dict[str, object] = {}
        #: (accepted, reason) of every parameter or service request answered
        self.replies: list[tuple[bool, str]] = []
        self._client = None
        self._client_ready = False

    def _on_timing(self, msg) -> None:
        self.timing_messages += 1

    def _on_state(self, msg) -> None:
        self.joint_names = list(msg.name)
        self.node.destroy_subscription(self._state_sub)   # one is enough: no 1 kHz load here

    def spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def publisher(self, msg_type, topic: str, qos=None):
        if topic not in self.publishers:
            self.publishers[topic] = self.node.create_publisher(msg_type, topic, qos or self.qos)
            self.spin_until(lambda: False, 0.3)         # let discovery match it
        return self.publishers[topic]

    # -- what a case sends ----------------------------------------------------------------
    def set_parameters(self, values: dict, wait: bool = True):
        """Ask the controller to set ``values`` (name -> value); the answers go to replies."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        if self._client is None:
            self._client = self.node.create_client(SetParameters, f"{self.controller}/set_parameters")
        client = self._client
        if not self._client_ready:
            if not self.spin_until(client.service_is_ready, 10.0):
                raise RuntimeError(f"{self.controller}/set_parameters never appeared")
            self._client_ready = True
        request = SetParameters.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()])
        future = client.call_async(request)
        if wait:
            self.spin_until(future.done, 10.0)
            if future.done():
                self.replies.extend((r.successful, r.reason) for r in future.result().results)
        return future

    def refused_flood(self, count: int = 200, seconds: float = 1.0) -> None:
        """``count`` refused requests (a NaN gain) in ``seconds``, then their answers."""
        futures = []
        for _ in range(count):
            futures.append(self.set_parameters({"Q_c": [float("nan"), 1.0]}, wait=False))
            self.spin_until(lambda: False, seconds / count)
        self.spin_until(lambda: all(f.done() for f in futures), 10.0)
        self.replies.extend((f.result().results[0].successful, f.result().results[0].reason)
                            for f in futures if f.done())

    def joint_state(self, names: list[str], position: list[float], velocity: list[float]):
        from sensor_msgs.msg import JointState

        msg = JointState(name=names, position=position, velocity=velocity)
        msg.header.stamp = self.node.get_clock().now().to_msg()
        return msg

    def commands(self, effort: Callable[[int], float], count: int, rate_hz: float = 1000.0) -> None:
        """``count`` commands on /joint_commands at ``rate_hz``, every joint at ``effort(i)``."""
        from sensor_msgs.msg import JointState

        pub = self.publisher(JointState, self.topics.JOINT_COMMANDS)
        names = self.joint_names
        for i in range(count):
            msg = JointState(name=names, effort=[effort(i)] * len(names))
            msg.header.stamp = self.node.get_clock().now().to_msg()
            pub.publish(msg)
            time.sleep(1.0 / rate_hz)

    def states(self, count: int, offset: float = 0.5) -> None:
        """``count`` well-formed states from a second /joint_states publisher, as fast as it
        can send them, every position ``offset`` away from zero."""
        from sensor_msgs.msg import JointState

        pub = self.publisher(JointState, self.topics.JOINT_STATES)
        names = self.joint_names
        for _ in range(count):
            pub.publish(self.joint_state(names, [offset] * len(names), [0.0] * len(names)))

    def huge_state(self, entries: int = 640_000) -> None:
        """One ~10 MB JointState (``entries`` names, positions and velocities)."""
        from sensor_msgs.msg import JointState

        pub = self.publisher(JointState, self.topics.JOINT_STATES)
        names = [f"j{i:06d}" for i in range(entries)]
        pub.publish(self.joint_state(names, [0.0] * entries, [0.0] * entries))

    def wrench(self, force: float, count: int = 100) -> None:
        from geometry_msgs.msg import WrenchStamped

        pub = self.publisher(WrenchStamped, self.topics.WRENCH)
        for _ in range(count):
            msg = WrenchStamped()
            msg.header.stamp = self.node.get_clock().now().to_msg()
            msg.wrench.force.x = msg.wrench.force.y = msg.wrench.force.z = force
            pub.publish(msg)
            time.sleep(0.01)

    def target_pose(self, position: list[float], quaternion_wxyz: list[float],
                    seconds: float = 2.0, rate_hz: float = 10.0) -> None:
        """A pose target on the controller's ~/target_pose (base frame) at ``rate_hz``."""
        from geometry_msgs.msg import PoseStamped

        from cr_control.nodes.qos import TARGET_QOS

        pub = self.publisher(PoseStamped, f"{self.controller}/{self.topics.TARGET_POSE_SUFFIX}",
                             TARGET_QOS)
        for _ in range(round(seconds * rate_hz)):
            msg = PoseStamped()
            msg.header.stamp = self.node.get_clock().now().to_msg()
            p, o = msg.pose.position, msg.pose.orientation
            p.x, p.y, p.z = position
            o.w, o.x, o.y, o.z = quaternion_wxyz
            pub.publish(msg)
            time.sleep(1.0 / rate_hz)

    def on_table(self, offset: list[float]) -> list[float]:
        """The robot's home tip (where its wiping table touches the tool; the Panda's
        without a robot) plus ``offset`` (m, base frame)."""
        tip = home_tip(ROBOTS[self.robot or "panda_ft"])
        return [float(x + d) for x, d in zip(tip, offset, strict=True)]

    def target_wrench(self, steps: list[tuple[float, float]], rate_hz: float = 10.0) -> None:
        """Wrench targets on ~/target_wrench: for each (force along the base's z (N), for how
        many seconds), that force at ``rate_hz``."""
        from geometry_msgs.msg import WrenchStamped

        from cr_control.nodes.qos import TARGET_QOS

        pub = self.publisher(WrenchStamped, f"{self.controller}/{self.topics.TARGET_WRENCH_SUFFIX}",
                             TARGET_QOS)
        for force, seconds in steps:
            for _ in range(round(seconds * rate_hz)):
                msg = WrenchStamped()
                msg.header.stamp = self.node.get_clock().now().to_msg()
                msg.wrench.force.z = force
                pub.publish(msg)
                time.sleep(1.0 / rate_hz)

    def zero_ft(self, calls: int = 15, every_s: float = 0.2) -> None:
        """The wiping stopped, then ``calls`` requests to zero the wrist sensor (~/zero_ft)
        while the tool presses, ``every_s`` apart; the answers go to replies."""
        from std_srvs.srv import Trigger

        self.set_parameters({"reference_amplitude": [0.0, 0.0, 0.0]})   # zeroing wants stillness
        self.spin_until(lambda: False, 2.0)
        client = self.node.create_client(Trigger, f"{self.controller}/zero_ft")
        if not self.spin_until(client.service_is_ready, 10.0):
            raise RuntimeError(f"{self.controller}/zero_ft never appeared")
        for _ in range(calls):
            future = client.call_async(Trigger.Request())
            self.spin_until(future.done, 5.0)
            if future.done():
                self.replies.append((future.result().success, future.result().message))
            self.spin_until(lambda: False, every_s)

    def silent_publishers(self) -> None:
        """A /joint_states publisher that never publishes and a /joint_commands publisher,
        both on the domain before the session's nodes start."""
        from sensor_msgs.msg import JointState

        self.publisher(JointState, self.topics.JOINT_STATES)
        self.publisher(JointState, self.topics.JOINT_COMMANDS)

    def joiners(self, count: int = 3, every_s: float = 0.5, stay_s: float = 0.5,
                topic: str = "/joint_states") -> None:
        """``count`` processes join the domain ``every_s`` apart, each a plain node that
        reads ``topic`` (/joint_states or the 1 Hz /plant/timing) for ``stay_s``."""
        kind = ("sensor_msgs.msg", "JointState") if topic == "/joint_states" else \
            ("std_msgs.msg", "Float64MultiArray")
        code = (f"import time, rclpy\nfrom {kind[0]} import {kind[1]}\n"
                "rclpy.init(); n = rclpy.create_node('joiner')\n"
                f"n.create_subscription({kind[1]}, {topic!r}, lambda m: None, 10)\n"
                f"end = time.monotonic() + {stay_s}\n"
                "while time.monotonic() < end: rclpy.spin_once(n, timeout_sec=0.05)\n"
                "n.destroy_node(); rclpy.shutdown()\n")
        env = isolated_env(self.context.get_domain_id())
        procs = []
        for _ in range(count):
            procs.append(subprocess.Popen([sys.executable, "-c", code], env=env,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            time.sleep(every_s)
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                raise RuntimeError("a joining process did not leave within 30 s") from None

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


CASES = [
    Case("baseline", "nothing (the run the others are judged against)", lambda x: None),
    Case("Q_c_1e308", "Q_c = [1e308, 1e308]", lambda x: x.set_parameters({"Q_c": [1e308, 1e308]})),
    Case("reference_frequency_1e308", "reference_frequency = 1e308",
         lambda x: x.set_parameters({"reference_frequency": 1e308})),
    Case("reference_amplitude_1000", "reference_amplitude = [1000, 1000]",
         lambda x: x.set_parameters({"reference_amplitude": [1000.0, 1000.0]})),
    Case("Q_c_nan", "Q_c = [nan, nan]", lambda x: x.set_parameters({"Q_c": [math.nan, math.nan]})),
    Case("Q_c_1e6_values", "a Q_c of 10^6 values (8 MB request)",
         lambda x: x.set_parameters({"Q_c": [1.0] * 1_000_000}), miss_margin=2.0),
    Case("refused_flood", "200 refused parameter requests in 1 s", lambda x: x.refused_flood()),
    Case("unknown_parameter", "an unknown parameter", lambda x: x.set_parameters({"no_such": 1.0})),
    Case("second_commander", "a second /joint_commands publisher: +-20 N m bang-bang, 1 s",
         lambda x: x.commands(lambda i: 20.0 if (i // 50) % 2 == 0 else -20.0, 1000)),
    Case("second_commander_1e308", "a second /joint_commands publisher: 1e308, 1 s",
         lambda x: x.commands(lambda i: 1e308, 1000)),
    Case("second_state_source", "50 000 well-formed states from a second /joint_states publisher",
         lambda x: x.states(50_000), extra_s=8.0),
    Case("huge_joint_state", "one 10 MB JointState (640 000 names)", lambda x: x.huge_state(),
         miss_margin=2.0),
    Case("wrench_1e12", "a wrench of 1e12 N, 1 s", lambda x: x.wrench(1e12)),
    Case("joining_nodes", "three processes join the domain and leave", lambda x: x.joiners(),
         miss_margin=5.0),
    # Discovered while the loop runs, and staying: Fast DDS opens its shared-memory ports then
    # (cr_control/nodes/discovery_settle.py; the nodes' 0.25 s announcements).
    Case("staying_node", "a process joins the domain and stays (reads /plant/timing)",
         lambda x: x.joiners(count=1, stay_s=3.0, topic="/plant/timing"), miss_margin=5.0),
    # -- a robot with a wrist sensor: targets out of reach, zeroing, wrench targets, intruder
    Case("robot_baseline", "nothing, on the robot (the run the robot cases are judged against)",
         lambda x: None, suite="robot"),
    Case("target_10_m", "a pose target 10 m up, 2 s at 10 Hz",
         lambda x: x.target_pose([0.0, 0.0, 10.0], [0.0, 1.0, 0.0, 0.0]), suite="robot",
         speed_judged=False),
    Case("target_1e300_m", "a pose target at 1e300 m, 2 s at 10 Hz",
         lambda x: x.target_pose([1e300, -1e300, 1e300], [0.0, 1.0, 0.0, 0.0]), suite="robot",
         speed_judged=False),
    Case("target_along_table", "a pose target 10 m along the table, at the tool's height, 2 s "
         "at 10 Hz", lambda x: x.target_pose(x.on_table([10.0, 0.0, 0.0]), [0.0, 1.0, 0.0, 0.0]),
         suite="robot", speed_judged=False, force_judged=True),
    Case("target_deep", "a pose target 0.5 m into the table below the tool, 2 s at 10 Hz",
         lambda x: x.target_pose(x.on_table([0.0, 0.0, -0.5]), [0.0, 1.0, 0.0, 0.0]),
         suite="robot", speed_judged=False, force_judged=True),
    Case("target_diagonal", "a pose target 10 m back, beside and down, the tool turned askew, "
         "2 s at 10 Hz", lambda x: x.target_pose(x.on_table([-10.0, 10.0, -10.0]),
                                                 [0.3, -0.5, 0.7, 0.4]),
         suite="robot", speed_judged=False, force_judged=True),
    Case("target_quaternion_1e200", "a pose target whose quaternion has norm 1e200",
         lambda x: x.target_pose([0.3, 0.0, 0.5], [0.0, 1e200, 0.0, 0.0]), suite="robot",
         speed_judged=False),
    Case("target_nan", "a pose target of NaN", lambda x: x.target_pose(
        [math.nan, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0]), suite="robot", force_judged=True),
    Case("wrench_target_1e6", "a wrench target of 1e6 N into the table, 2 s",
         lambda x: x.target_wrench([(1e6, 2.0)]), suite="robot"),
    Case("wrench_pull_away", "a wrench target of -10 N (pull away) 2 s, then +10 N 2 s",
         lambda x: x.target_wrench([(-10.0, 2.0), (10.0, 2.0)]), suite="robot",
         speed_judged=False, force_judged=True, extra_s=2.0),
    Case("zeroing_walk", "the wiping stopped (reference_amplitude 0), then ~/zero_ft 15 times, "
         "every 0.2 s, while pressing", lambda x: x.zero_ft(), suite="robot", speed_judged=False,
         force_judged=True, extra_s=2.0),
    Case("silent_intruder", "a node with a silent /joint_states and a /joint_commands "
         "publisher before the session starts, then 1e308 N m commands for 1 s",
         lambda x: x.commands(lambda i: 1e308, 1000), suite="robot",
         prepare=lambda x: x.silent_publishers()),
]
#: The session suites defined here: their baseline case, robot profile and scheme (Suite).
#: The "inputs" suite (no sessions) is cr_control.tools.fuzz_inputs.
SUITES = {"session": Suite("baseline", None), "robot": Suite("robot_baseline", "panda_ft")}
#: Every session suite, in the order they run: this module's, then the delay, position and
#: gains suites' (their modules beside this one).
SESSION_SUITES = {**SUITES, **fuzz_delay.SUITES, **fuzz_position.SUITES, **fuzz_gains.SUITES}
#: Every session case, by suite.
ALL_CASES = CASES + fuzz_delay.CASES + fuzz_position.CASES + fuzz_gains.CASES
CASE_NAMES = [case.name for case in ALL_CASES]
def suite_robot(suite: str, args: argparse.Namespace) -> str | None:
    """The robot profile a suite's sessions run on."""
    return args.robot or SESSION_SUITES[suite].robot


def suite_scheme(suite: str, args: argparse.Namespace) -> str:
    """The scheme a suite's sessions run: its own, else --scheme."""
    return SESSION_SUITES[suite].scheme or args.scheme


def run_case(case: Case, args: argparse.Namespace, out: Path, progress=print,
             reference: float | None = None) -> Row:
    """Run ``case`` in a recorded real-time session; its row (verdict not yet set);
    ``reference``: the baseline's median fresh share."""
    from cr_control.tools.session import Session, SessionConfig, SessionError

    cfg = SessionConfig(scheme=suite_scheme(case.suite, args),
                        duration=args.duration + case.extra_s,
                        robot=suite_robot(case.suite, args), out=out,
                        overrides=list(case.session_args),
                        name=f"fuzz-{datetime.now():%Y%m%d-%H%M%S}-{case.name}")
    session = Session(cfg, progress=lambda *_: None)
    domain = claim_free_domain()
    intruder = Intruder(domain.domain_id, cfg.scheme)
    intruder.robot, intruder.session = cfg.robot, session
    failure: list[str] = []
    if case.prepare is not None:
        case.prepare(intruder)

    def run() -> None:
        try:
            session.run(domain)
        except SessionError as exc:
            failure.append(str(exc).splitlines()[0])

    worker = threading.Thread(target=run, name=f"session-{case.name}")
    note = ""
    sent: float | None = None          # when the case began sending (wall clock)
    try:
        worker.start()
        started = intruder.spin_until(lambda: intruder.timing_messages >= 2 and intruder.joint_names,
                                      60.0 + args.duration)
        if started and worker.is_alive():
            sent = time.time()
            try:
                case.send(intruder)
            except Exception as exc:  # noqa: BLE001 - the row says what the fuzz itself could not do
                note = f"could not send: {exc}"
        elif worker.is_alive():
            note = "the session never started"
        while worker.is_alive():
            intruder.spin_until(lambda: not worker.is_alive(), 1.0)
    finally:
        worker.join()
        intruder.close()
        domain.release()
    row = judge(session.mcap, case.name, not failure, failure[0] if failure else note, reference,
                robot=cfg.robot)
    if sent is not None and case.send is not nothing and math.isfinite(row.first_state):
        intruder.notes.insert(0, f"sent at {sent - row.first_state:.1f} s")
    answers = ""
    if intruder.replies:
        accepted = sum(ok for ok, _ in intruder.replies)
        refused = [reason for ok, reason in intruder.replies if not ok]
        first = (refused or ["accepted"])[0]
        first = first if len(first) <= 70 else first[:67] + "..."
        answers = f"{len(intruder.replies)} answer(s), {accepted} accepted: {first}"
    row.seen = "; ".join(filter(None, [*intruder.notes, answers, row.seen]))
    return row


def format_rows(rows: list[Row], cases: dict[str, Case]) -> str:
    """The suite's table (q'/lim: the largest joint speed's share of its velocity limit;
    jump: the largest commanded position step in periods of the velocity limit), then
    what each case sent and what was seen."""
    width = max([27] + [len(r.case) for r in rows])
    head = f"{'case':{width}} {'alive':5} {'finite':6} {'max|q_dot|':>10} {'q_dot/lim':>9} " \
           f"{'max|f| N':>8} {'safe stop':9} {'resumed':7} {'miss ms':>7} {'jump':>6}  verdict"
    lines = [head, "-" * len(head)]
    for r in rows:
        yes = {True: "yes", False: "no"}
        lines.append(f"{r.case:{width}} {yes[r.alive]:5} {yes[r.finite]:6} {r.max_speed:10.3f} "
                     f"{r.speed_share:9.2f} {r.max_force:8.1f} {yes[r.safe_stop]:9} "
                     f"{yes[r.resumed]:7} {r.miss_ms:7.0f} {r.command_jump:6.2f}  {r.verdict}"
                     + (f"  ({r.note})" if r.note else ""))
    lines.append("")
    lines += [f"{r.case}: {cases[r.case].what}" + (f"; seen: {r.seen}" if r.seen else "")
              for r in rows]
    return "\n".join(lines)


ALL_SUITES = ("inputs", *SESSION_SUITES)


def build_parser() -> argparse.ArgumentParser:
    from cr_control.schemes.registry import SCHEMES
    from cr_control.tools.fuzz_inputs import INPUT_CASE_NAMES

    parser = argparse.ArgumentParser(prog="cr_fuzz", description=__doc__.split("\n\n")[0])
    parser.add_argument("--suite", default=",".join(ALL_SUITES),
                        help=f"comma-separated, of: {', '.join(ALL_SUITES)} (default: all)")
    parser.add_argument("--cases", default=None,
                        help=f"comma-separated, of any suite (default: every case of --suite): "
                             f"{', '.join(INPUT_CASE_NAMES + CASE_NAMES)}; a session suite's "
                             "baseline always runs")
    parser.add_argument("--scheme", default="adaptive_impedance", choices=sorted(SCHEMES))
    parser.add_argument("--robot", default=None,
                        help="a robot profile for every session (default: the session suite on "
                             "the scheme's thesis plant, the robot suite on panda_ft)")
    parser.add_argument("--duration", type=float, default=8.0, help="seconds per session")
    parser.add_argument("--out", type=Path, default=None,
                        help="keep the sessions here (default: a temporary folder)")
    return parser


def _names(text: str) -> list[str]:
    return [name.strip() for name in text.split(",") if name.strip()]


def run_suite(suite: str, wanted: list[str], args: argparse.Namespace, out: Path) -> bool:
    """The session suite's baseline and its ``wanted`` cases, then its table; all survived?"""
    cases = {case.name: case for case in ALL_CASES}
    baseline = SESSION_SUITES[suite].baseline
    order = [baseline] + [c.name for c in ALL_CASES if c.suite == suite and c.name in wanted
                          and c.name != baseline]
    rows: list[Row] = []
    for i, name in enumerate(order, 1):
        print(f"[{suite} {i}/{len(order)}] {name}: {cases[name].what} ...", flush=True)
        row = run_case(cases[name], args, out, reference=rows[0].fresh_median if rows else None)
        row.verdict = verdict(row, cases[name], rows[0] if rows else None)
        print(f"    {row.verdict}", flush=True)
        rows.append(row)
    print()
    print(format_rows(rows, cases))
    print()
    return all(r.verdict == "survived" for r in rows)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    from cr_control.tools import fuzz_inputs

    args = build_parser().parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")   # never off this machine
    suites = _names(args.suite)
    every = fuzz_inputs.INPUT_CASE_NAMES + CASE_NAMES
    unknown = sorted(set(suites) - set(ALL_SUITES))
    if unknown:
        print(f"cr_fuzz: unknown suite(s) {', '.join(unknown)}; known: {', '.join(ALL_SUITES)}",
              file=sys.stderr)
        return 2
    wanted = _names(args.cases) if args.cases is not None else [
        name for name in every if _suite_of(name) in suites]
    unknown = sorted(set(wanted) - set(every))
    if unknown:
        print(f"cr_fuzz: unknown case(s) {', '.join(unknown)}; known: {', '.join(every)}",
              file=sys.stderr)
        return 2
    if not 2.0 * SETTLE_S + 2.0 < args.duration <= 600.0:
        print(f"cr_fuzz: --duration must be in (4, 600] s, not {args.duration}", file=sys.stderr)
        return 2
    if args.robot is not None and args.robot not in ROBOTS:
        print(f"cr_fuzz: unknown robot {args.robot!r}; known: {', '.join(sorted(ROBOTS))}",
              file=sys.stderr)
        return 2
    ok = True
    inputs = [name for name in fuzz_inputs.INPUT_CASE_NAMES if name in wanted]
    if inputs:
        rows = fuzz_inputs.run_inputs(inputs, progress=lambda line: print(line, flush=True))
        print()
        print(fuzz_inputs.format_input_rows(rows))
        print()
        ok = all(r.verdict == "refused" for r in rows)
    with tempfile.TemporaryDirectory(prefix="cr_fuzz-") as tmp:
        for suite in SESSION_SUITES:
            if any(_suite_of(name) == suite for name in wanted):
                ok = run_suite(suite, wanted, args, args.out or Path(tmp)) and ok
    return 0 if ok else 1


def _suite_of(name: str) -> str:
    """The suite a case of any suite belongs to."""
    return next((case.suite for case in ALL_CASES if case.name == name), "inputs")


if __name__ == "__main__":
    sys.exit(main())
