"""The thesis's arm plants take their arm from a URDF: robot_description or
urdf_file, base_link, tip_link, as the controllers do.

compliant_plane (ch. 3), circular_surface (ch. 5), moving_object (ch. 2) and
flexible_joint_surface (ch. 6) are defined for a planar 2-link arm: the default URDFs give
the plants of before bit for bit (against the models built the old way, straight from the
URDF file with the link parameters written over it, and against the states recorded from
the code before the change), any planar 2-link URDF works and names the joints, anything
else is refused with one line.
"""

import math

import numpy as np
import pinocchio as pin
import pytest
from robot_data import needs_erd

from cr_control.core.parameters import ParameterError, resolve
from cr_control.core.paths import config_file
from cr_control.models.arm_model import two_link_inverse_kinematics
from cr_control.models.planar_chain import PlanarChain
from cr_sim.models.constrained_dynamics import mechanism_rk4, mechanism_work_size, planar_mechanism
from cr_sim.plants import flexible_joint_surface as fjs
from cr_sim.plants.arm_on_surface import arm_on_surface_step, work_size
from cr_sim.plants.registry import SCENARIOS, make_plant

DT = 1e-3
STEPS = 1000
THESIS_ARMS = ("compliant_plane", "circular_surface", "moving_object", "flexible_joint_surface")

#: State after 1 s of :func:`torques` from each default plant, recorded with the code before
#: the plants took a URDF (they agree bit for bit on the machine that recorded them).
RECORDED = {
    "compliant_plane": [3.293534949416516, -2.8291978115194985, 0.4699308008060767,
                        -0.9645043828814824],
    "circular_surface": [0.7770361682082247, -1.6062782361533252, 0.19982165854616962,
                         -0.3421697844812056],
    "moving_object": [1.2018586623465328, 1.08347640037988, 0.10517475520929574,
                      0.26998403684438416, -0.10299131458659327, -0.10977012308520802],
    "flexible_joint_surface": [2.908924281852575, -2.1496657039260856, 0.12448491317088128,
                               -0.05910644401605415, 2.8625900814086265, -2.1242822040724647,
                               -0.13135501341809155, -0.30715495015185007],
}

#: The thesis's 2-link arm renamed, its base link mounted on a world link by a fixed joint
#: (shifted and turned), other limits, and inertial values that the link_* parameters override.
RENAMED = """<?xml version="1.0"?>
<robot name="renamed_arm">
  <link name="world"/>
  <joint name="mount" type="fixed">
    <parent link="world"/><child link="arm_base"/>
    <origin xyz="0.4 -0.2 0.1" rpy="0 0 0.7"/>
  </joint>
  <link name="arm_base"/>
  <joint name="shoulder" type="revolute">
    <parent link="arm_base"/><child link="upper_arm"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-5" upper="5" effort="15" velocity="4"/>
  </joint>
  <link name="upper_arm">
    <inertial><origin xyz="0.2 0 0"/><mass value="2.0"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <joint name="elbow" type="revolute">
    <parent link="upper_arm"/><child link="forearm"/>
    <origin xyz="0.4 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-5" upper="5" effort="12" velocity="6"/>
  </joint>
  <link name="forearm">
    <inertial><origin xyz="0.2 0 0"/><mass value="1.5"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <joint name="flange_joint" type="fixed">
    <parent link="forearm"/><child link="flange"/><origin xyz="0.4 0 0"/>
  </joint>
  <link name="flange"/>
</robot>
"""
RENAMED_ROBOT = {"robot_description": RENAMED, "base_link": "arm_base", "tip_link": "flange"}


def _link(name: str) -> str:
    return (f'<link name="{name}"><inertial><origin xyz="0.15 0 0"/><mass value="0.1"/>'
            '<inertia ixx="0.3" ixy="0" ixz="0" iyy="0.3" iyz="0" izz="0.3"/></inertial></link>')


def _joint(name: str, parent: str, child: str, x: float, axis: str = "0 0 1",
           kind: str = "revolute") -> str:
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{x} 0 0"/><axis xyz="{axis}"/>'
            '<limit lower="-6" upper="6" effort="20" velocity="10"/></joint>')


