"""A wrist force/torque sensor in the URDF plant.

Checked: a :class:`Tool` replaces what the URDF mounts beyond the sensor link (the Panda's
hand and fingers) with its own mass, centre of mass and inertia, every frame of the URDF
survives and ``tcp`` adds ``tool_tcp``; the one-line refusals; ``urdf_surface`` with
``sensor_frame``: at rest out of contact the sensor reads the tool's weight and its moment
plus the bias, in static contact contact + weight, during a motion the tool's inertial
wrench (a finite-difference check of its momentum), with noise of the stated std; the true
contact wrench is K_e depth n; ``start_clearance`` puts the surface that far from the tip;
the ideal sensor (``sensor_frame`` empty) is bit for bit the plant before the wrist sensor.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from robot_data import needs_erd

from cr_control.core.parameters import ParameterError
from cr_control.models.urdf import RobotModelError, Tool, load_chain
from cr_sim.plants.registry import make_plant
from cr_sim.plants.urdf_surface import URDFSurface

PERIOD = 1e-3
PANDA_URDF = "package://example-robot-data/robots/panda_description/urdf/panda.urdf"
UR5_URDF = "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
PANDA_HOME = [0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]
UR5_HOME = [0.0, -1.5707963, 1.5707963, -1.5707963, -1.5707963, 0.0]
PANDA = {"urdf_file": PANDA_URDF, "base_link": "panda_link0", "tip_link": "panda_hand_tcp",
         "initial_joint_positions": PANDA_HOME}
UR5 = {"urdf_file": UR5_URDF, "base_link": "base_link", "tip_link": "tool0",
       "initial_joint_positions": UR5_HOME}
#: The tool of the robot scenarios (0.7 kg, 6 cm out along the flange axis), a little off-axis
#: and with products of inertia so that every term shows.
TOOL = {"tool_mass": 0.7, "tool_com": [0.01, -0.02, 0.06],
        "tool_inertia": [2e-3, 1e-4, -2e-4, 3e-3, 5e-5, 1.5e-3]}
BIAS = [2.0, -1.0, 3.0, 0.1, -0.05, 0.02]
#: The Franka hand (0.73 kg) and its two fingers (0.015 kg each) beyond panda_link8.
PANDA_HAND_MASS = 0.76
GRAVITY = np.array([0.0, 0.0, -9.81])
HAND_TCP = 0.1034           # panda_hand_tcp along the flange axis from panda_link8 (m)


pytestmark = needs_erd


def panda_tool(**changes) -> Tool:
    values = {"mass": TOOL["tool_mass"], "com": TOOL["tool_com"], "inertia": TOOL["tool_inertia"],
              **changes}
    return Tool("panda_link8", **values)


def plant(robot: dict, **overrides) -> URDFSurface:
    made = make_plant("urdf_surface", {**robot, **overrides})
    assert isinstance(made, URDFSurface)
    return made


def sensor_rotation(p: URDFSurface, frame: str) -> np.ndarray:
    """R (base <- sensor frame) at the plant's state, from a model query of its own."""
    model = p.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, p.chain.configuration(p.state[:p.chain.n]))
    return data.oMf[model.getFrameId(frame, pin.BODY)].rotation.copy()


def weight(R: np.ndarray, mass: float, com) -> np.ndarray:
    """The tool's weight and its moment about the sensor origin, sensor frame (6)."""
    force = R.T @ (mass * GRAVITY)
    return np.concatenate([force, np.cross(com, force)])


