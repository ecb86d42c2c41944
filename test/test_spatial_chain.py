"""The compiled 3-D chain (cr_control.models.spatial_chain) against Pinocchio, finite
differences, the planar chain and the thesis's closed forms."""

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from cr_control.models.arm_model import LinkParameters, TwoLinkArm, closed_form_dynamics
from cr_control.models.planar_chain import PlanarChain, coriolis_matrix, tool_jacobian_dot, tool_kinematics
from cr_control.models.planar_chain import mass_matrix as planar_mass_matrix
from cr_control.models.planar_chain import rnea as planar_rnea
from cr_control.models.spatial_chain import (
    HEADER,
    PER_JOINT,
    TIP,
    SpatialChain,
    coriolis_product,
    jacobian_dot,
    kinematics_only,
    mass_matrix,
    output_views,
    rnea,
    tip_dynamics_into,
    tip_kinematics,
    work_size,
)
from cr_control.models.urdf import CONTINUOUS, PRISMATIC, ChainModel, load_chain

# A prismatic joint along an unaligned axis, an unaligned revolute axis, a continuous joint,
# a revolute joint about -z, rotated joint and inertial origins, full inertia tensors, a
# finger (locked, its mass carried) and a base_link below the URDF root (re-rooting).
SYNTHETIC_URDF = """<?xml version="1.0"?>
<robot name="synthetic">
  <link name="world"/>
  <joint name="mount" type="fixed">
    <parent link="world"/><child link="base_link"/>
    <origin xyz="0.2 -0.1 0.5" rpy="0.3 -0.2 0.7"/>
  </joint>
  <link name="base_link">
    <inertial><mass value="3.0"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
  </link>
  <joint name="tilt" type="revolute">
    <parent link="base_link"/><child link="link1"/>
    <origin xyz="0.05 0.02 0.1" rpy="0.1 0.2 -0.3"/>
    <axis xyz="0.3 0.5 0.81"/>
    <limit lower="-2.5" upper="2.5" effort="50" velocity="2"/>
  </joint>
  <link name="link1">
    <inertial>
      <origin xyz="0.01 0.02 0.15" rpy="0.4 0.1 -0.2"/><mass value="1.3"/>
      <inertia ixx="0.02" ixy="0.001" ixz="-0.002" iyy="0.025" iyz="0.003" izz="0.015"/>
    </inertial>
  </link>
  <joint name="slide" type="prismatic">
    <parent link="link1"/><child link="link2"/>
    <origin xyz="0 0.1 0.3" rpy="-0.5 0.3 0.2"/>
    <axis xyz="0 0.6 0.8"/>
    <limit lower="-0.2" upper="0.4" effort="100" velocity="0.5"/>
  </joint>
  <link name="link2">
    <inertial>
      <origin xyz="-0.02 0.05 0.1" rpy="0 0.3 0"/><mass value="0.9"/>
      <inertia ixx="0.012" ixy="-0.001" ixz="0.0005" iyy="0.01" iyz="0.002" izz="0.008"/>
    </inertial>
  </link>
  <joint name="spin" type="continuous">
    <parent link="link2"/><child link="link3"/>
    <origin xyz="0.1 0 0.2" rpy="0.2 -0.4 0.1"/>
    <axis xyz="0 1 0"/>
    <limit effort="20" velocity="3"/>
  </joint>
  <link name="link3">
    <inertial>
      <origin xyz="0.03 0.08 -0.01" rpy="-0.3 0 0.5"/><mass value="0.6"/>
      <inertia ixx="0.004" ixy="0.0003" ixz="0" iyy="0.006" iyz="-0.0004" izz="0.005"/>
    </inertial>
  </link>
  <joint name="wrist" type="revolute">
    <parent link="link3"/><child link="link4"/>
    <origin xyz="0 0.15 0.05" rpy="1.2 0 -0.6"/>
    <axis xyz="0 0 -1"/>
    <limit lower="-3" upper="3" effort="10" velocity="3"/>
  </joint>
  <link name="link4">
    <inertial>
      <origin xyz="0.01 -0.01 0.04" rpy="0.1 0.2 0.3"/><mass value="0.4"/>
      <inertia ixx="0.001" ixy="0" ixz="0.0001" iyy="0.0012" iyz="0" izz="0.0009"/>
    </inertial>
  </link>
  <joint name="finger" type="prismatic">
    <parent link="link4"/><child link="finger_link"/>
    <origin xyz="0.02 0 0.05"/>
    <axis xyz="1 0 0"/>
    <limit lower="0.01" upper="0.04" effort="5" velocity="0.1"/>
  </joint>
  <link name="finger_link">
    <inertial>
      <origin xyz="0 0 0.02"/><mass value="0.1"/>
      <inertia ixx="0.0001" ixy="0" ixz="0" iyy="0.0001" iyz="0" izz="0.0001"/>
    </inertial>
  </link>
  <joint name="tool_joint" type="fixed">
    <parent link="link4"/><child link="tool"/>
    <origin xyz="0.01 -0.02 0.12" rpy="0.2 0.1 -0.4"/>
  </joint>
  <link name="tool"/>
</robot>
"""

