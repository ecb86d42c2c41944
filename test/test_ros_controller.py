"""The controller node over ROS: parameter services and bad input (separate process)."""

import itertools
import math
import subprocess
import sys

import numpy as np
import pytest
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_probe import RosProbe, next_domain, stop_node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from cr_control.core import topics
from cr_control.core.ros_env import isolated_env

pytestmark = pytest.mark.ros   # every test here starts ROS (conftest.py)

NODE = "adaptive_impedance"
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture(scope="module")
def controller():
    domain = next_domain()
    env = isolated_env(domain_id=domain)
    proc = subprocess.Popen([sys.executable, "-m", "cr_control.nodes.controller_node", NODE,
                             "--ros-args", "-p", "state_source:=/test_probe"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    probe = RosProbe(domain)
    commands, status = [], []
    probe.node.create_subscription(JointState, topics.JOINT_COMMANDS, commands.append, QOS)
    probe.node.create_subscription(Float64MultiArray, topics.status_topic(NODE), status.append, QOS)
    state_pub = probe.node.create_publisher(JointState, topics.JOINT_STATES, QOS)
    yield probe, proc, state_pub, commands, status
    probe.close()
    stop_node(proc, timeout=10)


def double_array(values):
    return ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=values)


def set_param(probe, name, value):
    req = SetParameters.Request(parameters=[Parameter(name=name, value=value)])
    return probe.call(SetParameters, f"/{NODE}/set_parameters", req).results[0]


def get_param(probe, name):
    req = GetParameters.Request(names=[name])
    return probe.call(GetParameters, f"/{NODE}/get_parameters", req).values[0]


_period_ns = itertools.count(1_000_000_000, 1_000_000)


def send_state(controller, position, velocity, names=("joint1", "joint2")):
    """Publish a joint state 1 ms after the previous one (a longer gap would be held)."""
    probe, proc, pub, commands, status = controller
    assert probe.spin_until(lambda: pub.get_subscription_count() > 0), "controller not subscribed"
    n = len(commands)
    msg = JointState(name=list(names), position=list(position), velocity=list(velocity))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(next(_period_ns), 1_000_000_000)
    pub.publish(msg)
    assert probe.spin_until(lambda: len(commands) > n and len(status) > n), "no command came back"
    return commands[-1], status[-1]


def status_value(status_msg, field):
    fields = topics.fields_of(status_msg.layout.dim[0].label)
    return status_msg.data[fields.index(field)]


Q0 = [3.0358, -2.4401]


def test_valid_change_is_accepted_and_used(controller):
    probe = controller[0]
    assert set_param(probe, "Q_c", double_array([50.0, 50.0])).successful
    assert list(get_param(probe, "Q_c").double_array_value) == [50.0, 50.0]


@pytest.mark.parametrize("name,value,reason", [
    ("Q_a", double_array([1.0, 2.0, 3.0]), "needs 2"),
    ("A_m", double_array([math.nan, 20.0]), "finite"),
    ("B_m", double_array([-400.0, 400.0]), "positive definite"),
    ("Q_b", double_array([1.0, 2.0, 2.0, 1.0]), "positive definite"),
    ("max_effort", ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=-1.0), "> 0"),
    ("A_hat_0", double_array([1.0, 1.0]), "read-only"),
    ("A_m", ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="fast"), ""),
    ("diagnostics_every", ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=0),
     ">= 1"),
])
def test_invalid_change_is_refused_and_old_value_stays(controller, name, value, reason):
    probe = controller[0]
    before = get_param(probe, name)
    result = set_param(probe, name, value)
    assert not result.successful
    assert reason.lower() in result.reason.lower()
    after = get_param(probe, name)
    assert list(after.double_array_value) == list(before.double_array_value)
    assert after.double_value == before.double_value
    assert controller[1].poll() is None                      # node still running


def test_change_takes_effect_on_the_next_cycle(controller):
    probe = controller[0]
    cmd, _ = send_state(controller, Q0, [0.0, 0.0])
    assert max(abs(x) for x in cmd.effort) > 0.3
    assert set_param(probe, "max_effort",
                     ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.3)).successful
    cmd, _ = send_state(controller, Q0, [0.0, 0.0])
    assert max(abs(x) for x in cmd.effort) == pytest.approx(0.3)
    set_param(probe, "max_effort", ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=100.0))


