"""Bad input gives a one-line error and a non-zero exit code, never a traceback.

Command-line cases run as subprocesses; parameter-service semantics run against a node
in this process that declares the adaptive impedance parameters the way the controller
node does (ros_parameters.declare + police_changes).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters, SetParametersAtomically
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_probe import RosProbe, next_domain

from cr_control.core import ros_yaml
from cr_control.core.parameters import ParameterError
from cr_control.nodes.ros_parameters import declare, police_changes, refuse_undeclared
from cr_control.schemes.registry import controller_class

SCHEME = "adaptive_impedance"
SPECS = controller_class(SCHEME).parameters()
NOISE = ("RTPS_TRANSPORT_SHM",)  # Fast DDS shared-memory chatter, not ours


def error_line(proc: subprocess.CompletedProcess) -> str:
    """The single line a failed command printed on stderr (asserting there is one)."""
    assert proc.returncode not in (0, None), proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and not any(n in ln for n in NOISE)]
    assert len(lines) == 1, proc.stderr
    return lines[0]


def run(module: str, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], env=env, capture_output=True,
                          text=True, timeout=120)


# -- cr_session -----------------------------------------------------------------------

def session(tmp_path: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    """cr_session with ``args``; it picks its own free domain (the test's is held here)."""
    env = {k: v for k, v in env.items() if k != "ROS_DOMAIN_ID"}
    return run("cr_control.tools.session", "--duration", "0.1", "--no-record", *args, env=env)


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.ros
@pytest.mark.parametrize("out,reason", [
    ("file", "is not a directory"),               # NotADirectoryError before
    ("file/below", "is not a directory"),
    ("/sys/cr_control_sessions", "cannot create"),  # read-only even for root (PermissionError)
])
def test_session_out_unusable(tmp_path, ros_env, out, reason):
    write(tmp_path / "file", "")
    target = out if out.startswith("/") else str(tmp_path / out)
    line = error_line(session(tmp_path, ros_env, "--out", target))
    assert line.startswith("cr_session: ") and reason in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]   # nothing created


@pytest.mark.ros
@pytest.mark.parametrize("text,reason", [
    ("a: [1, 2\n", "not valid YAML: expected ',' or ']'"),          # ParserError before
    ("- 1\n- 2\n", "not a ROS params file"),                        # AttributeError before
    (f"{SCHEME}: 3\n", f"node '{SCHEME}' has no ros__parameters"),
    ("\x00\x01binary", "not valid YAML"),
    (f"{SCHEME[:-1]}:\n  ros__parameters:\n    Q_c: [1.0, 1.0]\n", "no node 'adaptive_impedanc'"),
])
def test_session_params_file_malformed(tmp_path, ros_env, text, reason):
    params = write(tmp_path / "params.yaml", text)
    line = error_line(session(tmp_path, ros_env, "--out", str(tmp_path / "out"),
                              "--params-file", str(params)))
    assert str(params) in line and reason in line
    assert not (tmp_path / "out").exists()                           # no empty session dir


@pytest.mark.ros
def test_session_params_file_missing(tmp_path, ros_env):
    line = error_line(session(tmp_path, ros_env, "--out", str(tmp_path / "out"),
                              "--params-file", str(tmp_path / "nope.yaml")))
    assert "nope.yaml" in line and "No such file" in line
    assert not (tmp_path / "out").exists()


@pytest.mark.ros
@pytest.mark.parametrize("node,name", [(SCHEME, "Q_cc"), ("plant", "stifness"), ("recorder", "ouput")])
def test_session_refuses_unknown_parameters_by_name(tmp_path, ros_env, node, name):
    params = write(tmp_path / "params.yaml", f"{node}:\n  ros__parameters:\n    {name}: 1.0\n")
    line = error_line(session(tmp_path, ros_env, "--out", str(tmp_path / "out"),
                              "--params-file", str(params)))
    assert f"unknown parameter for {node}: {name}" in line
    assert not (tmp_path / "out").exists()


@pytest.mark.ros
def test_session_refuses_unknown_override(tmp_path, ros_env):
    line = error_line(session(tmp_path, ros_env, "--out", str(tmp_path / "out"),
                              "-p", f"{SCHEME}.Q_cc=[1, 1]"))
    assert "Q_cc (did you mean Q_c?)" in line
    assert not (tmp_path / "out").exists()


