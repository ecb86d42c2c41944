"""The five task-space schemes on the robot profiles (cr_control.robots: the Panda
through franka_ros2 with Franka's estimated wrench or a wrist sensor, the UR5 through
ur_robot_driver's effort interface at 500 Hz with its TCP sensor or a wrist sensor; each
robot compensates its own gravity, the UR5 its joint friction too), wiping a table with
Coulomb friction 0.3: offline and in lockstep over ROS, with numeric bounds.

What must hold on each profile, judged by the plant's TRUE contact force over the second half
of a 10 s run (cr_control.experiments.wiping): radial path error RMS <= 2 mm about the
commanded circle, its centre within 1 mm of the reference's, force error RMS <= 0.3 N, the
force never lost once the desired force is ramped in, the orientation held, no joint limit
approached, the contact-stability monitor calm. Measured (offline, 10 s):

| scheme | radial RMS | centre | force err RMS (N) |
|---|---|---|---|
| adaptive_impedance | 0.10-0.59 mm | 0.09-0.69 mm | 0.036-0.070 |
| robust_adaptive_impedance | 0.01-0.03 mm | 0.00-0.03 mm | 0.039-0.074 |
| nn_adaptive_impedance | 0.01 mm | 0.00-0.01 mm | 0.037-0.070 |
| impedance | 0.05-0.06 mm | 0.00-0.03 mm | 0.12-0.16 |
| fuzzy_unidirectional | 0.05-0.06 mm | 0.00-0.03 mm | 0.14-0.19 |

Before the profiles the chapter 3 laws drew their circle 6 mm off its place (their initial
estimate c_hat(0) pushed sideways: robots.C_HAT_0) and the chapter 5 laws, whose impedance has
one stiffness k_m = 60 N/m on every axis, circled at 3.3 and 21 mm radius instead of 50 mm on
the friction table (robots.TANGENTIAL gives them k_t = 3000 N/m in the table's plane).

Each with the driver's transport delay of its profile (1 cycle: the answer to a state acts
from the next cycle on) and at three times it (3 ms on the Panda, 6 ms on the UR5), where
before the wrist's gains came from the discrete-time rule the Panda's joint 7 oscillated at
1.01-1.27x its velocity limit in every scheme (cr_control.schemes.blocks.gain_bounds).
Measured at 3 cycles (offline, 8 s): force error RMS 0.04-0.17 N, radial 0.01-0.52 mm, joints
at most 0.17 of their velocity limits, no command at its effort limit.

On the 10x stiffer table (50 kN/m) too, with the chapter 5 laws' normal damping raised
above what a force measured one cycle late takes away (robots.CH5_DAMPING: before it, the
UR5's impedance erred by 1.05 N RMS at 500 Hz, the Panda's by 0.31 N), WITHOUT the driver's
delay: with it the contact loop rings (one cycle: 0.35-0.58 N RMS on the Panda, 0.53-1.23 N on
the UR5; three: 0.53-1.07 N and 1.0-12.8 N) -- the discrete-time rule asks a normal damping
of 140-180 N s/m of the chapter 5 laws on the Panda there, and no damping at all holds a
50 kN/m contact through m_m = 1.2 kg at the UR5's 500 Hz with two cycles of lag.

Through late bursts too (cr_sim.transport_delay: the driver holds the last command for 20-70
ms, then catches up), on about 1 % of the cycles, at the profile's delay and three times it:
the same bounds over 20 s runs (seed 10: 6 bursts, 3 of them in the judged half, 0.93 % of
the Panda's cycles late and 1.02 % of the UR5's: force error RMS 0.04-0.17 N, radial at
most 0.35 mm, joints at most 0.17 of their limits). Measured (offline, 20 s, seeds 1-3 on every
case, 4-7 on panda and panda_ft too): force error RMS 0.03-0.24 N, radial 0.01-0.36 mm,
joints at most 0.17 of their velocity limits, no command at its effort limit, no reflex, no
give-up but one: a burst in the start check's first second (test_a_late_burst_during_the_start_check,
open). A burst holds a torque that answered the arm as it was: the tool presses into the
table or lifts (up to ~2 N off within 70 ms), and from the catch-up the law's own contact loop
takes it back in ~0.2 s; the adaptive laws fare as the fixed impedance does, so nothing they
integrate meanwhile winds them up (docs/safety.md, 'Late bursts').
"""