# -- the tool in the chain model ----------------------------------------------------------------
def test_the_tool_replaces_the_pandas_hand_and_fingers():
    """Mass: the model loses the hand and fingers (0.76 kg) and gains the tool; the last
    body's spatial inertia grows by exactly the tool's, placed at panda_link8; the other
    bodies are those of the URDF, bit for bit."""
    bare = load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp")
    tool = panda_tool()
    tooled = load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp", tool=tool)
    empty = load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp", tool=Tool("panda_link8"))
    total = lambda chain: sum(inertia.mass for inertia in chain.model.inertias)  # noqa: E731
    assert total(bare) - total(empty) == pytest.approx(PANDA_HAND_MASS, abs=1e-12)
    assert total(tooled) - total(empty) == pytest.approx(tool.mass, abs=1e-12)
    assert tooled.tool == tool and bare.tool is None
    sensor = tooled.model.frames[tooled.model.getFrameId("panda_link8", pin.BODY)]
    assert sensor.parentJoint == 7
    added = tooled.model.inertias[7] - empty.model.inertias[7]
    expected = sensor.placement.act(tool.spatial_inertia)
    assert np.allclose(added.matrix(), expected.matrix(), atol=1e-12)
    # the subtree of the last joint (Pinocchio's centres of mass, in the joint's frame): the
    # tool adds its mass at its centre of mass
    data_tool, data_empty = tooled.model.createData(), empty.model.createData()
    q = tooled.configuration(np.array(PANDA_HOME) + 0.1)
    pin.centerOfMass(tooled.model, data_tool, q, True)
    pin.centerOfMass(empty.model, data_empty, q, True)
    assert data_tool.mass[7] - data_empty.mass[7] == pytest.approx(tool.mass, abs=1e-12)
    moment = data_tool.mass[7] * data_tool.com[7] - data_empty.mass[7] * data_empty.com[7]
    pin.framesForwardKinematics(tooled.model, data_tool, q)
    com = data_tool.oMf[tooled.model.getFrameId("panda_link8", pin.BODY)].act(np.array(tool.com))
    assert np.allclose(data_tool.oMi[7].act(moment / tool.mass), com, atol=1e-12)
    for j in range(1, 7):
        assert np.array_equal(bare.model.inertias[j].matrix(), tooled.model.inertias[j].matrix())


def test_every_frame_survives_and_tcp_adds_tool_tcp():
    bare = load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp")
    tooled = load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp", tool=panda_tool())
    names = lambda chain: [f.name for f in chain.model.frames]  # noqa: E731
    assert set(names(tooled)) - set(names(bare)) == {"tool", "tool_joint"}
    assert names(tooled)[:len(names(bare))] == names(bare)
    q = np.array(PANDA_HOME) + 0.1
    assert np.array_equal(bare.tip_pose(q).homogeneous, tooled.tip_pose(q).homogeneous)
    data_bare, data_tool = bare.model.createData(), tooled.model.createData()
    pin.framesForwardKinematics(bare.model, data_bare, bare.configuration(q))
    pin.framesForwardKinematics(tooled.model, data_tool, tooled.configuration(q))
    for i, name in enumerate(names(bare)):
        assert np.allclose(data_bare.oMf[i].homogeneous, data_tool.oMf[i].homogeneous, atol=1e-15), name
    # the tool frame is the sensor frame
    assert np.array_equal(data_tool.oMf[tooled.model.getFrameId("tool")].homogeneous,
                          data_tool.oMf[tooled.model.getFrameId("panda_link8")].homogeneous)
    # a contact point on the UR5's bare flange
    tcp = (0.01, 0.0, 0.12)
    flange = load_chain("", UR5_URDF, "base_link", "tool0")
    on_tcp = load_chain("", UR5_URDF, "base_link", "tool_tcp",
                        tool=Tool("tool0", 1.0, (0.0, 0.0, 0.05), (1e-3, 0, 0, 1e-3, 0, 1e-3), tcp))
    q = np.array(UR5_HOME) + 0.2
    assert np.allclose(on_tcp.tip_pose(q).translation, flange.tip_pose(q).act(np.array(tcp)),
                       atol=1e-15)
    assert on_tcp.model.existFrame("tool_tcp") and on_tcp.model.existFrame("tool_tcp_joint")


SLIDER_WITH_TOOL_LINK = """<robot name="slider">
  <link name="base_link"/>
  <joint name="rail" type="prismatic">
    <parent link="base_link"/><child link="tool"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="100" velocity="2"/>
  </joint>
  <link name="tool"><inertial><mass value="1.0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
</robot>
"""


@pytest.mark.parametrize(("tool", "reason"), [
    (Tool("panda_link9"), "sensor_link 'panda_link9' is not a link of the URDF"),
    (Tool("panda_leftfinger"), "sensor_link 'panda_leftfinger' is not on the chain from base_link"),
    (Tool("panda_link5"), "is not fixed to tip_link 'panda_hand_tcp': joint 'panda_joint7' moves"),
    (Tool("panda_link0"), "is not fixed to tip_link"),
])
def test_a_sensor_link_the_tool_cannot_ride_on_is_refused_in_one_line(tool, reason):
    with pytest.raises(RobotModelError) as refused:
        load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp", tool=tool)
    assert reason in str(refused.value) and "\n" not in str(refused.value)


