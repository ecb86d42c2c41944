"""The generic plant ``urdf_surface``: any URDF chain pressing a compliant plane or sphere.

Checked: one-line refusals; the Panda at rest under gravity compensation, falling onto the
pad without ever being pulled, held pressing it at rest with f = K_e depth; a prismatic
slider falling onto the pad and settling at K_e depth = m g; kinetic energy conserved in
free flight (UR5); friction against the tip's tangential velocity; the locked finger
joints published after the chain's; the 2-link arm through its URDF matching the chapter 3
plant to 1e-8 rad; continuous joints; refused commands; the automatic substep rule.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from robot_data import needs_erd

from cr_control.core.parameters import ParameterError
from cr_sim.models import contact3d
from cr_sim.plants.registry import make_plant
from cr_sim.plants.urdf_surface import URDFSurface

PERIOD = 1e-3
PANDA_HOME = [0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]
PANDA = {
    "urdf_file": "package://example-robot-data/robots/panda_description/urdf/panda.urdf",
    "base_link": "panda_link0", "tip_link": "panda_hand_tcp",
    "initial_joint_positions": PANDA_HOME,
}
UR5 = {
    "urdf_file": "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf",
    "base_link": "base_link", "tip_link": "tool0",
}
TWO_LINK = {"urdf_file": "two_link_arm.urdf", "base_link": "base_link", "tip_link": "tool0",
            "gravity": [0.0, -9.8, 0.0]}

#: A 1 kg slider on a vertical rail (prismatic joint along z), its tip at its origin.
SLIDER_URDF = """<?xml version="1.0"?>
<robot name="slider">
  <link name="base_link"/>
  <joint name="rail" type="prismatic">
    <parent link="base_link"/><child link="carriage"/>
    <origin xyz="0 0 0.5"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="100" velocity="2"/>
  </joint>
  <link name="carriage">
    <inertial>
      <mass value="1.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>
    </inertial>
  </link>
  <joint name="tool_joint" type="fixed"><parent link="carriage"/><child link="tool0"/></joint>
  <link name="tool0"/>
