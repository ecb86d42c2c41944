"""Chapter 4 and appendix C over ROS: the command interface a plant advertises
and the controller node checks, position commands on the topic contract, and each scheme
in lockstep against the offline loop.

- A controller whose scheme commands the other interface than its plant takes logs one
  ERROR line and exits with code 1 without ever publishing a command (both directions).
- A plant refuses commands in the wrong JointState field (efforts to a position plant,
  positions to an effort plant), counted in /plant/timing, and keeps its last good one.
- backstepping_force (case 1), mrac_force and cmmsd_backstepping (N = 2) as plant,
  controller and recorder processes in lockstep (4 s each) match the offline loop stamp by
  stamp to 1e-6. These schemes are slow (lightly damped plant, ~59 s observer mode): 4 s
  is a determinism check, not a convergence check (test_chapter4.py, test_cmmsd.py).
"""

import subprocess
import sys
import time

import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_probe import RosProbe, next_domain, start_node, stop_node, timing_field
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from cr_control.core import topics
from cr_control.core.paths import config_file
from cr_control.nodes.discovery_settle import SETTLE_VARIABLE
from cr_control.nodes.qos import READY_QOS

pytestmark = pytest.mark.ros   # every test here starts ROS (conftest.py)

QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
PLANT = [sys.executable, "-m", "cr_sim.plant_node"]
CONTROLLER = [sys.executable, "-m", "cr_control.nodes.controller_node"]
LOCKSTEP_S = 4.0


@pytest.fixture
def probe(ros_env):
    p = RosProbe(int(ros_env["ROS_DOMAIN_ID"]))
    yield p
    p.close()


# -- the command interface ---------------------------------------------------------------
@pytest.mark.parametrize("scheme,scenario,mode,message", [
    ("adaptive_impedance", "dynamic_constraint", "lockstep",
     "adaptive_impedance commands efforts but the plant takes positions (scenario "
     "dynamic_constraint): refusing to drive it"),
    ("backstepping_force", "compliant_plane", "realtime",
     "backstepping_force commands positions but the plant takes efforts (scenario "
     "compliant_plane): refusing to drive it"),
], ids=["effort-scheme-position-plant", "position-scheme-effort-plant"])
def test_controller_refuses_a_plant_of_the_other_interface(scheme, scenario, mode, message,
                                                           ros_env, probe):
    """The controller exits with code 1 and one ERROR line; no command is ever published and
    the plant (still running) counts none, refused or applied."""
    commands, timing, interface = [], [], []
    node = probe.node
    node.create_subscription(JointState, topics.JOINT_COMMANDS, commands.append, QOS)
    node.create_subscription(Float64MultiArray, topics.PLANT_TIMING, timing.append, QOS)
    node.create_subscription(String, topics.PLANT_COMMAND_INTERFACE, interface.append, READY_QOS)
    plant = start_node([*PLANT, "--ros-args", "-p", f"scenario:={scenario}", "-p", f"mode:={mode}"],
                  ros_env)
    controller = start_node([*CONTROLLER, scheme], ros_env)
    try:
        assert probe.spin_until(lambda: controller.poll() is not None, timeout=90), \
            "the controller did not exit"
        code, out = stop_node(controller)
        assert code == 1, out[-3000:]
        assert out.count(message) == 1, out[-3000:]
        assert probe.spin_until(lambda: interface, timeout=20), "the plant advertised nothing"
        assert [m.data for m in interface] == ["effort" if scenario == "compliant_plane" else "position"]
        if mode == "realtime":          # the plant started (the controller connected) and says
            probe.spin_until(lambda: len(timing) >= 2, timeout=20)
            assert timing and timing_field(timing[-1], "commands_refused") == 0
            assert timing_field(timing[-1], "window_fresh_share") == 0.0
        else:
            probe.spin_until(lambda: False, timeout=1.0)
        assert commands == []
        assert plant.poll() is None
    finally:
        stop_node(controller)
        code, plant_out = stop_node(plant)
    assert "refused a command" not in plant_out, plant_out[-3000:]


