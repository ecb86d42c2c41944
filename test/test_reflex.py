"""The plant's reflexes (libfranka's Cartesian and joint reflexes): a contact force
above the scenario's ``max_contact_force`` or a joint velocity above its URDF limit safe-
stops the plant, in realtime and in lockstep, logged once, shown in /plant/timing
(``safe_stop_reason``) and ended by ``resume``.

The node tests drive the plant node callback by callback (no spinning, no clock waits) as
test_plant_realtime.py does; the chapter 4 tests check the position plant's safe stop
(a retract) offline; the last test runs mrac_force with its thesis defaults over ROS in
lockstep, which diverges (6600 N by 60 s without the reflex) and must end in a reflex stop.
"""

import math

import numpy as np
import pytest
from plant_harness import PERIOD, tick
from rclpy.serialization import serialize_message
from ros_probe import next_domain
from sensor_msgs.msg import JointState

from cr_control.core import topics
from cr_control.schemes.registry import make_controller
from cr_sim.loop_stats import (
    SAFE_STOP_CONTACT_FORCE,
    SAFE_STOP_JOINT_VELOCITY,
    SAFE_STOP_NONE,
    SAFE_STOP_WATCHDOG,
)
from cr_sim.plant_node import IDLE_RESENDS, PlantNode
from cr_sim.plant_setup import NODE_PARAMETERS
from cr_sim.plants.dynamic_constraint import equilibrium
from cr_sim.plants.registry import SCENARIOS, make_plant

#: The thesis scenarios and their force reflex defaults (N) with the task force behind each.
DEFAULT_MAX_FORCE = {"compliant_plane": 50.0, "circular_surface": 50.0, "moving_object": 20.0,
                     "dynamic_constraint": 5.0, "cmmsd": 10.0, "flexible_joint_surface": 20.0}


def answer(node: PlantNode, **values) -> None:
    """Deliver a command (``effort=[...]`` or ``position=[...]``) answering the latest state."""
    msg = JointState(name=list(node.command_names), **values)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(node.state_stamp, 1_000_000_000)
    node._on_command(serialize_message(msg))


def timing(node: PlantNode) -> dict[str, float]:
    """The node's /plant/timing values as it publishes them now, by name."""
    node._publish_timing(at_once=True)
    return dict(zip(topics.PLANT_TIMING_FIELDS, node.report.message.data, strict=True))


def pressed_into_the_plane(node: PlantNode, depth: float) -> None:
    """Put the ch. 3 arm at rest ``depth`` (m) inside the plane x - y + 0.25 = 0."""
    r = np.array([-0.05, 0.2]) + depth * np.array([-1.0, 1.0]) / math.sqrt(2.0)
    plant = node.plant
    plant.reset_state(plant.arm.inverse_kinematics(r, -1.0))


def start_lockstep(node: PlantNode) -> None:
    """What the lockstep node does once a controller is connected: publish the first state."""
    node._publish_state(0, 0)


# -- every scenario ------------------------------------------------------------------------
@pytest.mark.parametrize("scenario", sorted(DEFAULT_MAX_FORCE))
def test_every_thesis_scenario_has_a_read_only_max_contact_force(scenario):
    spec = {p.name: p for p in SCENARIOS[scenario][0]}["max_contact_force"]
    assert spec.default == DEFAULT_MAX_FORCE[scenario] and spec.read_only and spec.kind == "positive"
    assert "task" in spec.description or "no contact" in spec.description
    plant = make_plant(scenario)
    assert plant.max_contact_force == DEFAULT_MAX_FORCE[scenario]
    assert make_plant(scenario, {"max_contact_force": 7.5}).max_contact_force == 7.5
    # at t = 0 every plant is well below its limit (ch. 2, 6: lambda = 2 N; ch. 4: 1.5 N)
    start = {"moving_object": 2.0, "flexible_joint_surface": 2.0, "dynamic_constraint": 1.5}
    assert plant.contact_force_magnitude() == pytest.approx(start.get(scenario, 0.0), abs=1e-9)


def test_noise_never_reaches_the_reflexes():
    """The reflexes watch the true force and velocities: measurement noise neither trips
    them nor is drawn by them (the measured noise sequence is that of a plant nobody asks)."""
    noisy = {"force_noise_std": 1000.0, "velocity_noise_std": 100.0, "noise_seed": 3}
    watched, alone = make_plant("compliant_plane", noisy), make_plant("compliant_plane", noisy)
    for _ in range(5):
        assert watched.contact_force_magnitude() == 0.0
        assert watched.true_velocity() == [0.0, 0.0]
        a, b = watched.measurement(), alone.measurement()
        np.testing.assert_array_equal(a.force, b.force)
    assert np.abs(a.force).max() > 50.0                # the noise alone is above the limit