def arm_urdf(*joints: tuple) -> str:
    """A serial arm base_link -> link1 -> ... -> tool0; ``joints``: (x offset, axis, type)."""
    body = ['<robot name="arm"><link name="base_link"/>']
    parent = "base_link"
    for i, (x, axis, kind) in enumerate(joints, start=1):
        body += [_joint(f"joint{i}", parent, f"link{i}", x, axis, kind), _link(f"link{i}")]
        parent = f"link{i}"
    body += [f'<joint name="tool0_joint" type="fixed"><parent link="{parent}"/>'
             '<child link="tool0"/><origin xyz="0.3 0 0"/></joint><link name="tool0"/></robot>']
    return "".join(body)




# -- the plants of before, built the old way ----------------------------------------------------
def old_model(values: dict, urdf_name: str = "two_link_arm.urdf") -> pin.Model:
    """The arm as the plants built it before: the URDF file with the link parameters and
    gravity written over it (every scenario read two_link_arm.urdf, moving_object its own)."""
    model = pin.buildModelFromUrdf(str(config_file(urdf_name)))
    model.gravity.linear = np.array([0.0, -values["gravity"], 0.0])
    model.jointPlacements[model.getJointId("joint2")].translation = np.array(
        [values["link_length"][0], 0.0, 0.0])
    for i, joint in enumerate(("joint1", "joint2")):
        izz = values["link_inertia"][i]
        model.inertias[model.getJointId(joint)] = pin.Inertia(
            values["link_mass"][i], np.array([values["link_com"][i], 0.0, 0.0]),
            np.diag([izz, izz, izz]))
    model.frames[model.getFrameId("tool0")].placement.translation = np.array(
        [values["link_length"][1], 0.0, 0.0])
    return model


def _static(model: pin.Model, q: np.ndarray, normal: np.ndarray, force: float) -> np.ndarray:
    """G(q) - J_Phi^T force with J_Phi = n^T J_tool (and -n_x on an object axis)."""
    data = model.createData()
    gravity = pin.computeGeneralizedGravity(model, data, q)
    J = pin.computeFrameJacobian(model, data, q, model.getFrameId("tool0"), pin.LOCAL_WORLD_ALIGNED)
    jphi = normal @ J[:2]
    if model.nv == 3:
        jphi[2] = -normal[0]
    return gravity - jphi * force