def test_a_sensor_on_the_tips_own_link_is_accepted():
    """panda_link7 is the body the last joint moves: the flange and the hand ride on it."""
    chain = load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp", tool=Tool("panda_link7", 0.5))
    bare = load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp")
    mass = lambda c: sum(i.mass for i in c.model.inertias)  # noqa: E731
    assert mass(bare) - mass(chain) == pytest.approx(PANDA_HAND_MASS - 0.5, abs=1e-12)


@pytest.mark.parametrize(("make", "reason"), [
    (lambda: panda_tool(mass=-0.1), "tool mass must be >= 0 kg"),
    (lambda: panda_tool(mass=math.nan), "tool mass must be a finite number, got nan"),
    (lambda: panda_tool(com=(0.0, 0.1)), "tool com needs 3 finite values"),
    (lambda: panda_tool(inertia=(1e-3, 0, 0, 1e-3, 0)), "tool inertia needs 6 finite values"),
    (lambda: panda_tool(inertia=(-1e-3, 0, 0, 1e-3, 0, 1e-3)), "is not physical"),
    (lambda: panda_tool(inertia=(1e-3, 0, 0, 1e-3, 0, 3e-3)), "each at most the sum of the other two"),
    (lambda: panda_tool(inertia=(1e-3, 2e-3, 0, 1e-3, 0, 1e-3)), "is not physical"),
    (lambda: panda_tool(mass=0.0), "tool inertia without tool mass"),
    (lambda: panda_tool(tcp=(0.0, 0.0)), "tool tcp needs 3 finite values"),
])
def test_a_non_physical_tool_is_refused_in_one_line(make, reason):
    with pytest.raises(RobotModelError) as refused:
        make()
    assert reason in str(refused.value) and "\n" not in str(refused.value)


def test_a_urdf_with_a_link_named_tool_is_refused():
    with pytest.raises(RobotModelError, match="already has a link or joint named 'tool'"):
        load_chain(SLIDER_WITH_TOOL_LINK, "", "base_link", "tool", tool=Tool("tool", 1.0))


def test_without_a_tool_the_chain_is_what_it_was():
    """The chain's own checks still come first: a wrong tip is named as such."""
    with pytest.raises(RobotModelError, match="tip_link 'nope' is not a link"):
        load_chain("", PANDA_URDF, "panda_link0", "nope", tool=panda_tool())


# -- the plant's wrist sensor -------------------------------------------------------------------
@pytest.mark.parametrize(("overrides", "reason"), [
    ({"sensor_frame": "panda_link3"}, "is not fixed to tip_link 'panda_hand_tcp'"),
    ({"sensor_frame": "panda_rightfinger"}, "is not on the chain"),
    ({"sensor_frame": "flange"}, "sensor_link 'flange' is not a link of the URDF"),
    ({"tool_mass": 0.7}, "tool_mass need sensor_frame"),
    ({"ft_bias": BIAS, "ft_noise_std": [0.2, 0.0]}, "ft_bias, ft_noise_std need sensor_frame"),
    ({"sensor_frame": "panda_link8", "force_noise_std": 0.1}, "use ft_noise_std"),
    ({"sensor_frame": "panda_link8", "tool_tcp": [0.0, 0.1]}, "tool_tcp needs 3 values"),
    ({"sensor_frame": "panda_link8", "tool_mass": -1.0}, "tool_mass must be >= 0"),
    ({"sensor_frame": "panda_link8", **TOOL, "tool_inertia": [1, 0, 0, 1, 0, 3]}, "is not physical"),
    ({"sensor_frame": "panda_link8", "start_clearance": -0.01}, "start_clearance must be >= 0"),
])
def test_plant_refusals_are_parameter_errors_of_one_line(overrides, reason):
    with pytest.raises(ParameterError) as refused:
        plant(PANDA, **overrides)
    assert reason in str(refused.value) and "\n" not in str(refused.value)


