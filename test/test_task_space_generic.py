"""The generic task space (any URDF arm): the thesis's arm is its special case, and the
pieces beside the thesis laws (null space, singularities, targets, the force admittance)
do what they claim, with numbers."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from cr_control import robots
from cr_control.core.parameters import ParameterError
from cr_control.models.urdf import load_chain
from cr_control.offline import run, run_scheme
from cr_control.schemes.blocks.task_space import (
    model_force,
    null_space_torque,
    task_dynamics,
    task_frame,
    task_model,
)
from cr_control.schemes.registry import controller_class, make_controller
from cr_sim.plants.registry import make_plant

GOLDEN = json.loads((Path(__file__).parent / "data" / "thesis_task_space_golden.json").read_text())
THESIS_SCHEMES = ("adaptive_impedance", "robust_adaptive_impedance", "nn_adaptive_impedance",
                  "impedance", "fuzzy_unidirectional")


# -- the thesis case is the special case ---------------------------------------------------------
@pytest.mark.parametrize("scheme", THESIS_SCHEMES)
def test_thesis_arm_through_the_generic_path_gives_the_thesis_numbers(scheme):
    """The five schemes on the thesis's 2-link URDF, through the same code as on the Panda,
    give the numbers of the planar implementation they replaced (test/data, recorded at
    dbff71e: e.g. 12.6 mm RMS over 5-10 s for adaptive_impedance) within 1e-6 relative;
    measured: within 1e-14, joint positions equal to the last bit at 1 s intervals."""
    gold = GOLDEN[scheme]
    r = run_scheme(scheme, gold["duration"])
    t = r.time
    late = t >= 5.0
    e = np.hypot(r.column("e_x"), r.column("e_y"))
    f_err = np.hypot(r.column("f_err_x"), r.column("f_err_y"))
    got = {"pos_err_rms_5_10_m": np.sqrt(np.mean(e[late] ** 2)), "pos_err_max_m": e.max(),
           "force_err_rms_5_10_N": np.sqrt(np.mean(f_err[late] ** 2)),
           "torque_peak_Nm": np.abs(r.command).max()}
    for name, value in got.items():
        assert value == pytest.approx(gold[name], rel=1e-6), name
    assert np.allclose(r.position[::1000], gold["q_every_1s"], rtol=1e-6, atol=1e-9)
    assert np.allclose(r.command[::1000], gold["command_every_1s"], rtol=1e-6, atol=1e-9)
    assert r.column("singularity_damping").max() == 0.0     # never damped on the thesis paths


# -- the task-space model on a spatial, redundant arm ------------------------------------------------
@pytest.fixture(scope="module")
def panda():
    r = robots.robot("panda")
    scheme = "adaptive_impedance"
    # the model with gravity (the profile's robot compensates its own: its controllers' have none)
    values = controller_class(scheme).robot_values({**robots.controller_values(r, scheme),
                                                    "robot_compensates_gravity": False})
    model = task_model(values)
    chain = load_chain("", r.urdf_file, r.base_link, r.tip_link, np.array(robots.GRAVITY))
    return model, chain, np.array(r.home)


def _states(home, count=5, seed=0):
    rng = np.random.default_rng(seed)
    return [(home + rng.uniform(-0.3, 0.3, home.size), rng.uniform(-0.5, 0.5, home.size))
            for _ in range(count)]


def test_panda_task_is_3d_position_and_orientation_with_one_spare_joint(panda):
    model, _, _ = panda
    assert (model.n, model.m, model.position_axes, model.orientation_axes) == (7, 3, ("x", "y", "z"),
                                                                                ("x", "y", "z"))
    assert model.redundant


def test_model_force_is_the_task_space_model_3_2(panda):
    """M_r a + C_r v + G_r from the compiled law equals the task-space matrices, and
    J^T (that) + N^T G makes the true joint dynamics accelerate the tip by exactly a."""
    model, chain, home = panda
    data = chain.model.createData()
    rng = np.random.default_rng(1)
    for q, _ in _states(home):
        frame0 = task_frame(model.chain, model.task, 1e12, q, np.zeros(7))
        v = frame0.J_bar @ rng.normal(size=3)       # a velocity of the task (no self-motion)
        frame = task_frame(model.chain, model.task, 1e12, q, v)
        a, v_task = rng.normal(size=3), frame.r_dot
        F = model_force(model.chain, frame, a, v_task)
        M_r, C_r, G_r = task_dynamics(model.chain, frame)
        assert np.allclose(F, M_r @ a + C_r @ v_task + G_r, atol=1e-9)
        N_T = np.eye(7) - frame.J.T @ frame.J_bar.T
        tau = frame.J.T @ F + N_T @ frame.G
        qdd = pin.aba(chain.model, data, q, v, tau)
        assert np.allclose(frame.J @ qdd + frame.J_dot @ v, a, atol=1e-8)


def test_null_space_torque_never_moves_the_position_task(panda):
    """J_bar^T tau_null = 0 (dynamically consistent): orientation, posture and gravity
    beyond the task leave the law's closed loop (3.7) alone."""
    model, _, home = panda
    gains = np.array([30.0, 30.0, 30.0, 3.0, 3.0, 3.0, 10.0, 2.0, 100.0, 0.1, 50.0, 20.0])
    for q, v in _states(home, seed=2):
        frame = task_frame(model.chain, model.task, 100.0, q, v)
        quat_d = np.array([0.0, 1.0, 0.0, 0.0])
        tau, e_o, posture_error = null_space_torque(model.task, gains, frame, quat_d,
                                                    np.zeros(3), home)
        assert np.abs(tau).max() > 1.0
        assert np.abs(frame.J_bar.T @ tau).max() < 1e-9
        assert posture_error > 0.0 and np.linalg.norm(e_o) > 0.0


