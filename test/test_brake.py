"""The plant's brakes (its safe stop): stable on every joint whatever its inertia, at the
plant's rate and in lockstep.

The law (:mod:`cr_control.models.brake`, :meth:`cr_sim.plants.base.Plant.safe_stop_command`):

    tau = G(q) - M(q) (2 w_b q' + w_b^2 (q - q_stop)),   q_stop = q_b + q_b'/w_b

held for one period as every command is, bounded by the plant node's effort limits.
Before, tau = G(q) - K_d q' - K_p (q - q_stop) with K_d = 30 N m s/rad: on the Panda's
wrist joint 7 (K_d dt / M_77 ~ 5.7, beyond the explicit limit 2) the command alternated
+-12 N m every cycle at +-1.19 rad/s after every safe stop, on the UR5's wrist 3 (2 ms)
+-28 N m at +-1.63 rad/s, and the Panda's contact force fell from 10 to 3.9 N
(:func:`test_the_old_law_chattered_on_the_wrist` keeps that law to show what the checks
catch).

Each case starts the robot of a profile (config/robots/<robot>/plant.yaml: what the robot
compensates itself, its wrench, its rate) at home moving at half its URDF velocity limit on
every joint (alternating signs), in free motion or pressing 10 N into the table while it
slides along it (wiping), engages the brakes and checks, per joint: the speed falls
monotonically (it never rises more than ``RISE`` above a value it had before), every joint is
below ``REST_SPEED`` within ``REST_TIME``, and in the last 100 cycles the effort changes sign
at most twice (chatter changes it every cycle).
"""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from cr_control import robots
from cr_control.core.parameters import ParameterError
from cr_control.models.brake import MAX_BRAKE_STEP, brake_torque, stop_position
from cr_control.models.urdf import resolve_urdf_file
from cr_sim.plant_node import NODE_PARAMETERS, command_limiter, initial_command
from cr_sim.plants.registry import SCENARIOS, make_plant

SETTINGS = {p.name: p.default for p in NODE_PARAMETERS}
#: Speed (rad/s) every joint is below within REST_TIME (s) of the brakes' engaging.
REST_SPEED, REST_TIME = 0.01, 0.25
#: How far (rad/s) a joint's speed may rise above a value it had earlier in the stop.
RISE = 0.01
#: The most sign changes of a joint's effort over the last 100 cycles (chatter: 99).
MAX_SIGN_CHANGES = 2
#: Efforts below this (N m) count as zero for the sign changes (at rest they are ~1e-12).
EFFORT_FLOOR = 1e-6


def sign_changes(efforts: np.ndarray) -> np.ndarray:
    """Per joint (column): how often the effort changes sign between consecutive rows, only
    between values beyond EFFORT_FLOOR."""
    e = np.where(np.abs(efforts) > EFFORT_FLOOR, np.sign(efforts), 0.0)
    return ((e[1:] * e[:-1]) < 0.0).sum(axis=0)


def largest_rise(speeds: np.ndarray) -> np.ndarray:
    """Per joint (column): the most the speed rises above a value it had before."""
    lowest = np.minimum.accumulate(speeds, axis=0)
    return (speeds - lowest).max(axis=0)


def robot_plant(name: str, contact: bool, **overrides):
    """The robot ``name``'s plant (its profile's values and ``overrides``) at home, moving at
    half its URDF velocity limits, pressing 10 N and sliding along the table if ``contact``;
    and its period."""
    r = robots.robot(name)
    values = {k: v for k, v in robots.plant_values(r).items() if k != "scenario"}
    values.update(overrides)
    if not contact:
        values["surface"] = "none"
    plant = make_plant("urdf_surface", values)
    n = len(plant.command_joints)
    q0 = np.array(r.home)
    if contact:                       # the table 10 N / K_e above the tip: pressing 10 N
        tip = plant.tip_position(q0)
        values["surface_point"] = [*tip[:2], tip[2] + 10.0 / values["stiffness"]]
        plant = make_plant("urdf_surface", values)
    limits = plant.joint_limits().velocity
    v0 = 0.5 * limits * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    if contact:                       # along the table: no tip velocity along its normal
        Jz = plant.tip_jacobian(q0)[2:3]
        v0 -= np.linalg.pinv(Jz) @ (Jz @ v0)
    plant.reset_state(q0, v0)
    return plant, 1.0 / r.rate_hz


def brake(plant, period: float, seconds: float, law=None):
    """Brake ``plant`` for ``seconds`` as the plant node does (the brakes' command bounded
    by its effort limits, held for a period); ``law(plant)`` instead of the plant's own if
    given. Returns (speeds of the braked joints, efforts, contact forces) per cycle."""
    limiter = command_limiter(plant, SETTINGS, period)
    braked = [plant.joint_names.index(name) for name in plant.command_joints]
    plant.begin_safe_stop()
    speeds, efforts, forces = [], [], []
    for _ in range(round(seconds / period)):
        command = np.array(limiter.bound(plant.safe_stop_command() if law is None else law(plant)))
        plant.step(command, period)
        speeds.append(np.abs(np.asarray(plant.true_velocity())[braked]))
        efforts.append(command)
        forces.append(plant.contact_force_magnitude())
    return np.array(speeds), np.array(efforts), np.array(forces)