POSE = np.array(PANDA_HOME) + np.array([0.3, 0.2, -0.4, 0.3, 0.5, -0.3, 0.6])


def held_still(p: URDFSurface, q0: np.ndarray):
    """Gravity compensation with a joint PD about q0 (the arm stays where it is)."""
    n = p.chain.n
    return lambda s: s.gravity(s.state[:n]) - 50.0 * (s.state[:n] - q0) - 5.0 * s.state[n:]


def test_at_rest_out_of_contact_the_sensor_reads_the_tools_weight_and_the_bias():
    """F = R^T m g, T = c x F, + bias, to 1e-6 (no noise), in a tilted pose where every
    component shows; the arm carries the tool (gravity compensation of the model holds it)."""
    p = plant({**PANDA, "initial_joint_positions": list(POSE)}, sensor_frame="panda_link8",
              start_clearance=0.05, ft_bias=BIAS, **TOOL)
    assert p.wrench_frame == "panda_link8" and p.base_frame == "panda_link0"
    hold = held_still(p, POSE)
    for _ in range(300):
        p.step(hold(p), PERIOD)
    assert np.max(np.abs(p.state[7:])) < 1e-9 and p.contact_depth() == pytest.approx(-0.05, abs=1e-9)
    m = p.measurement()
    expected = weight(sensor_rotation(p, "panda_link8"), TOOL["tool_mass"], TOOL["tool_com"]) + BIAS
    assert np.max(np.abs(np.concatenate([m.force, m.torque]) - expected)) < 1e-6
    assert np.max(np.abs(expected[:3] - BIAS[:3])) > 1.0      # the weight is there, tilted
    assert np.max(np.abs(expected[3:] - BIAS[3:])) > 0.05     # and its moment
    assert np.array_equal(p.sensor_wrench(), np.concatenate([m.force, m.torque]))
    # at home the flange points down: the weight is +m g along its axis
    home = plant(PANDA, sensor_frame="panda_link8", start_clearance=0.05, tool_mass=0.7,
                 tool_com=[0.0, 0.0, 0.06])
    home.step(home.gravity(np.array(PANDA_HOME)), PERIOD)
    assert np.allclose(home.sensor_wrench(), [0.0, 0.0, 0.7 * 9.81, 0.0, 0.0, 0.0], atol=1e-6)


def pressing_at_rest(p: URDFSurface, seconds: float = 0.1):
    """Hold the arm at rest pressing the pad: tau = G(q) - J_v^T f with f the contact force
    at its (penetrating) initial pose, so q'' = 0."""
    n = p.chain.n
    q0 = p.state[:n].copy()
    tau = p.gravity(q0) - p.tip_jacobian(q0).T @ p.contact_force()
    for _ in range(round(seconds / PERIOD)):
        p.step(tau, PERIOD)
    assert np.max(np.abs(p.state[n:])) < 1e-9 and np.max(np.abs(p.state[:n] - q0)) < 1e-10


def test_in_static_contact_the_sensor_reads_contact_plus_weight():
    """The Panda 2 mm into the pad: f = K_e depth n = 10 N up; the sensor reads R^T f and its
    moment about the flange (the tip is 0.1034 m out along the flange axis) + the weight."""
    bare = load_chain("", PANDA_URDF, "panda_link0", "panda_hand_tcp")
    r0 = bare.tip_pose(np.array(PANDA_HOME)).translation
    p = plant(PANDA, sensor_frame="panda_link8", ft_bias=BIAS, surface_point=list(r0 + [0, 0, 0.002]),
              **TOOL)
    pressing_at_rest(p)
    contact = p.contact_wrench()
    assert np.allclose(contact.force, [0.0, 0.0, 5000.0 * 0.002], atol=1e-9)
    assert np.array_equal(contact.torque, np.zeros(3))
    assert np.allclose(contact.point, r0, atol=1e-9)
    R = sensor_rotation(p, "panda_link8")
    f = R.T @ contact.force
    expected = (np.concatenate([f, np.cross([0.0, 0.0, HAND_TCP], f)])
                + weight(R, TOOL["tool_mass"], TOOL["tool_com"]) + BIAS)
    assert np.max(np.abs(p.sensor_wrench() - expected)) < 1e-6
    assert p.contact_force_magnitude() == pytest.approx(10.0, abs=1e-9)   # the reflex: true force