def test_velocity_limits_are_the_urdf_ones():
    assert make_plant("compliant_plane").velocity_limits() == [(0, 10.0), (1, 10.0)]
    assert make_plant("moving_object").velocity_limits() == [(0, 10.0), (1, 10.0), (2, 5.0)]
    # ch. 6: the links' URDF limits (the motors have none)
    assert make_plant("flexible_joint_surface").velocity_limits() == [(0, 10.0), (1, 10.0)]
    assert make_plant("dynamic_constraint").velocity_limits() == []
    assert make_plant("cmmsd").velocity_limits() == []


# -- the node, realtime ----------------------------------------------------------------------
@pytest.mark.ros
def test_contact_force_reflex_in_realtime_brakes_logs_once_and_resumes(make_node):
    node = make_node(max_contact_force=2.0)
    tick(node)
    answer(node, effort=[0.1, 0.1])
    tick(node)
    assert not node.safe_stop
    assert timing(node)["safe_stop_reason"] == SAFE_STOP_NONE

    pressed_into_the_plane(node, 0.02)               # 150 N/m x 20 mm = 3 N > 2 N
    tick(node)
    assert node.safe_stop and node.stats.safe_stop_reason == SAFE_STOP_CONTACT_FORCE
    errors = [m for level, m in node.log.lines if level == "error"]
    assert len(errors) == 1
    assert errors[0].startswith("REFLEX: contact force 3 N > max_contact_force 2 N at t = 0.003 s: "
                                "safe stop, braking (gravity held"), errors[0]
    for _ in range(20):                               # brakes; commands ignored; logged once
        before = node.command.tolist()
        answer(node, effort=[5.0, 5.0])
        assert node.command.tolist() == before
        brake = node.limiter.bound(node.plant.safe_stop_command())
        tick(node)
        assert node.command.tolist() == pytest.approx(brake)
    assert node.log.count("REFLEX") == 1
    values = timing(node)
    assert values["safe_stop"] == 1.0 and values["safe_stop_reason"] == SAFE_STOP_CONTACT_FORCE
    assert "SAFE STOP (contact force reflex)" in node.log.lines[-1][1]

    # resume while still pressing too hard: a new trip, logged again
    node._on_parameter("resume", True)
    tick(node)
    assert node.safe_stop and node.log.count("REFLEX") == 2
    # resume once out of contact: commands apply again, timing says so
    node.plant.reset_state(node.plant.arm.inverse_kinematics([0.1, 0.2], -1.0))
    node._on_parameter("resume", True)
    tick(node)
    assert not node.safe_stop and node.get_parameter("resume").value is False
    assert timing(node)["safe_stop_reason"] == SAFE_STOP_NONE
    answer(node, effort=[0.2, 0.3])
    assert node.command.tolist() == [0.2, 0.3]


@pytest.mark.ros
def test_joint_velocity_reflex_at_the_urdf_limit(make_node):
    node = make_node()
    tick(node)
    plant = node.plant
    q = plant.state[:2]
    plant.reset_state(q, [9.9, 0.0])                  # below the 10 rad/s limit: runs on
    tick(node)
    assert not node.safe_stop
    plant.reset_state(plant.state[:2], [10.5, 0.0])
    tick(node)
    assert node.safe_stop and node.stats.safe_stop_reason == SAFE_STOP_JOINT_VELOCITY
    assert node.log.count("REFLEX: joint joint1 velocity 10.") == 1
    assert "beyond its URDF <limit velocity> 10" in node.log.lines[-1][1]
    for _ in range(3000):            # the brakes (20 N m at most) bring it to rest in ~2.3 s
        tick(node)
    assert np.abs(plant.state[2:]).max() < 1e-2
    assert node.log.count("REFLEX") == 1
    assert timing(node)["safe_stop_reason"] == SAFE_STOP_JOINT_VELOCITY