import numpy as np
import pytest
from lockstep_replay import as_read
from ros_probe import next_domain

from cr_control import robots
from cr_control.experiments.wiping import Case, late_bursts, run_case
from cr_control.models.urdf import load_chain
from cr_control.offline import robot_period, run_scheme
from cr_control.schemes.blocks.wrist_sensor import ZERO_START_WINDOW_S

#: The torque-interface profiles (the position and velocity ones: test_admittance_outer_loop).
PROFILES = tuple(name for name, r in robots.ROBOTS.items() if r.command_interface == "effort")
CASES = [(r, s) for r in PROFILES for s in robots.TASK_SPACE_SCHEMES]
#: The stiff table's runs, without the driver's delay (module docstring).
NO_DELAY = (("command_delay_cycles", 0),)
#: The torque-interface profiles and their schemes (the three-delay cases).
EFFORT_CASES = [(r, s) for r, s in CASES
                if getattr(robots.robot(r), "command_interface", "effort") == "effort"]
#: The lockstep comparison: every scheme once, on the Panda (1 kHz) and the UR5 (500 Hz) in turn
#: (the transport is the scheme's and the rate's, not the arm's: each robot with every scheme
#: would run the same messages twice).
LOCKSTEP_CASES = [(("panda", "ur5")[i % 2], s) for i, s in enumerate(robots.TASK_SPACE_SCHEMES)]
#: Late bursts (module docstring): one scheme of each family per robot at three times its
#: delay first (the fast tier runs these: test/conftest.py STUDIES), then every other scheme and
#: delay factor.
BURST_FIRST = [("panda", "adaptive_impedance", 3), ("panda_ft", "nn_adaptive_impedance", 3),
               ("ur5", "fuzzy_unidirectional", 3), ("ur5_ft", "robust_adaptive_impedance", 3)]
BURST_CASES = BURST_FIRST + [(r, s, f) for r in PROFILES for s in robots.TASK_SPACE_SCHEMES
                             for f in (1, 3) if (r, s, f) not in BURST_FIRST]
#: About 1 % of the cycles late, in bursts of 20-70 ms; the seed puts 6 bursts in a 20 s run,
#: 3 of them in its judged second half, on both rates (1 kHz and 500 Hz).
BURST_FRACTION, BURST_SEED, BURST_RUN_S = 0.01, 10, 20.0
CH5 = ("impedance", "fuzzy_unidirectional")

RADIAL_RMS_M = 2e-3
CENTRE_M = 1e-3
FORCE_ERR_RMS_N = 0.3
ORIENTATION_MAX_DEG = {"robust_adaptive_impedance": 4.0,      # its model is 10 % light
                       "nn_adaptive_impedance": 3.0}
POSTURE_MAX_RAD = 0.02
#: Contact is judged from this long after the law starts (s): after the start-up hold and
#: once the desired force is above the sensors' noise (the chapter 5 laws just touch before).
LAW_START_S = ZERO_START_WINDOW_S + 1e-3
CONTACT_FROM_S = {**dict.fromkeys(CH5, 0.1)}


def sensor_noise_free(robot: str) -> dict:
    """Plant overrides that take the noise off the profile's wrench (the lockstep comparison)."""
    if robots.robot(robot).wrench == "estimated":
        return {"force_noise_std": 0.0}
    return {"ft_noise_std": [0.0, 0.0]}


def metrics(run, robot: str) -> dict[str, float]:
    """The orientation, posture and joint-limit figures of a run."""
    rot = np.linalg.norm(np.column_stack([run.column(f"e_rot_{a}") for a in "xyz"]), axis=1)
    r = robots.robot(robot)
    limits = load_chain("", r.urdf_file, r.base_link, r.tip_link).limits
    n = len(limits.lower)
    q = run.position[:, :n]
    return {"orientation_max_deg": float(np.degrees(rot.max())),
            "posture_max": float(run.column("posture_error").max())
            if "posture_error" in run.status_fields else 0.0,
            "limit_margin": float(np.minimum(q - limits.lower, limits.upper - q).min()),
            "held": float(run.column("held").sum())}


def contact_from(run, scheme: str) -> float:
    """The smallest true normal force once contact must hold (see the module docstring)."""
    since = LAW_START_S + CONTACT_FROM_S.get(scheme, 0.05)
    return float(run.true_force[run.time >= since, 2].min())


