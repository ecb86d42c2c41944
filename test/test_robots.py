"""The five task-space schemes on the Panda (7 joints) and the UR5 (6), wiping a table
(cr_control.tools.robots): offline and in lockstep over ROS, with numeric bounds.

Measured (offline, 20 s, metrics over the last half; bounds below with their margin):

| robot / scheme | path RMS | force mean | force err RMS | orientation max | posture max |
|---|---|---|---|---|---|
| panda adaptive_impedance | 5.91 mm | 9.979 N | 0.022 N | 0.63 deg | 0.0056 rad |
| panda robust_adaptive_impedance | 5.87 mm | 9.977 N | 0.024 N | 2.72 deg | 0.0087 rad |
| panda nn_adaptive_impedance | 0.095 mm | 10.000 N | 0.0016 N | 1.70 deg | 0.0051 rad |
| panda impedance | 0.020 mm | 9.886 N | 0.114 N | 0.39 deg | 0.0039 rad |
| panda fuzzy_unidirectional | 0.016 mm | 9.858 N | 0.142 N | 0.41 deg | 0.0041 rad |
| ur5 adaptive_impedance | 5.92 mm | 9.979 N | 0.022 N | 0.26 deg | – |
| ur5 robust_adaptive_impedance | 5.82 mm | 9.977 N | 0.024 N | 0.97 deg | – |
| ur5 nn_adaptive_impedance | 0.66 mm | 10.000 N | 0.0030 N | 0.91 deg | – |
| ur5 impedance | 0.011 mm | 9.886 N | 0.114 N | 0.17 deg | – |
| ur5 fuzzy_unidirectional | 0.009 mm | 9.858 N | 0.142 N | 0.17 deg | – |

The chapter 3 laws converge slowly on the path (the thesis's own 12.6 mm at 10 s on its
arm) and hold the force through the force admittance on the reference; the chapter 5 laws
track the path closely and keep f = f_dm K_e/(K_e + k_m) = 9.88 N (impedance; fuzzy: d_m
tuned) by design; the NN law (with the robots' gentler adaptation gains,
cr_control.tools.robots.NN_GAINS), after its learning transient, tracks both closely. The
NN leaves the table while it learns the arm's weight (until 1.23 s on the Panda, 1.09 s on
the UR5, with its 2 s force ramp: robots.NN_FORCE_RAMP_TIME), as its thesis run starts with
a torque peak: contact is checked from 1.5 s on for it, from 0.05 s on (the desired force is
ramped in from 0 N over 1 s, after the guarded approach has found the table) for the others.
The contact-stability monitor never acts in these runs.
No run comes within 0.66 rad of a joint limit.

Issue 24: the robots' sensor is a realistic wrist sensor (0.7 kg tool, a bias of a few
newtons, 0.2 N of noise; cr_control.tools.robots.SENSOR), compensated and zeroed at start
(a 30 ms hold while the bias is averaged: the law's clock starts after it). The force is
judged by the plant's TRUE contact force (never by the sensor's reading). Measured then
(offline, 20 s, last half):

| robot / scheme | path RMS | true force mean | true force err RMS | orientation max |
|---|---|---|---|---|
| panda adaptive_impedance | 6.30 mm | 9.968 N | 0.044 N | 0.69 deg |
| panda robust_adaptive_impedance | 5.91 mm | 9.966 N | 0.048 N | 2.69 deg |
| panda nn_adaptive_impedance | 0.092 mm | 9.991 N | 0.065 N | 1.33 deg |
| panda impedance | 0.255 mm | 9.881 N | 0.126 N | 0.42 deg |
| panda fuzzy_unidirectional | 0.204 mm | 9.852 N | 0.153 N | 0.44 deg |
| ur5 adaptive_impedance | 6.04 mm | 9.969 N | 0.043 N | 0.24 deg |
| ur5 robust_adaptive_impedance | 5.88 mm | 9.967 N | 0.047 N | 0.97 deg |
| ur5 nn_adaptive_impedance | 0.668 mm | 9.991 N | 0.050 N | 0.86 deg |
| ur5 impedance | 0.882 mm | 9.876 N | 0.130 N | 0.15 deg |
| ur5 fuzzy_unidirectional | 0.704 mm | 9.847 N | 0.158 N | 0.15 deg |

Two bounds moved, for a reason found, not to make room: the sensor's 0.2 N of noise on
every axis reaches the chapter 5 laws' in-plane axes (their path error 0.02 -> 0.2-0.9 mm:
PATH_RMS_M 0.1 -> 1.5 mm) and the NN law's force (its error RMS 0.0016 -> 0.05-0.065 N: the
noise it follows and the bias averaged over 30 noisy readings, 0.04 N per axis; 0.01 ->
0.08 N). The lockstep comparison runs the sensor without noise: the laws turn 0.2 N of noise
into torque steps of up to 2.3 N m per ms, beyond the plant node's torque-rate limit (1 N m
per ms) that the offline loop does not have.
"""