ROBOTS = {
    "panda": lambda: load_chain("", "package://example-robot-data/robots/panda_description/urdf/panda.urdf",
                                "panda_link0", "panda_hand_tcp"),
    "ur5": lambda: load_chain("", "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf",
                              "base_link", "tool0"),
    "thesis_arm": lambda: load_chain("", "two_link_arm.urdf", "base_link", "tool0", gravity=[0, -9.8, 0]),
    "synthetic": lambda: load_chain(SYNTHETIC_URDF, "", "base_link", "tool"),
}
SAMPLES = 10


@pytest.fixture(scope="module", params=list(ROBOTS))
def robot(request) -> tuple[ChainModel, np.ndarray]:
    chain = ROBOTS[request.param]()
    return chain, SpatialChain.from_chain(chain).chain


def assert_close(actual, expected, tol: float = 1e-10) -> None:
    """|actual - expected| <= tol, relative to the magnitude of ``expected`` where it exceeds 1."""
    expected = np.asarray(expected)
    error = np.abs(np.asarray(actual) - expected).max()
    assert error <= tol * max(1.0, np.abs(expected).max()), error


def states(chain: ChainModel, seed: int):
    """SAMPLES random (q, v, a, x): joint positions inside the limits (continuous anywhere)."""
    rng = np.random.default_rng(seed)
    lower = np.where(np.isfinite(chain.limits.lower), chain.limits.lower, -np.pi)
    upper = np.where(np.isfinite(chain.limits.upper), chain.limits.upper, np.pi)
    for _ in range(SAMPLES):
        yield rng.uniform(lower, upper), *rng.uniform(-2, 2, size=(3, chain.n))