def assert_stable_stop(speeds: np.ndarray, efforts: np.ndarray, period: float) -> None:
    rise, changes = largest_rise(speeds), sign_changes(efforts[-100:])
    rest = speeds[round(REST_TIME / period):].max(axis=0)
    print(f"\n  largest rise {rise.max():.2e} rad/s, speeds after {REST_TIME} s "
          f"{rest.max():.1e} rad/s, sign changes (last 100 cycles) {changes.tolist()}")
    assert np.all(rise <= RISE), rise
    assert np.all(rest < REST_SPEED), rest
    assert np.all(changes <= MAX_SIGN_CHANGES), changes


# -- the robots --------------------------------------------------------------------------------
@pytest.mark.parametrize("contact", [True, False], ids=["wiping", "free"])
@pytest.mark.parametrize("name", ["panda_ft", "ur5_ft"])
def test_brakes_stop_every_joint_monotonically_without_chatter(name, contact):
    plant, period = robot_plant(name, contact)
    v0 = np.abs(plant.true_velocity()[:len(plant.command_joints)])
    force0 = plant.contact_force_magnitude()
    speeds, efforts, forces = brake(plant, period, 1.0)
    print(f"{name} at {1 / period:g} Hz, {'wiping' if contact else 'free'}: joint speeds "
          f"{np.round(v0, 2).tolist()} rad/s, contact force {force0:.1f} -> {forces[-1]:.1f} N")
    assert_stable_stop(speeds, efforts, period)
    if contact:
        # the brakes hold the tip on the table: the force stays between 5 N and its start
        assert 5.0 < forces[-1] < 1.2 * force0 and forces.min() > 1.0


def test_brakes_of_a_wrist_100_times_lighter():
    """Whatever the inertias: the Panda with its link 7 a hundredth of its mass and inertia
    (a valid URDF) brakes the same way."""
    xml = resolve_urdf_file(robots.robot("panda_ft").urdf_file).read_text()
    link7 = ('<mass value="0.735522"/>\n            <inertia ixx="0.012516" ixy="-0.000428" '
             'ixz="-0.001196" iyy="0.010027" iyz="-0.000741" izz="0.004815"/>')
    assert link7 in xml
    light = ('<mass value="0.00735522"/>\n            <inertia ixx="0.00012516" ixy="-0.00000428" '
             'ixz="-0.00001196" iyy="0.00010027" iyz="-0.00000741" izz="0.00004815"/>')
    for contact in (True, False):
        plant, period = robot_plant("panda_ft", contact, robot_description=xml.replace(link7, light))
        speeds, efforts, _ = brake(plant, period, 1.0)
        assert_stable_stop(speeds, efforts, period)


def test_the_old_law_chattered_on_the_wrist():
    """tau = G - K_d q' - K_p (q - q_b), K_d = 30 N m s/rad, K_p = 1000 N m/rad, the brakes
    before: on the Panda's joint 7 the effort alternates every cycle at +-12 N m (its limit)
    and the speed stays at ~1.2 rad/s; the checks above catch it."""
    def old_law(plant):
        n = len(plant.command_joints)
        q, v = np.array(plant.true_position()[:n]), np.array(plant.true_velocity()[:n])
        return plant.gravity_torque(q) - 30.0 * v - 1000.0 * (q - hold)

    plant, period = robot_plant("panda_ft", contact=False)
    hold = np.array(plant.true_position()[:7])
    speeds, efforts, _ = brake(plant, period, 1.0, law=old_law)
    assert sign_changes(efforts[-100:])[6] == 99
    assert np.abs(efforts[-100:, 6]).min() > 11.99
    assert speeds[-100:, 6].min() > 1.0


# -- the law, whatever the inertia ---------------------------------------------------------------
@pytest.mark.parametrize("step", [0.05, MAX_BRAKE_STEP])
def test_the_law_decouples_the_joints_and_their_speeds_fall_as_an_exponential(step):
    """On M q'' = tau (M an SPD matrix with inertias over six decades, no gravity), the law
    held for dt at w_b dt = ``step`` from (q, q') toward stop_position(q, q'): in every
    direction of M (its eigenvectors) the speed falls monotonically and never reverses;
    at the Panda's w_b dt = 0.05 within 2 % of q' e^{-w_b t} (continuous time: exactly)."""
    rng = np.random.default_rng(3)
    Q = np.linalg.qr(rng.standard_normal((4, 4)))[0]
    M = Q @ np.diag([1e-4, 1e-2, 1.0, 100.0]) @ Q.T
    w, dt = 50.0, step / 50.0
    q, v = np.zeros(4), rng.standard_normal(4)
    hold, v0 = stop_position(q, v, w), v.copy()
    Minv = np.linalg.inv(M)
    modes = [np.abs(Q.T @ v)]
    for k in range(1, round(0.3 / dt)):
        a = Minv @ brake_torque(M, None, q, v, hold, w)
        q, v = q + dt * v + 0.5 * dt * dt * a, v + dt * a
        modes.append(np.abs(Q.T @ v))
        assert np.all((Q.T @ v) * (Q.T @ v0) >= 0.0)          # never reverses
        if step <= 0.05:
            assert np.all(np.abs(v - v0 * np.exp(-w * k * dt)) <= 0.02 * np.abs(v0)), k
    assert np.all(np.diff(np.array(modes), axis=0) <= 0.0)