@pytest.mark.ros
def test_the_watchdog_reports_its_reason_and_a_reflex_does_not_overwrite_it(make_node):
    node = make_node(watchdog_missed_cycles=3, max_contact_force=2.0)
    tick(node)
    answer(node, effort=[0.0, 0.0])
    for _ in range(4):
        tick(node)
    assert node.safe_stop and node.stats.safe_stop_reason == SAFE_STOP_WATCHDOG
    assert node.log.count("SAFE STOP: watchdog: no new command for 3 consecutive cycles") == 1
    pressed_into_the_plane(node, 0.02)
    tick(node)
    assert node.stats.safe_stop_reason == SAFE_STOP_WATCHDOG and node.log.count("REFLEX") == 0


# -- the node, lockstep ----------------------------------------------------------------------
@pytest.mark.ros
def test_contact_force_reflex_in_lockstep_brakes_and_the_loop_goes_on(make_node):
    """After the trip each command still steps the plant one period, with the brakes'
    command instead of the controller's, and a new state goes out."""
    node = make_node(mode="lockstep", max_contact_force=2.0)
    reference = make_plant("compliant_plane")
    start_lockstep(node)
    answer(node, effort=[0.1, 0.1])
    reference.step(np.array([0.1, 0.1]), PERIOD)
    np.testing.assert_array_equal(node.plant.state, reference.state)
    assert not node.safe_stop

    pressed_into_the_plane(node, 0.02)
    answer(node, effort=[0.1, 0.1])                    # this step ends inside: trip
    assert node.safe_stop and node.stats.safe_stop_reason == SAFE_STOP_CONTACT_FORCE
    assert node.log.count("REFLEX: contact force") == 1
    for _ in range(50):
        stamp, t = node.state_stamp, node.plant.time
        brake = node.limiter.bound(node.plant.safe_stop_command())
        answer(node, effort=[5.0, 5.0])
        assert node.plant.time == pytest.approx(t + PERIOD)     # stepped one period ...
        assert node.command.tolist() == pytest.approx(brake)    # ... with the brakes
        assert node.state_stamp > stamp                          # ... and published
    assert node.log.count("REFLEX") == 1
    assert timing(node)["safe_stop_reason"] == SAFE_STOP_CONTACT_FORCE
    assert node.stats.total_cycles == 52

    node.plant.reset_state(node.plant.arm.inverse_kinematics([0.1, 0.2], -1.0))
    node._on_parameter("resume", True)
    node._resend_if_stalled()                          # the lockstep node's timer
    assert not node.safe_stop and timing(node)["safe_stop_reason"] == SAFE_STOP_NONE
    for _ in range(25):                 # from the last brake torque at the rate limit
        answer(node, effort=[0.0, 0.0])
    assert node.command.tolist() == [0.0, 0.0] and not node.safe_stop


@pytest.mark.ros
def test_position_plant_reflex_in_lockstep_retracts(make_node):
    node = make_node(scenario="dynamic_constraint", mode="lockstep", max_contact_force=1.6)
    start_lockstep(node)
    answer(node, position=[0.3])                       # pushes in: f rises past 1.6 N
    for _ in range(2000):
        if node.safe_stop:
            break
        answer(node, position=[0.3])
    assert node.safe_stop and node.stats.safe_stop_reason == SAFE_STOP_CONTACT_FORCE
    assert node.log.count("retracting the command from [0.3] to the contact-free position") == 1
    retract = node.plant.retract_command
    commands = []
    for _ in range(1000):
        answer(node, position=[0.3])
        commands.append(node.command[0])
    assert retract()[0] == 0.0                         # reached in 0.6 s at 0.5 m/s, held
    assert commands[-1] < 0.3 and node.plant.contact_force_magnitude() < 1.6


# -- chapter 4: the position plant's safe stop -----------------------------------------------
def test_dynamic_constraint_safe_stop_retracts_at_rest_to_the_zero_force_position():
    """At rest pressing with 1.5 N (delta = delta_c = 0.225 m): delta_c retracts to the
    zero-force equilibrium delta = 0 at retract_speed (0.45 s) and stays; the end effector
    comes to rest there. The force never exceeds the 1.5 N of the stop and decays: the
    compliant layer (m_c = 50 kg, damping ratio ~0.01) keeps ringing for a while and
    touches the retracted end effector on its outward swings (the thesis's constraint is
    bilateral: its states follow delta even out of contact)."""
    plant = make_plant("dynamic_constraint")
    assert equilibrium(plant.values, 0.0)[0] == 0.0
    assert plant.contact_free_position().tolist() == [0.0]
    plant.begin_safe_stop()
    assert "from [0.225] to the contact-free position [0.0] at [0.5] per s" in plant.describe_safe_stop()
    ramp, forces = [], []
    for _ in range(100_000):
        ramp.append(plant.retract_command()[0])
        plant.step(plant.safe_stop_command(), PERIOD)
        forces.append(plant.contact_force_magnitude())
    ramp, forces = np.array(ramp), np.array(forces)
    assert np.abs(np.diff(ramp)).max() <= 0.5 * PERIOD + 1e-12
    assert ramp[449] > 0.0 and (ramp[451:] == 0.0).all()
    assert forces.max() <= 1.5 + 1e-9 and forces[60_000:].max() < 0.3 * 1.5
    assert abs(plant.state[0]) < 1e-6 and abs(plant.state[1]) < 1e-6