@pytest.mark.ros
@pytest.mark.parametrize("override,reason", [
    (f"{SCHEME}.Q_c=[1.0, -1.0]", f"{SCHEME}: Q_c must be positive definite"),
    (f"{SCHEME}.Q_c=[1e308, 1e308]", f"{SCHEME}: Q_c is out of bounds (each |x| <= 1e4)"),
    ("plant.stiffness=stiff", "plant: stiffness must be a number"),
])
def test_session_refuses_bad_values_before_starting(tmp_path, ros_env, override, reason):
    line = error_line(session(tmp_path, ros_env, "--out", str(tmp_path / "out"), "-p", override))
    assert line.startswith(f"cr_session: {reason}")
    assert not (tmp_path / "out").exists()


@pytest.mark.ros
def test_session_knows_every_recorder_parameter(tmp_path):
    """The session's list of recorder parameters is what the recorder node declares."""
    from cr_control.recording.recorder import Recorder
    from cr_control.tools.session import RECORDER_PARAMETERS

    probe = RosProbe(next_domain())
    recorder = Recorder(context=probe.context, parameter_overrides=[
        Parameter("output", value=str(tmp_path / "unused.mcap"))])
    try:
        declared = set(recorder.list_parameters([], 0).names)
    finally:
        recorder.writer.close()
        recorder.destroy_node()
        probe.close()
    assert declared - {"use_sim_time", "start_type_description_service"} == set(RECORDER_PARAMETERS)


# -- nodes started with a bad params file ---------------------------------------------

