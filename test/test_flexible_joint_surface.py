"""Chapter 6 plant: the flexible-joint 2-link arm on the rigid surface x - y + 0.35 = 0.

Measured (RK4, 1 kHz, substeps = 1): constraint drift max |Phi| ~ 2e-11 m over 20 s under
tau_m0 + 0.5 sin(3t) (K_s = 10, J_m = 0.5) and ~8e-12 m (K_s = 300, J_m = 1); energy drift
after a kick along the surface ~3e-10 J (K_s = 10) and ~7e-9 J (K_s = 300) over 5 s; the
q_m'' sensor matches central differences of q_m' to ~2e-6 rad/s^2 (constant command).
"""

import math

import numpy as np
import pinocchio as pin
import pytest

from cr_control.core.parameters import ParameterError, resolve
from cr_sim.models.constrained_dynamics import ConstrainedModel, PointOnPlane
from cr_sim.plants.flexible_joint_surface import (
    PARAMETERS,
    FlexibleJointSurface,
    buffer_size,
    flexible_joint_derivative,
)
from cr_sim.plants.registry import make_plant

DT = 1e-3
STIFF = {"joint_stiffness": [300.0, 300.0], "motor_inertia": [1.0, 1.0]}
RNG = np.random.default_rng(6)


def plant(overrides=None) -> FlexibleJointSurface:
    return FlexibleJointSurface(resolve(PARAMETERS, overrides))


def reference_model(p: FlexibleJointSurface) -> ConstrainedModel:
    """Pinocchio's KKT route: tool0 on the world plane n . p + 0.35/sqrt(2) = 0."""
    plane = PointOnPlane("tool0", "universe", np.array([1.0, -1.0, 0.0]), -0.35 / math.sqrt(2))
    return ConstrainedModel(p.model, [plane], 20.0, 20.0)


def reference_derivative(cm, p, x, tau_m):
    """x' of [q_l, q_l', q_m, q_m'] by Pinocchio (links) and (6.2) (motors); and lambda."""
    ql, vl, qm, vm = x[:2], x[2:4], x[4:6], x[6:]
    tau_l = p.stiffness * (qm - ql)
    a, lam = cm.accelerations(ql, vl, tau_l)
    return np.concatenate([vl, a, vm, (tau_m - tau_l) / p.motor_inertia]), lam[0]


def test_defaults_start_on_the_surface_at_rest_and_stay_there():
    p = plant()
    x0 = p.state
    q_l0 = x0[:2]
    assert q_l0[0] == 2.85 and abs(q_l0[1] + 2.1202) < 1e-3 and math.sin(q_l0[1]) < 0
    r = p.tool_position(q_l0)
    assert abs(r[0] - r[1] + 0.35) < 1e-12 and abs(p.constraint(q_l0)) < 1e-12
    assert abs(p.constraint_error[0]) < 1e-12 and p.constraint_error[1] == 0.0
    assert p.constraint_force == pytest.approx(2.0, abs=1e-12)
    # static motor torque tau_m0 = G - J_Phi^T lambda0 = K_s (q_m0 - q_l0) (documented numbers)
    tau0 = p.held
    assert np.allclose(tau0, [0.00186136, 0.70863366], atol=1e-8)
    assert np.allclose(tau0, p.gravity(q_l0) - 2.0 * p.constraint_jacobian(q_l0), atol=1e-15)
    assert np.allclose(p.stiffness * (x0[4:6] - q_l0), tau0, atol=1e-14)
    assert np.allclose(x0[4:6], [2.850186, -2.049345], atol=1e-6)
    assert not x0[2:4].any() and not x0[6:].any()
    assert np.abs(p.motor_acceleration).max() < 1e-12
    m = p.measurement()
    assert np.allclose(m.position, x0[[0, 1, 4, 5]]) and np.allclose(m.effort, [*tau0, *tau0])
    assert np.allclose(m.force, [math.sqrt(2), -math.sqrt(2), 0.0])
    for _ in range(2000):
        p.step(tau0, DT)
    assert p.time == pytest.approx(2.0)
    assert np.abs(p.state - x0).max() < 1e-9
    assert abs(p.constraint_force - 2.0) < 1e-6
    # safe stop at rest: the brake command is the spring torque, i.e. tau_m0
    p.begin_safe_stop()
    assert np.allclose(p.safe_stop_command(), tau0, atol=1e-8)


