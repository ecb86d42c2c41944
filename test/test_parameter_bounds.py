"""Every numeric parameter has a physical bound, and parameter requests are cheap.

A fuzz of the running nodes found finite but absurd values accepted (``Q_c = [1e308, 1e308]``
made the law's output non-finite), a refused 10^6-element request blocking the controller
for 0.14-0.24 s, a WARN line per refused request and "Invalid access to undeclared
parameter(s): []" for an unknown name. The service tests run against a node in this process
that declares the adaptive impedance parameters the way the controller node does
(ros_parameters.declare + police_changes).
"""

from __future__ import annotations

import array
import time
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters, SetParametersAtomically
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_probe import RosProbe, next_domain

from cr_control import robots
from cr_control.core import parameters
from cr_control.core.parameters import (
    BOUNDED_KINDS,
    SCALAR_KINDS,
    ParameterError,
    bound_text,
    describe,
    resolve,
    validate,
)
from cr_control.core.paths import config_dir
from cr_control.nodes.ros_parameters import REFUSED_WARN_EVERY_S, declare, police_changes
from cr_control.schemes.blocks.task_space import task_model
from cr_control.schemes.impedance.base import TaskSpaceController
from cr_control.schemes.registry import SCHEMES, controller_class, make_controller
from cr_sim.plant_node import plant_parameters
from cr_sim.plants.registry import SCENARIOS

SCHEME = "adaptive_impedance"
SPECS = controller_class(SCHEME).parameters()
NODE = "crbounds"
HUGE = 10**6


def spec_sets() -> dict[str, list]:
    """Every scheme's parameters (the five task-space ones also on the Panda) and every
    scenario's plant parameters."""
    sets = {scheme: controller_class(scheme).parameters() for scheme in SCHEMES}
    panda = robots.robot("panda")
    sets.update({f"{scheme} on the panda": controller_class(scheme).parameters(
        robots.controller_values(panda, scheme)) for scheme in robots.TASK_SPACE_SCHEMES})
    sets.update({f"plant {scenario}": plant_parameters(scenario) for scenario in SCENARIOS})
    return sets


SPEC_SETS = spec_sets()


def shaped(param, x: float):
    """A value of ``param``'s kind and size whose largest magnitude is ``x``."""
    if param.kind == "integer":
        return int(x) if x < 1e300 else 10**308
    if param.kind in SCALAR_KINDS:
        return x
    return [-x if param.kind == "nd" else x] * (param.size or 1)


# -- the specs -------------------------------------------------------------------------------

@pytest.mark.parametrize("owner", sorted(SPEC_SETS))
def test_every_numeric_parameter_has_a_bound_that_holds(owner):
    """Each numeric spec has a bound, printed in its description (as the node declares it
    and the params files show it), the default within it, 10x it and 1e308 refused."""
    numeric = [p for p in SPEC_SETS[owner] if p.kind in BOUNDED_KINDS]
    assert numeric
    for p in numeric:
        assert p.bound is not None, f"{owner}: {p.name} has no bound"
        assert validate(p, p.default)[0], f"{owner}: the default of {p.name} is refused"
        assert describe(p).endswith(f" ({bound_text(p)})")      # declared and in params files
        for x in (10 * p.bound, 1e308):
            ok, reason, _ = validate(p, shaped(p, x))
            assert not ok and reason.startswith(f"{p.name} is out of bounds ("), (owner, p.name, reason)


@pytest.mark.parametrize("path", sorted(config_dir().rglob("*.yaml")),
                         ids=lambda p: str(p.relative_to(config_dir())))
def test_shipped_params_files_are_within_the_bounds(path):
    """config/*.yaml and config/robots/** (generated or not: the chapter 4 cases) validate."""
    for node, body in yaml.safe_load(path.read_text()).items():
        values = body["ros__parameters"]
        if node == "plant":
            specs = plant_parameters(values.get("scenario", "compliant_plane"))
        else:
            specs = controller_class(node).parameters(values)
        resolve(specs, values)


def test_the_fuzzed_values_are_refused_with_a_reason():
    specs = {p.name: p for p in SPECS}
    assert validate(specs["Q_c"], [1e308, 1e308])[1] == (
        "Q_c is out of bounds (each |x| <= 1e4): got 1e+308")
    assert validate(specs["reference_frequency"], 1e308)[1] == (
        "reference_frequency is out of bounds (<= 100): got 1e+308")
    assert validate(specs["reference_amplitude"], [1000.0, 1000.0])[1] == (
        "reference_amplitude is out of bounds (each |x| <= 10): got 1000.0")
    with pytest.raises(ParameterError, match="Q_c is out of bounds"):
        resolve(SPECS, {"Q_c": [1e308, 1e308]})


