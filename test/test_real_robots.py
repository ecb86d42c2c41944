"""Robots as their drivers are: gravity left to the robot, the start check, the brake that works
through a forward_command_controller, the wrench conventions, the guarded start.

Measured here (offline, cr_control.experiments.wiping; panda and ur5 profiles, every scheme):
a controller whose gravity setting does not match the robot is stopped 16-106 ms after its
first state, every joint below half its velocity limit (largest 0.37-0.41 of it); its line
names robot_compensates_gravity and which way to set it when the tip moves along gravity.
"""

import math

import numpy as np
import pytest

from cr_control import offline, robots
from cr_control.experiments.wiping import Case, run_case
from cr_control.schemes.blocks import safe_stop
from cr_control.schemes.registry import make_controller
from cr_sim.plants.registry import make_plant

PROFILES = ("panda", "ur5")


def robot_plant(name: str, **overrides):
    values = {k: v for k, v in robots.plant_values(robots.robot(name)).items() if k != "scenario"}
    return make_plant("urdf_surface", {**values, **overrides})


@pytest.mark.parametrize("name", PROFILES)
def test_a_robot_that_compensates_gravity_holds_still_on_a_zero_command(name):
    """libfranka and ur_robot_driver add g(q) to every command: zero torque holds the arm; the
    same arm without that falls. The plant's brake and initial hold leave G out there."""
    period = 1.0 / robots.robot(name).rate_hz
    speeds = {}
    for compensates in (True, False):
        plant = robot_plant(name, surface="none", robot_compensates_gravity=compensates)
        n = len(plant.command_joints)
        for _ in range(200):
            plant.step(np.zeros(n), period)
        speeds[compensates] = float(np.max(np.abs(plant.true_velocity())))
        G = plant.gravity_torque(plant.measurement().position)
        assert np.allclose(G, 0.0) == compensates
    print(f"\n{name}: largest joint speed after {200 * period:g} s of zero torque: "
          f"{speeds[True]:.2e} rad/s (robot compensates), {speeds[False]:.3f} (it does not)")
    assert speeds[True] < 1e-6
    assert speeds[False] > 0.1


def test_the_controller_leaves_gravity_out_where_the_robot_adds_it():
    """The start-up hold's command is G(q) of the model, zero on a gravity-compensating robot;
    the wrist sensor's compensation still takes the tool's weight off (real gravity)."""
    r = robots.robot("panda_ft")
    commands = {}
    for compensates in (True, False):
        c = make_controller("impedance", {**robots.controller_values(r, "impedance"),
                                          "robot_compensates_gravity": compensates})
        plant = robot_plant("panda_ft", robot_compensates_gravity=compensates)
        run = offline.run(c, plant, 0.01, 1e-3)
        commands[compensates] = run.command[0]
        # the tool's weight is compensated either way: the law sees ~0 N in the air at start
        assert np.abs(run.column("f_z")[:5]).max() < 1.0
    assert np.abs(commands[True]).max() < 1e-9
    assert np.abs(commands[False]).max() > 5.0          # the Panda's G(q) at home: tens of N m


def mismatch_case(scheme: str, robot: str, robot_adds: bool, clearance: float) -> Case:
    """A controller whose gravity setting is the opposite of the robot's."""
    class Mismatch(Case):
        def overrides(self):
            c, p = super().overrides()
            c["robot_compensates_gravity"] = not robot_adds
            p["robot_compensates_gravity"] = robot_adds
            return c, p
    return Mismatch(scheme, robot, clearance=clearance, duration=1.5)


@pytest.mark.parametrize("scheme", robots.TASK_SPACE_SCHEMES)
@pytest.mark.parametrize("robot", PROFILES)
@pytest.mark.parametrize("robot_adds", [True, False], ids=["robot-adds", "robot-does-not"])
def test_a_gravity_mismatch_is_caught_in_the_first_second(scheme, robot, robot_adds):
    """Both directions: the robot compensates and the controller adds G too (the arm rises),
    or neither does (it falls from 5 cm above the table): one line naming the parameter,
    braking before any joint reaches half its velocity limit."""
    values, errors = run_case(mismatch_case(scheme, robot, robot_adds, 0.05))
    print(f"\n{scheme} on {robot}: stopped at {values['gave_up_at_s']:.3f} s, joints at most "
          f"{values['joint_speed_max_fraction']:.2f} of their limit; {errors[0]}")
    assert values["gave_up"] == 1.0 and values["gave_up_at_s"] < 1.0
    assert values["joint_speed_max_fraction"] < 0.5
    assert len(errors) == 1 and "robot_compensates_gravity" in errors[0]
    expected = "robot_compensates_gravity: true" if robot_adds else "robot_compensates_gravity: false"
    assert expected in errors[0]


def test_a_matching_controller_passes_the_start_check():
    """Every scheme on both profiles with the right setting never gives up (the wiping runs of
    test_robots.py cover the rest)."""
    for scheme in robots.TASK_SPACE_SCHEMES:
        for robot in PROFILES:
            values, errors = run_case(Case(scheme, robot, clearance=0.05, duration=2.5))
            assert values["gave_up"] == 0.0 and not errors, (scheme, robot, errors)


