"""The five task-space laws on arms that take joint positions or velocities, through the
admittance outer loop (cr_control.schemes.blocks.admittance_outer_loop), offline on the
position- and velocity-interface profiles (cr_control.robots: ur5_position, ur5_velocity,
panda_position, xarm7; the plant cr_sim.plants.joint_servo, with the profiles' transport
delay and the plant node's command limits).

Checked: a task-space law on a position interface is the law inside the loop (its own
parameters, status and targets, the loop's after them); wiping the default table (mu = 0.3),
judged by the plant's TRUE normal force and the REAL tip's path over the second half of a 6 s
run: force error RMS <= 0.5 N and radial path RMS <= 3 mm (what does not hold yet is marked
xfail with the measured figure); a 30 kN/m table held after the guarded approach (peak <= 1.5 x
the target, no contact lost); the command stream inside the joints' velocity, acceleration
and (Panda) jerk limits; a law that gives up brakes through a command that decelerates to
rest at the acceleration limit; a robot that does not move (its own stop) keeps the command
within max_lead of it; over a minute of wiping nothing drifts (the circle's centre within
1 mm); a live 10x step of a stiffness or damping moves the next commands by at most 1 mm at
the tip and the force by at most 20 % of the target.

Measured (offline, 6 s, default table, with the plant node's limits; force error RMS N /
radial RMS mm):

| scheme | ur5_position | panda_position | xarm7 |
|---|---|---|---|
| adaptive_impedance | 0.064 / 0.07 | 0.040 / 0.42 | 0.142 / 0.37 |
| robust_adaptive_impedance | 0.065 / 0.06 | 0.041 / 0.42 | 0.143 / 0.37 |
| nn_adaptive_impedance | 0.064 / 0.05 | 0.041 / 0.42 | 0.143 / 0.37 |
| impedance | 0.213 / 0.08 | 0.204 / 0.43 | 0.103 / 0.37 |
| fuzzy_unidirectional | 0.213 / 0.08 | 0.204 / 0.43 | 0.103 / 0.37 |

The xArm answers at 150 Hz: its 6.7 ms cycle is integrated whole (max_dt defaults to two
control periods where that is longer than 5 ms). With the 5 ms default every cycle was cut
to 5 ms, the virtual arm ran 25 % slower than the stamps the law's reference follows, and
the chapter 3 laws' circle came out 39.5 mm for 50 (radial RMS 12.12, 12.06 and 5.10 mm; the
tool's tilt was 6 mrad, the orientation error 0.5 mrad RMS: the wrist's orientation damping
bound, 0.146 N m s/rad, was not the cause).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from lockstep_replay import as_read
from robot_data import needs_erd

from cr_control import offline, robots
from cr_control.core.parameters import ParameterError
from cr_control.experiments.wiping import Case, run_case
from cr_control.schemes.blocks.admittance_outer_loop import AdmittanceOuterLoop
from cr_control.schemes.registry import make_controller

pytestmark = needs_erd

PROFILES = ("ur5_position", "panda_position", "xarm7")
CASES = [(r, s) for r in PROFILES for s in robots.TASK_SPACE_SCHEMES]
FORCE_ERR_RMS_N = 0.5
RADIAL_RMS_M = 3e-3
#: What does not hold yet (module docstring): case -> measured radial RMS (mm, 6 s).
OPEN: dict[tuple[str, str], float] = {}


def marks(case):
    if case in OPEN:
        return [pytest.mark.xfail(strict=True, reason=f"radial path RMS {OPEN[case]} mm on the "
                                  "xArm (module docstring)")]
    return []


def test_a_law_on_a_position_interface_is_the_law_inside_the_loop():
    r = robots.robot("ur5_position")
    values = robots.controller_values(r, "impedance")
    loop = make_controller("impedance", values)
    assert isinstance(loop, AdmittanceOuterLoop) and loop.command_interface == "position"
    assert type(loop.law).__name__ == "ImpedanceController"
    assert loop.law.values["robot_compensates_gravity"]            # the virtual arm: none
    assert loop.law.values["command_interface"] == "effort"
    assert loop.status_fields[:len(loop.law.status_fields)] == loop.law.status_fields
    assert loop.status_fields[-2:] == ["virtual_lead", "command_clipped"]
    assert loop.reference_fields == loop.law.reference_fields and loop.TASK_SPACE
    effort = make_controller("impedance", robots.controller_values(robots.robot("ur5"), "impedance"))
    assert not isinstance(effort, AdmittanceOuterLoop) and effort.command_interface == "effort"
    # a live gain reaches the law; the loop's own gains stay its own
    assert loop.check_parameter("d_m", 200.0) is None
    loop.set_parameter("d_m", 200.0)
    assert loop.law.values["d_m"] == 200.0 and loop.values["d_m"] == 200.0
    loop.set_parameter("ik_damping", 0.02)
    assert loop._ik_damping == 0.02 and "ik_damping" not in loop.law.values
    assert loop.set_target_wrench(np.array([0.0, 0.0, 5.0]))


def test_each_state_of_a_slow_driver_is_integrated_whole():
    """max_dt covers the driver's period: the xArm's 150 Hz (6.7 ms) takes 2 periods by
    default, a max_dt below the period is refused at start and live (with 5 ms every cycle
    was cut to 5 ms: the virtual arm ran 25 % slower than the stamps the law's reference
    follows, and the chapter 3 laws' circle came out 39.5 mm for 50, radial RMS 12.1 mm);
    the 500 Hz and 1 kHz profiles keep 5 ms."""
    values = robots.controller_values(robots.robot("xarm7"), "adaptive_impedance")
    loop = make_controller("adaptive_impedance", values)
    assert loop.values["max_dt"] == pytest.approx(2.0 / 150.0)
    assert loop.law.values["max_dt"] == loop.values["max_dt"]
    assert "shorter than control_period" in loop.check_parameter("max_dt", 0.005)
    assert loop.check_parameter("max_dt", 0.007) is None
    with pytest.raises(ParameterError, match="shorter than control_period"):
        make_controller("adaptive_impedance", {**values, "max_dt": 0.005})
    for robot in ("ur5", "ur5_position", "panda", "panda_position"):
        r = robots.robot(robot)
        assert make_controller("impedance", robots.controller_values(r, "impedance")).values[
            "max_dt"] == 0.005


@pytest.mark.parametrize("robot,scheme", [pytest.param(*c, marks=marks(c)) for c in CASES],
                         ids=[f"{r}-{s}" for r, s in CASES])
def test_wiping_through_the_outer_loop(robot, scheme):
    values, errors = run_case(Case(scheme, robot, duration=6.0, node_limits=True))
    print(f"\n{robot} {scheme}: force error RMS {values['force_err_rms_N']:.3f} N, radial "
          f"{values['radial_rms_m'] * 1e3:.2f} mm, peak {values['force_peak_N']:.2f} N")
    assert not errors and values["safe_stop_reason"] == 0.0 and values["gave_up"] == 0.0
    assert values["contact_lost_s"] == 0.0
    assert values["force_err_rms_N"] <= FORCE_ERR_RMS_N
    assert values["radial_rms_m"] <= RADIAL_RMS_M


#: Item of the stiff table: 30 kN/m, the tool started 1 cm above it (the guarded approach at
#: the profiles' 5 mm/s).
STIFF = (("stiffness", 30000.0), ("start_clearance", 0.01))
STIFF_CASES = [(r, s) for r in PROFILES for s in ("impedance", "adaptive_impedance",
                                                    "robust_adaptive_impedance",
                                                    "nn_adaptive_impedance")]


@pytest.mark.parametrize("robot,scheme", STIFF_CASES, ids=[f"{r}-{s}" for r, s in STIFF_CASES])
def test_a_stiff_table_is_held_after_the_guarded_approach(robot, scheme):
    """30 kN/m (where peers' position arms bounce): after the first touch the tool never
    leaves the table and the force peaks at most 1.5 x the 10 N target. Measured (6 s):
    peaks 10.2-14.1 N (the UR5's chapter 3 laws 13.8-14.1 N; the xArm's 10.4-10.5 N with its
    force admittance damping of 300 N s/m, 14.8-15.4 N at 150), force error RMS 0.15-0.83 N,
    no contact lost (at 15 mm/s: 14-64 ms lost). The outer loop's damping ratio there: the
    chapter 5 impedance's d_m / (2 sqrt(m_m (k_m + K))) = 150 / (2 sqrt(4 x 30060)) = 0.22;
    the chapter 3 laws' reference model (3.8), A_m / (2 sqrt(B_m)) = 20 / (2 sqrt(400)) = 0.5."""
    values, errors = run_case(Case(scheme, robot, duration=6.0, plant=STIFF))
    print(f"\n{robot} {scheme} 30 kN/m: peak {values['force_peak_N']:.2f} N, lost "
          f"{values['contact_lost_s']:.3f} s, RMS {values['force_err_rms_N']:.3f} N")
    assert not errors and values["safe_stop_reason"] == 0.0
    assert values["contact_lost_s"] == 0.0
    assert values["force_peak_N"] <= 1.5 * robots.WIPE_FORCE


def position_chatter_case(monitor: bool) -> tuple:
    """config/panda_position_stiff_table.yaml offline, with the plant node's command limits
    and the profile's delay (a lockstep session's); (run, the controller's error lines)."""
    from cr_control.tools.session import _load_params_file, config_file
    params = _load_params_file(config_file("panda_position_stiff_table.yaml"))
    robot, scheme = "panda_position", "adaptive_impedance"
    plant = params["plant"]
    controller, p = offline.build_scheme(
        scheme, {**params[scheme], "stability_monitor": monitor}, plant, robot)
    errors: list[str] = []
    controller.log_error = errors.append
    controller.log_warning = controller.log_info = lambda message: None
    period = offline.robot_period(robot)
    run = offline.run(controller, p, 6.0, period, None, True,
                      offline.build.node_limiter(p, scheme, robot, plant, period),
                      offline.build.node_delay(scheme, robot, plant))
    return run, errors


def test_the_position_chatter_case_holds_with_the_monitor_and_is_stopped_without():
    """config/panda_position_stiff_table.yaml (1e5 N/m, stiff gains, Franka's estimated
    wrench): with the monitor it reacts within the first second and the force holds 10 N
    (measured: 9.1 N at 1 s, settled by 1.5 s; every half second from 1.5 to 4 s 0.06-0.08 N
    RMS about a mean within 0.1 N of 10 N; contact never lost from 1 s on, though as the
    stiffness comes back the chatter returns at ~4.5 s and dips the force to 5.6 N before the
    monitor reacts again);
    without it the tool bounces (contact lost in every bounce) and the start check stops it
    at 0.50 s naming the chatter (behind the position servo the tip is never 0.15 m/s off its
    reference: the speed check alone let it bounce at 5.8-6.1 N RMS for 10 s)."""
    on, on_errors = position_chatter_case(True)
    off, off_errors = position_chatter_case(False)
    f_on = on.true_force[:, 2]
    assert not on_errors and on.safe_stop_reason == 0
    assert on.time[np.argmax(on.column("stiffness_scale") < 1.0)] < 1.0
    for start in np.arange(1.5, 4.0, 0.5):
        w = (on.time >= start) & (on.time < start + 0.5)
        assert f_on[w].std() < 0.2 and abs(f_on[w].mean() - robots.WIPE_FORCE) < 0.5, start
    assert f_on[on.time >= 1.0].min() > 0.0
    assert off.column("stiffness_scale").min() == 1.0 and off.safe_stop_reason == 0
    assert (off.true_force[(off.time > 0.2) & (off.time < 0.5), 2] <= 0.0).any()   # it bounced
    assert len(off_errors) == 1 and "the contact force oscillates" in off_errors[0], off_errors
    assert "stability_monitor off" in off_errors[0]
    assert off.true_force[off.time >= 4.0, 2].mean() < 1.0       # stopped: no task left


def limits_of(robot: str, controller) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r = robots.robot(robot)
    n = len(controller.state_joint_names)
    v = controller.chain_model.limits.velocity
    a = np.broadcast_to(np.array(r.acceleration_limit, dtype=float), (n,))
    j = (np.broadcast_to(np.array(r.jerk_limit, dtype=float), (n,)) if r.jerk_limit
         else np.full(n, np.inf))
    return v, a, j


@pytest.mark.parametrize("robot", ["panda_position", "ur5_velocity"])
def test_the_command_stream_stays_inside_the_limits_and_the_brake_decelerates_to_rest(robot):
    """Mid-wipe the law gives up (as after a failed start check): the loop's brake, from the
    last command at the acceleration limits, one factor on every joint, then held."""
    gave_up_at = 3.0

    def give_up(k, t, controller, plant):
        if t >= gave_up_at and not controller.gave_up:
            controller.give_up("test: the law gives up")

    run = offline.run_scheme("impedance", 4.5, robot=robot, hook=give_up)
    controller, _ = offline.build_scheme("impedance", robot=robot)
    period = offline.robot_period(robot)
    v_lim, a_lim, j_lim = limits_of(robot, controller)
    velocity = robot.endswith("velocity")
    # the command's velocity at each cycle (a position stream: its finite difference)
    v = run.command.copy() if velocity else np.vstack([np.zeros(len(v_lim)),
                                                        np.diff(run.command, axis=0) / period])
    a = np.diff(v, axis=0) / period
    assert np.all(np.abs(v) <= v_lim * (1 + 1e-9))
    assert np.all(np.abs(a[1:]) <= a_lim * (1 + 1e-6))
    if np.all(np.isfinite(j_lim)):
        assert np.all(np.abs(np.diff(a[1:], axis=0)) / period <= j_lim * (1 + 1e-6))
    speed = np.max(np.abs(v[run.time >= gave_up_at + period]), axis=1)
    assert speed[0] > 1e-3                                          # it was moving
    assert speed[-1] < 1e-9 and np.all(np.diff(speed) <= 1e-9)      # down to rest, never up
    assert np.max(np.abs(run.velocity[-1, :len(v_lim)])) < 2e-3      # the robot at rest too


def test_a_robot_that_does_not_follow_keeps_the_command_within_max_lead():
    """The robot stands still (its own stop): the measured joints never move while the law
    wipes; the command stays within max_lead of them (the virtual arm drawn back), so a
    robot that resumes is not sent a far pose."""
    controller, plant = offline.build_scheme("adaptive_impedance", robot="ur5_position")
    m = plant.measurement()
    n = len(controller.state_joint_names)
    q, v = m.position[:n].copy(), np.zeros(n)
    period = offline.robot_period("ur5_position")
    J = plant.tip_jacobian(q)
    leads = []
    for k in range(2000):
        out = controller.step(k * period, q, v, np.concatenate([m.force, m.torque]))
        dq = out.command - q
        leads.append(float(np.linalg.norm(J @ dq)))
    assert max(leads) <= controller.values["max_lead"] * 1.05
    assert np.isfinite(leads).all()


@pytest.mark.parametrize("robot,scheme", [("ur5_position", "impedance"),
                                          ("panda_position", "nn_adaptive_impedance"),
                                          ("xarm7", "impedance"),
                                          ("ur5_velocity", "robust_adaptive_impedance")])
def test_nothing_drifts_over_a_minute_of_wiping(robot, scheme):
    """60 s of wiping: the real circle's centre, fitted over 5 s windows, stays within 1 mm of
    where it was at 5-10 s (anchoring to the measured joints every cycle: nothing is integrated
    from joint increments). Measured: at most 0.078 mm (the xArm's impedance 0.077 mm, with the
    gains within the discrete-time bounds; 116 mm before them); the tool's height within 1 um."""
    from cr_control.experiments.wiping import circle_fit

    run = offline.run_scheme(scheme, 60.0, robot=robot)
    controller, _ = offline.build_scheme(scheme, robot=robot)
    tip = controller.tip_positions(run.position[::5, :len(controller.state_joint_names)])
    t = run.time[::5]
    centres = np.array([circle_fit(tip[(t >= a) & (t < a + 5.0), :2])[0]
                        for a in (5.0, 15.0, 25.0, 35.0, 45.0, 55.0)])
    drift = np.linalg.norm(centres - centres[0], axis=1)
    print(f"\n{robot} {scheme}: centre drift {np.round(drift * 1e3, 3)} mm")
    assert drift.max() <= 1e-3 and run.safe_stop_reason == 0


#: The live gain steps (x10 at t = 4 s) and the laws they belong to.
GAIN_STEPS = [("impedance", name) for name in ("k_m", "d_m", "tangential_stiffness",
                                               "tangential_damping", "orientation_stiffness",
                                               "posture_stiffness")] + [
    ("adaptive_impedance", "force_admittance_damping"), ("fuzzy_unidirectional", "d_med")]
#: Steps smaller than x10: x10 is beyond the gain's discrete-time bound and refused
#: (force_admittance_damping 1500 N s/m on m_a = 1 kg at the virtual arm's 1 ms: d_a T / m_a
#: = 1.5 > 1, the rule's pure damping loop with gain margin 2; cr_control/schemes/blocks/
#: gain_bounds.py).
STEP = {"force_admittance_damping": 6.0}


@pytest.fixture(scope="module")
def unchanged():
    """The runs without a gain step (5 s, ur5_position), per scheme."""
    return {scheme: offline.run_scheme(scheme, 5.0, robot="ur5_position")
            for scheme in {scheme for scheme, _ in GAIN_STEPS}}


@pytest.mark.parametrize("scheme,name", GAIN_STEPS, ids=[f"{s}-{n}" for s, n in GAIN_STEPS])
def test_a_tenfold_gain_step_moves_the_command_little(unchanged, scheme, name):
    """A parameter set 10x its value while wiping (as ros2 param set does; the node asks
    check_parameter first): the next commands' tip within 1 mm of the unchanged run's, the
    true force within 20 % of the 10 N target of it. Measured on ur5_position: at most 0.072
    mm (tangential_stiffness) and 1.40 N (k_m: the impedance's own new equilibrium)."""
    robot = "ur5_position"
    period = offline.robot_period(robot)
    at = int(round(4.0 / period))
    controller, _ = offline.build_scheme(scheme, robot=robot)
    value = controller.values[name]
    factor = STEP.get(name, 10.0)
    tenfold = (np.asarray(value, dtype=float) * factor).tolist() if np.ndim(value) else value * factor
    refused: list[str] = []

    def step_gain(k, t, c, plant):
        if k == at:
            why = c.check_parameter(name, tenfold)
            if why:
                refused.append(why)
            else:
                c.set_parameter(name, tenfold)

    run = offline.run_scheme(scheme, 5.0, robot=robot, hook=step_gain)
    base = unchanged[scheme]
    n = len(controller.state_joint_names)
    tips = [controller.tip_positions(r.command[at - 1:at + 3, :n]) for r in (run, base)]
    jump = float(np.linalg.norm(tips[0] - tips[1], axis=1).max())
    force = float(np.abs(run.true_force[at:, 2] - base.true_force[at:, 2]).max())
    print(f"\n{scheme} {name} x10{' (refused)' if refused else ''}: command tip {jump * 1e3:.4f} "
          f"mm, force {force:.2f} N")
    assert not refused and run.safe_stop_reason == 0
    assert jump <= 1e-3 and force <= 0.2 * robots.WIPE_FORCE


@pytest.mark.ros
@pytest.mark.parametrize("robot,scheme", [("ur5_position", "adaptive_impedance"),
                                          ("ur5_velocity", "impedance")])
def test_lockstep_over_ros_matches_the_offline_loop(robot, scheme, tmp_path):
    """Plant (joint_servo), controller (the law in the outer loop) and recorder over ROS in
    lockstep for 2 s: the commands (JointState positions or velocities) and the law's status
    are the offline loop's."""
    from ros_probe import next_domain

    from cr_control.analysis.analyze import load_session
    from cr_control.tools.session import Session, SessionConfig

    duration = 2.0
    cfg = SessionConfig(scheme=scheme, duration=duration, mode="lockstep", out=tmp_path,
                        domain_id=next_domain(), name="run", robot=robot,
                        overrides=["plant.ft_noise_std=[0.0, 0.0]"])
    s = load_session(Session(cfg, progress=lambda _: None).run().mcap)
    rate = robots.robot(robot).rate_hz
    run = as_read(s.status, rate, round(duration * rate), lambda ages: offline.run_scheme(
        scheme, duration, robot=robot, plant_overrides={"ft_noise_std": [0.0, 0.0]},
        wrench_ages=ages))
    rows = np.rint(s.status["stamp"] * rate).astype(int)
    assert len(rows) > 0.9 * duration * rate and np.all(s.status["held"] == 0.0)
    for field in ("e_x", "e_z", "f_z", "tau_2", "q_c_2", "virtual_lead"):
        diff = np.abs(s.status[field] - run.column(field)[rows]).max()
        print(f"{robot} {scheme} {field}: lockstep vs offline {diff:.3g}")
        assert diff < 1e-6, field
    cmd_rows = np.rint(s.joint_commands.time * rate).astype(int)
    sent = s.joint_commands.velocity if robot.endswith("velocity") else s.joint_commands.position
    assert np.abs(sent - run.command[cmd_rows]).max() < 1e-9
    assert s.contact_wrench.force[s.contact_wrench.time >= 0.5, 2].min() > 0.0


@pytest.mark.parametrize("hostile", ["law_1e300", "law_nan", "far_target", "absurd_gain"])
def test_hostile_inputs_never_make_the_command_jump(hostile):
    """A law that answers 1e300 or NaN for 0.2 s, a target pose 10 m away, a stiffness 1e4x
    (refused, or taken): the commanded positions never move by more than one cycle of the
    joint's velocity limit, stay finite, and no reflex is needed."""
    robot = "ur5_position"
    period = offline.robot_period(robot)
    controller, _ = offline.build_scheme("impedance", robot=robot)
    v_lim = controller.chain_model.limits.velocity

    def hook(k, t, c, plant):
        if hostile == "far_target" and k == 1500:
            c.set_target_pose(np.array([10.0, 0.0, 10.0]), np.array([1.0, 0.0, 0.0, 0.0]))
        if hostile == "absurd_gain" and k == 1500 and c.check_parameter("k_m", 6e5) is None:
            c.set_parameter("k_m", 6e5)
        if hostile.startswith("law_") and k == 1500:
            law = c.law
            compute = law.compute
            bad = 1e300 if hostile == "law_1e300" else math.nan

            calls = []

            def broken(t_, dt, q, v, f):
                out = compute(t_, dt, q, v, f)
                calls.append(t_)
                if len(calls) <= 100:
                    out.command[:] = bad
                return out
            law.compute = broken

    run = offline.run_scheme("impedance", 4.0, robot=robot, hook=hook)
    step = np.abs(np.diff(run.command, axis=0))
    assert np.isfinite(run.command).all()
    assert np.all(step <= v_lim * period * (1 + 1e-9))
    assert run.safe_stop_reason == 0
    if hostile == "law_1e300":            # the virtual arm flung: the limits held the stream
        assert run.column("command_clipped").max() > 0