@pytest.mark.parametrize("robot,scheme", CASES, ids=[f"{r}-{s}" for r, s in CASES])
def test_wiping_holds_the_force_on_the_path(robot, scheme):
    values, errors = run_case(Case(scheme, robot, duration=10.0))
    print(f"\n{robot} {scheme}: radial {values['radial_rms_m'] * 1e3:.2f} mm, centre "
          f"{values['centre_err_m'] * 1e3:.2f} mm, force error mean "
          f"{values['force_err_mean_N']:+.3f} N RMS {values['force_err_rms_N']:.3f} N")
    assert not errors and values["safe_stop_reason"] == 0.0
    assert values["radial_rms_m"] <= RADIAL_RMS_M
    assert values["centre_err_m"] <= CENTRE_M
    assert values["force_err_rms_N"] <= FORCE_ERR_RMS_N
    assert values["joint_speed_max_fraction"] <= 0.5
    assert values["torque_limit_run_cycles"] <= 10
    run = run_scheme(scheme, 3.0, robot=robot)
    m = metrics(run, robot)
    assert contact_from(run, scheme) > 0.0                     # contact never lost
    assert m["orientation_max_deg"] < ORIENTATION_MAX_DEG.get(scheme, 1.0)
    assert m["posture_max"] < POSTURE_MAX_RAD                   # no drift in the null space
    assert m["limit_margin"] > 0.5                              # no joint limit approached
    assert m["held"] == 0.0 and np.isfinite(run.command).all()
    # the guarded approach finds the table it starts on; the stability monitor stays calm
    assert run.column("approach_phase")[-1] == 2.0
    assert run.column("stiffness_scale").min() == 1.0


@pytest.mark.parametrize("robot,scheme", CASES, ids=[f"{r}-{s}" for r, s in CASES])
def test_wiping_a_stiff_table(robot, scheme):
    """The 10x stiffer table (module docstring): the force error RMS stays within 0.3 N
    (without the driver's delay: with it, not yet)."""
    values, errors = run_case(Case(scheme, robot, table="stiff", duration=8.0, plant=NO_DELAY))
    print(f"\n{robot} {scheme} stiff: force error RMS {values['force_err_rms_N']:.3f} N")
    assert not errors and values["force_err_rms_N"] <= FORCE_ERR_RMS_N
    assert values["radial_rms_m"] <= RADIAL_RMS_M and values["centre_err_m"] <= CENTRE_M


@pytest.mark.parametrize("robot,scheme", EFFORT_CASES, ids=[f"{r}-{s}" for r, s in EFFORT_CASES])
def test_wiping_at_three_times_the_drivers_delay(robot, scheme):
    """At three times the profile's delay (3 ms on the Panda, 6 ms on the UR5) every scheme
    wipes as at one: force error RMS <= 0.3 N, radial <= 2 mm, no joint above half its
    velocity limit, no command at its effort limit for more than 10 cycles, no reflex."""
    delay = 3 * robots.robot(robot).command_delay_cycles
    values, errors = run_case(Case(scheme, robot, duration=8.0,
                                   plant=(("command_delay_cycles", delay),)))
    print(f"\n{robot} {scheme} at {delay} cycles: force error RMS {values['force_err_rms_N']:.3f} "
          f"N, radial {values['radial_rms_m'] * 1e3:.2f} mm, joints at "
          f"{values['joint_speed_max_fraction']:.2f} of their limits")
    assert not errors and values["safe_stop_reason"] == 0.0
    assert values["force_err_rms_N"] <= FORCE_ERR_RMS_N
    assert values["radial_rms_m"] <= RADIAL_RMS_M
    assert values["joint_speed_max_fraction"] <= 0.5
    assert values["torque_limit_run_cycles"] <= 10


@pytest.mark.parametrize("robot,scheme,factor", BURST_CASES,
                         ids=[f"{r}-{s}-{f}x" for r, s, f in BURST_CASES])
