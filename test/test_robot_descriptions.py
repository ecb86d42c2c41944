"""Hostile robot descriptions are refused before Pinocchio parses them, in one line; no NaN
leaves a plant.

Robot descriptions (:func:`cr_control.models.urdf.check_urdf` and the chain checks of
:func:`cr_control.models.urdf.load_chain`; the controllers and the plant load every URDF
through them). Before, a fuzz of hostile URDFs found: a chain or tree 4000 links deep
crashed the plant, the controller and cr_session with SIGSEGV (Pinocchio's parser recurses;
3500 links loaded, in 42 s); a joint origin of 1e300 m was accepted and the plant then
published NaN forever; zero mass and inertia on the Panda's link 7 started (joint 7 reached
13x its velocity limit); negative masses and non-positive-definite inertias started and
failed later; a lower position limit above the upper one was accepted; an effort limit of 0
removed the joint's clip and rate limit, a velocity limit of 0 its reflex; an entity
expansion under expat's limit took 4 GB and 42 s to start (here: a 3 MB URDF expanding to
250 MB took 1 s and 400 MB). The hostile URDFs below are the Panda's with one change, or
generated chains.

NaN (:mod:`cr_sim.plant_node`): every reflex passes only a value inside its limit (NaN
trips it), and a non-finite state stops the plant node with one ERROR line and exit code 1
without publishing it.
"""

from __future__ import annotations

import math
import subprocess
import sys
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from cr_control import robots
from cr_control.core.parameters import ParameterError
from cr_control.models.urdf import (
    MAX_LINKS,
    MAX_URDF_CHARS,
    RobotModelError,
    check_urdf,
    load_chain,
)
from cr_control.schemes.registry import make_controller
from cr_control.tools.fuzz_inputs import LINK7, PANDA_BASE, PANDA_TIP, chain, panda_urdf, panda_with
from cr_sim.loop_stats import SAFE_STOP_CONTACT_FORCE, SAFE_STOP_JOINT_VELOCITY
from cr_sim.plants.registry import SCENARIOS, make_plant
from cr_sim.supervisor import reflex

PANDA = panda_urdf()
BASE, TIP = PANDA_BASE, PANDA_TIP


def refusal(xml: str, base: str = BASE, tip: str = TIP) -> str:
    """The one-line reason load_chain refuses ``xml`` with (asserting it does)."""
    with pytest.raises(RobotModelError) as info:
        load_chain(xml, "", base, tip)
    message = str(info.value)
    assert "\n" not in message and message
    return message