def test_robot_bounds_come_from_the_urdf():
    """On the Panda, max_effort is at most 10x its strongest joint (87 N m) and the posture
    must lie within the URDF's position limits (panda_joint4: [-3.07, -0.07])."""
    values = robots.controller_values(robots.robot("panda"), "impedance")
    specs = {p.name: p for p in controller_class("impedance").parameters(values)}
    assert specs["max_effort"].bound == pytest.approx(870.0)
    assert validate(specs["max_effort"], 100.0)[0] and not validate(specs["max_effort"], 1000.0)[0]
    posture = list(values["posture"])
    posture[3] = 0.0
    with pytest.raises(ParameterError, match=r"posture: panda_joint4 = 0 is outside its URDF "
                                             r"limits \[-3\.07\d*, -0\.069\d*\]"):
        make_controller("impedance", {**values, "posture": posture})
    for name in robots.ROBOTS:      # the shipped postures (the home poses) are inside
        values = robots.controller_values(robots.robot(name), "impedance")
        robot = SimpleNamespace(model=task_model(TaskSpaceController.robot_values(values)))
        TaskSpaceController.check_values(robot, values)


def test_sizes_are_checked_before_any_value_is_read(monkeypatch):
    converted = []
    monkeypatch.setattr(parameters, "_as_floats", lambda value: converted.append(len(value)))
    q_c = next(p for p in SPECS if p.name == "Q_c")
    ok, reason, _ = validate(q_c, array.array("d", [1.0]) * HUGE)
    assert not ok and reason == f"Q_c needs 2 (diagonal) or 4 (full) values, got {HUGE}"
    joints = next(p for p in SPECS if p.name == "joint_names")
    assert validate(joints, ["j"] * HUGE)[1] == f"joint_names takes at most 100 values, got {HUGE}"
    assert converted == []


# -- the parameter services ------------------------------------------------------------------

@pytest.fixture
def served():
    """A node with the scheme's parameters, policed, spun by the probe's executor."""
    probe = RosProbe(next_domain())
    node = Node(NODE, context=probe.context)
    applied: dict[str, object] = {}
    declare(node, SPECS)
    police_changes(node, SPECS, applied.__setitem__)
    # As the controller node does at start: rclpy's first log line in a process costs up to
    # a second (inspect.getmodule scans every module), which a refusal must not be charged.
    node.get_logger().info(f"{len(SPECS)} parameters")
    probe.executor.add_node(node)
    yield probe, node, applied
    probe.executor.remove_node(node)
    node.destroy_node()
    probe.close()


def message(name: str, value) -> ParameterMsg:
    if isinstance(value, float):
        return ParameterMsg(name=name, value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE, double_value=value))
    return ParameterMsg(name=name, value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=value))


SERVICES = {"set_parameters": SetParameters, "set_parameters_atomically": SetParametersAtomically}


def set_remote(probe: RosProbe, service: str, *params: ParameterMsg):
    """The results of one request to the node's ``service``."""
    kind = SERVICES[service]
    response = probe.call(kind, f"/{NODE}/{service}", kind.Request(parameters=list(params)))
    return response.results if service == "set_parameters" else [response.result]


def value_of(node: Node, name: str) -> np.ndarray:
    return np.asarray(node.get_parameter(name).value)


@pytest.mark.ros
def test_the_bound_is_in_the_declared_description_and_the_params_file(served):
    _, node, _ = served
    assert node.describe_parameter("Q_c").description.endswith(
        "2 values (diagonal) or 4 (full, row-major). (each |x| <= 1e4)")
    assert "(each |x| <= 1e4)\n    Q_c: [5.0, 5.0]\n" in (config_dir() / f"{SCHEME}.yaml").read_text()


@pytest.mark.ros
@pytest.mark.parametrize("service", sorted(SERVICES))
def test_fuzzed_values_are_refused_and_the_old_values_stay(served, service):
    probe, node, applied = served
    for name, value in (("Q_c", [1e308, 1e308]), ("reference_frequency", 1e308),
                        ("reference_amplitude", [1000.0, 1000.0])):
        before = value_of(node, name)
        [result] = set_remote(probe, service, message(name, value))
        assert not result.successful and result.reason.startswith(f"{name} is out of bounds")
        assert np.array_equal(value_of(node, name), before)
    assert not applied