def test_wiping_through_late_bursts(robot, scheme, factor):
    """Late answers never integrate into a flail: with bursts of 20-70 ms in which the driver
    holds the last command on ~1 % of the cycles, at the profile's delay and at three times
    it, every scheme keeps the bounds above over the judged half of a 20 s run (force error
    RMS <= 0.3 N, radial <= 2 mm, no joint above half its velocity limit, no command at its
    effort limit for more than 10 cycles), with no reflex and no give-up."""
    delay = factor * robots.robot(robot).command_delay_cycles
    plant = (("command_delay_cycles", delay),) + late_bursts(robot, BURST_FRACTION, BURST_SEED)
    values, errors = run_case(Case(scheme, robot, duration=BURST_RUN_S, plant=plant))
    print(f"\n{robot} {scheme} at {delay} cycles, {values['late_bursts']:.0f} late bursts "
          f"({values['late_fraction'] * 100:.2f} % of the cycles): force error RMS "
          f"{values['force_err_rms_N']:.3f} N, radial {values['radial_rms_m'] * 1e3:.2f} mm, "
          f"joints at {values['joint_speed_max_fraction']:.2f} of their limits, "
          f"{values['torque_limit_run_cycles']:.0f} cycles at a limit")
    assert values["late_bursts"] == 6 and values["late_bursts_judged"] == 3
    assert 0.009 <= values["late_fraction"] <= 0.011
    assert not errors and values["safe_stop_reason"] == 0.0 and values["gave_up"] == 0.0
    assert values["force_err_rms_N"] <= FORCE_ERR_RMS_N
    assert values["radial_rms_m"] <= RADIAL_RMS_M
    assert values["joint_speed_max_fraction"] <= 0.5
    assert values["torque_limit_run_cycles"] <= 10


@pytest.mark.xfail(strict=True, reason="a burst in the start check's first second: the chapter 3 "
                   "laws' transient at contact (the circle starts at full speed), held and "
                   "answered at the catch-up, takes the tip 0.153 m/s off its reference at "
                   "0.27 s (start check 0.15 m/s): the controller gives up for good (force "
                   "error RMS 9.8 N)")
def test_a_late_burst_during_the_start_check():
    """panda_ft, robust_adaptive_impedance at three times its delay, seed 5 (2.2 % of the
    cycles late; the first burst 48 cycles at 0.205 s). When the guarded approach finds the
    table (0.092 s) the wiping circle starts at its full speed (r_d' steps from 0 to a w =
    0.05 m/s along y, 3.93), and the chapter 3 laws' command steps by 3-5 N m on joints 1, 3
    and 5: joint 5 swings to 0.44 rad/s and the wrist rings for ~0.2 s, the tip at up to 0.10
    m/s (0.3 rad/s on the Panda's estimated wrench, 0.26-0.32 at the profile's delay). A burst
    holds one of those commands for 48 ms, and the law's answer at the catch-up moves the tip
    0.153 m/s off its reference, which the start check (safe_stop.start_check: a gravity
    mismatch or a grossly wrong model) takes for a wrong model. Open: the path's start (a
    velocity step at contact) and the start check's reading of a held command. Started from
    rest (reference_ramp_time 1 s) this run holds (0.077 N RMS), but the shipped chatter
    case (config/panda_stiff_table.yaml) then fails with its monitor on (the start check
    gives up at 0.607 s, 8.23 N RMS; it holds with ramps of 0 and 0.3 s, not 0.1 or 1 s,
    and with all of them without the table's friction), so the profiles keep the
    full-speed start until the monitor holds that case from rest."""
    r = "panda_ft"
    plant = (("command_delay_cycles", 3 * robots.robot(r).command_delay_cycles),
             *late_bursts(r, BURST_FRACTION, 5))
    values, errors = run_case(Case("robust_adaptive_impedance", r, duration=8.0, plant=plant))
    print(f"\ngave up at {values['gave_up_at_s']:.3f} s: {errors}; force error RMS "
          f"{values['force_err_rms_N']:.3f} N")
    assert not errors and values["gave_up"] == 0.0 and values["safe_stop_reason"] == 0.0
    assert values["force_err_rms_N"] <= FORCE_ERR_RMS_N
    assert values["radial_rms_m"] <= RADIAL_RMS_M


def test_panda_is_redundant_and_the_ur5_is_not():
    """The Panda's 7th joint is left to the posture task; the UR5's 6 are all the task's."""
    panda = run_scheme("impedance", 0.01, robot="panda")
    ur5 = run_scheme("impedance", 0.01, robot="ur5")
    assert "posture_error" in panda.status_fields and "posture_error" not in ur5.status_fields
    for run in (panda, ur5):
        assert [f for f in run.status_fields if f.startswith(("e_rot", "r_"))] == [
            "r_x", "r_y", "r_z", "e_rot_x", "e_rot_y", "e_rot_z"]


