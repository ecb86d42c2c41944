"""Your robot: a controller drives a stand-in for a ros2_control robot that speaks exactly
the topics of docs/any_robot.md, "Your robot over ros2_control".

The stand-in (a node in this process) owns the simulated Panda of the wiping task and
behaves like joint_state_broadcaster (/joint_states: all 9 joints, fingers first, arm
joints shuffled, positions, velocities, efforts, stamped), force_torque_sensor_broadcaster
(/force_torque_sensor_broadcaster/wrench: the wrist sensor's force and torque, frame_id
panda_link8) and an effort
forward_command_controller (/effort_controller/commands: a Float64MultiArray mapped onto
its own ``joints`` list, an order unlike the URDF's and the states'). It steps the plant
1 ms per command and then publishes the next state (lockstep: each command answers the
state it was computed from; a state with no answer within 1 s is sent again). The
controller is the ``adaptive_impedance`` executable with the Panda's params file,
``forward_command_topic`` and ``joint_names`` = the forward_command_controller's order.

- every array has 7 finite values and, mapped by the forward controller's joint order,
  equals the controller's /joint_commands efforts of the same cycle (same stamp);
- 2 s of the closed loop reproduce the offline loop (``offline.run`` on the panda_ft
  scheme, without the plant node's command limits: a forward_command_controller has none):
  same plant, same law, same stamps (integer nanoseconds), float64 carried losslessly, so
  the same floating-point operations: states, forces and torques agree bit for bit (0
  measured; asserted to 1e-12). Anything a lost or reordered message changes is far above
  that: one cycle fed the previous wrench (offline, at 20, 500 or 1500 ms) moves the joints
  by 5e-9 to 8e-7 rad and the force by 7e-6 to 1e-3 N by 2 s; so where the controller read
  an older wrench than its state's (its status's ``wrench_age_ms``), the offline loop reads
  the same one (lockstep_replay.py);
- the TRUE contact force (the plant's, not the sensor's reading) is positive from 50 ms after
  the law starts (after the 30 ms start-up zeroing) and within 0.5 N of the 10 N desired
  once ramped in (t >= 1.5 s);
- a state that lacks an arm joint is not computed on: the controller holds (it logs why
  and answers with its last command, bit for bit; a forward_command_controller would keep
  applying that command anyway), and the next good state gets a fresh command.
"""

import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from lockstep_replay import as_read
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_probe import RosProbe, start_node, stop_node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from cr_control import robots
from cr_control.core import topics
from cr_control.core.paths import config_file
from cr_control.offline import build_scheme, run
from cr_control.schemes.blocks.wrist_sensor import ZERO_START_WINDOW_S
from cr_sim.plants.registry import make_plant

pytestmark = pytest.mark.ros   # every test here starts ROS (conftest.py)

QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
FORWARD_TOPIC = "/effort_controller/commands"
ARM = [f"panda_joint{i}" for i in range(1, 8)]
#: joint_state_broadcaster's order here: fingers first, the arm shuffled.
STATE_ORDER = ["panda_finger_joint2", "panda_finger_joint1", "panda_joint5", "panda_joint2",
               "panda_joint7", "panda_joint1", "panda_joint4", "panda_joint6", "panda_joint3"]
#: The forward_command_controller's ``joints`` (= the controller's joint_names).
FORWARD_JOINTS = ["panda_joint3", "panda_joint6", "panda_joint1", "panda_joint7",
                  "panda_joint4", "panda_joint2", "panda_joint5"]
CYCLES = 2000
PERIOD = 1e-3
#: A state no answer came for is sent again after this long (a state published before the
#: controller's subscription matched). Long: the controller answers a resent state again,
#: and its array (no stamp) would be taken for the next state's answer; a controller
#: descheduled for 1 s on a busy machine must not look like a lost state.
RESEND_S = 5.0
DESIRED_FORCE = robots.WIPE_FORCE


def stamp_key(t: float) -> int:
    """A plant time as the header's integer nanoseconds (as the offline loop rounds it)."""
    return round(t * 1e9)