def old_plant(scenario: str):
    """(packed model, initial state, initial held command, step(x, held, command)) of the
    plant of before: its model built the old way, stepped by the plant's own kernel."""
    plant = make_plant(scenario)   # only the surface and the disturbance, which did not change
    values = resolve(SCENARIOS[scenario][0], {})
    if scenario in ("compliant_plane", "circular_surface"):
        chain = PlanarChain.from_model(old_model(values), "tool0").chain
        q0 = two_link_inverse_kinematics(values["link_length"], (0.0, 0.0),
                                         values["initial_position"], values["elbow_sign"])
        work, sensors = np.empty(work_size(2)), np.zeros(7)

        def step(x, held, command, t):
            arm_on_surface_step(chain, plant.surface, plant.disturbance_packed, t, x, held, command,
                                DT, 1, sensors, work)
        return chain, np.concatenate([q0, np.zeros(2)]), np.zeros(2), step
    normal = np.asarray(values["constraint_normal" if scenario == "moving_object"
                               else "surface_normal"], dtype=float)
    normal = normal / math.hypot(*normal)
    if scenario == "moving_object":
        model = old_model(values, "moving_object.urdf")
        a = values["base_position"]
        model.jointPlacements[model.getJointId("joint1")].translation = np.array([a[0], a[1], 0.0])
        obj = model.getJointId("object_x")
        model.jointPlacements[obj].translation = np.array([0.0, values["object_height"], 0.0])
        model.inertias[obj] = pin.Inertia(values["object_mass"], np.zeros(3), np.eye(3) * 1e-3)
        mech = planar_mechanism(model, "tool0", "object_frame", np.array([*normal, 0.0]), 0.0,
                                20.0, 20.0)
        x_o, x_co = values["initial_object_position"], values["initial_contact_position"]
        y_co = -normal[0] * x_co / normal[1]
        arm_q = two_link_inverse_kinematics(values["link_length"], a,
                                            (x_o + x_co, values["object_height"] + y_co),
                                            values["elbow_sign"])
        q0 = np.array([*arm_q, x_o])
        held = _static(model, q0, normal, values["initial_force"])
        work, lam = np.empty(mechanism_work_size(mech)), np.zeros(1)

        def step(x, held, command, t):
            if command.shape == (3,) and np.all(np.isfinite(command)):
                held[:] = command
            mechanism_rk4(mech, x, held, DT, 1, work, lam)
        return mech, np.concatenate([q0, np.zeros(3)]), held, step
    model = old_model(values)
    offset = values["surface_offset"] / math.hypot(*values["surface_normal"])
    mech = planar_mechanism(model, "tool0", "base_link", np.array([*normal, 0.0]), -offset,
                            20.0, 20.0)
    theta1, theta2 = values["initial_link_position"]
    q_l0 = np.array([theta1, fjs.surface_angle(values["link_length"], normal, offset, theta1,
                                                theta2)])
    held = _static(model, q_l0, normal, values["initial_force"])
    ks, jm = np.asarray(values["joint_stiffness"]), np.asarray(values["motor_inertia"])
    flex, work = np.concatenate([ks, jm]), np.empty(mechanism_work_size(mech))
    buf, sensors = np.empty(fjs.buffer_size(2)), np.zeros(5)

    def step(x, held, command, t):
        fjs.flexible_joint_step(mech, flex, x, held, command, DT, 1, work, buf, sensors)
    return mech, np.concatenate([q_l0, np.zeros(2), q_l0 + held / ks, np.zeros(2)]), held, step


def packed(plant) -> np.ndarray:
    return plant.chain if hasattr(plant, "chain") else plant.mech


def held_command(plant) -> np.ndarray:
    return plant.held if hasattr(plant, "held") else plant.measurement().effort[-len(plant.command_joints):]


def torques(base: np.ndarray) -> list[np.ndarray]:
    """The fixed command sequence: the initial held torque (the gravity torque for the
    compliant-contact plants) plus 0.3 sin(5 t + i) N m on joint i."""
    n = len(base)
    return [base + np.array([0.3 * math.sin(5.0 * k * DT + i) for i in range(n)])
            for k in range(STEPS)]


def base_torque(scenario: str, plant) -> np.ndarray:
    if scenario in ("compliant_plane", "circular_surface"):
        return plant.gravity_torque(plant.measurement().position)
    return np.array(held_command(plant), dtype=float)


def trajectory(plant, commands) -> np.ndarray:
    out = []
    for command in commands:
        plant.step(command, DT)
        m = plant.measurement()
        out.append(np.concatenate([plant.state, m.position, m.velocity, m.effort, m.force,
                                   np.asarray(plant.sensors() if callable(plant.sensors)
                                              else plant.sensors, dtype=float)]))
    return np.array(out)


# -- the thesis's arms -----------------------------------------------------------------------------
@pytest.mark.parametrize("scenario", THESIS_ARMS)
def test_default_plant_is_the_plant_of_before_bit_for_bit(scenario):
    """Same packed model, initial state and held command as the model built the old way, the
    same states over 1 s of a fixed torque sequence, and the states recorded before."""
    plant = make_plant(scenario)
    chain, x0, held0, step = old_plant(scenario)
    assert np.array_equal(packed(plant), chain)
    assert np.array_equal(plant.state, x0)
    assert np.array_equal(held_command(plant), held0)
    commands = torques(base_torque(scenario, plant))
    x, held = x0.copy(), held0.copy()
    for k, command in enumerate(commands):
        plant.step(command, DT)
        step(x, held, command, k * DT)
        assert np.array_equal(plant.state, x), f"step {k}"
    np.testing.assert_allclose(plant.state, RECORDED[scenario], rtol=1e-12, atol=1e-14)
    assert plant.joint_names[:2] == ("joint1", "joint2")