def symmetric_crba(model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
    M = pin.crba(model, data, q)
    return np.triu(M) + np.triu(M, 1).T


def test_packing_layout(robot):
    chain, packed = robot
    assert packed.shape == (HEADER + PER_JOINT * chain.n + TIP,)
    assert packed[0] == chain.n
    assert_close(packed[1:4], chain.model.gravity.linear, 0.0)
    assert SpatialChain.from_chain(chain).joint_names == chain.joint_names


def test_tip_kinematics_matches_pinocchio(robot):
    chain, packed = robot
    model, data = chain.model, chain.model.createData()
    for q, v, _, _ in states(chain, 1):
        p, R, J, jdot_v = tip_kinematics(packed, q, v)
        q_pin = chain.configuration(q)
        pin.forwardKinematics(model, data, q_pin, v, np.zeros(chain.n))
        pin.updateFramePlacements(model, data)
        assert_close(p, data.oMf[chain.tip].translation)
        assert_close(R, data.oMf[chain.tip].rotation)
        acceleration = pin.getFrameClassicalAcceleration(model, data, chain.tip, pin.LOCAL_WORLD_ALIGNED)
        assert_close(jdot_v[:3], acceleration.linear)
        assert_close(jdot_v[3:], acceleration.angular)
        assert_close(J, pin.computeFrameJacobian(model, data, q_pin, chain.tip, pin.LOCAL_WORLD_ALIGNED))


def test_jacobian_dot_is_the_time_derivative_of_the_jacobian(robot):
    chain, packed = robot
    model, data = chain.model, chain.model.createData()
    step = 1e-5
    for q, v, _, _ in states(chain, 2):
        J_dot = jacobian_dot(packed, q, v)
        assert_close(J_dot @ v, tip_kinematics(packed, q, v)[3])
        forward, backward = (tip_kinematics(packed, q + sign * step * v, v)[2] for sign in (1, -1))
        assert_close(J_dot, (forward - backward) / (2 * step), 1e-7)
        # Pinocchio's LOCAL_WORLD_ALIGNED time variation is d/dt J too
        pin.computeJointJacobiansTimeVariation(model, data, chain.configuration(q), v)
        assert_close(J_dot, pin.getFrameJacobianTimeVariation(model, data, chain.tip,
                                                              pin.LOCAL_WORLD_ALIGNED))


def test_dynamics_match_pinocchio(robot):
    chain, packed = robot
    model, data = chain.model, chain.model.createData()
    for q, v, a, x in states(chain, 3):
        q_pin = chain.configuration(q)
        M = mass_matrix(packed, q)
        assert np.array_equal(M, M.T)
        assert_close(M, symmetric_crba(model, data, q_pin))
        assert_close(rnea(packed, q, v, a, True), pin.rnea(model, data, q_pin, v, a))
        gravity = pin.computeGeneralizedGravity(model, data, q_pin)
        assert_close(rnea(packed, q, v, a, False), pin.rnea(model, data, q_pin, v, a) - gravity)
        assert_close(rnea(packed, q, np.zeros(chain.n), np.zeros(chain.n), True), gravity)
        C = pin.computeCoriolisMatrix(model, data, q_pin, v)
        assert_close(coriolis_product(packed, q, v, x), C @ x)
        assert_close(coriolis_product(packed, q, v, v), rnea(packed, q, v, np.zeros(chain.n), False))


def test_hot_path_kernel_matches_the_entry_points_and_pinocchio(robot):
    chain, packed = robot
    model, data = chain.model, chain.model.createData()
    work = np.full(work_size(chain.n), np.nan)
    p, R, J, jdot_v, M, h = output_views(work, chain.n)
    for q, v, _, _ in states(chain, 4):   # the same work vector every cycle, as the controller does
        tip_dynamics_into(packed, q, v, work)
        for computed, expected in zip((p, R, J, jdot_v), tip_kinematics(packed, q, v), strict=True):
            assert_close(computed, expected, 1e-12)
        assert_close(M, mass_matrix(packed, q), 1e-12)
        assert_close(h, rnea(packed, q, v, np.zeros(chain.n), True), 1e-12)
        assert_close(h, pin.nonLinearEffects(model, data, chain.configuration(q), v))


def test_kinematics_only_chain_has_no_dynamics(robot):
    chain, packed = robot
    geometry = kinematics_only(packed)
    assert not np.array_equal(geometry, packed) and packed[0] == geometry[0]
    for q, v, a, _ in states(chain, 5):
        assert np.abs(rnea(geometry, q, v, a, True)).max() == 0.0
        assert np.abs(mass_matrix(geometry, q)).max() == 0.0
        kinematics = zip(tip_kinematics(geometry, q, v), tip_kinematics(packed, q, v), strict=True)
        assert all(np.array_equal(computed, expected) for computed, expected in kinematics)


def test_synthetic_chain_exercises_every_joint_kind():
    chain = ROBOTS["synthetic"]()
    assert chain.joint_names == ("tilt", "slide", "spin", "wrist")
    assert chain.kinds[1] == PRISMATIC and chain.kinds[2] == CONTINUOUS
    packed = SpatialChain.from_chain(chain).chain
    axes = [packed[HEADER + PER_JOINT * j + 1:HEADER + PER_JOINT * j + 4] for j in range(chain.n)]
    assert_close(axes[0], np.array([0.3, 0.5, 0.81]) / np.linalg.norm([0.3, 0.5, 0.81]), 1e-15)
    assert_close(axes[1], [0.0, 0.6, 0.8], 1e-15)
    assert_close(np.abs(axes[3]), [0.0, 0.0, 1.0], 0.0)
    # gravity is re-expressed in base_link, which the fixed mount joint turns by rpy (0.3, -0.2, 0.7)
    assert_close(packed[1:4], pin.rpy.rpyToMatrix(0.3, -0.2, 0.7).T @ [0.0, 0.0, -9.81], 1e-15)


@pytest.mark.parametrize("params", [LinkParameters(), LinkParameters(
    length=[0.3, 0.45], com=[0.12, 0.2], mass=[0.1, 0.35], inertia=[0.3, 0.05])], ids=["thesis", "odd"])
def test_thesis_arm_matches_the_planar_chain_and_the_closed_forms(params):
    arm = TwoLinkArm(params)
    chain = ChainModel(arm.model, arm.tool, "base_link", "tool0", arm.joint_names, ("revolute",) * 2,
                       None, np.zeros(2), np.zeros(2))
    packed = SpatialChain.from_chain(chain).chain
    planar = PlanarChain.from_model(arm.model, "tool0").chain
    rng = np.random.default_rng(6)
    for _ in range(SAMPLES):
        q, v, a, x = rng.uniform(-3, 3, size=(4, 2))
        p, _, J, jdot_v = tip_kinematics(packed, q, v)
        r_planar, J_planar, jdot_v_planar = tool_kinematics(planar, q, v)
        assert_close(p[:2], r_planar)
        assert_close(J[:2], J_planar)
        assert_close(jdot_v[:2], jdot_v_planar)
        assert_close(jacobian_dot(packed, q, v)[:2], tool_jacobian_dot(planar, q, v))
        assert_close(mass_matrix(packed, q), planar_mass_matrix(planar, q))
        assert_close(rnea(packed, q, v, a, True), planar_rnea(planar, q, v, a, True))
        assert_close(coriolis_product(packed, q, v, x), coriolis_matrix(planar, q, v) @ x)
        M, C, G, J_printed = closed_form_dynamics(params, q, v)
        assert_close(mass_matrix(packed, q), M)
        assert_close(coriolis_product(packed, q, v, x), C @ x)
        assert_close(rnea(packed, q, np.zeros(2), np.zeros(2), True), G)
        assert_close(J[:2], J_printed)


def test_the_loaded_thesis_arm_is_the_planar_model():
    chain = ROBOTS["thesis_arm"]()
    packed = SpatialChain.from_chain(chain).chain
    planar = PlanarChain.from_model(TwoLinkArm().model, "tool0").chain
    q, v, a = np.array([0.7, -1.9]), np.array([0.4, -0.8]), np.array([1.1, 0.3])
    assert_close(rnea(packed, q, v, a, True), planar_rnea(planar, q, v, a, True))
    assert_close(tip_kinematics(packed, q, v)[2][:2], tool_kinematics(planar, q, v)[1])


def _two_joint_model(second_parent: int, second_joint: pin.JointModel) -> tuple[pin.Model, int]:
    model = pin.Model()
    first = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "first")
    model.appendBodyToJoint(first, pin.Inertia.Random(), pin.SE3.Identity())
    offset = pin.SE3(np.eye(3), np.array([0.3, 0.0, 0.0]))
    second = model.addJoint(second_parent, second_joint, offset, "second")
    model.appendBodyToJoint(second, pin.Inertia.Random(), pin.SE3.Identity())
    tip = model.addFrame(pin.Frame("tip", second, 0, offset, pin.FrameType.OP_FRAME))
    return model, tip


def test_refuses_what_is_not_a_serial_chain_of_supported_joints():
    loaded = ROBOTS["thesis_arm"]()
    branched, tip = _two_joint_model(0, pin.JointModelRZ())
    with pytest.raises(ValueError, match="not a serial chain"):
        SpatialChain.from_chain(dataclasses.replace(loaded, model=branched, tip=tip))
    spherical, tip = _two_joint_model(1, pin.JointModelSpherical())
    with pytest.raises(ValueError, match="JointModelSpherical"):
        SpatialChain.from_model(spherical, tip)
    serial, _ = _two_joint_model(1, pin.JointModelPY())
    on_first = serial.addFrame(pin.Frame("elbow", 1, 0, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    with pytest.raises(ValueError, match="not fixed to the last joint"):
        SpatialChain.from_model(serial, on_first)