def controller(params: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    return run("cr_control.nodes.controller_node", SCHEME, "--ros-args", "--params-file", str(params),
               env=env)


@pytest.mark.ros
def test_node_refuses_misspelt_parameter(tmp_path, ros_env):
    params = write(tmp_path / "p.yaml", f"{SCHEME}:\n  ros__parameters:\n    Q_cc: [1.0, 1.0]\n")
    line = error_line(controller(params, ros_env))
    assert line == f"{SCHEME}: refused to start: unknown parameter for {SCHEME}: Q_cc (did you mean Q_c?)"


@pytest.mark.ros
def test_plant_refuses_misspelt_parameter(tmp_path, ros_env):
    params = write(tmp_path / "p.yaml", "plant:\n  ros__parameters:\n    stifness: 300.0\n")
    line = error_line(run("cr_sim.plant_node", "--ros-args", "--params-file", str(params), env=ros_env))
    assert line.startswith("plant: refused to start: unknown parameter for plant: stifness")


@pytest.mark.ros
def test_node_refuses_wrong_type_with_the_name(tmp_path, ros_env):
    params = write(tmp_path / "p.yaml", f"{SCHEME}:\n  ros__parameters:\n    Q_c: fast\n")
    line = error_line(controller(params, ros_env))     # InvalidParameterTypeException before
    assert line == (f"{SCHEME}: refused to start: parameter Q_c must be a double array, "
                    "got a string ('fast')")


# -- the same checks in process (fast) ------------------------------------------------

@pytest.fixture
def probe():
    p = RosProbe(next_domain())
    yield p
    p.close()


def node_with(probe: RosProbe, **overrides) -> Node:
    return Node("crtest", context=probe.context, parameter_overrides=[
        Parameter(name, value=value) for name, value in overrides.items()])


@pytest.mark.ros
def test_integers_for_doubles_are_taken(probe):
    node = node_with(probe, max_effort=50, Q_c=[7, 7])
    values = declare(node, SPECS)
    assert values["max_effort"] == 50.0 and list(values["Q_c"].diagonal()) == [7.0, 7.0]
    assert node.get_parameter("max_effort").type_ == Parameter.Type.DOUBLE


@pytest.mark.ros
def test_wrong_type_is_a_parameter_error(probe):
    with pytest.raises(ParameterError, match=r"parameter max_effort must be a double, got a bool"):
        declare(node_with(probe, max_effort=True), SPECS)


@pytest.mark.ros
def test_undeclared_overrides_are_refused_after_declaring(probe):
    node = node_with(probe, Q_cc=[1.0, 1.0], use_sim_time=False)
    declare(node, SPECS)
    with pytest.raises(ParameterError, match=r"unknown parameter for crtest: Q_cc \(did you mean Q_c\?\)"):
        refuse_undeclared(node)


def test_yaml_numbers_as_ros_reads_them():
    assert ros_yaml.load("[1e12, -2E-3, 3, 1.5, abc]") == [1e12, -2e-3, 3, 1.5, "abc"]
    with pytest.raises(yaml.YAMLError):
        ros_yaml.load("[1, 2")


# -- live changes: cr_param and the parameter services --------------------------------

@pytest.fixture
def served(probe):
    """A node with the scheme's parameters, policed, spun by the probe's executor."""
    node = node_with(probe)
    applied: dict[str, object] = {}
    declare(node, SPECS)
    police_changes(node, SPECS, applied.__setitem__)
    probe.executor.add_node(node)
    yield probe, node, applied
    probe.executor.remove_node(node)
    node.destroy_node()


def cr_param(probe: RosProbe, *args: str) -> subprocess.CompletedProcess:
    """Run cr_param against the probe's domain while the probe serves the node."""
    proc = subprocess.Popen([sys.executable, "-m", "cr_control.tools.param_tool", "--domain-id",
                             str(probe.context.get_domain_id()), "--timeout", "30", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert probe.spin_until(lambda: proc.poll() is not None, timeout=60), "cr_param hung"
    out, err = proc.communicate()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


@pytest.mark.ros
def test_cr_param_unknown_parameter(served):
    probe, _, _ = served
    for command in (("set", "/crtest", "Q_cc", "[1.0, 1.0]"), ("get", "/crtest", "Q_cc")):
        proc = cr_param(probe, *command)                              # IndexError before
        assert proc.returncode == 2
        assert error_line(proc) == "cr_param: unknown parameter for /crtest: Q_cc (did you mean Q_c?)"


@pytest.mark.ros
def test_cr_param_reads_exponent_floats(served):
    probe, node, applied = served
    proc = cr_param(probe, "set", "/crtest", "Q_c", "[2e3, 2e3]")  # strings before
    assert proc.returncode == 0, proc.stderr
    assert list(node.get_parameter("Q_c").value) == [2e3, 2e3]
    assert list(applied["Q_c"].diagonal()) == [2e3, 2e3]


@pytest.mark.ros
def test_cr_param_unreadable_value(served):
    proc = cr_param(served[0], "set", "/crtest", "Q_c", "[1.0, 2.0")
    assert proc.returncode == 2 and "not valid YAML" in error_line(proc)


def double_array(name: str, values: list[float]) -> ParameterMsg:
    return ParameterMsg(name=name, value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=values))


@pytest.mark.ros
def test_set_parameters_is_per_parameter_atomically_is_all_or_nothing(served):
    """ROS semantics, as police_changes documents them: SetParameters answers each
    parameter on its own (the good half of a mixed request is applied); with
    SetParametersAtomically one refused value refuses the whole request."""
    probe, node, applied = served
    good, bad = double_array("Q_c", [50.0, 50.0]), double_array("Q_a", [1.0, -1.0])
    atomic = probe.call(SetParametersAtomically, "/crtest/set_parameters_atomically",
                        SetParametersAtomically.Request(parameters=[good, bad])).result
    assert not atomic.successful and "positive definite" in atomic.reason
    assert list(node.get_parameter("Q_c").value) != [50.0, 50.0] and not applied

    results = probe.call(SetParameters, "/crtest/set_parameters",
                         SetParameters.Request(parameters=[good, bad])).results
    assert [r.successful for r in results] == [True, False]
    assert list(node.get_parameter("Q_c").value) == [50.0, 50.0] and list(applied) == ["Q_c"]
    assert list(node.get_parameter("Q_a").value) != [1.0, -1.0]


@pytest.mark.ros
def test_recorder_refuses_misspelt_parameter(tmp_path, ros_env):
    """The recorder, started by hand with a params file naming a parameter it does not have."""
    params = tmp_path / "recorder.yaml"
    params.write_text(f"recorder:\n  ros__parameters:\n    output: {tmp_path / 'x.mcap'}\n"
                      "    ready_timout: 5.0\n")
    proc = subprocess.run([sys.executable, "-m", "cr_control.recording.recorder", "--ros-args",
                           "--params-file", str(params)], env=ros_env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode != 0
    assert "ready_timout (did you mean ready_timeout?)" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "x.mcap").exists()
