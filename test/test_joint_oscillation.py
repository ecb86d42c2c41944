"""Detectable: the controller's status reports the command age it sees and the lightest
joint's oscillation; cr_analyze reports both; the contact-stability monitor watches that
joint too (cr_control.schemes.blocks.contact_guard.joint_monitor)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from robot_data import needs_erd

from cr_control import offline, robots
from cr_control.analysis.metrics import lateness_and_oscillation
from cr_control.core import topics
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.registry import make_controller
from cr_sim.plants.registry import make_plant

M, N, T = 3, 7, 1e-3
LIMIT = 2.61            # the Panda's joint 7 (rad/s)


def channel(monitor: bool = True):
    """The guard's gains and state on 3 axes, watching joint 7 (index 6)."""
    g = guard.guard_gains(M).pack({**{p.name: p.default for p in guard.guard_parameters(M)},
                                   "stability_monitor": float(monitor),
                                   "oscillation_joint": 6.0, "oscillation_limit": LIMIT})
    s = np.zeros(guard.guard_state(M).size)
    guard.guard_start(g, s, M)
    return g, s


def drive(g, s, seconds: float, amplitude: float, hz: float, t0: float = 0.0):
    """Joint 7 oscillating at ``amplitude`` x its limit and ``hz``, the others still; the
    (joint_oscillation, joint_scale) series."""
    out = []
    status = np.zeros(guard.GUARD_STATUS_SIZE)
    for k in range(round(seconds / T)):
        v = np.zeros(N)
        v[6] = amplitude * LIMIT * math.sin(2.0 * math.pi * hz * (t0 + k * T))
        guard.joint_monitor(g, s, v, T, M)
        guard.write_status(s, M, status)
        out.append((status[5], status[6]))
    return np.array(out)


def test_a_wrist_oscillation_is_measured_and_scales_the_joint_gains_down_then_back():
    """80 Hz at half the velocity limit (the delay oscillation's kind): joint_oscillation
    reaches 0.333 (0.5 / sqrt 2 = 0.354 less 6 %: the two discrete 5 Hz high-passes at 1 kHz
    and the window's ripple), the joint-space gains fall to stability_stiffness_scale
    (0.2) within 0.1 s; calm, they are back to 1 after MONITOR_CALM_S + restore time (5 s).
    Two events (detected, calm)."""
    g, s = channel()
    shaking = drive(g, s, 0.3, 0.5, 80.0)
    assert shaking[-1, 0] == pytest.approx(0.333, abs=0.01)
    reached = int(np.argmax(shaking[:, 1] <= 0.2 + 1e-9))
    print(f"scale at 0.2 after {reached} ms")
    assert shaking[-1, 1] == pytest.approx(0.2) and 20 <= reached <= 100
    calm = drive(g, s, 6.0, 0.0, 80.0)
    assert calm[-1, 0] < 1e-3 and calm[-1, 1] == 1.0
    assert calm[int(0.4 / T), 1] == pytest.approx(0.2)          # not before calm for 0.5 s
    assert s[guard.guard_state(M).offset("events")] == 2.0


def test_the_wiping_motion_and_a_single_step_are_no_oscillation():
    """A slow motion (1 Hz, at the full velocity limit) and one 0.3 x limit step ring out
    with few sign changes: measured, never acted on."""
    g, s = channel()
    slow = drive(g, s, 2.0, 1.0, 1.0)
    assert slow[:, 1].min() == 1.0 and slow[200:, 0].max() < 0.1
    g, s = channel()
    status = np.zeros(guard.GUARD_STATUS_SIZE)
    for k in range(500):
        v = np.zeros(N)
        v[6] = 0.3 * LIMIT if k >= 100 else 0.0
        guard.joint_monitor(g, s, v, T, M)
    guard.write_status(s, M, status)
    assert status[6] == 1.0


def test_with_the_monitor_off_it_is_measured_only():
    g, s = channel(monitor=False)
    shaking = drive(g, s, 0.3, 0.5, 80.0)
    assert shaking[-1, 0] > 0.3 and shaking[:, 1].min() == 1.0


@needs_erd
def test_every_robot_scheme_reports_it_and_wiping_stays_far_below_the_threshold():
    """The status of every task-space scheme carries joint_oscillation and joint_scale; on
    the Panda's wiping task (the profile's one-cycle delay, 3 s) the wrist stays below 0.01
    of its limit and the monitor never acts. The joint watched is panda_joint7, the
    lightest."""
    for scheme in robots.TASK_SPACE_SCHEMES:
        c = make_controller(scheme, robots.controller_values(robots.robot("panda"), scheme))
        assert {"joint_oscillation", "joint_scale"} <= set(c.status_fields)
        assert c._oscillation_joint == (6, pytest.approx(2.61))
    run = offline.run_scheme("adaptive_impedance", 3.0, robot="panda")
    print(f"joint_oscillation max {run.column('joint_oscillation').max():.4f}")
    assert run.column("joint_oscillation").max() < 0.01
    assert run.column("joint_scale").min() == 1.0


def test_the_command_age_the_controller_sees():
    """The controller node's status carries command_age (topics), the controller's
    gate.age: 1 period when every state is answered, 31 after a state 30 periods late."""
    assert topics.NODE_STATUS_FIELDS[-2] == "command_age"
    ctl, plant = make_controller("adaptive_impedance"), make_plant("compliant_plane")
    ctl.log_error = ctl.log_info = lambda text: None
    ages = []
    for k in range(100):
        m = plant.measurement()
        stamp = m.time + (0.030 if k >= 50 else 0.0)
        plant.step(ctl.step(stamp, m.position, m.velocity, m.force).command, T)
        ages.append(ctl.gate.age)
    assert ages[0] == 0.0 and set(np.round(ages[1:50], 9)) == {1.0}
    assert ages[50] == pytest.approx(31.0) and ages[51] == pytest.approx(1.0)


def test_cr_analyze_reports_both():
    age = np.array([0.0] + [1.0] * 97 + [31.0, 1.0])
    oscillation = np.linspace(0.0, 0.2, 100)
    wrench_age = np.array([-1.0] + [0.0] * 98 + [2.0])
    out = lateness_and_oscillation({"command_age": age, "joint_oscillation": oscillation,
                                    "joint_scale": np.linspace(1.0, 0.2, 100),
                                    "wrench_age_ms": wrench_age})
    assert out["command_age_p50_cycles"] == 1.0 and out["command_age_max_cycles"] == 31.0
    assert out["wrench_age_p50_ms"] == 0.0 and out["wrench_age_max_ms"] == 2.0
    assert out["joint_oscillation_max_of_limit"] == pytest.approx(0.2)
    assert out["joint_oscillation_p99_of_limit"] == pytest.approx(np.percentile(oscillation, 99))
    assert out["joint_scale_min"] == pytest.approx(0.2)
    assert lateness_and_oscillation({}) == {}