</robot>
"""




def plant(robot: dict, **overrides) -> URDFSurface:
    """A urdf_surface plant through the registry (ROS-style values)."""
    made = make_plant("urdf_surface", {**robot, **overrides})
    assert isinstance(made, URDFSurface)
    return made


def run(p: URDFSurface, command, seconds: float):
    """Step ``p`` for ``seconds`` with ``command(p)`` each period; yield after every step."""
    for _ in range(round(seconds / PERIOD)):
        p.step(command(p), PERIOD)
        yield p


# -- refusals ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("overrides", "reason"), [
    ({}, "no robot given"),
    ({"robot_description": "<robot name='x'><link name='a'></robot>"}, "not valid XML"),
    ({"robot_description": "<robot name='x'><joint name='j' type='revolute'/></robot>"},
     "does not parse"),
    ({**TWO_LINK, "tip_link": "flange"}, "'flange' is not a link of the URDF"),
    ({**TWO_LINK, "initial_joint_positions": [0.1, 0.2, 0.3]}, "initial_joint_positions needs 2"),
    ({**TWO_LINK, "surface_normal": [0.0, 0.0, 0.0]}, "surface_normal must not be zero"),
    ({**TWO_LINK, "surface_point": [1.0, 2.0]}, "surface_point needs 3 values"),
    ({**TWO_LINK, "substeps": -1}, "substeps must be >= 0"),
])
def test_refusals_are_parameter_errors_of_one_line(overrides, reason):
    with pytest.raises(ParameterError) as refused:
        make_plant("urdf_surface", overrides)
    message = str(refused.value)
    assert reason in message and "\n" not in message


# -- the Panda on its pad -----------------------------------------------------------------------
@needs_erd
def test_panda_with_gravity_compensated_stays_at_rest_touching_at_zero_force():
    p = plant(PANDA)
    q0 = np.array(PANDA_HOME)
    G = p.gravity(q0)
    assert p.contact_depth() == 0.0 and np.all(p.contact_force() == 0.0)
    for s in run(p, lambda _: G, 0.5):
        assert np.max(np.abs(s.contact_force())) < 1e-9
    assert np.max(np.abs(p.state[7:])) < 1e-10
    assert np.max(np.abs(p.state[:7] - q0)) < 1e-12


@needs_erd
def test_panda_without_command_falls_onto_the_pad_which_never_pulls():
    """Zero torque: the arm falls onto the pad, which pushes it up (+z) and never pulls, with
    no tangential force (no friction). (A 7-joint arm touching at one point has no rest
    pose to come to without a controller: it keeps folding; see the held test below.)"""
    p = plant(PANDA)
    forces, depths = [], []
    for s in run(p, lambda _: np.zeros(7), 0.5):
        forces.append(s.contact_force())
        depths.append(s.contact_depth())
    f, depth = np.array(forces), np.array(depths)
    assert f[:, 2].max() > 50.0                           # it lands on the pad, hard
    assert np.all(f[:, 2] >= 0.0) and np.all(f[:, :2] == 0.0)
    assert np.all(f[depth <= 0.0] == 0.0)                 # no force without contact


@needs_erd
def test_panda_held_pressing_the_pad_comes_to_rest_with_force_k_e_times_depth():
    """Gravity compensation, a joint impedance about home (M (K_d q' + K_p (q - q0)), 20 rad/s,
    critically damped) and 10 N pushed down through J^T: the arm settles on the pad,
    f = K_e depth (the pad's damping term vanishes at rest)."""
    p = plant(PANDA)
    q0 = np.array(PANDA_HOME)
    push = p.tip_jacobian(q0).T @ np.array([0.0, 0.0, -10.0])

    def held(s: URDFSurface) -> np.ndarray:
        q, v = s.state[:7], s.state[7:]
        return s.gravity(q) + push - s.mass_matrix(q) @ (40.0 * v + 400.0 * (q - q0))

    for s in run(p, held, 1.5):
        assert s.contact_force()[2] >= 0.0
    f, depth = p.contact_force(), p.contact_depth()
    assert np.max(np.abs(p.state[7:])) < 1e-4
    assert depth > 0.0 and f[2] > 5.0 and np.all(f[:2] == 0.0)
    assert f[2] == pytest.approx(5000.0 * depth, rel=0.01)
    assert p.measurement().force == pytest.approx(f)


def test_slider_without_command_falls_onto_the_pad_and_rests_at_k_e_depth_equal_m_g():
    p = plant({"robot_description": SLIDER_URDF, "tip_link": "tool0"})
    f_min = math.inf
    for s in run(p, lambda _: np.zeros(1), 2.0):
        f_min = min(f_min, float(s.contact_force()[2]))
    f, depth = p.contact_force(), p.contact_depth()
    assert f_min >= 0.0
    assert abs(p.state[1]) < 1e-6
    assert f[2] == pytest.approx(9.81, rel=1e-6)          # m g
    assert f[2] == pytest.approx(5000.0 * depth, rel=0.01)


def test_slider_rests_on_a_sphere_touched_at_its_initial_position():
    p = plant({"robot_description": SLIDER_URDF}, surface="sphere", surface_radius=0.05)
    assert p.contact_depth() == pytest.approx(0.0, abs=1e-15)
    list(run(p, lambda _: np.zeros(1), 2.0))
    assert p.contact_force() == pytest.approx([0.0, 0.0, 9.81], rel=1e-6)
    assert p.contact_depth() == pytest.approx(9.81 / 5000.0, rel=1e-6)


def test_contact_law_pushes_along_the_normal_and_never_pulls():
    sphere = contact3d.packed(contact3d.SPHERE, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.1, 1000.0, 10.0)
    r = np.array([0.06, 0.0, 0.07])
    f, depth = contact3d.contact_force(sphere, r, np.zeros(3))
    assert depth == pytest.approx(0.1 - np.linalg.norm(r))
    assert f == pytest.approx(1000.0 * depth * r / np.linalg.norm(r))
    f, _ = contact3d.contact_force(sphere, r, 10.0 * r)           # leaving fast: no pull
    assert np.all(f == 0.0)
    plane = contact3d.packed(contact3d.PLANE, (0.0, 0.0, 1.0), (0.0, 0.0, 2.0), 0.0, 1000.0, 0.0,
                             coulomb=1.0, viscous=3.0)
    f, depth = contact3d.contact_force(plane, [0.0, 0.0, 1.01], [1.0, 0.0, 0.0])
    assert depth == pytest.approx(-0.01) and np.all(f == 0.0)     # no friction off contact
    none = contact3d.packed(contact3d.NONE)
    assert contact3d.contact_force(none, [0.0, 0.0, -5.0], [0.0, 0.0, 0.0])[1] == -math.inf


def test_measurement_noise_is_seeded_and_leaves_the_truth_alone():
    noisy = {"position_noise_std": 1e-3, "velocity_noise_std": 1e-2, "force_noise_std": 0.5}
    a, b = plant(TWO_LINK, **noisy, noise_seed=7), plant(TWO_LINK, **noisy, noise_seed=7)
    ma, mb = a.measurement(), b.measurement()
    assert np.all(ma.position == mb.position) and np.all(ma.force == mb.force)
    assert np.all(ma.position != a.state[:2]) and np.all(ma.force != 0.0)
    assert np.all(a.contact_force() == 0.0) and a.contact_force_magnitude() == 0.0
    assert a.true_velocity() == [0.0, 0.0]


# -- free flight, friction ----------------------------------------------------------------------
@needs_erd
def test_kinetic_energy_is_conserved_in_free_flight():
    """UR5 (no <dynamics>), no gravity, no surface: T = 1/2 q'^T M q' stays constant; RK4 at
    1 kHz keeps it to 1e-10 relative over 1 s (measured: 3e-14)."""
    p = plant(UR5, surface="none", gravity=[0.0, 0.0, 0.0],
              initial_joint_positions=[0.1, -1.0, 1.2, -0.5, 0.7, 0.3])
    p.reset_state(p.state[:6], np.array([1.0, -0.8, 0.6, 1.2, -1.0, 1.5]))
    T0 = p.kinetic_energy()
    drift = max(abs(s.kinetic_energy() - T0) for s in run(p, lambda _: np.zeros(6), 1.0))
    assert T0 > 0.1 and drift / T0 < 1e-10
    assert np.max(np.abs(p.state[6:])) > 0.1                # it did move


@needs_erd
def test_friction_opposes_the_tangential_velocity_of_the_tip():
    mu, c_v, eps, K = 0.5, 5.0, 1e-3, 5000.0
    q0 = np.array(PANDA_HOME)
    r0 = plant(PANDA, surface="none").tip_position(q0)      # the plane 2 mm above the tip
    p = plant(PANDA, surface_point=list(r0 + [0.0, 0.0, 0.002]), friction_coulomb=mu,
              friction_viscous=c_v, friction_velocity_epsilon=eps, substeps=4)
    Jv = p.tip_jacobian(q0)
    v_tip = np.array([0.05, 0.02, 0.0])
    p.reset_state(q0, np.linalg.pinv(Jv) @ v_tip)
    f = p.contact_force()
    f_n = K * 0.002                                          # no normal velocity
    assert f[2] == pytest.approx(f_n, rel=1e-9)
    expected = -(mu * f_n / math.sqrt(v_tip @ v_tip + eps**2) + c_v) * v_tip
    assert f[:2] == pytest.approx(expected[:2], rel=1e-9)
    # and on the way: pressing down while sliding, friction never pushes along the motion
    push = Jv.T @ np.array([0.0, 0.0, -10.0])
    works = []
    for s in run(p, lambda s: s.gravity(s.state[:7]) + push, 0.2):
        v = s.tip_jacobian(s.state[:7]) @ s.state[7:]
        f = s.contact_force()
        works.append(f[:2] @ v[:2])
    assert max(works) <= 0.0 and min(works) < 0.0


# -- joints, commands ---------------------------------------------------------------------------
@needs_erd
def test_locked_finger_joints_are_published_after_the_chain():
    p = plant(PANDA)
    arm = tuple(f"panda_joint{i}" for i in range(1, 8))
    assert p.joint_names == (*arm, "panda_finger_joint1", "panda_finger_joint2")
    assert p.command_joint_names == arm and p.command_joints == arm
    assert p.wrench_frame == "panda_link0"
    p.step(np.arange(7.0), PERIOD)
    m = p.measurement()
    assert m.position.shape == m.velocity.shape == m.effort.shape == (9,)
    assert np.all(m.position[7:] == 0.0) and np.all(m.velocity[7:] == 0.0)
    assert np.all(m.effort == [*range(7), 0.0, 0.0])
    limits = p.joint_limits()
    assert limits.effort.tolist() == [87.0] * 4 + [12.0] * 3
    assert p.safe_stop_command().shape == (7,)


def test_a_refused_command_keeps_the_last_good_one():
    p = plant(TWO_LINK)
    p.step(np.array([0.3, -0.2]), PERIOD)
    for bad in (np.array([1.0]), np.array([np.nan, 0.0]), np.array([[1.0, 2.0]])):
        p.step(bad, PERIOD)
        assert np.all(p.measurement().effort == [0.3, -0.2])


def test_automatic_substeps_keep_h_omega_c_at_most_one_half():
    soft = plant(TWO_LINK, stiffness=150.0)
    stiff = plant({"robot_description": SLIDER_URDF}, stiffness=5.0e6, damping=0.0)
    assert soft.substeps_for(PERIOD) == 1
    omega = math.sqrt(5.0e6 / 1.0)                           # slider: m_n = 1 kg
    assert stiff.step_rate == pytest.approx(omega)
    assert stiff.substeps_for(PERIOD) == math.ceil(PERIOD * omega / 0.5)
    assert plant(TWO_LINK, substeps=3).substeps_for(PERIOD) == 3


# -- the planar chapter 3 plant through its URDF ------------------------------------------------
def _torque(t: float, G0: np.ndarray, J0: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """A fixed torque sequence: gravity at q0, a push into the plane then away from it
    (30 sin(15 t) N along -n), and a wobble."""
    return G0 - J0.T @ (30.0 * math.sin(15.0 * t) * normal) + 0.5 * np.array(
        [math.sin(20.0 * t), math.cos(13.0 * t)])


@pytest.mark.parametrize("joint_type", ["revolute", "continuous"])
def test_two_link_urdf_matches_the_chapter_3_plant_to_1e_8_rad(joint_type):
    reference = make_plant("compliant_plane")
    q0 = reference.measurement().position
    robot = dict(TWO_LINK)
    if joint_type == "continuous":
        from cr_control.models.urdf import resolve_urdf_file

        text = resolve_urdf_file("two_link_arm.urdf").read_text()
        robot = {**robot, "urdf_file": "", "robot_description": text.replace(
            'type="revolute"', 'type="continuous"')}
    p = plant(robot, initial_joint_positions=list(q0), surface="plane",
              surface_point=[-0.05, 0.2, 0.0], surface_normal=[1.0, -1.0, 0.0],
              stiffness=150.0, damping=0.0, substeps=1)
    assert p.chain.kinds == (joint_type, joint_type)
    normal = np.array([1.0, -1.0]) / math.sqrt(2.0)
    G0, J0 = p.gravity(q0), p.tip_jacobian(q0)[:2]
    error, pressed, separated = 0.0, 0, 0
    for k in range(500):
        tau = _torque(k * PERIOD, G0, J0, normal)
        reference.step(tau, PERIOD)
        p.step(tau, PERIOD)
        error = max(error, float(np.max(np.abs(p.state[:2] - reference.state[:2]))))
        pressed += p.contact_depth() > 0.0
        separated += p.contact_depth() < 0.0
        assert p.contact_force()[:2] == pytest.approx(reference.contact_force(), abs=1e-8)
    assert error < 1e-8
    assert pressed > 50 and separated > 50                   # both regimes were visited