def test_dynamic_constraint_safe_stop_after_the_mrac_divergence_keeps_the_force_down():
    """mrac_force (thesis defaults) offline until its force first exceeds 5 N, then the
    safe stop: the target is where f = 0 for the constraint's state then (beyond the
    zero-force equilibrium and the held command); the force rises ~1 % more for ~0.15 s
    (the end effector's and the constraint's momentum: a 20 kg end effector on a 10 N/m
    servo cannot stop within a period) and never comes back above the limit; without the
    brakes' damping the lightly damped pair rings back to > 12 N."""
    plant, controller = make_plant("dynamic_constraint"), make_controller("mrac_force")
    while plant.contact_force_magnitude() <= plant.max_contact_force:
        m = plant.measurement()
        plant.step(controller.step(m.time, m.position, m.velocity, m.force).command, PERIOD)
    assert plant.time == pytest.approx(16.478, abs=1e-6)
    x = plant.state
    free_now = x[0] - plant.raw_force() / 40.0          # k_o + k_s
    target = plant.contact_free_position()[0]
    assert target == pytest.approx(free_now) and target < min(0.0, plant.held[0])
    plant.begin_safe_stop()
    forces = []
    for _ in range(150_000):
        plant.step(plant.safe_stop_command(), PERIOD)
        forces.append(plant.contact_force_magnitude())
    forces = np.array(forces)
    print(f"\nch. 4 safe stop after the MRAC trip: max f {forces.max():.4f} N at "
          f"+{forces.argmax() * PERIOD:.3f} s, max after 1 s {forces[1000:].max():.3f} N")
    assert forces.max() < 1.02 * plant.max_contact_force
    assert forces[1000:].max() < plant.max_contact_force
    assert plant.state[0] == pytest.approx(target, abs=1e-6) and abs(plant.state[1]) < 1e-6


# -- mrac_force over ROS ---------------------------------------------------------------------
#: Simulated seconds of the mrac_force session: its force first exceeds 5 N at 16.478 s
#: (offline, identical in lockstep); 0.5 s more shows the force turning down.
MRAC_DURATION = 17.0


@pytest.mark.ros
def test_mrac_force_with_thesis_defaults_ends_in_a_reflex_stop(tmp_path):
    """mrac_force diverges with its thesis defaults (6600 N by 60 s); in a lockstep session
    the plant's force reflex stops it at 5 N: the recording shows safe_stop_reason 2, the
    force never above the limit plus the ~1 % the end effector's momentum adds after the
    trip, the controller's commands replaced by the retract, and the plant's log one REFLEX
    line."""
    from cr_control.analysis.analyze import load_session
    from cr_control.tools.session import Session, SessionConfig

    cfg = SessionConfig(scheme="mrac_force", duration=MRAC_DURATION, mode="lockstep", out=tmp_path,
                        domain_id=next_domain(), name="run")
    result = Session(cfg, progress=lambda _: None).run()
    s = load_session(result.mcap)
    log = (result.logs / "plant.log").read_text()
    assert log.count("REFLEX:") == 1, log[-3000:]
    assert "REFLEX: contact force 5.001 N > max_contact_force 5 N at t = 16.478 s" in log

    f = s.wrench.force[:, 0]
    t = s.wrench.time                                # lockstep: simulated time from 0
    trip = int(np.argmax(f > 5.0))
    print(f"\nmrac_force: reflex at t = {t[trip]:.3f} s, f = {f[trip]:.4f} N; max f afterwards "
          f"{f.max():.4f} N; f at the end {f[-1]:.3f} N")
    assert t[trip] == pytest.approx(16.478, abs=1e-6)
    assert f.max() < 1.02 * 5.0 and f[-1] < 5.0
    reasons, stamps = s.timing["safe_stop_reason"], s.timing["stamp"]
    assert reasons[-1] == SAFE_STOP_CONTACT_FORCE and s.timing["safe_stop"][-1] == 1.0
    assert (reasons[stamps < t[trip]] == SAFE_STOP_NONE).all()
    # the controller's commands are applied up to the trip, the retract after it
    states, commands = s.joint_states, s.joint_commands
    assert len(states.time) == len(commands.time) == int(MRAC_DURATION * 1000)
    np.testing.assert_array_equal(states.time, commands.time)
    # delta_c held over the period into each state (its effort is k (delta_c - delta), k = 10)
    applied = states.position[1:, 0] + states.effort[1:, 0] / 10.0
    sent = commands.position[:-1, 0]                 # the command answering the state before
    assert np.abs(applied[:trip] - sent[:trip]).max() < 1e-12
    assert np.abs(applied[trip:] - sent[trip:]).min() > 0.1