def test_finger_joints_are_published_and_ignored():
    """The Panda plant publishes its locked finger joints; the controller reads and commands
    the 7 arm joints only."""
    run = run_scheme("adaptive_impedance", 0.01, robot="panda")
    assert run.position.shape[1] == 9 and run.command.shape[1] == 7


def test_the_ur5_runs_at_its_drivers_rate():
    """ur_robot_driver's effort interface runs at 500 Hz: the profile's plant and its offline
    loop step every 2 ms."""
    assert robot_period("ur5") == pytest.approx(2e-3)
    run = run_scheme("impedance", 0.02, robot="ur5")
    assert np.allclose(np.diff(run.time), 2e-3)


# -- lockstep over ROS -----------------------------------------------------------------------------
LOCKSTEP_S = 2.0
#: Lockstep against offline, per field kind (m, N, N m, rad): the same numbers, with the plant
#: node's torque-rate limit opened (OPEN_RATE_LIMIT). With the node's 1 kN m/s limit the runs
#: parted at the guarded approach's contact, where the law asks a torque step the limit clips
#: (up to 1.26 N and 2.31 N m apart; with the impact damping 0.12-0.24 mm in e_y on the UR5);
#: the limit itself is tested with the plant's guards.
LOCKSTEP_TOL = {"e": 1e-9, "f": 1e-6, "tau": 1e-6, "e_rot": 1e-9}
@pytest.mark.ros
@pytest.mark.parametrize("robot,scheme", LOCKSTEP_CASES, ids=[f"{r}-{s}" for r, s in LOCKSTEP_CASES])
def test_lockstep_over_ros_matches_the_offline_loop(robot, scheme, tmp_path):
    """Plant, controller and recorder over ROS in lockstep for 2 s on the robot: the
    recording gives the offline numbers, the plant node's command limits (its 1000 N m/s
    torque-rate limit, which the NN law's learning transient meets: 2.5 N m per ms on the
    Panda) applied in both."""
    from cr_control.analysis.analyze import load_session
    from cr_control.tools.session import Session, SessionConfig

    cfg = SessionConfig(scheme=scheme, duration=LOCKSTEP_S, mode="lockstep", out=tmp_path,
                        domain_id=next_domain(), name="run", robot=robot,
                        overrides=[f"plant.{k}={v}" for k, v in sensor_noise_free(robot).items()])
    s = load_session(Session(cfg, progress=lambda _: None).run().mcap)
    rate = robots.robot(robot).rate_hz
    offline = as_read(s.status, rate, round(LOCKSTEP_S * rate), lambda ages: run_scheme(
        scheme, LOCKSTEP_S, robot=robot, plant_overrides=sensor_noise_free(robot),
        wrench_ages=ages))
    rows = np.rint(s.status["stamp"] * rate).astype(int)
    assert len(rows) > 0.9 * LOCKSTEP_S * rate
    fingers = ["panda_finger_joint1", "panda_finger_joint2"] if robot.startswith("panda") else []
    assert len(s.joint_states.names) == offline.command.shape[1] + len(fingers)
    assert s.joint_states.names[len(s.joint_states.names) - len(fingers):] == fingers
    f_z = s.contact_wrench.force[:, 2]          # the true contact force
    since = LAW_START_S + CONTACT_FROM_S.get(scheme, 0.05)
    assert f_z[s.contact_wrench.time >= since].min() > 0.0
    assert np.all(s.status["held"] == 0.0)
    for field in ("e_x", "e_y", "e_z", "f_z", "tau_1", "tau_4", "e_rot_x"):
        kind = "e_rot" if field.startswith("e_rot") else field.split("_")[0]
        diff = np.abs(s.status[field] - offline.column(field)[rows]).max()
        print(f"{robot} {scheme} {field}: lockstep vs offline {diff:.3g}")
        assert diff < LOCKSTEP_TOL[kind], field
    cmd_rows = np.rint(s.joint_commands.time * rate).astype(int)
    assert np.abs(s.joint_commands.effort - offline.command[cmd_rows]).max() < LOCKSTEP_TOL["tau"]
