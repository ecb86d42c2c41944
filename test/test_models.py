"""The arm model (URDF through Pinocchio) against the thesis's closed forms, and the plant."""

import numpy as np
import pytest

from cr_control.models.arm_model import LinkParameters, TwoLinkArm, closed_form_dynamics
from cr_control.schemes.blocks.task_space import task_dynamics, task_frame, task_model
from cr_control.schemes.registry import controller_class
from cr_sim.models.surfaces import circle, contact_force, plane
from cr_sim.plants.compliant_plane import PARAMETERS
from cr_sim.plants.registry import make_plant

RNG = np.random.default_rng(7)
SAMPLES = [(RNG.uniform(-np.pi, np.pi, 2), RNG.uniform(-2, 2, 2)) for _ in range(20)]


@pytest.fixture(scope="module")
def arm():
    return TwoLinkArm()


@pytest.mark.parametrize("q,v", SAMPLES)
def test_pinocchio_matches_printed_closed_forms(arm, q, v):
    """M, C, G of (2.103) and J of (6.117) equal Pinocchio's to rounding error."""
    M, C, G, J = closed_form_dynamics(arm.params, q, v)
    assert np.abs(arm.mass_matrix(q) - M).max() < 1e-12
    assert np.abs(arm.coriolis_matrix(q, v) - C).max() < 1e-12
    assert np.abs(arm.gravity(q) - G).max() < 1e-12
    assert np.abs(arm.jacobian(q) - J).max() < 1e-12
    assert np.abs(arm.nonlinear_effects(q, v) - (C @ v + G)).max() < 1e-12


def test_base_parameters_are_the_corrected_thesis_values():
    """docs/thesis.md: p = [0.6135, 0.0045, 0.30225, 0.441, 0.147] (ch. 2 prints p2 = 0.04)."""
    p = LinkParameters().base_parameters()
    assert np.allclose(p, [0.6135, 0.0045, 0.30225, 0.441, 0.147], atol=1e-12)


@pytest.mark.parametrize("q,v", SAMPLES[:5])
def test_mass_matrix_properties(arm, q, v):
    """M symmetric positive definite; M' - 2C skew-symmetric (Property 3.2)."""
    M = arm.mass_matrix(q)
    assert np.allclose(M, M.T) and np.linalg.eigvalsh(M).min() > 0
    h = 1e-6
    M_dot = (arm.mass_matrix(q + h * v) - arm.mass_matrix(q - h * v)) / (2 * h)
    N = M_dot - 2 * arm.coriolis_matrix(q, v)
    assert np.abs(N + N.T).max() < 1e-8


@pytest.mark.parametrize("q,v", SAMPLES[:5])
def test_task_space_model_reproduces_joint_dynamics(arm, q, v):
    """M_r r'' + C_r r' + G_r = J^-T tau + f (3.2) for the accelerations of (3.1): the generic
    task space (any URDF arm) on the thesis's 2-link arm."""
    cls = controller_class("adaptive_impedance")
    model = task_model(cls.robot_values(None))
    if abs(np.linalg.det(arm.jacobian(q))) < 1e-3:
        pytest.skip("near a singularity")
    tau, f = np.array([0.7, -0.3]), np.array([2.0, -1.0])
    frame = task_frame(model.chain, model.task, 1e12, q, v)   # no singularity damping
    assert np.allclose(frame.J, arm.jacobian(q), atol=1e-12) and frame.damping == 0.0
    qdd = arm.forward_dynamics(q, v, tau + frame.J.T @ f)
    r_dd = frame.J @ qdd + frame.J_dot @ v
    M_r, C_r, G_r = task_dynamics(model.chain, frame)
    residual = M_r @ r_dd + C_r @ frame.r_dot + G_r - np.linalg.inv(frame.J).T @ tau - f
    assert np.abs(residual).max() < 1e-9
    assert np.allclose(M_r, M_r.T) and np.linalg.eigvalsh(M_r).min() > 0


