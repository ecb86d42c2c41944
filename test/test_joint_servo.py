"""The position- and velocity-interface plant ``joint_servo``: a URDF arm behind its joint
servos, on the URDF plant's table.

Checked: a ramp tracked with the servo's velocity feed-forward; a step answered as the
stated PD servo (omega_s, zeta_s); pressed 2 mm below the table it presses with the
table and the servo's stiffness in series; a 1 rad jump, a command beyond the position limits,
a velocity beyond the limits: never a jump (the reference's velocity, acceleration and jerk
inside the limits, stopped at the position limit without overshoot); a non-finite command
refused; the safe stop decelerating at the limits on one factor and holding; the supervisor
reading the velocity field of a velocity plant and the node's command limits for it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from plant_harness import Log
from robot_data import needs_erd

from cr_control.models.joint_rate_limit import limiter_state, packed_limits, rate_limit
from cr_sim.plant_setup import NODE_PARAMETERS, command_limiter, initial_command
from cr_sim.plants.joint_servo import JointServoSurface
from cr_sim.plants.registry import make_plant
from cr_sim.supervisor import PlantSupervisor

pytestmark = needs_erd

PERIOD = 0.002
UR5_HOME = [0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0]
UR5 = {
    "urdf_file": "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf",
    "base_link": "base_link", "tip_link": "tool0", "initial_joint_positions": UR5_HOME,
    "stiffness": 5000.0, "damping": 20.0, "acceleration_limit": [5.0],
}
DEFAULTS = {p.name: p.default for p in NODE_PARAMETERS}


def servo(**overrides) -> JointServoSurface:
    return make_plant("joint_servo", {**UR5, **overrides})


def run(plant: JointServoSurface, commands) -> np.ndarray:
    """Step ``plant`` through ``commands`` (one per period); the references (k x 2n)."""
    out = []
    for c in commands:
        plant.step(np.asarray(c, dtype=float), PERIOD)
        out.append(plant.reference)
    return np.array(out)


def test_a_ramp_is_tracked_and_a_step_answered_as_the_stated_servo():
    plant = servo()
    q0 = np.array(UR5_HOME)
    ramp = [q0 + np.array([0.2, 0, 0, 0, 0, 0]) * k * PERIOD for k in range(1, 751)]
    run(plant, ramp)
    # velocity feed-forward: a ramp at 0.2 rad/s is followed without lag
    assert abs(plant.measurement().position[0] - ramp[-1][0]) < 1e-5
    # a 1 mrad step on the wrist: the PD servo (omega_s, zeta_s) on the reference segment,
    # its torque held for each servo substep (computed torque: the joint alone), as a scalar
    plant = servo(surface="none", acceleration_limit=[])
    target = q0 + np.array([0, 0, 0, 0, 0, 1e-3])
    w, z = plant.omega, plant.zeta
    k_sub = plant.substeps_for(PERIOD)
    h = PERIOD / k_sub
    q = v = 0.0
    errors = []
    for k in range(100):
        speed = 1e-3 / PERIOD if k == 0 else 0.0
        for i in range(k_sub):
            r = min(1e-3, speed * i * h) if k == 0 else 1e-3
            a = w * w * (r - q) + 2 * z * w * (speed - v)
            q, v = q + v * h + a * h * h / 2, v + a * h
        plant.step(target, PERIOD)
        errors.append(plant.measurement().position[5] - q0[5] - q)
    assert max(abs(e) for e in errors) < 0.02e-3          # within 2 % of the step throughout
    assert np.max(plant.measurement().position[5] - q0[5]) == pytest.approx(1e-3, abs=2e-5)


def test_pressed_below_the_table_it_presses_with_the_servo_and_table_in_series():
    plant = servo()
    q0 = np.array(UR5_HOME)
    J = plant.tip_jacobian(q0)
    dq = np.linalg.pinv(J) @ np.array([0.0, 0.0, -0.002])
    run(plant, [q0 + dq * min(1.0, k / 250) for k in range(1000)])
    M = plant.mass_matrix(q0)
    apparent = np.linalg.inv(J @ np.linalg.solve(M, J.T))[2, 2]
    series = 1.0 / (1.0 / 5000.0 + 1.0 / (apparent * plant.omega ** 2))
    assert plant.contact_force()[2] == pytest.approx(series * 0.002, rel=0.02)
    assert plant.measurement().effort[:6] == pytest.approx(plant.arm.applied_effort)


def test_commands_outside_the_limits_never_jump():
    plant = servo(jerk_limit=[2000.0])
    q0 = np.array(UR5_HOME)
    jump = q0 + np.array([1.0, 0, 0, 0, 0, 0])
    refs = run(plant, [jump] * 400)
    p, v = refs[:, 0], refs[:, 6]
    a = np.diff(np.concatenate([[0.0], v])) / PERIOD
    assert np.max(np.abs(v)) <= plant.joint_limits().velocity[0] + 1e-9     # the URDF's
    assert np.max(np.abs(a)) <= 5.0 + 1e-9                         # acceleration limit
    assert np.max(np.abs(np.diff(a))) / PERIOD <= 2000.0 + 1e-6    # jerk limit
    assert plant.commands_clipped > 0
    # as a driver's limiter, it does not plan: the far target is passed and come back to
    vmax = plant.joint_limits().velocity[0]
    assert 1.0 < np.max(p) <= 1.0 + vmax ** 2 / (2 * 5.0) + vmax * PERIOD
    # a command far beyond the position limit stops at the limit, without overshoot
    plant = servo(initial_joint_positions=[6.0, *UR5_HOME[1:]])
    beyond = np.array([100.0, *UR5_HOME[1:]])
    refs = run(plant, [beyond] * 1500)
    upper = plant.joint_limits().upper[0]
    assert np.max(refs[:, 0]) <= upper and refs[-1, 0] == pytest.approx(upper)
    assert abs(refs[-1, 6]) < 1e-9
    # decelerating at the limit all the way (the last step onto the limit off the stream's
    # lattice: within 1 %)
    assert np.max(np.abs(np.diff(refs[:, 6]))) / PERIOD <= 5.0 * 1.01
    # a non-finite command is refused: the last one stays
    held = plant.held.copy()
    plant.step(np.array([math.nan] * 6), PERIOD)
    assert np.array_equal(plant.held, held) and plant.state_is_finite()


def test_the_velocity_interface_follows_velocities_inside_the_limits():
    plant = servo(command_interface="velocity")
    assert np.array_equal(plant.held, np.zeros(6))
    fast = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 10.0])          # beyond pi rad/s
    slow = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    refs = run(plant, [fast] * 500 + [slow] * 500)
    assert np.max(np.abs(refs[:, 11])) <= plant.joint_limits().velocity[5] + 1e-9
    assert np.max(np.abs(np.diff(refs[:, 6:], axis=0))) / PERIOD <= 5.0 + 1e-6
    assert plant.measurement().velocity[0] == pytest.approx(0.3, abs=1e-4)
    assert plant.measurement().velocity[5] == pytest.approx(0.0, abs=1e-4)


def test_the_safe_stop_decelerates_at_the_limits_and_holds():
    plant = servo(surface="none", command_interface="velocity")
    run(plant, [np.array([0.5, 0.25, 0.0, 0.0, 0.0, 0.0])] * 300)
    sup = PlantSupervisor(plant, PERIOD, command_limiter(plant, DEFAULTS, PERIOD),
                          command=initial_command(plant), logger=lambda: Log())
    sup.engage(1, "test")
    refs = []
    for _ in range(300):
        sup.step()
        refs.append(plant.reference)
    refs = np.array(refs)
    v = refs[:, 6:]
    decel = -np.diff(v, axis=0) / PERIOD
    assert np.max(decel[:, 0]) == pytest.approx(5.0, rel=1e-6)      # the joint with most to lose
    assert np.max(decel) <= 5.0 + 1e-6 and np.min(decel) >= -1e-9     # never speeds up
    ratio = v[:45, 1] / v[:45, 0]            # 0.1 s to rest
    assert np.allclose(ratio, 0.5)                                    # one factor: on its path
    assert np.all(v[-100:] == 0.0) and np.ptp(refs[-100:, :6], axis=0).max() == 0.0
    assert np.max(np.abs(plant.measurement().velocity)) < 1e-3


def test_the_supervisor_reads_a_velocity_plants_velocities():
    plant = servo(command_interface="velocity")
    sup = PlantSupervisor(plant, PERIOD, command_limiter(plant, DEFAULTS, PERIOD),
                          command=initial_command(plant), logger=lambda: Log(),
                          scenario="joint_servo")
    names = tuple(plant.command_joints)

    class Msg:
        def __init__(self, velocity=(), effort=()):
            self.name, self.position, self.frame_id = names, (), ""
            self.velocity, self.effort = tuple(velocity), tuple(effort)
    assert sup.accept(Msg(velocity=[0.1] + [0.0] * 5), b"A", 0.0)
    assert sup.accept(Msg(velocity=[1.0] + [0.0] * 5), b"A", 0.0)
    assert sup.command[0] == pytest.approx(0.1 + 5.0 * PERIOD)   # the node's rate: acceleration
    assert not sup.accept(Msg(effort=[0.0] * 6), b"A", 0.0)
    limiter = command_limiter(plant, DEFAULTS, PERIOD)
    assert limiter.upper == pytest.approx(plant.joint_limits().velocity.tolist())


def test_the_rate_limiter_keeps_a_jerk_limited_stream_smooth():
    n = 2
    limits = packed_limits([-1, -1], [1, 1], [2.0, 2.0], [10.0, 10.0], [1000.0, math.inf])
    state = limiter_state(np.zeros(n))
    out = np.zeros(n)
    positions = []
    for _ in range(1000):
        rate_limit(state, limits, np.array([5.0, -5.0]), False, 1e-3, out)
        positions.append(out.copy())
    p = np.array(positions)
    v = np.diff(np.vstack([np.zeros(n), p]), axis=0) / 1e-3
    a = np.diff(np.vstack([np.zeros(n), v]), axis=0) / 1e-3
    assert np.max(np.abs(v)) <= 2.0 + 1e-9 and np.max(np.abs(a)) <= 10.0 + 1e-6
    assert np.max(np.abs(np.diff(a[:, 0]))) / 1e-3 <= 1000.0 + 1e-3
    assert p[-1] == pytest.approx([1.0, -1.0]) and np.all(np.abs(p) <= 1.0)