MISMATCH = ("adaptive_impedance commands efforts but the plant takes positions (scenario "
            "dynamic_constraint): refusing to drive it")


def test_session_runner_reports_the_refusing_controller(ros_env, tmp_path):
    """The session runner's process group sees the controller exit early and shows its log
    tail, which holds the reason."""
    from cr_control.tools.session import ProcessGroup, SessionError

    group = ProcessGroup(tmp_path, ros_env, progress=lambda _: None)
    group.start("adaptive_impedance", [*CONTROLLER, "adaptive_impedance"])
    group.start("plant", [*PLANT, "--ros-args", "-p", "scenario:=dynamic_constraint",
                          "-p", "mode:=lockstep", "-p", "duration:=5.0"])
    try:
        with pytest.raises(SessionError) as err:
            group.wait("plant", 90.0, "] [plant]: t=")
    finally:
        group.stop()
    assert "adaptive_impedance exited early (code 1)" in str(err.value)
    assert MISMATCH in str(err.value)


def test_container_refuses_a_plant_of_the_other_interface(ros_env, tmp_path):
    """Composed: the container ends with code 1 and the same line."""
    params = tmp_path / "params.yaml"
    params.write_text("plant:\n  ros__parameters:\n    scenario: dynamic_constraint\n"
                      "    mode: lockstep\n")
    proc = subprocess.run([sys.executable, "-m", "cr_control.tools.container", "adaptive_impedance",
                           "--ros-args", "--params-file", str(params)], env=ros_env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert (proc.stdout + proc.stderr).count(MISMATCH) == 1


@pytest.mark.parametrize("scenario,joints,wrong,right,why", [
    ("dynamic_constraint", ["delta"], {"effort": [0.5]}, {"position": [0.3]},
     "it carries efforts but this plant takes positions (scenario dynamic_constraint)"),
    ("compliant_plane", ["joint1", "joint2"], {"position": [0.1, 0.2]}, {"effort": [0.0, 0.0]},
     "it carries positions but this plant takes efforts (scenario compliant_plane)"),
], ids=["position-plant", "effort-plant"])
def test_plant_refuses_commands_in_the_wrong_field(scenario, joints, wrong, right, why, ros_env,
                                                   probe):
    """Refused (counted, logged with the reason), the plant's last good command stays; a
    command in the right field is then applied."""
    states, timing = [], []
    node = probe.node
    node.create_subscription(JointState, topics.JOINT_STATES, states.append, QOS)
    node.create_subscription(Float64MultiArray, topics.PLANT_TIMING, timing.append, QOS)
    pub = node.create_publisher(JointState, topics.JOINT_COMMANDS, QOS)
    plant = start_node([*PLANT, "--ros-args", "-p", f"scenario:={scenario}",
                   "-p", "watchdog_reaction:=disabled", "-p", "commander:=/test_probe"], ros_env)
    try:
        assert probe.spin_until(lambda: len(states) > 10, timeout=60), "plant never started"
        for _ in range(5):
            pub.publish(JointState(name=joints, **wrong))
            probe.spin_until(lambda: False, timeout=0.02)
        n = len(timing)
        assert probe.spin_until(lambda: len(timing) > n + 1, timeout=20)
        assert timing_field(timing[-1], "commands_refused") == 5
        if scenario == "dynamic_constraint":     # at rest in equilibrium: nothing moved
            assert states[-1].position[0] == pytest.approx(0.225, abs=1e-12)
            assert states[-1].effort[0] == pytest.approx(0.0, abs=1e-12)
        pub.publish(JointState(name=joints, **right))
        n = len(timing)
        assert probe.spin_until(lambda: len(timing) > n + 1, timeout=20)
        assert timing_field(timing[-1], "commands_refused") == 5
        if scenario == "dynamic_constraint":     # servo force k (delta_c - delta) != 0
            assert abs(states[-1].effort[0]) > 0.1
    finally:
        code, out = stop_node(plant)
    assert why in out, out[-3000:]


def test_empty_list_in_a_params_file_starts_the_node(ros_env):
    """``theta_hat_0: []`` (the shipped cmmsd_backstepping.yaml, every session's params.yaml):
    rcl cannot type an empty YAML list; the controller node reads it as an empty vector."""
    # a discovery settle of 0.1 s: its timer's "subscribing ... now" line says the node spins
    # (where Ctrl-C ends it quietly), whenever a loaded machine gets there
    env = {**ros_env, SETTLE_VARIABLE: "0.1"}
    proc = start_node([*CONTROLLER, "cmmsd_backstepping", "--ros-args", "--params-file",
                  str(config_file("cmmsd_backstepping.yaml"))], env)
    deadline = time.monotonic() + 60
    out = ""
    while time.monotonic() < deadline and proc.poll() is None:
        out += proc.stdout.readline() or ""
        if "subscribing to /joint_states now" in out:
            break
    code, rest = stop_node(proc)
    out += rest
    assert "commanding ['q1', 'q2'] (effort)" in out, out[-3000:]
    assert "refused to start" not in out and code == 0, out[-3000:]


# -- lockstep over ROS -------------------------------------------------------------------
@pytest.mark.parametrize("scheme,fields", [
    ("backstepping_force", ("f_x", "f_err_x", "tau_1", "z_1", "z_2", "b3_hat", "a0_hat", "d_hat")),
    ("mrac_force", ("f_x", "tau_1", "f_m", "eps_p", "b3_hat", "r3p_hat", "t0_hat")),
    ("cmmsd_backstepping", ("r_x", "e_x", "u", "d_hat", "theta_hat_norm", "z_1")),
])
def test_lockstep_over_ros_matches_offline(scheme, fields, tmp_path):
    """Plant, controller and recorder as processes in lockstep (4 s): the recorded commands
    (positions for the chapter 4 schemes, efforts on the N = 2 chain) and status match the
    offline loop, rows matched by stamp (a loaded recorder may miss messages; the loop
    cannot: the plant steps only on a command)."""
    from cr_control.analysis.analyze import load_session
    from cr_control.offline import run_scheme
    from cr_control.tools.session import Session, SessionConfig

    cfg = SessionConfig(scheme=scheme, duration=LOCKSTEP_S, mode="lockstep", out=tmp_path,
                        domain_id=next_domain(), name="run")
    s = load_session(Session(cfg, progress=lambda _: None).run().mcap)
    reference = run_scheme(scheme, LOCKSTEP_S)
    steps = int(LOCKSTEP_S * 1000)
    c = np.round(np.asarray(s.joint_commands.time) * 1000.0).astype(int)
    k = np.round(np.asarray(s.status["stamp"]) * 1000.0).astype(int)
    j = np.round(np.asarray(s.joint_states.time) * 1000.0).astype(int)
    print(f"\n{scheme}: recorded {len(np.unique(c))} of {steps} commands, {len(k)} statuses, "
          f"{len(j)} states")
    assert len(np.unique(c)) >= steps // 2 and len(k) >= steps // 2
    assert c.max() == k.max() == steps - 1
    position_scheme = scheme != "cmmsd_backstepping"
    sent = s.joint_commands.position if position_scheme else s.joint_commands.effort
    assert np.asarray(sent).shape[1] == reference.command.shape[1]
    worst = {"command": np.abs(sent - reference.command[c]).max(),
             "position": np.abs(s.joint_states.position - reference.position[j]).max(),
             **{f: np.abs(s.status[f] - reference.column(f)[k]).max() for f in fields}}
    print(f"{scheme}: largest difference from the offline loop {max(worst.values()):.3g}")
    for name, value in worst.items():
        assert value < 1e-6, name
    assert s.status["held"].max() == 0.0