def test_inverse_kinematics_round_trip_on_the_printed_branch(arm):
    r = np.array([-0.05, 0.2])
    q = arm.inverse_kinematics(r)
    assert np.allclose(arm.tool_position(q), r, atol=1e-12)
    assert np.sin(q[1]) < 0
    with pytest.raises(ValueError, match="out of reach"):
        arm.inverse_kinematics(np.array([0.7, 0.0]))


def test_plane_pushes_only_when_penetrated_and_never_pulls():
    surface = plane(np.array([1.0, -1.0]), 0.25, 150.0, 20.0)
    outside = np.array([0.0, 0.2])           # x - y + 0.25 > 0: free space
    inside = np.array([-0.05, 0.25])         # 0.05/sqrt(2) m deep
    assert np.all(contact_force(surface, outside, np.zeros(2)) == 0)
    f = contact_force(surface, inside, np.zeros(2))
    assert np.allclose(f, 150 * 0.05 / np.sqrt(2) * np.array([1, -1]) / np.sqrt(2))
    leaving_fast = np.array([10.0, -10.0])   # damping would pull: clipped to zero
    assert np.all(contact_force(surface, inside, leaving_fast) == 0)
    with pytest.raises(ValueError, match="zero"):
        plane(np.zeros(2), 0.25, 150.0, 0.0)


def test_circle_pushes_outward_from_its_centre_only_when_penetrated():
    surface = circle([0.8, -0.4], 0.3, 1000.0, 0.0)
    assert np.all(contact_force(surface, np.array([0.8, -0.05]), np.zeros(2)) == 0)  # 5 cm out
    f = contact_force(surface, np.array([0.8, -0.11]), np.zeros(2))                   # 1 cm in
    assert np.allclose(f, [0.0, 10.0])
    f = contact_force(surface, np.array([0.8 + 0.29 / np.sqrt(2), -0.4 - 0.29 / np.sqrt(2)]),
                      np.zeros(2))
    assert np.allclose(f, 10.0 * np.array([1.0, -1.0]) / np.sqrt(2))


def test_plant_starts_at_rest_touching_with_zero_force():
    plant = make_plant("compliant_plane")
    m = plant.measurement()
    assert np.allclose(plant.arm.tool_position(m.position), [-0.05, 0.2], atol=1e-12)
    assert np.all(m.velocity == 0) and np.abs(m.force).max() < 1e-9


def test_rk4_converges_at_fourth_order():
    """1 s of gravity-driven motion into the plane: 1 ms steps agree with 0.125 ms steps."""
    def final_state(substeps):
        plant = make_plant("compliant_plane", {"substeps": substeps})
        for _ in range(1000):
            plant.step(np.array([0.5, 0.2]), 1e-3)
        return plant.state

    x1, x2, x8 = final_state(1), final_state(2), final_state(8)
    assert np.abs(x1 - x8).max() < 1e-6
    assert np.abs(x2 - x8).max() < np.abs(x1 - x8).max()


def test_plant_refuses_non_finite_commands_and_keeps_the_last():
    plant = make_plant("compliant_plane")
    plant.step(np.array([0.3, 0.1]), 1e-3)
    plant.step(np.array([np.nan, 1.0]), 1e-3)
    plant.step(np.array([1.0, 2.0, 3.0]), 1e-3)
    assert np.allclose(plant.measurement().effort, [0.3, 0.1])
    assert np.isfinite(plant.state).all()


def test_plant_parameters_have_thesis_defaults():
    defaults = {p.name: p.default for p in PARAMETERS}
    assert defaults["stiffness"] == 150.0
    assert defaults["link_inertia"] == [0.3, 0.3] and defaults["link_mass"] == [0.1, 0.1]
    assert defaults["surface_offset"] == 0.25 and defaults["surface_normal"] == [1.0, -1.0]