def test_a_tool_tcp_on_the_ur5s_flange_presses_a_tilted_plane():
    """The UR5's flange carries a 1 kg tool whose point 12 cm out touches a tilted plane
    (2 mm deep): f = K_e depth n, and the sensor reads its moment p x R^T f."""
    tcp = [0.01, 0.0, 0.12]
    tooled = load_chain("", UR5_URDF, "base_link", "tool_tcp",
                        tool=Tool("tool0", 1.0, (0.0, 0.0, 0.05), (1e-3, 0, 0, 1e-3, 0, 1e-3), tcp))
    r0 = tooled.tip_pose(np.array(UR5_HOME)).translation
    normal = np.array([0.3, 0.0, 1.0]) / math.hypot(0.3, 1.0)
    p = plant({**UR5, "tip_link": "tool_tcp"}, sensor_frame="tool0", tool_mass=1.0,
              tool_com=[0.0, 0.0, 0.05], tool_inertia=[1e-3, 0, 0, 1e-3, 0, 1e-3], tool_tcp=tcp,
              surface_normal=list(normal), surface_point=list(r0 + 0.002 * normal))
    pressing_at_rest(p)
    contact = p.contact_wrench()
    assert np.allclose(contact.force, 5000.0 * 0.002 * normal, atol=1e-9)
    R = sensor_rotation(p, "tool0")
    f = R.T @ contact.force
    expected = np.concatenate([f, np.cross(tcp, f)]) + weight(R, 1.0, [0.0, 0.0, 0.05])
    assert np.max(np.abs(p.sensor_wrench() - expected)) < 1e-6
    assert np.linalg.norm(np.cross(tcp, f)) > 0.1


def test_noise_has_the_stated_std_and_leaves_the_truth_alone():
    p = plant(PANDA, sensor_frame="panda_link8", ft_bias=BIAS, ft_noise_std=[0.2, 0.01],
              start_clearance=0.05, noise_seed=7, **TOOL)
    truth = p.sensor_wrench()
    samples = np.array([np.concatenate([(m := p.measurement()).force, m.torque]) for _ in range(4000)])
    std = samples.std(axis=0)
    assert np.all(np.abs(std[:3] / 0.2 - 1.0) < 0.1) and np.all(np.abs(std[3:] / 0.01 - 1.0) < 0.1)
    standard_error = np.array([0.2] * 3 + [0.01] * 3) / math.sqrt(len(samples))
    assert np.all(np.abs(samples.mean(axis=0) - truth) < 4 * standard_error)
    assert np.array_equal(p.sensor_wrench(), truth)
    again = plant(PANDA, sensor_frame="panda_link8", ft_bias=BIAS, ft_noise_std=[0.2, 0.01],
                  start_clearance=0.05, noise_seed=7, **TOOL)
    assert np.array_equal(again.measurement().force, samples[0, :3])