# -- what is refused, and why ---------------------------------------------------------------
HOSTILE = {
    "a chain 4000 links deep": (chain(4000), "the URDF has 4002 links: more than the 500"),
    "a chain 3500 links deep": (chain(3500), "the URDF has 3502 links: more than the 500"),
    "a tree 4000 links deep": (chain(4000, branches=True), "the URDF has 8002 links"),
    "a joint origin of 1e300 m": (
        panda_with('xyz="0 0 0.333"', 'xyz="0 0 1e300"'),
        "joint 'panda_joint1': <origin xyz=\"0.0 0.0 1e+300\"> places a frame 1e+300 m from its "
        "parent: more than 100 m"),
    "an inertial origin of 200 m": (
        panda_with('xyz="0.003875 0.002081 -0.04762"', 'xyz="200 0 0"'),
        "link 'panda_link1': <origin xyz=\"200.0 0.0 0.0\"> places a frame 200 m"),
    "a NaN origin": (panda_with('xyz="0 0 0.333"', 'xyz="0 0 nan"'),
                     "joint 'panda_joint1': <origin xyz=\"0 0 nan\"> needs 3 finite numbers"),
    "an infinite rpy": (panda_with('rpy="-1.5707963267948966 0 0"', 'rpy="inf 0 0"'),
                        "joint 'panda_joint2': <origin rpy=\"inf 0 0\"> needs 3 finite numbers"),
    "a zero axis": (panda_with('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>'),
                    "joint 'panda_joint1': <axis xyz=\"0.0 0.0 0.0\"> is zero"),
    "zero mass and inertia on link 7": (
        panda_with(LINK7, '<mass value="0"/>\n            <inertia ixx="0" ixy="0" ixz="0" iyy="0" '
                          'iyz="0" izz="0"/>'),
        "joint 'panda_joint7' moves link 'panda_link7', which has mass 0 kg: the link a joint of "
        "the chain moves needs a mass >= 1e-09 kg and a positive definite inertia"),
    "no inertial on link 7": (
        panda_with(f'<inertial>\n            <origin rpy="0 0 0" xyz="1.0517e-02 -4.252e-03 '
                   f'6.1597e-02"/>\n            {LINK7}\n        </inertial>', ""),
        "joint 'panda_joint7' moves link 'panda_link7', which has no <inertial>"),
    "a rod without inertia about one axis on link 7": (
        panda_with(LINK7, '<mass value="0.735522"/>\n            <inertia ixx="0.01" ixy="0" '
                          'ixz="0" iyy="0.01" iyz="0" izz="0"/>'),
        "joint 'panda_joint7' moves link 'panda_link7', which has principal moments [0, 0.01, "
        "0.01] kg m^2"),
    "a negative mass": (panda_with('<mass value="3.228604"/>', '<mass value="-3.228604"/>'),
                        "link 'panda_link3': <mass value=\"-3.2286\">: a link's mass must be >= 0"),
    "a NaN mass": (panda_with('<mass value="3.228604"/>', '<mass value="nan"/>'),
                   "link 'panda_link3': <mass value=\"nan\"> needs a finite number"),
    "a mass of 1e300 kg": (panda_with('<mass value="3.228604"/>', '<mass value="1e300"/>'),
                           "a link's mass must be >= 0 and at most 10000 kg"),
    "an inertia that is not positive semi-definite": (
        panda_with('izz="0.004815"', 'izz="-0.004815"'),
        "link 'panda_link7': its <inertia> is not positive semi-definite (principal moments "
        "[-0.00494,"),
    "inertia without mass": (
        panda_with('<mass value="0"/>\n          <origin rpy="0 0 0" xyz="0 0 0"/>\n          '
                   '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>',
                   '<mass value="0"/>\n          <origin rpy="0 0 0" xyz="0 0 0"/>\n          '
                   '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/>'),
        "link 'panda_link8': rotational inertia (principal moments [1, 1, 1] kg m^2) without mass "
        "is not physical"),
    "a lower position limit above the upper one": (
        panda_with('lower="-2.8973" upper="2.8973"', 'lower="2.8973" upper="-2.8973"'),
        "joint 'panda_joint1': <limit lower=\"2.8973\" upper=\"-2.8973\">: the lower position "
        "limit is above the upper one"),
    "an effort limit of 0": (
        panda_with('effort="12.0"', 'effort="0"'),
        "joint 'panda_joint5': <limit effort=\"0\">: an effort limit must be > 0 (0 would remove "
        "its command clip and rate limit); give the joint's real limit"),
    "a velocity limit of 0": (
        panda_with('velocity="2.61"', 'velocity="0"'),
        "joint 'panda_joint5': <limit velocity=\"0\">: a velocity limit must be > 0 (0 would "
        "remove its velocity reflex); give the joint's real limit"),
    "a negative velocity limit": (panda_with('velocity="2.175"', 'velocity="-2.175"'),
                                  "a velocity limit must be > 0 (-2.175 would remove"),
    "an infinite effort limit": (panda_with('effort="87.0"', 'effort="inf"'),
                                 "joint 'panda_joint1': <limit effort=\"inf\"> needs a finite number"),
    "a negative joint damping": (
        panda_with('damping="0.003"', 'damping="-1"'),
        "joint 'panda_joint1': <dynamics damping=\"-1\"> must be >= 0 (a negative one would drive "
        "the joint)"),
    "an entity declaration": (
        '<?xml version="1.0"?><!DOCTYPE robot [<!ENTITY a "aaaaaaaaaa">]>'
        + PANDA[PANDA.index("<robot"):].replace("</robot>", "<gazebo>&a;&a;</gazebo></robot>"),
        "the URDF declares an entity (<!ENTITY ...>): refused, a URDF has no use for one"),
    "more than 4 MiB": (PANDA + " " * (4 * 2**20), "the URDF is 4.0 MiB of text: more than the 4 MiB"),
    "not XML": (PANDA[:-20], "the URDF is not valid XML"),
    "another root element": ("<sdf version='1.6'><model name='m'/></sdf>",
                             "the URDF's root element is <sdf>, not <robot>"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_descriptions_are_refused_in_one_line(case):
    xml, reason = HOSTILE[case]
    message = refusal(xml)
    assert reason in message, message


def test_an_entity_expansion_is_refused_before_anything_expands_it():
    """A 3 MB URDF whose entity expands to 250 MB (1 s and 400 MB to load before): refused
    at once, whatever its size below the bound."""
    xml = ('<?xml version="1.0"?><!DOCTYPE robot [<!ENTITY a "' + "x" * 250 + '">]>'
           + PANDA[PANDA.index("<robot"):].replace("</robot>", "<gazebo>" + "&a;" * 1_000_000
                                                   + "</gazebo></robot>"))
    assert len(xml) < MAX_URDF_CHARS
    tracemalloc.start()
    try:
        assert "declares an entity" in refusal(xml)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 50 * 2**20, peak        # nothing expanded: the expansion alone is 250 MB


def test_a_long_file_is_read_no_further_than_the_bound(tmp_path):
    path = tmp_path / "long.urdf"
    path.write_text(PANDA + "<!--" + "x" * (5 * 2**20) + "-->")
    with pytest.raises(RobotModelError, match="the URDF is 4.0 MiB of text: more than the 4 MiB"):
        load_chain("", str(path), BASE, TIP)


def test_the_bounds_are_stated():
    assert MAX_URDF_CHARS == 4 * 2**20 and MAX_LINKS == 500
    assert check_urdf(chain(MAX_LINKS - 2)).tag == "robot"         # 500 links: accepted
    with pytest.raises(RobotModelError, match="501 links"):
        check_urdf(chain(MAX_LINKS - 1))


def test_the_robots_and_the_thesis_arms_pass():
    for name in robots.ROBOTS:
        r = robots.robot(name)
        assert load_chain("", r.urdf_file, r.base_link, r.tip_link).n in (6, 7)
    for scenario in SCENARIOS:
        if scenario != "urdf_surface":
            make_plant(scenario)
    chain_model = load_chain(chain(20), "", "base_link", "tool0")
    assert chain_model.n == 20


def test_off_the_chain_a_massless_frame_or_a_zero_limit_is_no_concern():
    """The checks of the chain's joints concern the joints a controller drives: a finger's
    zero effort limit (the finger is locked) and the Panda's massless frames (link 8, the
    TCP: mass 0, inertia 0) pass."""
    finger = panda_with('<limit effort="100" lower="0.0" upper="0.04" velocity="0.2"/>',
                        '<limit effort="0" lower="0.0" upper="0.04" velocity="0"/>')
    assert load_chain(finger, "", BASE, TIP).n == 7


def test_the_plant_and_the_controllers_refuse_with_the_same_line():
    """Both load the robot through load_chain: the plant (with its wrist sensor's tool, which
    is mounted after the checks) and a task-space controller give the reason as a
    ParameterError (the nodes print it as their one line)."""
    xml, reason = HOSTILE["a joint origin of 1e300 m"]
    r = robots.robot("panda_ft")
    values = {k: v for k, v in robots.plant_values(r).items() if k != "scenario"}
    with pytest.raises(ParameterError, match="places a frame 1e\\+300 m from its parent"):
        make_plant("urdf_surface", {**values, "robot_description": xml})
    controller = {**robots.controller_values(r, "adaptive_impedance"), "robot_description": xml}
    with pytest.raises(ParameterError, match="places a frame 1e\\+300 m from its parent"):
        make_controller("adaptive_impedance", controller)


def error_line(proc: subprocess.CompletedProcess) -> str:
    """The single line a failed command printed on stderr (asserting there is one)."""
    assert proc.returncode == 1, (proc.returncode, proc.stdout + proc.stderr)
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "RTPS_TRANSPORT_SHM" not in ln]
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.mark.ros
@pytest.mark.parametrize("case", ["a chain 4000 links deep", "a joint origin of 1e300 m",
                                  "zero mass and inertia on link 7"])
def test_the_plant_executable_exits_1_with_one_line(tmp_path, ros_env, case):
    xml, reason = HOSTILE[case]
    path = tmp_path / "x.urdf"
    path.write_text(xml)
    deep = case.startswith("a chain")
    plant = Path(sys.executable).with_name("plant")
    start = time.monotonic()
    proc = subprocess.run(
        [str(plant), "--ros-args", "-p", "scenario:=urdf_surface", "-p", f"urdf_file:={path}",
         "-p", f"base_link:={'base_link' if deep else BASE}",
         "-p", f"tip_link:={'tool0' if deep else TIP}"],
        env=ros_env, capture_output=True, text=True, timeout=120)
    elapsed = time.monotonic() - start
    line = error_line(proc)
    assert line.startswith("plant: refused to start: ") and reason[:60] in line, line
    print(f"\n{case}: exit 1 in {elapsed:.1f} s: {line}")   # a figure, not a verdict


# -- no NaN leaves a plant -------------------------------------------------------------------
class Watched:
    """A plant as the reflexes see it: a contact force and true joint velocities."""

    def __init__(self, force: float, velocity: list[float]):
        self.force, self.velocity = force, velocity

    def contact_force_magnitude(self) -> float:
        return self.force

    def true_velocity(self) -> list[float]:
        return self.velocity


LIMITS = [(0, 2.0, "joint1"), (1, 3.0, "joint2")]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_every_reflex_takes_a_value_that_is_not_a_number_as_a_violation(bad):
    assert reflex(Watched(1.0, [0.5, -0.5]), 50.0, LIMITS) is None
    reason, line = reflex(Watched(bad, [0.5, -0.5]), 50.0, LIMITS)
    assert reason == SAFE_STOP_CONTACT_FORCE and line.startswith("REFLEX: contact force")
    reason, line = reflex(Watched(1.0, [0.5, bad]), 50.0, LIMITS)
    assert reason == SAFE_STOP_JOINT_VELOCITY and line.startswith("REFLEX: joint joint2 velocity")
    # no velocity limits known: the force alone
    assert reflex(Watched(1.0, [bad, bad]), 50.0, []) is None


def test_a_non_finite_state_is_seen_in_every_plant():
    plants = [make_plant(s) for s in SCENARIOS if s != "urdf_surface"]
    r = robots.robot("panda_ft")
    plants.append(make_plant("urdf_surface", {k: v for k, v in robots.plant_values(r).items()
                                              if k != "scenario"}))
    for plant in plants:
        assert plant.state_is_finite()
        plant._x[-1] = math.nan
        assert not plant.state_is_finite(), type(plant).__name__


def answer(node, effort) -> None:
    msg = JointState(name=list(node.command_names), effort=list(effort))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(node.state_stamp, 1_000_000_000)
    node._on_command(serialize_message(msg))


def errors(node) -> list[str]:
    return [m for level, m in node.log.lines if level == "error"]


def published(node) -> np.ndarray:
    """What the node's last joint state and wrench messages carry."""
    out = node.messages
    return np.concatenate([out.position, out.velocity, out.effort, out.wrench_values])


@pytest.mark.ros
def test_a_non_finite_state_stops_the_lockstep_plant_with_one_error_line(make_node):
    node = make_node(mode="lockstep")
    node._publish_state(0, 0)
    answer(node, [0.1, 0.1])
    stamp, last = node.state_stamp, published(node)
    assert np.isfinite(last).all() and node.exit_code == 0
    plant = node.plant
    plant.reset_state(plant.state[:2], [math.nan, 0.0])
    answer(node, [0.1, 0.1])
    assert node.finished.done() and node.exit_code == 1
    assert errors(node) == ["NON-FINITE: the plant's state is not finite at t = 0.002 s: nothing "
                            "more is published (the last state was finite) and the plant stops, "
                            "exit code 1; a controller sees its states stop"]
    assert node.state_stamp == stamp                       # nothing published since
    np.testing.assert_array_equal(published(node), last)
    answer(node, [0.1, 0.1])                               # a late command changes nothing
    assert node.state_stamp == stamp and len(errors(node)) == 1


@pytest.mark.ros
def test_a_non_finite_state_in_a_safe_stop_stops_the_realtime_plant(make_node):
    """Braking cannot help a NaN state: after the reflex's line, one NON-FINITE line."""
    from plant_harness import tick

    node = make_node()
    tick(node)
    plant = node.plant
    plant.reset_state(plant.state[:2], [30.0, 0.0])        # beyond the 10 rad/s limit
    tick(node)
    assert node.safe_stop and len(errors(node)) == 1
    stamp, last = node.state_stamp, published(node)
    plant.reset_state(plant.state[:2], [0.0, math.inf])
    tick(node)
    assert node.finished.done() and node.exit_code == 1
    assert len(errors(node)) == 2 and errors(node)[1].startswith("NON-FINITE: the plant's state")
    assert node.state_stamp == stamp
    np.testing.assert_array_equal(published(node), last)
    tick(node)
    assert node.state_stamp == stamp and len(errors(node)) == 2


@pytest.mark.ros
def test_a_non_finite_wrench_is_not_published(make_node):
    """A finite state whose measurement is not (a sensor model gone wrong): the same stop."""
    from plant_harness import tick

    node = make_node()
    tick(node)
    stamp = node.state_stamp
    measure = node.plant.measurement
    node.plant.measurement = lambda: replace(measure(), force=np.array([math.nan, 0.0, 0.0]))
    tick(node)
    assert node.finished.done() and node.exit_code == 1 and node.state_stamp == stamp
    assert errors(node) == [errors(node)[0]] and errors(node)[0].startswith(
        "NON-FINITE: the joint state or wrench to publish is not finite at t = ")