def test_singularities_cap_the_apparent_mass():
    """Near the stretched-out 2-link arm (theta_2 -> 0) the generalised inverse is damped so
    that no task direction weighs more than singularity_mass; away from it nothing changes
    (the thesis's paths reach 14 kg: never damped at the default 100 kg)."""
    model = task_model(controller_class("adaptive_impedance").robot_values(None))
    for theta_2 in (0.01, 0.05):
        q = np.array([0.7, theta_2])
        undamped = task_frame(model.chain, model.task, 1e12, q, np.zeros(2))
        assert np.linalg.eigvalsh(undamped.Lam).max() > 300.0
        for m_s in (20.0, 100.0):
            frame = task_frame(model.chain, model.task, m_s, q, np.zeros(2))
            assert frame.damping > 0.0
            assert np.linalg.eigvalsh(frame.Lam).max() <= m_s * (1 + 1e-9)
    assert task_frame(model.chain, model.task, 100.0, np.array([3.0, -2.2]), np.zeros(2)).damping == 0.0


# -- targets and the force admittance ---------------------------------------------------------------
def test_target_pose_is_followed_without_a_jump():
    """A target pose switches the thesis path to a critically damped approach: r_d and r_d'
    continue from the path at the switch, and r_d reaches the target (sent once: no
    target_timeout, test/test_contact_guard.py has the timeouts)."""
    plant = make_plant("compliant_plane")
    ctrl = make_controller("adaptive_impedance", {"target_timeout": 0.0})
    refs = []
    for k in range(3000):
        if k == 1000:
            ctrl.set_target_pose(np.array([-0.02, 0.3, 0.0]), np.array([1.0, 0.0, 0.0, 0.0]))
        m = plant.measurement()
        out = ctrl.step(m.time, m.position, m.velocity, m.force)
        refs.append(out.reference.copy())
        plant.step(out.command, 1e-3)
    refs = np.array(refs)
    jump = np.abs(np.diff(refs[:, :4], axis=0)).max(axis=0)
    assert jump[:2].max() < 1e-3 and jump[2:4].max() < 0.02   # r_d, r_d' continuous
    assert np.allclose(refs[-1, :2], [-0.02, 0.3], atol=1e-4)
    assert np.abs(refs[-1, 2:4]).max() < 1e-3


def test_force_admittance_holds_the_desired_force_whatever_the_stiffness():
    """On the chapter 3 plane the thesis law regulates position: the force follows from K_e.
    With the force admittance on the reference the force along f_d settles at |f_d| for a
    soft and a stiff plane alike (measured 7.059 N for 7.071 N at K_e = 150, 1500, 15000)."""
    f_d = [5.0, -5.0]
    n_f = np.array([1.0, -1.0]) / math.sqrt(2)
    for stiffness in (150.0, 1500.0, 15000.0):
        r = run_scheme("adaptive_impedance", 10.0,
                       {"force_admittance_damping": 50.0, "desired_force": f_d,
                        "force_admittance_limit": 0.1},
                       {"stiffness": stiffness})
        late = r.time >= 8.0
        along = r.force[late, :2] @ n_f
        assert abs(along.mean() - math.hypot(*f_d)) < 0.05, stiffness
    off = run_scheme("adaptive_impedance", 10.0, {"desired_force": f_d}, {"stiffness": 1500.0})
    assert abs((off.force[off.time >= 8.0, :2] @ n_f).mean() - math.hypot(*f_d)) > 20.0