class StandInRobot:
    """A simulated Panda behind joint_state_broadcaster, force_torque_sensor_broadcaster
    and an effort forward_command_controller, stepped 1 ms per command."""

    def __init__(self, node, plant):
        self.node, self.plant = node, plant
        names = list(plant.joint_names)
        self.state_index = [names.index(j) for j in STATE_ORDER]
        # the plant's commanded joints, each taken from the array by the forward order
        self.from_array = [FORWARD_JOINTS.index(j) for j in plant.command_joints]
        self.state_pub = node.create_publisher(JointState, topics.JOINT_STATES, QOS)
        self.wrench_pub = node.create_publisher(WrenchStamped, topics.WRENCH, QOS)
        self.command_sub = node.create_subscription(Float64MultiArray, FORWARD_TOPIC,
                                                    self._on_array, QOS)
        node.create_subscription(JointState, topics.JOINT_COMMANDS, self._on_joint_commands, QOS)
        node.create_subscription(Float64MultiArray, "/adaptive_impedance/status", self._on_status, QOS)
        self.status: dict[str, list[float]] = {"stamp": [], "wrench_age_ms": []}
        self.rows: list[tuple[int, object, list[float]]] = []   # (stamp, measurement, array)
        self.joint_commands: dict[int, tuple[list[str], list[float]]] = {}
        self.pending = None            # (stamp, measurement) of the state awaiting its command
        self.messages: tuple = ()      # that state's wrench and joint state, for a resend
        self.budget = 0                # states to publish, one per command
        self.drop = None               # a joint left out of the next state
        self.stray = self.resends = 0
        self.last_sent = 0.0
        self.truth: dict[int, np.ndarray] = {}    # the true contact force of each state

    def publish_state(self) -> None:
        """The wrench, then the joint state (the controller reads the force it last got)."""
        m = self.plant.measurement()
        key = stamp_key(m.time)
        sec, nanosec = divmod(key, 1_000_000_000)
        wrench = WrenchStamped()
        wrench.header.stamp.sec, wrench.header.stamp.nanosec = sec, nanosec
        wrench.header.frame_id = self.plant.wrench_frame
        wrench.wrench.force.x, wrench.wrench.force.y, wrench.wrench.force.z = (float(f) for f in m.force)
        wrench.wrench.torque.x, wrench.wrench.torque.y, wrench.wrench.torque.z = (
            float(f) for f in m.torque)
        self.truth[key] = self.plant.contact_wrench().force
        keep = [(j, i) for j, i in zip(STATE_ORDER, self.state_index, strict=True) if j != self.drop]
        state = JointState(name=[j for j, _ in keep],
                           position=[float(m.position[i]) for _, i in keep],
                           velocity=[float(m.velocity[i]) for _, i in keep],
                           effort=[float(m.effort[i]) for _, i in keep])
        state.header.stamp = wrench.header.stamp
        self.drop = None
        self.pending, self.messages = (key, m), (wrench, state)
        self.resend()

    def resend(self) -> None:
        wrench, state = self.messages
        self.wrench_pub.publish(wrench)
        self.state_pub.publish(state)
        self.last_sent = time.monotonic()

    def resend_if_stalled(self) -> None:
        if self.pending is not None and time.monotonic() - self.last_sent > RESEND_S:
            self.resends += 1
            self.resend()

    def _on_array(self, msg: Float64MultiArray) -> None:
        if self.pending is None:
            self.stray += 1            # no state awaits a command: not lockstep any more
            return
        key, m = self.pending
        data = list(msg.data)
        self.rows.append((key, m, data))
        self.pending = None
        if len(data) != len(FORWARD_JOINTS) or not all(map(math.isfinite, data)):
            return                     # forward_command_controller ignores it; asserted below
        self.plant.step(np.array([data[i] for i in self.from_array]), PERIOD)
        if len(self.rows) < self.budget:
            self.publish_state()

    def _on_status(self, msg: Float64MultiArray) -> None:
        """The controller's status: the wrench age it read at each state (lockstep_replay)."""
        fields = topics.fields_of(msg.layout.dim[0].label)
        for name in self.status:
            self.status[name].append(msg.data[fields.index(name)])

    def _on_joint_commands(self, msg: JointState) -> None:
        key = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.joint_commands.setdefault(key, (list(msg.name), list(msg.effort)))