def tool_momentum(p: URDFSurface, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(h = m v_c, L_c = R I_c R^T omega, R) of the tool at the plant's state, world frame."""
    model, tool, n = p.model, p.chain.tool, p.chain.n
    data = model.createData()
    pin.forwardKinematics(model, data, p.chain.configuration(p.state[:n]), p.state[n:])
    R = pin.updateFramePlacement(model, data, frame).rotation.copy()
    velocity = pin.getFrameVelocity(model, data, frame, pin.LOCAL_WORLD_ALIGNED)
    omega = velocity.angular.copy()
    v_com = velocity.linear + np.cross(omega, R @ np.array(tool.com))
    return tool.mass * v_com, R @ tool.inertia_matrix @ R.T @ omega, R


def rate_of_change(values: list[np.ndarray], k: int, h: float) -> np.ndarray:
    """d/dt of ``values`` (sampled every h) at k: five-point central differences, O(h^4)."""
    return (values[k - 2] - 8 * values[k - 1] + 8 * values[k + 1] - values[k + 2]) / (12 * h)


def test_during_a_motion_the_sensor_reads_the_tools_inertial_wrench():
    """Out of contact, a constant command swinging the arm: the sensor's reading less the
    weight is -(dh/dt, dL_c/dt + c x dh/dt) in the sensor frame, the momentum's rate of
    change taken by five-point central differences of the trajectory (h = 1e-4 s)."""
    p = plant(PANDA, sensor_frame="panda_link8", surface="none", **TOOL)
    frame = p.model.getFrameId("panda_link8", pin.BODY)
    tau = p.gravity(np.array(PANDA_HOME)) + np.array([3.0, -4.0, 2.0, 3.0, 2.0, 2.0, 1.5])
    h, com = 1e-4, np.array(TOOL["tool_com"])
    momenta, readings = [], []
    for _ in range(3000):
        momenta.append(tool_momentum(p, frame))
        readings.append(p.sensor_wrench())
        p.step(tau, h)
    largest = np.zeros(6)
    for k in range(500, 2999, 500):
        R = momenta[k][2]
        dh, dL = (R.T @ rate_of_change([m[i] for m in momenta], k, h) for i in (0, 1))
        inertial = readings[k] - weight(R, TOOL["tool_mass"], com)
        expected = np.concatenate([-dh, -dL - np.cross(com, dh)])
        assert np.max(np.abs(inertial - expected)) < 1e-7, (k, inertial, expected)
        largest = np.maximum(largest, np.abs(expected))
    assert largest[:3].max() > 1.0 and largest[3:].max() > 0.05     # a real motion


def test_start_clearance_puts_the_surface_that_far_from_the_tip():
    for robot, overrides in ((PANDA, {}), (PANDA, {"surface_normal": [0.0, 0.6, 0.8]}),
                             (PANDA, {"surface": "sphere", "surface_radius": 0.2}),
                             (UR5, {"surface_normal": [1.0, 0.0, 1.0]})):
        p = plant(robot, start_clearance=0.05, **overrides)
        assert p.contact_depth() == pytest.approx(-0.05, abs=1e-12)
        r0 = p.tip_position(p.state)
        normal = p.surface_normal_at(r0)
        moved = p.surface[1:4] - (r0 - 0.2 * normal if overrides.get("surface") == "sphere" else r0)
        assert np.allclose(moved, -0.05 * normal, atol=1e-12)
    # the arm held still never touches; released, it falls onto the table
    p = plant(PANDA, start_clearance=0.05)
    for _ in range(400):
        p.step(np.zeros(7), PERIOD)
    assert p.contact_depth() > 0.0 and p.contact_force()[2] > 0.0


GOLDEN = json.loads((Path(__file__).parent / "data" / "urdf_surface_ideal_sensor_golden.json").read_text())
GOLDEN_CASES = {
    "panda_fall": (PANDA, {}, lambda p, t: np.zeros(7)),
    "panda_press": (PANDA, {"friction_coulomb": 0.3, "friction_viscous": 5.0},
                    lambda p, t: p.gravity(p.state[:7]) + np.array([0, 2, 0, -2, 0, 1, 0.5]) * np.sin(5 * t)),
    "panda_noise": (PANDA, {"position_noise_std": 1e-4, "velocity_noise_std": 1e-3,
                            "force_noise_std": 0.5, "noise_seed": 3}, lambda p, t: np.zeros(7)),
    "ur5_sphere": (UR5, {"surface": "sphere", "surface_radius": 0.2},
                   lambda p, t: p.gravity(p.state[:6]) + 0.5 * np.sin(3 * t)),
}


@pytest.mark.parametrize("case", sorted(GOLDEN_CASES))
def test_the_ideal_sensor_is_bit_for_bit_the_plant_before_the_wrist_sensor(case):
    robot, extra, command = GOLDEN_CASES[case]
    p = plant(robot, **extra)
    assert p.wrench_frame == robot["base_link"] and p.chain.tool is None
    for k in range(1, 401):
        p.step(command(p, (k - 1) * PERIOD), PERIOD)
        m = p.measurement()
        assert np.array_equal(m.torque, np.zeros(3))
        if str(k) in GOLDEN[case]:
            row = np.concatenate([[m.time], m.position, m.velocity, m.effort, m.force, p.state,
                                  [p.contact_depth()], p.contact_force()])
            assert [float(x).hex() for x in row] == GOLDEN[case][str(k)], k


def test_every_other_plant_measures_zero_torque():
    assert np.array_equal(make_plant("compliant_plane").measurement().torque, np.zeros(3))