@pytest.mark.ros
@pytest.mark.parametrize("service", sorted(SERVICES))
def test_a_huge_value_is_refused_before_it_is_read(served, service, monkeypatch):
    """A 10^6-element Q_c (8 MB) is refused from the request's size by the parameter gate,
    off the control thread: the service's callback never runs, neither our conversion nor
    rclpy's (Parameter.from_parameter_msg type-checks every element in Python) reads it, and
    the reason is the node's own (read from the C request's name and length). Through
    node.set_parameters (in process) the on-set
    callback refuses it from its length. Times are printed, not asserted."""
    probe, node, applied = served
    read = []
    from_msg = Parameter.from_parameter_msg.__func__
    monkeypatch.setattr(Parameter, "from_parameter_msg", classmethod(
        lambda cls, msg: read.append(msg.name) or from_msg(cls, msg)))
    monkeypatch.setattr(parameters, "_as_floats", lambda value: read.append(len(value)))
    [server] = [s for s in node.parameter_gate.services if s.srv_name == f"{NODE}/{service}"]
    handled = []

    def timed(request, response, handle=server.callback):
        start = time.perf_counter()
        out = handle(request, response)
        handled.append(time.perf_counter() - start)
        return out

    server.callback = timed
    before = value_of(node, "Q_c")
    start = time.perf_counter()
    [result] = set_remote(probe, service, message("Q_c", array.array("d", [1.0]) * HUGE))
    round_trip = time.perf_counter() - start
    assert not result.successful
    assert result.reason == f"Q_c needs 2 (diagonal) or 4 (full) values, got {HUGE}"
    assert handled == [] and node.parameter_gate.refused == 1
    assert read == [] and not applied and np.array_equal(value_of(node, "Q_c"), before)

    # in process, through rclpy's set_parameters and our on-set callback
    big = Parameter("Q_c", Parameter.Type.DOUBLE_ARRAY, array.array("d", [1.0]) * HUGE)
    start = time.perf_counter()
    [local] = node.set_parameters([big])
    in_process = time.perf_counter() - start
    assert not local.successful and read == []
    print(f"\n10^6-element Q_c over {service}: refused in a round trip of "
          f"{1e3 * round_trip:.1f} ms; node.set_parameters {1e3 * in_process:.3f} ms")


@pytest.mark.ros
def test_refusals_are_rate_limited_per_parameter(served, capfd):
    """200 refused requests (oversized ones refused from the request, non-definite ones by the
    on-set callback) give one WARN line per REFUSED_WARN_EVERY_S, not 200."""
    probe, _, _ = served
    client = probe.node.create_client(SetParameters, f"/{NODE}/set_parameters")
    assert probe.spin_until(client.service_is_ready)
    requests = [SetParameters.Request(parameters=[message("Q_c", value)])
                for value in ([1.0, -1.0], [1.0] * 5)]
    capfd.readouterr()
    start = time.monotonic()
    for i in range(200):
        future = client.call_async(requests[i % 2])
        assert probe.spin_until(future.done)
        assert not future.result().results[0].successful
    elapsed = time.monotonic() - start
    lines = [ln for ln in capfd.readouterr().err.splitlines() if "refused Q_c" in ln]
    print(f"\n200 refused requests in {elapsed:.2f} s: {len(lines)} WARN line(s)")
    assert 1 <= len(lines) <= 1 + int(elapsed / REFUSED_WARN_EVERY_S)


@pytest.mark.ros
@pytest.mark.parametrize("service", sorted(SERVICES))
@pytest.mark.parametrize("size", [2, HUGE])
def test_an_unknown_parameter_is_refused_by_name(served, service, size):
    probe, _, applied = served
    [result] = set_remote(probe, service, message("Q_cc", array.array("d", [1.0]) * size))
    assert not result.successful
    assert result.reason == f"unknown parameter for {NODE}: Q_cc (did you mean Q_c?)"
    assert not applied


@pytest.mark.ros
def test_a_mixed_request_applies_the_known_parameter(served):
    probe, node, applied = served
    results = set_remote(probe, "set_parameters", message("Q_c", [50.0, 50.0]),
                         message("Q_cc", [1.0, 1.0]))
    assert [r.successful for r in results] == [True, False] and "Q_cc" in results[1].reason
    assert list(node.get_parameter("Q_c").value) == [50.0, 50.0] and list(applied) == ["Q_c"]