@pytest.mark.parametrize("position,velocity,names", [
    ([math.nan, 0.0], [0.0, 0.0], ("joint1", "joint2")),
    ([0.0, 0.0], [math.inf, 0.0], ("joint1", "joint2")),
    ([0.0, 0.0, 1.0], [0.0, 0.0], ("joint1", "joint2")),
    ([0.0, 0.0], [0.0, 0.0], ("joint1", "elbow")),
])
def test_bad_joint_states_never_give_a_non_finite_command(controller, position, velocity, names):
    good, _ = send_state(controller, Q0, [0.0, 0.0])
    cmd, status = send_state(controller, position, velocity, names)
    assert np.isfinite(cmd.effort).all() and list(cmd.effort) == list(good.effort)
    assert status_value(status, "held") == 1.0
    assert np.isfinite(status.data).all()


def test_bad_params_file_stops_the_node_with_a_reason(tmp_path, ros_env):
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"{NODE}:\n  ros__parameters:\n    B_m: [400.0, -1.0]\n")
    proc = subprocess.run([sys.executable, "-m", "cr_control.nodes.controller_node", NODE, "--ros-args",
                           "--params-file", str(bad)], env=ros_env, capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 1
    assert "B_m must be positive definite" in proc.stderr


def test_unknown_scheme_is_a_usage_error(ros_env):
    proc = subprocess.run([sys.executable, "-m", "cr_control.nodes.controller_node", "nope"], env=ros_env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "schemes:" in proc.stderr


def test_cr_param_sets_refuses_and_gets(controller):
    """The command-line tool (no ros2 CLI here) uses the same services."""
    domain = controller[0].context.get_domain_id()

    def cr_param(*args):
        return subprocess.run([sys.executable, "-m", "cr_control.tools.param_tool", "--domain-id",
                               str(domain), "--timeout", "30", *args], capture_output=True, text=True,
                              timeout=120)

    ok = cr_param("set", NODE, "Q_b", "[7, 7]")             # integers coerced to doubles
    assert ok.returncode == 0, ok.stderr
    refused = cr_param("set", NODE, "Q_b", "[7.0, -7.0]")
    assert refused.returncode == 1 and "positive definite" in refused.stderr
    got = cr_param("get", NODE, "Q_b")
    assert got.returncode == 0 and "7.0, 7.0" in got.stdout
    assert "Q_b" in cr_param("list", NODE).stdout.split()


def test_position_scheme_checks_the_advertised_interface(ros_env):
    """A position scheme (backstepping_force, 1 joint) answers a state with a position-only
    command once the plant advertises "position" (latched /plant/command_interface); when
    the advertised interface turns to "effort" it logs one ERROR line and exits with code 1."""
    from std_msgs.msg import String

    from cr_control.nodes.qos import READY_QOS

    proc = subprocess.Popen([sys.executable, "-m", "cr_control.nodes.controller_node",
                             "backstepping_force", "--ros-args", "-p", "state_source:=/test_probe"],
                            env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    probe = RosProbe(int(ros_env["ROS_DOMAIN_ID"]))
    failure = None
    try:
        commands = []
        probe.node.create_subscription(JointState, topics.JOINT_COMMANDS, commands.append, QOS)
        advertise = probe.node.create_publisher(String, topics.PLANT_COMMAND_INTERFACE, READY_QOS)
        advertise.publish(String(data="position"))
        states = probe.node.create_publisher(JointState, topics.JOINT_STATES, QOS)
        assert probe.spin_until(lambda: states.get_subscription_count() > 0, 60), "not subscribed"
        stamp = itertools.count(1_000_000_000, 1_000_000)

        def answered():
            msg = JointState(name=["delta"], position=[0.225], velocity=[0.0])
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(next(stamp), 1_000_000_000)
            states.publish(msg)
            probe.spin_until(lambda: commands, timeout=0.05)
            return bool(commands)

        assert probe.spin_until(answered, timeout=30), "no command came back"
        cmd = commands[-1]
        assert list(cmd.name) == ["delta"] and len(cmd.position) == 1 and len(cmd.effort) == 0
        assert math.isfinite(cmd.position[0])
        advertise.publish(String(data="effort"))
        assert probe.spin_until(lambda: proc.poll() is not None, timeout=30), "did not exit"
    except AssertionError as exc:   # reported with what the node printed
        failure = exc
    finally:
        probe.close()
        _, out = stop_node(proc)
    assert failure is None, f"{failure}; the node printed:\n{out[-3000:]}"
    assert proc.returncode == 1, out[-3000:]
    assert out.count("backstepping_force commands positions but the plant takes efforts: "
                     "refusing to drive it") == 1, out[-3000:]