@pytest.mark.parametrize("scenario", THESIS_ARMS)
def test_the_urdf_as_robot_description_gives_the_same_trajectory(scenario):
    urdf_file = resolve(SCENARIOS[scenario][0], {})["urdf_file"]
    xml = config_file(urdf_file).read_text()
    by_file = make_plant(scenario)
    by_text = make_plant(scenario, {"robot_description": xml, "urdf_file": ""})
    commands = torques(base_torque(scenario, by_file))
    assert np.array_equal(trajectory(by_text, commands), trajectory(by_file, commands))


@pytest.mark.parametrize("scenario", THESIS_ARMS)
def test_the_default_urdf_carries_the_link_parameters(scenario):
    """The link_* defaults override the default URDF with its own values (chapter 5: the
    0.6 m arm of two_link_arm_ch5.urdf)."""
    values = resolve(SCENARIOS[scenario][0], {})
    assert values["urdf_file"] == ("two_link_arm_ch5.urdf" if scenario == "circular_surface"
                                   else "two_link_arm.urdf")
    model = pin.buildModelFromUrdf(str(config_file(values["urdf_file"])))
    floats = lambda xs: [float(x) for x in xs]  # noqa: E731
    tool = model.frames[model.getFrameId("tool0")].placement.translation
    assert floats([model.jointPlacements[2].translation[0], tool[0]]) == floats(values["link_length"])
    assert floats(model.inertias[j].lever[0] for j in (1, 2)) == floats(values["link_com"])
    assert floats(model.inertias[j].mass for j in (1, 2)) == floats(values["link_mass"])
    assert floats(model.inertias[j].inertia[2, 2] for j in (1, 2)) == floats(values["link_inertia"])


# -- another planar 2-link arm ---------------------------------------------------------------------
RENAMED_JOINTS = {
    "compliant_plane": ("shoulder", "elbow"),
    "circular_surface": ("shoulder", "elbow"),
    "moving_object": ("shoulder", "elbow", "object_x"),
    "flexible_joint_surface": ("shoulder", "elbow", "shoulder_motor", "elbow_motor"),
}


@pytest.mark.parametrize("scenario", THESIS_ARMS)
def test_renamed_arm_on_a_shifted_base_publishes_its_names(scenario):
    """Joint names and limits are the URDF's; the plant lives in base_link's frame (the mount
    does not matter) and link_* override the URDF's geometry and inertia, so with the thesis's
    values the motion is the default plant's, bit for bit."""
    plant = make_plant(scenario, RENAMED_ROBOT)
    default = make_plant(scenario)
    assert plant.joint_names == RENAMED_JOINTS[scenario]
    commands = torques(base_torque(scenario, default))
    assert np.array_equal(trajectory(plant, commands), trajectory(default, commands))
    limits = plant.joint_limits()
    if scenario == "flexible_joint_surface":
        assert plant.command_joints == ("shoulder_motor", "elbow_motor")
        assert plant.sensor_fields == ("lambda", "phi", "phi_dot", "shoulder_motor_acceleration",
                                       "elbow_motor_acceleration")
        assert plant.velocity_limits() == [(0, 4.0), (1, 6.0)]
    else:
        assert list(limits.effort[:2]) == [15.0, 12.0]
        assert list(limits.velocity[:2]) == [4.0, 6.0]
        assert list(limits.upper[:2]) == [5.0, 5.0]
    if scenario == "moving_object":
        assert list(limits.velocity) == [4.0, 6.0, 5.0]     # the object axis of moving_object.urdf


def test_link_parameters_override_the_urdf():
    plant = make_plant("compliant_plane", {**RENAMED_ROBOT, "link_length": [0.35, 0.3],
                                           "initial_position": [0.1, 0.3]})
    assert plant.arm.params.length == [0.35, 0.3]
    np.testing.assert_allclose(plant.arm.tool_position(plant.measurement().position), [0.1, 0.3],
                               atol=1e-12)
    np.testing.assert_allclose(plant.arm.tool_position(np.zeros(2)), [0.65, 0.0], atol=1e-15)