# -- the offline loop and a lockstep session agree; a session ends ----------------------------
def cr_session(tmp_path, name: str, *args: str) -> tuple[int, str, str]:
    """cr_session in lockstep (in this process): its exit status, stderr and plant log."""
    import contextlib
    import io

    from cr_control.tools import session

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = session.main(["--mode", "lockstep", "--out", str(tmp_path), "--name", name,
                             "--domain-id", str(next_domain()), "--no-analysis", *args])
    return code, err.getvalue(), (tmp_path / name / "logs" / "plant.log").read_text()


@pytest.mark.ros
def test_a_stiff_plane_stops_offline_as_in_lockstep(tmp_path):
    """The chapter 3 plane at K_e = 1500 N/m: the contact force overshoots the 50 N reflex
    limit. The offline loop (what cr_sweep and cr_tune run) and a lockstep session of the
    same settings (the plant node's defaults: its command limits clip nothing before the
    trip) trip the same reflex at the same simulated time."""
    from cr_control import offline

    stiff = offline.run_scheme("adaptive_impedance", 1.0, plant_overrides={"stiffness": 1500.0})
    assert stiff.safe_stop_reason == SAFE_STOP_CONTACT_FORCE
    code, err, log = cr_session(tmp_path, "stiff", "--scheme", "adaptive_impedance",
                                "--duration", "1", "-p", "plant.stiffness=1500.0")
    assert code == 0, err
    assert log.count("REFLEX: contact force") == 1, log[-3000:]
    lockstep_at = float(log.split("max_contact_force 50 N at t = ")[1].split(" s")[0])
    print(f"\nreflex stop: offline at {stiff.safe_stop_at:.3f} s, lockstep at {lockstep_at:.3f} s")
    assert abs(lockstep_at - stiff.safe_stop_at) <= 3 * PERIOD


@pytest.mark.ros
def test_a_lockstep_session_ends_with_why_once_nothing_commands_the_stopped_plant(tmp_path):
    """backstepping_force with a 1.2 N force reflex (the plant starts at 1.5 N): the plant
    safe-stops at its first step and retracts; the law, saturated against it, stops
    commanding after max_bad_cycles (offline: at 0.73 s) and has no brake to publish. The
    session then ends at once with the plant's reason and exit status 3, instead of waiting
    for a command that never comes (before: 140-180 s and "plant did not finish")."""
    code, err, log = cr_session(tmp_path, "ends", "--scheme", "backstepping_force",
                                "--duration", "10", "-p", "plant.max_contact_force=1.2")
    assert code == 3, err
    assert err.startswith("cr_session: the plant ended the session early: ENDED: in a safe stop "
                          "(contact force reflex at t = 0.001 s) and no command for "), err
    # The silence is read by the plant's 1 s resend timer, so it is 2-3 s of wall time (CI
    # once printed 3.0): what the rule guarantees is the lower bound, idle_s = 2 resends.
    silent = float(err.split("no command for ")[1].split(" s")[0])
    resend_s = next(p.default for p in NODE_PARAMETERS if p.name == "lockstep_resend_s")
    assert silent >= IDLE_RESENDS * resend_s, err
    assert "the controller stopped commanding" in err
    assert log.count("REFLEX: contact force") == 1 and log.count("ENDED:") == 1, log[-3000:]
    ended_at = float(err.split("the plant stops at t = ")[1].split(" s")[0])
    assert 0.5 < ended_at < 1.0                  # where the law stopped: far from the 10 s