# -- every effort scenario ------------------------------------------------------------------------
#: The effort scenarios but urdf_surface (it needs a robot: the tests above).
EFFORT_SCENARIOS = sorted(name for name, (_, factory) in SCENARIOS.items()
                          if factory.command_interface == "effort" and name != "urdf_surface")


@pytest.mark.parametrize("overrides", [{}, {"link_inertia": [1e-4, 1e-4]}],
                         ids=["thesis", "light links"])
@pytest.mark.parametrize("scenario", EFFORT_SCENARIOS)
def test_every_effort_plant_brakes_without_chatter(scenario, overrides):
    """Every effort plant, pushed for 0.2 s beyond its holding command, then braked at 1 kHz:
    no effort alternates, every joint at rest within REST_TIME (the thesis arms also with
    links 3000 times lighter than the thesis's 0.3 kg m^2: K_d dt / M was ~10 for the old
    law's K_d = 30 N m s/rad)."""
    if overrides and "link_inertia" not in {p.name for p in SCENARIOS[scenario][0]}:
        pytest.skip("no link_inertia in this scenario")
    plant, period = make_plant(scenario, overrides), 1e-3
    hold = initial_command(plant)
    push = hold + np.where(np.arange(hold.size) % 2 == 0, 0.2, -0.2) * np.maximum(1.0, np.abs(hold))
    for _ in range(200):
        plant.step(push, period)
    moving = np.abs(plant.true_velocity()).max()
    speeds, efforts, _ = brake(plant, period, 1.0)
    print(f"\n{scenario} {overrides}: |q'| {moving:.3g} when braking began")
    assert moving > 0.01
    assert np.all(sign_changes(efforts[-100:]) <= MAX_SIGN_CHANGES)
    assert speeds[round(REST_TIME / period):].max() < REST_SPEED


# -- the node: lockstep, and the rate ------------------------------------------------------------
def answer(node, effort) -> None:
    """Deliver a command answering the node's latest state."""
    msg = JointState(name=list(node.command_names), effort=list(effort))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(node.state_stamp, 1_000_000_000)
    node._on_command(serialize_message(msg))


@pytest.mark.ros
@pytest.mark.parametrize("name", ["panda_ft", "ur5_ft"])
def test_the_lockstep_node_brakes_after_a_velocity_reflex(make_node, name):
    """The plant node in lockstep at the profile's rate, in free motion (the cases in
    contact above brake through the same calls): the wrist faster than its URDF limit trips
    the reflex; from then on every command steps the plant with the brakes, which stop
    every joint as offline."""
    r = robots.robot(name)
    values = {k: v for k, v in robots.plant_values(r).items() if k != "scenario"}
    values["surface"] = "none"
    node = make_node(scenario="urdf_surface", mode="lockstep", rate_hz=float(r.rate_hz),
                     **values)
    plant, n = node.plant, len(node.command_names)
    limits = plant.joint_limits().velocity
    v0 = 0.5 * limits * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    v0[-1] = 1.05 * limits[-1]                           # the wrist beyond its limit
    plant.reset_state(np.array(r.home), v0)
    node._publish_state(0, 0)
    speeds, efforts = [], []
    for _ in range(round(1.0 * r.rate_hz)):
        answer(node, np.zeros(n))
        speeds.append(np.abs(plant.true_velocity()[:n]))
        efforts.append(node.command.copy())
    assert node.safe_stop and node.log.count("REFLEX: joint") == 1
    assert_stable_stop(np.array(speeds[1:]), np.array(efforts[1:]), 1.0 / r.rate_hz)


@pytest.mark.ros
def test_the_node_refuses_a_brake_frequency_its_rate_cannot_hold(make_node):
    with pytest.raises(ParameterError, match="brake_frequency 200 rad/s is too high for rate_hz "
                                             "500: .* 0.25 x rate_hz \\(125 rad/s here\\)"):
        make_node(brake_frequency=200.0, rate_hz=500.0)
    assert make_node(brake_frequency=125.0, rate_hz=500.0).plant.brake_frequency == 125.0