# -- refused ---------------------------------------------------------------------------------------
def refusal(scenario: str, overrides: dict) -> str:
    with pytest.raises(ParameterError) as info:
        make_plant(scenario, overrides)
    message = str(info.value)
    assert "\n" not in message and message
    return message


@pytest.mark.parametrize("scenario", THESIS_ARMS)
def test_a_planar_three_link_arm_is_refused(scenario):
    urdf = arm_urdf((0.0, "0 0 1", "revolute"), (0.3, "0 0 1", "revolute"),
                    (0.3, "0 0 1", "revolute"))
    assert refusal(scenario, {"robot_description": urdf}) == (
        f"{scenario} simulates a planar 2-link arm, but the chain base_link -> tool0 has 3 "
        "joints (joint1, joint2, joint3), not 2; the scenario urdf_surface simulates any other arm")


@needs_erd
@pytest.mark.parametrize("scenario", ["compliant_plane", "flexible_joint_surface"])
def test_the_panda_is_refused(scenario):
    panda = {"urdf_file": "package://example-robot-data/robots/panda_description/urdf/panda.urdf",
             "base_link": "panda_link0", "tip_link": "panda_hand_tcp"}
    joints = ", ".join(f"panda_joint{i}" for i in range(1, 8))
    assert refusal(scenario, panda) == (
        f"{scenario} simulates a planar 2-link arm, but the chain panda_link0 -> panda_hand_tcp "
        f"has 7 joints ({joints}), not 2; the scenario urdf_surface simulates any other arm")


@pytest.mark.parametrize("joints, reason", [
    (((0.0, "0 0 1", "revolute"), (0.3, "0 1 0", "revolute")),
     "joint 'joint2' is a revolute joint about y, not a revolute joint about z"),
    (((0.0, "0 0 1", "revolute"), (0.3, "0 0 -1", "revolute")),
     "joint 'joint2' is a revolute joint about (0, 0, -1), not a revolute joint about z"),
    (((0.0, "0 0 1", "continuous"), (0.3, "0 0 1", "revolute")),
     "joint 'joint1' is a continuous joint, not a revolute joint about z"),
    (((0.0, "0 0 1", "revolute"), (0.3, "1 0 0", "prismatic")),
     "joint 'joint2' is a prismatic joint along x, not a revolute joint about z"),
    (((0.1, "0 0 1", "revolute"), (0.3, "0 0 1", "revolute")),
     "joint 'joint1' is at x-y [0.1, 0.0] m from 'base_link', not at its origin"),
])
def test_a_two_joint_chain_that_is_not_the_planar_arm_is_refused(joints, reason):
    assert refusal("circular_surface", {"robot_description": arm_urdf(*joints)}) == (
        f"circular_surface simulates a planar 2-link arm, but {reason}; the scenario "
        "urdf_surface simulates any other arm")


def test_a_rotated_joint_origin_is_refused():
    urdf = arm_urdf((0.0, "0 0 1", "revolute"), (0.3, "0 0 1", "revolute")).replace(
        '<origin xyz="0.3 0 0"/><axis', '<origin xyz="0.3 0 0" rpy="0.2 0 0"/><axis', 1)
    assert "joint 'joint2' has a rotated origin" in refusal("compliant_plane",
                                                             {"robot_description": urdf})


@pytest.mark.parametrize("scenario", THESIS_ARMS)
def test_a_urdf_that_cannot_be_loaded_gives_its_reason(scenario):
    assert refusal(scenario, {"robot_description": "<robot name='x'><link name='a'>"}).startswith(
        "the URDF is not valid XML: ")
    broken = RENAMED.replace('<parent link="upper_arm"/>', '<parent link="nowhere"/>')
    assert refusal(scenario, {**RENAMED_ROBOT, "robot_description": broken}).startswith(
        "the URDF does not parse: ")
    assert refusal(scenario, {"tip_link": "flange"}).startswith(
        "tip_link 'flange' is not a link of the URDF (links: ")
    assert refusal(scenario, {"urdf_file": "no_such_arm.urdf"}) == (
        "urdf_file no_such_arm.urdf: no such file")