def test_a_force_target_in_free_space_is_named_not_gravity():
    """A law asked 10 N at once (approach_speed 0) in free space pushes the tip down, as a
    falling arm would move: the start check names the force target first, not gravity (a
    session with the table removed and the profile's wiping force said "falling with gravity:
    set robot_compensates_gravity: false")."""
    law = make_controller("adaptive_impedance",
                          robots.controller_values(robots.robot("panda_ft"), "adaptive_impedance"))
    values = {**law.values, "approach_speed": 0.0}
    down = np.array([0.0, 0.0, -0.165])
    check = lambda values: safe_stop.start_check(      # noqa: E731
        "adaptive_impedance", 0.797, down, np.array([0.0, 0.0, -9.81]), np.zeros(7),
        [f"j{i}" for i in range(7)], np.full(7, 2.6), values)
    assert list(values["desired_force"]) == [0.0, 0.0, 10.0]
    pushed = check(values)
    assert "the force target pushes the tip through free space" in pushed.message
    assert pushed.brake_holds_gravity is False
    falling = check({**values, "desired_force": [0.0, 0.0, 0.0]})
    assert "falling with gravity" in falling.message and falling.brake_holds_gravity


def test_a_controller_that_gives_up_brakes_through_the_command_interface():
    """A controller that gives up keeps publishing a braking command: the offline loop applies
    each output as a forward_command_controller applies the last command it got, forever.
    After a mismatch stop the arm comes to rest and stays there (no drift), on a robot that
    compensates gravity and on one that does not."""
    for robot_adds in (True, False):
        case = mismatch_case("adaptive_impedance", "panda", robot_adds, 0.05)
        c, p = case.overrides()
        controller, plant = offline.build_scheme(case.scheme, c, p, case.robot)
        controller.log_error = lambda message: None
        run = offline.run(controller, plant, 3.0, 1e-3)
        assert controller.gave_up and not controller.commanding
        late = run.time >= 2.0
        speed = np.abs(run.velocity[late, :7]).max()
        drift = np.abs(run.position[-1, :7] - run.position[np.argmax(late), :7]).max()
        print(f"\nrobot adds gravity: {robot_adds}: joints at most {speed:.2e} rad/s after 2 s, "
              f"{drift:.2e} rad drift over the last second")
        assert speed < 1e-3 and drift < 1e-3


def test_a_saturated_law_brakes_instead_of_going_silent():
    """max_bad_cycles: a law stuck at its limit stops commanding and brakes (its command is the
    brake, not the law's, and is finite and inside the limits)."""
    r = robots.robot("panda")
    c = make_controller("impedance", {**robots.controller_values(r, "impedance"),
                                      "max_effort": 5.0, "start_check_time": 0.0,
                                      "robot_compensates_gravity": False})   # G(q): > 5 N m
    c.log_error = c.log_info = lambda message: None
    plant = robot_plant("panda", robot_compensates_gravity=False)
    run = offline.run(c, plant, 0.5, 1e-3)
    assert c.stops >= 1 and c.brakes and not c.commanding
    assert np.isfinite(run.command).all() and np.abs(run.command).max() <= 5.0 + 1e-12


def test_wrench_conventions():
    """Franka's estimated external wrench is the reaction (wrench_sign -1) in the base frame;
    UR's TCP sensor leaves the payload out (sensor_removes_payload): in the air at rest it
    reads its bias only, a wrist sensor the tool's weight too."""
    panda = robot_plant("panda", surface_point=[0.0, 0.0, 10.0])    # pressed hard from above
    estimated = panda.measurement().force
    assert estimated[2] < 0.0 and panda.contact_force()[2] > 0.0      # reaction: the opposite
    assert panda.wrench_frame == "panda_link0"
    tcp = robot_plant("ur5", surface="none").sensor_wrench()
    wrist = robot_plant("ur5_ft", surface="none").sensor_wrench()
    bias = np.array(robots.SENSOR["ft_bias"])
    weight = robots.SENSOR["tool_mass"] * 9.81
    assert np.allclose(tcp, bias, atol=1e-9)
    assert math.isclose(np.linalg.norm(wrist[:3] - bias[:3]), weight, rel_tol=1e-6)


@pytest.mark.parametrize("table", ["default", "stiff"])
@pytest.mark.parametrize("robot", PROFILES)
@pytest.mark.parametrize("scheme", robots.TASK_SPACE_SCHEMES)
def test_a_guarded_start_from_above_the_table(scheme, robot, table):
    """Started 5 cm above the default table and a 10x stiffer one (50 kN/m): impact at most
    1.5 x approach_speed, force peak at most 1.5 x the target, no contact lost after the first
    touch, no sideways drift over 1 mm before contact. (Before the impact damping every scheme
    bounced off the stiff table for 30-110 ms.)"""
    # the stiff table without the driver's delay (test_robots: its contact rings with it)
    plant = (("command_delay_cycles", 0),) if table == "stiff" else ()
    values, errors = run_case(Case(scheme, robot, table, clearance=0.05, duration=5.0,
                                   plant=plant))
    print(f"\n{scheme} on {robot}, {table} table: impact {values['impact_speed_m_s']:.3f} m/s, peak "
          f"{values['force_peak_N']:.2f} N, lost {values['contact_lost_s']:.3f} s, drift "
          f"{values['drift_before_contact_m'] * 1e3:.2f} mm")
    assert not errors
    assert values["impact_speed_m_s"] <= 1.5 * robots.robot(robot).approach_speed
    assert values["force_peak_N"] <= 1.5 * robots.WIPE_FORCE
    assert values["contact_lost_s"] == 0.0
    assert values["drift_before_contact_m"] < 1e-3


@pytest.mark.parametrize("scale", [0.7, 1.3])
@pytest.mark.parametrize("scheme", robots.TASK_SPACE_SCHEMES)
def test_a_wrong_model_costs_little(scheme, scale):
    """The controller's masses and inertias 30 % off the arm's (Panda): the mean force error
    stays within 0.5 N (measured 0.003-0.13 N on the Panda and UR5, both ways)."""
    values, errors = run_case(Case(scheme, "panda", model_scale=scale, duration=6.0))
    print(f"\n{scheme}, model x{scale}: force error mean {values['force_err_mean_N']:+.3f} N")
    assert not errors and abs(values["force_err_mean_N"]) <= 0.5