def test_kernel_matches_pinocchio_kkt_and_the_motor_equation():
    """Second route: the compiled derivative against Pinocchio's constrained forward dynamics
    with tau = K_s (q_m - q_l), and (6.2); and 5 RK4 steps against RK4 on that reference."""
    for overrides in (None, STIFF):
        p = plant(overrides)
        cm = reference_model(p)
        work, buf = np.empty(p._work.size), np.empty(buffer_size(2))
        x0 = p.state
        for _ in range(5):
            x = x0 + np.concatenate([RNG.normal(0, 0.05, 2), RNG.normal(0, 1, 2),
                                     RNG.normal(0, 0.05, 2), RNG.normal(0, 1, 2)])
            tau_m = p.held + RNG.normal(0, 2, 2)
            out, lam = np.empty(8), np.empty(1)
            phi, phi_dot = flexible_joint_derivative(p.mech, p.flex, x, tau_m, work, buf[:2],
                                                     out, lam)
            ref, lam_ref = reference_derivative(cm, p, x, tau_m)
            assert np.abs(out - ref).max() < 1e-9 and abs(lam[0] - lam_ref) < 1e-9
            phi_ref, J, _ = cm.constraint(x[:2], x[2:4])
            assert abs(phi - phi_ref[0]) < 1e-14 and abs(phi_dot - J[0] @ x[2:4]) < 1e-14
            assert abs(phi - p.constraint(x[:2])) < 1e-14
        tau_m = p.held + np.array([0.4, -0.3])
        x = p.state
        for _ in range(5):
            k1, _ = reference_derivative(cm, p, x, tau_m)
            k2, _ = reference_derivative(cm, p, x + 0.5 * DT * k1, tau_m)
            k3, _ = reference_derivative(cm, p, x + 0.5 * DT * k2, tau_m)
            k4, _ = reference_derivative(cm, p, x + DT * k3, tau_m)
            x = x + DT / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            p.step(tau_m, DT)
        assert np.abs(p.state - x).max() < 1e-12
        assert p.constraint_force == pytest.approx(reference_derivative(cm, p, x, tau_m)[1],
                                                   abs=1e-9)


@pytest.mark.parametrize("overrides", [None, STIFF], ids=["Ks10_Jm0.5", "Ks300_Jm1"])
def test_constraint_drift_under_a_moving_command(overrides):
    p = plant(overrides)
    tau0 = p.held
    drift, lam = 0.0, []
    for k in range(20000):
        p.step(tau0 + 0.5 * math.sin(3.0 * k * DT), DT)
        drift = max(drift, abs(p.constraint_error[0]))
        lam.append(p.constraint_force)
    lam = np.array(lam)
    print(f"\n{overrides}: max |Phi| {drift:.2e} m, lambda [{lam.min():.2f}, {lam.max():.2f}] N")
    assert drift < 1e-6 and np.all(np.isfinite(lam)) and np.all(np.isfinite(p.state))
    assert abs(p.constraint(p.state[:2])) < 1e-6
    assert np.ptp(lam) > 1.0   # the command did move the arm along the surface


def total_energy(p, q_m0, tau0):
    """Links (kinetic + potential), motors (kinetic), springs, minus the work of tau0."""
    x = p.state
    ql, vl, qm, vm = x[:2], x[2:4], x[4:6], x[6:]
    theta = qm - ql
    return (pin.computeKineticEnergy(p.model, p.data, ql, vl)
            + pin.computePotentialEnergy(p.model, p.data, ql)
            + 0.5 * vm @ (p.motor_inertia * vm) + 0.5 * theta @ (p.stiffness * theta)
            - tau0 @ (qm - q_m0))


@pytest.mark.parametrize("overrides, bound", [(None, 1e-8), (STIFF, 5e-8)],
                         ids=["Ks10_Jm0.5", "Ks300_Jm1"])
def test_energy_is_conserved_with_the_static_command(overrides, bound):
    """The frictionless constraint does no work: after a kick (links 1 rad/s along the
    surface, motors [0.5, -0.8] rad/s) the total energy stays put over 5 s (measured
    ~3e-10 J for K_s = 10, ~7e-9 J for K_s = 300)."""
    p = plant(overrides)
    tau0, x0 = p.held, p.state
    J = p.constraint_jacobian(x0[:2])
    tangent = np.array([-J[1], J[0]]) / np.hypot(*J)
    p.reset_state(x0[[0, 1, 4, 5]], np.concatenate([tangent, [0.5, -0.8]]))
    assert abs(p.constraint_error[1]) < 1e-15
    e0 = total_energy(p, x0[4:6], tau0)
    err = 0.0
    for k in range(5000):
        p.step(tau0, DT)
        if k % 10 == 9:
            err = max(err, abs(total_energy(p, x0[4:6], tau0) - e0))
    print(f"\n{overrides}: E0 {e0:.4f} J, max |E - E0| {err:.2e} J over 5 s")
    assert np.abs(p.state[:2] - x0[:2]).max() > 0.5       # it did move a lot
    assert err < bound