def run_until(probe: RosProbe, robot: StandInRobot, done, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() > deadline:
            return False
        probe.executor.spin_once(timeout_sec=0.05)
        robot.resend_if_stalled()
    return True


@pytest.fixture
def probe(ros_env):
    p = RosProbe(int(ros_env["ROS_DOMAIN_ID"]), name="stand_in_robot")
    yield p
    p.close()


def test_a_controller_drives_a_ros2_control_robot(ros_env, probe):
    r = robots.robot("panda_ft")
    values = {k: v for k, v in robots.plant_values(r).items() if k != "scenario"}
    robot = StandInRobot(probe.node, make_plant("urdf_surface", values))
    executable = Path(sys.executable).with_name("adaptive_impedance")
    assert executable.is_file(), executable
    started = time.monotonic()
    controller = start_node([str(executable)], ros_env, "--params-file",
                            str(config_file("robots/panda_ft/adaptive_impedance.yaml")),
                            "-p", f"forward_command_topic:={FORWARD_TOPIC}",
                            "-p", f"joint_names:=[{', '.join(FORWARD_JOINTS)}]",
                            "-p", "state_source:=/stand_in_robot",   # as joint_state_broadcaster
                            # the stand-in steps on each answer, as a lockstep plant does, and
                            # stamps its simulated time: no real-time delay watch on it
                            "-p", "lockstep:=true")
    try:
        node = probe.node
        connected = run_until(probe, robot, lambda: controller.poll() is not None or (
            robot.command_sub.get_publisher_count() > 0
            and robot.state_pub.get_subscription_count() > 0
            and robot.wrench_pub.get_subscription_count() > 0
            and node.count_publishers(topics.JOINT_COMMANDS) > 0), timeout=90)
        assert connected and controller.poll() is None, "the controller did not come up"
        up = time.monotonic()
        robot.budget = CYCLES
        robot.publish_state()
        assert run_until(probe, robot, lambda: len(robot.rows) >= CYCLES, timeout=60), \
            f"{len(robot.rows)} of {CYCLES} cycles answered"
        looped = time.monotonic()
        # a state without panda_joint4, then a good one
        robot.budget, robot.drop = CYCLES + 2, "panda_joint4"
        robot.publish_state()
        assert run_until(probe, robot, lambda: len(robot.rows) >= CYCLES + 2, timeout=10)
        keys = [key for key, _, _ in robot.rows]
        assert run_until(probe, robot, lambda: all(k in robot.joint_commands for k in keys)
                         and len(robot.status["stamp"]) >= CYCLES, timeout=10), \
            "a /joint_commands or status message is missing"
        run_until(probe, robot, lambda: False, timeout=0.3)     # nothing more arrives
    finally:
        code, out = stop_node(controller)
    assert code == 0, out[-3000:]
    print(f"\ncontroller up in {up - started:.1f} s; {CYCLES} cycles in {looped - up:.1f} s wall; "
          f"{robot.resends} states resent")
    assert robot.stray == 0 and len(robot.rows) == CYCLES + 2

    # every array: 7 finite efforts = /joint_commands of its cycle, mapped by joint name
    arrays = np.array([data for _, _, data in robot.rows])
    assert arrays.shape == (CYCLES + 2, 7) and np.isfinite(arrays).all()
    worst = 0.0
    for key, _, data in robot.rows:
        names, efforts = robot.joint_commands[key]
        assert sorted(names) == sorted(FORWARD_JOINTS) and len(efforts) == 7
        by_name = dict(zip(names, efforts, strict=True))
        worst = max(worst, max(abs(by_name[j] - d) for j, d in zip(FORWARD_JOINTS, data, strict=True)))
    assert worst <= 1e-12
    assert np.abs(arrays).max() > 1.0          # real torques (gravity alone is tens of N m)

    # the closed loop is the offline loop, stamp for stamp (reading the wrench the controller
    # read: lockstep_replay)
    status = {name: np.array(values) for name, values in robot.status.items()}
    reference = as_read(status, 1 / PERIOD, CYCLES, lambda ages: run(
        *build_scheme("adaptive_impedance", robot="panda_ft"), CYCLES * PERIOD, PERIOD,
        wrench_ages=ages))
    loop = robot.rows[:CYCLES]
    t = np.array([m.time for _, m, _ in loop])
    q = np.array([m.position for _, m, _ in loop])
    v = np.array([m.velocity for _, m, _ in loop])
    f = np.array([m.force for _, m, _ in loop])
    tau = arrays[:CYCLES][:, robot.from_array]            # in the plant's (URDF) joint order
    np.testing.assert_array_equal(t, reference.time)
    dq, dv = np.abs(q - reference.position).max(), np.abs(v - reference.velocity).max()
    df, dtau = np.abs(f - reference.force).max(), np.abs(tau - reference.command).max()
    print(f"vs offline: max |dq| {dq:.3g} rad, |dv| {dv:.3g} rad/s, |df| {df:.3g} N, "
          f"|dtau| {dtau:.3g} N m")
    assert max(dq, dv, df, dtau) <= 1e-12

    # the task (the true contact force): pressing from 50 ms after the law starts, the desired
    # force once ramped in
    fz = np.array([robot.truth[key][2] for key, _, _ in loop])
    after = fz[t >= 0.05 + ZERO_START_WINDOW_S + PERIOD]
    ramped = fz[t >= 1.5]
    print(f"f_z from 50 ms: min {after.min():.3f} N; from 1.5 s: {ramped.min():.3f}.."
          f"{ramped.max():.3f} N (desired {DESIRED_FORCE:g}); at 2 s {fz[-1]:.3f} N")
    assert after.min() > 0.0
    assert np.abs(ramped - DESIRED_FORCE).max() < 0.5

    # the state without panda_joint4: held (the last command, bit for bit), logged
    bad_key, _, held = robot.rows[CYCLES]
    assert held == robot.rows[CYCLES - 1][2]
    assert robot.joint_commands[bad_key][1] == robot.joint_commands[robot.rows[CYCLES - 1][0]][1]
    assert "joint state lacks some of" in out and "holding the last command" in out, out[-3000:]
    print("\n".join(line for line in out.splitlines() if "lacks" in line or "holding" in line))
    assert robot.rows[CYCLES + 1][2] != held                 # the next good state: computed