import numpy as np
import pytest
from ros_probe import next_domain

from cr_control.models.urdf import load_chain
from cr_control.schemes.blocks.wrist_sensor import ZERO_START_WINDOW_S
from cr_control.tools import robots
from cr_control.tools.offline import run_scheme

CASES = [(r, s) for r in ("panda", "ur5") for s in robots.TASK_SPACE_SCHEMES]
CH3 = ("adaptive_impedance", "robust_adaptive_impedance")
CH5 = ("impedance", "fuzzy_unidirectional")

#: Bounds with margin over the measured values of the module docstring.
PATH_RMS_M = {**dict.fromkeys(CH3, 8e-3), "nn_adaptive_impedance": 1.5e-3,
              **dict.fromkeys(CH5, 1.5e-3)}
FORCE_ERR_RMS_N = {**dict.fromkeys(CH3, 0.05), "nn_adaptive_impedance": 0.08,
                   **dict.fromkeys(CH5, 0.2)}
ORIENTATION_MAX_DEG = {"robust_adaptive_impedance": 4.0,      # its model is 10 % light
                       "nn_adaptive_impedance": 3.0}           # its learning transient
POSTURE_MAX_RAD = 0.02
#: Contact is judged from this long after the law starts (s): after the start-up hold.
LAW_START_S = ZERO_START_WINDOW_S + 1e-3
#: The chapter 5 laws: from 0.1 s (f_d 0.28 N): before, their desired force is below the
#: sensor's 0.2 N noise and the tool just touches (f = 0, "lost", until 62 ms after the law
#: starts on the Panda); the ideal sensor's start transient pressed 1 N by accident.
CONTACT_FROM_S = {"nn_adaptive_impedance": 1.5, **dict.fromkeys(CH5, 0.1)}
#: The lockstep comparison's sensor: without noise (module docstring).
NOISE_FREE = {"ft_noise_std": [0.0, 0.0]}


def metrics(run, robot: str) -> dict[str, float]:
    """What the bounds judge, from an offline run or a recording's columns."""
    t = run.time
    late = t >= t[-1] / 2
    path = np.hypot(run.column("e_x"), run.column("e_y"))
    f_z = run.true_force[:, 2]              # the true contact force
    rot = np.linalg.norm(np.column_stack([run.column(f"e_rot_{a}") for a in "xyz"]), axis=1)
    r = robots.robot(robot)
    limits = load_chain("", r.urdf_file, r.base_link, r.tip_link).limits
    n = len(limits.lower)
    q = run.position[:, :n]
    return {"path_rms": float(np.sqrt(np.mean(path[late] ** 2))),
            "force_err_rms": float(np.sqrt(np.mean((f_z[late] - robots.WIPE_FORCE) ** 2))),
            "orientation_max_deg": float(np.degrees(rot.max())),
            "posture_max": float(run.column("posture_error").max())
            if "posture_error" in run.status_fields else 0.0,
            "limit_margin": float(np.minimum(q - limits.lower, limits.upper - q).min()),
            "torque_max": float(np.abs(run.command).max()),
            "held": float(run.column("held").sum())}


def contact_from(run, scheme: str) -> float:
    """The smallest true normal force once contact must hold (see the module docstring)."""
    since = LAW_START_S + CONTACT_FROM_S.get(scheme, 0.05)
    return float(run.true_force[run.time >= since, 2].min())


@pytest.fixture(scope="module", params=CASES, ids=[f"{r}-{s}" for r, s in CASES])
def wiping(request):
    robot, scheme = request.param
    return robot, scheme, run_scheme(scheme, 20.0, robot=robot)