def test_motor_acceleration_sensor():
    """q_m'' (assumption 6.3) equals central differences of q_m' and (tau_m - K_s theta)/J_m."""
    p = plant()
    tau = p.held + np.array([0.3, -0.2])
    vm, acc = [], []
    for _ in range(500):
        p.step(tau, DT)
        x = p.state
        vm.append(x[6:])
        acc.append(p.motor_acceleration)
        assert np.allclose(acc[-1], (tau - p.stiffness * (x[4:6] - x[:2])) / p.motor_inertia,
                           atol=1e-13)
        assert np.allclose(p.sensors()[3:], acc[-1], atol=0)
    vm, acc = np.array(vm), np.array(acc)
    fd = (vm[2:] - vm[:-2]) / (2 * DT)
    err = np.abs(fd - acc[1:-1]).max()
    print(f"\nq_m'' sensor vs central differences: {err:.1e} (|q_m''| up to {np.abs(acc).max():.2f})")
    assert err < 1e-5
    assert p.sensor_fields == ("lambda", "phi", "phi_dot", "joint1_motor_acceleration",
                               "joint2_motor_acceleration")
    assert p.sensors()[0] == p.constraint_force and p.sensors()[1:3] == list(p.constraint_error)


def test_a_constrained_plant_must_sense_lambda_and_the_drift_first():
    from cr_sim.plants.base import ConstrainedPlant

    with pytest.raises(TypeError, match="begin with lambda, phi, phi_dot"):
        type("Unsensed", (ConstrainedPlant,), {"sensor_fields": ("phi", "lambda", "phi_dot")})


def test_refused_commands_keep_the_held_one():
    a, b = plant(), plant()
    tau = a.held + np.array([0.2, 0.1])
    a.step(tau, DT)
    b.step(tau, DT)
    for bad in (np.array([np.nan, 0.0]), np.array([0.0, np.inf]), np.array([1.0, 2.0, 3.0]),
                np.array([1.0]), np.zeros((1, 2)), np.zeros(0)):
        a.step(bad, DT)
        b.step(tau, DT)
        assert np.array_equal(a.state, b.state) and np.array_equal(a.held, tau)
    assert np.all(np.isfinite(a.state)) and math.isfinite(a.constraint_force)
    assert not a.accept(np.array([np.nan, 0.0])) and a.accept(np.array([0.0, 1.0]))
    assert not a.accept(np.zeros(4))


@pytest.mark.parametrize("overrides, words", [
    ({"joint_stiffness": [0.0, 10.0]}, "joint_stiffness"),
    ({"joint_stiffness": [10.0, -1.0]}, "joint_stiffness"),
    ({"motor_inertia": [0.0, 0.5]}, "motor_inertia"),
    ({"initial_link_position": [-0.785, -2.0]}, "no point"),
    ({"surface_normal": [0.0, 0.0]}, "surface_normal"),
    ({"substeps": 0}, "substeps"),
])
def test_invalid_parameters_raise_one_line_errors(overrides, words):
    with pytest.raises(ParameterError) as info:
        make_plant("flexible_joint_surface", overrides)
    assert words in str(info.value) and "\n" not in str(info.value)
    # also past resolve(): the plant checks its values itself
    if "joint_stiffness" in overrides:
        values = resolve(PARAMETERS)
        values["joint_stiffness"] = np.array(overrides["joint_stiffness"])
        with pytest.raises(ParameterError, match="joint_stiffness"):
            FlexibleJointSurface(values)


def test_registry_joints_limits_and_brakes():
    p = make_plant("flexible_joint_surface")
    assert isinstance(p, FlexibleJointSurface)
    assert p.joint_names == ("joint1", "joint2", "joint1_motor", "joint2_motor")
    assert p.command_joints == ("joint1_motor", "joint2_motor")
    limits = p.joint_limits()
    assert np.array_equal(limits.effort, [100.0, 100.0])
    assert np.all(np.isinf(limits.velocity)) and np.all(np.isinf(limits.upper))
    assert np.all(np.isinf(limits.lower)) and np.all(limits.lower < 0)
    m = p.measurement()
    assert m.position.shape == m.velocity.shape == m.effort.shape == (4,) and m.force.shape == (3,)
    # the brakes: spring torque compensated, motors braked at w_b scaled by their inertia
    # J_m, toward where they come to rest (q_m + q_m'/w_b when braking began), held there
    tau0 = p.held
    p.step(tau0 + np.array([1.0, -1.0]), DT)
    p.begin_safe_stop()
    x = p.state
    w, J_m = p.brake_frequency, p.motor_inertia
    stop = x[4:6] + x[6:] / w
    for _ in range(3):
        p.step(p.safe_stop_command(), DT)
    x1 = p.state
    expect = (p.stiffness * (x1[4:6] - x1[:2])
              - J_m * (2.0 * w * x1[6:] + w * w * (x1[4:6] - stop)))
    assert p.safe_stop_command().shape == (2,)
    assert np.allclose(p.safe_stop_command(), expect, atol=1e-12)
    assert np.allclose(p._brake_hold, stop, rtol=0.0, atol=1e-15)
    # noise reaches the measurement, not the state
    noisy = plant({"position_noise_std": 1e-3, "force_noise_std": 0.1})
    assert not np.array_equal(noisy.measurement().position, noisy.state[[0, 1, 4, 5]])
