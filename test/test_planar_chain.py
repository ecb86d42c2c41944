"""The compiled planar-chain dynamics against Pinocchio (the URDF model) and the thesis."""

import numpy as np
import pinocchio as pin
import pytest

from cr_control.models.arm_model import LinkParameters, TwoLinkArm, closed_form_dynamics
from cr_control.models.planar_chain import (
    PlanarChain,
    coriolis_matrix,
    forward_dynamics,
    mass_matrix,
    rnea,
    solve_spd,
    tool_jacobian_dot,
    tool_kinematics,
)

# Deliberately unequal links so a swapped index shows.
ODD = LinkParameters(length=[0.3, 0.45], com=[0.12, 0.2], mass=[0.1, 0.35], inertia=[0.3, 0.05])


@pytest.fixture(params=[LinkParameters(), ODD], ids=["thesis", "odd"])
def arm(request):
    return TwoLinkArm(request.param)


def test_every_quantity_matches_pinocchio(arm):
    chain = PlanarChain.from_model(arm.model, "tool0").chain
    rng = np.random.default_rng(1)
    for _ in range(50):
        q, v, a, tau = rng.uniform(-3, 3, size=(4, 2))
        assert np.abs(rnea(chain, q, v, a, True) - pin.rnea(arm.model, arm.data, q, v, a)).max() < 1e-12
        assert np.abs(mass_matrix(chain, q) - arm.mass_matrix(q)).max() < 1e-12
        assert np.abs(forward_dynamics(chain, q, v, tau) - arm.forward_dynamics(q, v, tau)).max() < 1e-10
        r, J, jdot_v = tool_kinematics(chain, q, v)
        r_pin, J_pin, jdot_v_pin = arm.kinematics(q, v)
        assert np.abs(r - r_pin).max() < 1e-12
        assert np.abs(J - J_pin).max() < 1e-12
        assert np.abs(jdot_v - jdot_v_pin).max() < 1e-12


def test_matches_the_printed_closed_forms():
    """M, C, G (2.103) and J (6.117) with the thesis's parameters."""
    params = LinkParameters()
    chain = PlanarChain.from_model(TwoLinkArm(params).model, "tool0").chain
    q, v = np.array([0.7, -1.9]), np.array([0.4, -0.8])
    M, C, G, J = closed_form_dynamics(params, q, v)
    assert np.abs(mass_matrix(chain, q) - M).max() < 1e-12
    assert np.abs(rnea(chain, q, v, np.zeros(2), True) - (C @ v + G)).max() < 1e-12
    assert np.abs(tool_kinematics(chain, q, v)[1] - J).max() < 1e-12


def test_three_links_match_pinocchio():
    """Dimension-generic: a 3-link planar chain built directly in Pinocchio."""
    model = pin.Model()
    parent, placement = 0, pin.SE3.Identity()
    for i, (length, mass) in enumerate([(0.3, 0.2), (0.25, 0.15), (0.2, 0.1)]):
        parent = model.addJoint(parent, pin.JointModelRZ(), placement, f"j{i}")
        model.appendBodyToJoint(parent, pin.Inertia(mass, np.array([length / 2, 0.01, 0]),
                                                    np.diag([0.01, 0.02, 0.03 + i * 0.01])),
                                 pin.SE3.Identity())
        placement = pin.SE3(np.eye(3), np.array([length, 0.0, 0.0]))
    model.addFrame(pin.Frame("tool", parent, 0, placement, pin.FrameType.OP_FRAME))
    model.gravity.linear = np.array([0.0, -9.81, 0.0])
    data = model.createData()
    chain = PlanarChain.from_model(model, "tool").chain
    rng = np.random.default_rng(2)
    for _ in range(20):
        q, v, a = rng.uniform(-2, 2, size=(3, 3))
        assert np.abs(rnea(chain, q, v, a, True) - pin.rnea(model, data, q, v, a)).max() < 1e-12
        assert np.abs(forward_dynamics(chain, q, v, a) - pin.aba(model, data, q, v, a)).max() < 1e-10
        J = pin.computeFrameJacobian(model, data, q, model.getFrameId("tool"), pin.LOCAL_WORLD_ALIGNED)
        assert np.abs(tool_kinematics(chain, q, v)[1] - J[:2]).max() < 1e-12


def test_refuses_a_model_that_is_not_a_planar_chain():
    model = pin.Model()
    joint = model.addJoint(0, pin.JointModelRX(), pin.SE3.Identity(), "j")
    model.addFrame(pin.Frame("tool", joint, 0, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    with pytest.raises(ValueError, match="revolute z"):
        PlanarChain.from_model(model, "tool")


def test_cholesky_solve():
    A = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    b = np.array([1.0, -2.0, 0.5])
    assert np.abs(A @ solve_spd(A, b) - b).max() < 1e-14


def test_coriolis_matrix_and_jacobian_derivative_match_pinocchio(arm):
    chain = PlanarChain.from_model(arm.model, "tool0").chain
    rng = np.random.default_rng(3)
    for _ in range(30):
        q, v = rng.uniform(-3, 3, size=(2, 2))
        assert np.abs(coriolis_matrix(chain, q, v) - arm.coriolis_matrix(q, v)).max() < 1e-12
        pin.computeJointJacobiansTimeVariation(arm.model, arm.data, q, v)
        J_dot = pin.getFrameJacobianTimeVariation(arm.model, arm.data, arm.tool,
                                                  pin.LOCAL_WORLD_ALIGNED)[:2]
        assert np.abs(tool_jacobian_dot(chain, q, v) - J_dot).max() < 1e-12