def test_wiping_holds_the_force_on_the_path(wiping):
    robot, scheme, run = wiping
    m = metrics(run, robot)
    assert m["path_rms"] < PATH_RMS_M[scheme]
    assert m["force_err_rms"] < FORCE_ERR_RMS_N[scheme]
    assert contact_from(run, scheme) > 0.0                     # contact never lost
    assert m["orientation_max_deg"] < ORIENTATION_MAX_DEG.get(scheme, 1.0)
    assert m["posture_max"] < POSTURE_MAX_RAD                   # no drift in the null space
    assert m["limit_margin"] > 0.5                              # no joint limit approached
    assert m["held"] == 0.0 and np.isfinite(run.command).all()
    # the guarded approach finds the table it starts on; the stability monitor stays calm
    assert run.column("approach_phase")[-1] == 2.0
    assert run.column("stiffness_scale").min() == 1.0


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


# -- lockstep over ROS -----------------------------------------------------------------------------
LOCKSTEP_S = 2.0
#: Lockstep against offline. 1e-6 before issue 24; the guarded approach's contact (the
#: reference stops at once) asks a torque step at the plant node's rate limit (1 N m per
#: cycle: r_d' goes from the approach speed to the path's at once), so from then the runs
#: differ slightly (measured: 1.1e-5 m in e_x and 0.018 N in f_z on the Panda; torques up to
#: 0.96 N m apart for a few cycles, ur5 robust_adaptive_impedance). Per field kind: m, N, N m, rad.
#: Lockstep vs offline. The force differs by up to 1.26 N (measured 0.56-1.26 N on the Panda
#: and UR5 chapter 3 laws) since the robots run the wrist sensor with its tool and the guarded
#: approach: at contact the law asks a torque step the plant node's rate limit (1000 N m/s)
#: clips, the offline loop has none; before that merge 0.05 N held. Positions still agree to
#: 1e-4 m; a joint command by up to 2.31 N m (the UR5's, at that contact; 1.5 held before).
LOCKSTEP_TOL = {"e": 1e-4, "f": 2.0, "tau": 3.0, "e_rot": 1e-3}


@pytest.mark.ros
@pytest.mark.parametrize("robot,scheme", CASES, ids=[f"{r}-{s}" for r, s in CASES])
def test_lockstep_over_ros_matches_the_offline_loop(robot, scheme, tmp_path):
    """Plant, controller and recorder over ROS in lockstep for 2 s on the robot: the
    recording gives the offline numbers where the plant node's torque-rate limit (1000 N m/s)
    never acts; the NN law's learning transient asks more (2.5 N m per ms on the Panda), so
    there the node's limit shapes the run and it is judged by the bounds."""
    from cr_control.analysis.analyze import load_session
    from cr_control.tools.session import Session, SessionConfig

    cfg = SessionConfig(scheme=scheme, duration=LOCKSTEP_S, mode="lockstep", out=tmp_path,
                        domain_id=next_domain(), name="run", robot=robot,
                        overrides=["plant.ft_noise_std=[0.0, 0.0]"])
    s = load_session(Session(cfg, progress=lambda _: None).run().mcap)
    offline = run_scheme(scheme, LOCKSTEP_S, robot=robot, plant_overrides=NOISE_FREE)
    rows = np.rint(s.status["stamp"] * 1e3).astype(int)
    assert len(rows) > 0.9 * LOCKSTEP_S * 1000
    fingers = ["panda_finger_joint1", "panda_finger_joint2"] if robot == "panda" else []
    assert len(s.joint_states.names) == offline.command.shape[1] + len(fingers)
    assert s.joint_states.names[len(s.joint_states.names) - len(fingers):] == fingers
    f_z = s.contact_wrench.force[:, 2]          # the true contact force
    since = LAW_START_S + CONTACT_FROM_S.get(scheme, 0.05)
    assert f_z[s.contact_wrench.time >= since].min() > 0.0
    assert np.all(s.status["held"] == 0.0)
    if scheme == "nn_adaptive_impedance":
        print(f"{robot} NN: f_z at the end {f_z[-1]:.3f} N")
        # its 2 s force ramp ends here, the rate limit shaping its learning: 11.81 / 9.38 N
        assert abs(f_z[-1] - robots.WIPE_FORCE) < 2.5
        return
    for field in ("e_x", "e_y", "e_z", "f_z", "tau_1", "tau_4", "e_rot_x"):
        kind = "e_rot" if field.startswith("e_rot") else field.split("_")[0]
        diff = np.abs(s.status[field] - offline.column(field)[rows]).max()
        print(f"{robot} {scheme} {field}: lockstep vs offline {diff:.3g}")
        assert diff < LOCKSTEP_TOL[kind], field
    cmd_rows = np.rint(s.joint_commands.time * 1e3).astype(int)
    assert np.abs(s.joint_commands.effort - offline.command[cmd_rows]).max() < LOCKSTEP_TOL["tau"]