def test_force_ramp_starts_from_zero():
    r = run_scheme("impedance", 1.2, {"approach_speed": 0.0}, robot="panda")
    f_d = r.column("f_d_z")
    assert f_d[0] == 0.0 and f_d[-1] == pytest.approx(robots.WIPE_FORCE)
    assert np.all(np.diff(f_d) >= -1e-12)


def test_a_path_ramped_in_starts_from_rest():
    """The robots' circle (r_d' = a w along y at its start) runs on a time whose rate is
    ramped in over reference_ramp_time: r_d' and r_d'' start at 0 and r_d' changes by at most
    (a w^2 + 1.5 a w / T) dt per cycle (no step); from T on r_d is the circle T / 2 later."""
    T, a, w = 1.0, robots.WIPE_RADIUS, robots.WIPE_FREQUENCY
    r = run_scheme("adaptive_impedance", T + 0.5, {"approach_speed": 0.0,
                                                   "reference_ramp_time": T}, robot="panda")
    v = np.column_stack([r.column(f"v_d_{c}") for c in "xy"])
    acc = np.column_stack([r.column(f"a_d_{c}") for c in "xy"])
    assert np.abs(v[0]).max() == 0.0 and np.abs(acc[0]).max() == 0.0
    assert np.abs(np.diff(v, axis=0)).max() < (a * w * w + 1.5 * a * w / T) * 1e-3
    assert np.abs(np.diff(acc, axis=0)).max() < 0.01 * a * w * w
    late = r.time >= T
    tau = r.time[late] - 0.5 * T
    start = np.array([r.column(f"r_d_{c}")[0] for c in "xy"])
    circle = start[:, None] + a * np.array([1.0 - np.cos(w * tau), -np.sin(w * tau)])
    assert np.abs(np.column_stack([r.column(f"r_d_{c}")[late] for c in "xy"])
                  - circle.T).max() < 1e-12
    assert np.abs(np.hypot(*v[late].T) - a * w).max() < 1e-12


# -- joints and refusals ---------------------------------------------------------------------------
def test_joint_names_set_the_command_order():
    """joint_names may permute the chain's joints (a forward_command_controller's order):
    the same torques come out in that order."""
    r = robots.robot("ur5")
    values = robots.controller_values(r, "impedance")
    plant_values = {k: v for k, v in robots.plant_values(r).items() if k != "scenario"}
    chain_order = run(make_controller("impedance", values), make_plant("urdf_surface", plant_values), 0.05)
    names = list(load_chain("", r.urdf_file, r.base_link, r.tip_link).joint_names)
    permuted = names[::-1]
    ctrl = make_controller("impedance", {**values, "joint_names": permuted})
    assert ctrl.values["joint_names"] == permuted
    reordered = run(ctrl, make_plant("urdf_surface", plant_values), 0.05)
    assert np.array_equal(reordered.command, chain_order.command)   # run() maps by name
    m = make_plant("urdf_surface", plant_values).measurement()
    q, v = m.position[:6], m.velocity[:6]
    direct = make_controller("impedance", {**values, "joint_names": permuted}).step(0.0, q, v, m.force)
    fresh = make_controller("impedance", values).step(0.0, q, v, m.force)
    assert np.array_equal(direct.command, fresh.command[::-1])
    with pytest.raises(ParameterError, match="not the chain's joints"):
        make_controller("impedance", {**values, "joint_names": ["a", "b"]})


@pytest.mark.ros
@pytest.mark.parametrize("override,reason", [
    ("urdf_file:=nope.urdf", "urdf_file nope.urdf: no such file"),
    ("tip_link:=nowhere", "tip_link 'nowhere' is not a link of the URDF"),
    ("robot_description:='<robot name=\"x\"><link name=\"a\"/></robot>'",
     "base_link 'base_link' is not a link of the URDF"),
])
def test_controller_refuses_a_bad_robot_in_one_line(ros_env, override, reason):
    proc = subprocess.run([sys.executable, "-m", "cr_control.nodes.controller_node",
                           "adaptive_impedance", "--ros-args", "-p", override],
                          env=ros_env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "RTPS_TRANSPORT_SHM" not in ln]
    assert len(lines) == 1 and lines[0].startswith("adaptive_impedance: refused to start: " + reason), lines
