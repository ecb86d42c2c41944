"""The controller side of the wrist force/torque sensor:
compensation f = R_S (F_S - b_F) - m g, the start-up zeroing, ~/zero_ft's offline
equivalent (:meth:`TaskSpaceController.zero_ft`), cr_identify_tool, and the Panda's wiping
task judged by the plant's TRUE contact force (never by the sensor).

Measured (offline, the Panda's wiping task with the robot profile's sensor: 0.7 kg tool,
bias [2, -1.5, 3] N, 0.2 N noise; adaptive_impedance; true normal force, mean over the last
half):
- compensation on (the profile): 6 s: 9.935 N (std 0.036 N; the law's reading 9.945 N);
- sensor frame only (rotation, no tool weight, no bias): 19.92 N (+9.9 N: weight 6.87 N and
  bias 3 N pressed on top); tool weight but no zeroing: 12.96 N (+3 N: the bias);
- compensation off (the sensor's reading taken as the base-frame force): unstable (the S
  frame's z points down: a pressing force reads as pulling): true mean 6.5 N with a standard
  deviation of 35 N, peaks of 293 N, commands stopped at the joint 6 limit.
- cr_identify_tool on the noisy sensor (6 poses, 3 s settle, 1 s average): mass 0.6995 kg
  (-0.07 %), centre of mass 0.05 mm off, bias within 0.008 N and 0.0002 N m; with this
  test's shorter poses (2 s, 0.5 s): 0.089 % and 0.16 mm.
- the compensation's cost: ~3 us per cycle (micro-timing, printed; load average 7 on the
  2-core machine); the Panda's compute p50 33 us without, 38 us with it (offline loop).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from robot_data import needs_erd

from cr_control import offline, robots
from cr_control.core.parameters import ParameterError
from cr_control.schemes.blocks import wrist_sensor as ws
from cr_control.schemes.registry import make_controller
from cr_control.tools import identify_tool
from cr_sim.plants.registry import make_plant

pytestmark = needs_erd

PANDA = robots.robot("panda_ft")
BIAS = robots.SENSOR["ft_bias"]
CONTROLLER = "adaptive_impedance"


def panda_plant(**overrides):
    values = {k: v for k, v in robots.plant_values(PANDA).items() if k != "scenario"}
    return make_plant("urdf_surface", {**values, **overrides})


def panda_controller(**overrides):
    return make_controller(CONTROLLER, {**robots.controller_values(PANDA, CONTROLLER),
                                        **overrides})


#: The profile's controller holding its start pose in free space: no desired force, no
#: force admittance (it would follow the unknown bias, a drift of 0.16 rad/s at the joints).
HOLD = {"reference_amplitude": [0.0] * 3, "reference_offset": [0.0] * 3,
        "desired_force": [0.0] * 3, "force_admittance_damping": 0.0}


# -- the compensation itself ----------------------------------------------------------------------
@pytest.mark.parametrize("offset", [0.0, 0.3, -0.4])
def test_at_rest_out_of_contact_the_compensated_force_is_zero(offset):
    """Noise-free sensor, the profile's bias given as ft_bias: R_S (F_S - b_F) - m g = 0 to
    round-off at poses that turn the sensor's axes (gravity in S changes)."""
    q0 = (np.array(PANDA.home) + offset * np.array([0.3, 0.5, -0.4, 0.2, 0.6, -0.3, 0.8])).tolist()
    plant = panda_plant(surface="none", ft_noise_std=[0.0, 0.0], initial_joint_positions=q0)
    c = panda_controller(ft_bias=BIAS, zero_ft_at_start=False)
    plant.step(plant.gravity_torque(q0), 1e-9)     # held, as a robot is: no acceleration in the reading
    m = plant.measurement()
    f = c.wrist.compensate(0.0, m.position[:7], m.velocity[:7], np.concatenate([m.force, m.torque]))
    assert np.abs(f).max() < 1e-9
    R = ws.frame_rotation(c.model.chain_model, m.position[:7], "panda_link8")
    assert np.allclose(c.wrist.R.reshape(3, 3), R, atol=1e-12)     # compiled = Pinocchio


def test_in_static_contact_it_is_the_contact_force():
    """Pressing: the plant held by a constant command into the table; the compensated force
    equals the plant's true contact force (base frame) to the tool's (tiny) inertial part."""
    plant = panda_plant(ft_noise_std=[0.0, 0.0])
    c = panda_controller(ft_bias=BIAS, zero_ft_at_start=False)
    run = offline.run(c, plant, 2.0)
    law = np.column_stack([run.column(f"f_{a}") for a in "xyz"])
    late = run.time > 1.0
    assert run.true_force[late, 2].min() > 5.0
    assert np.abs(law[late] - run.true_force[late]).max() < 0.05


def test_a_sensor_frame_off_the_tips_body_is_refused_in_one_line():
    with pytest.raises(ParameterError) as refused:
        panda_controller(sensor_frame="panda_link5")
    assert "is not fixed to tip_link" in str(refused.value) and "\n" not in str(refused.value)
    with pytest.raises(ParameterError) as refused:
        panda_controller(sensor_frame="panda_link5", tool_mass=0.0)   # no tool: our own check
    assert "does not ride on tip_link" in str(refused.value) and "\n" not in str(refused.value)
    with pytest.raises(ParameterError, match="not a frame of the URDF"):
        panda_controller(sensor_frame="nope", tool_mass=0.0)


def test_without_a_wrist_sensor_the_force_reaches_the_law_unchanged():
    """The defaults (no sensor frame, tool, bias or zeroing): nothing is compensated."""
    c = make_controller(CONTROLLER, robots.robot_parameters(PANDA))
    assert not c.wrist.active and not c.reads_wrench


def test_compensation_cost_is_printed():
    """Micro-timing of the compiled compensation (printed, not asserted: no wall-clock
    assertions on the shared machine)."""
    c = panda_controller(ft_bias=BIAS, zero_ft_at_start=False)
    q, v, w = np.array(PANDA.home), np.zeros(7), np.array([1.0, 2.0, 9.0, 0.1, 0.2, 0.0])
    out = np.empty(3), np.empty(9), np.empty(6), np.empty(6)
    comp = c.wrist.comp
    ws.compensate_into(c.model.chain, comp, 0.0, q, v, w, out[3], out[1], out[2], out[0])
    for name, call in (("compensate_into (compiled)", lambda: ws.compensate_into(
            c.model.chain, comp, 0.0, q, v, w, out[3], out[1], out[2], out[0])),
            ("WristSensor.compensate (the cycle's call)", lambda: c.wrist.compensate(
                0.0, q, v, w))):
        k = 20000
        start = time.perf_counter()
        for _ in range(k):
            call()
        print(f"{name}: {1e6 * (time.perf_counter() - start) / k:.2f} us per call")


# -- zeroing --------------------------------------------------------------------------------------
def test_zero_ft_finds_the_bias_and_blends_it_in_without_a_jump():
    """The arm held in free space, the controller told no bias; ~/zero_ft at 1.8 s (once the
    law has settled from the bias it reads as a force: 0.013 rad/s at the joints): the bias
    is the simulated one within 0.05 N (0.2 N noise over 200 readings: 0.014 N std), the
    compensated force is then ~0, and the command changes smoothly while it blends in."""
    plant = panda_plant(surface="none")
    c = panda_controller(zero_ft_at_start=False, **HOLD)
    answers = []

    def hook(k, t, controller, _plant):
        if k in (1800, 1820):
            answers.append(controller.zero_ft())

    run = offline.run(c, plant, 2.9, hook=hook)
    assert answers[0][0] and "averaging" in answers[0][1], answers[0][1]
    assert answers[1] == (False, "a zeroing is already under way")
    assert np.abs(c.wrist.bias - BIAS)[:3].max() < 0.05
    assert np.abs(c.wrist.bias - BIAS)[3:].max() < 0.01
    law = np.column_stack([run.column(f"f_{a}") for a in "xyz"])
    before, after = law[(run.time > 1.6) & (run.time < 1.8)], law[run.time > 2.6]
    assert np.linalg.norm(before.mean(axis=0)) > 3.0          # the bias, uncompensated
    assert np.linalg.norm(after.mean(axis=0)) < 0.1         # measured 0.057: noise of the means
    steps = np.abs(np.diff(run.command, axis=0)).max(axis=1)
    blend = (run.time[1:] > 1.99) & (run.time[1:] < 2.6)
    quiet = (run.time[1:] > 1.6) & (run.time[1:] < 1.8)
    print(f"command steps: {steps[quiet].max():.4f} N m before, {steps[blend].max():.4f} N m "
          "while the bias blends in")
    assert steps[blend].max() < 3.0 * steps[quiet].max() + 0.05


def test_zero_ft_refuses_when_it_cannot():
    c = panda_controller(zero_ft_at_start=False)
    assert c.zero_ft() == (False, "no state and wrench yet: nothing to zero")
    plant = panda_plant(surface="none", ft_noise_std=[0.0, 0.0])
    plant.step(plant.gravity_torque(np.array(PANDA.home)), 1e-9)      # held: no acceleration
    m = plant.measurement()
    wrench = np.concatenate([m.force, m.torque])
    moving = np.full(7, 0.1)
    c.step(0.0, m.position[:7], moving, wrench)
    ok, why = c.zero_ft()
    assert not ok and why.startswith("moving: |q'| = 0.265 rad/s")
    # pressing: the bias is known, the compensated force is a contact of 8 N
    c2 = panda_controller(zero_ft_at_start=False, ft_bias=BIAS)
    pressed = wrench.copy()
    c2.step(0.0, m.position[:7], np.zeros(7), wrench)
    R = c2.wrist.R.reshape(3, 3)
    pressed[:3] = wrench[:3] + R.T @ np.array([0.0, 0.0, 8.0])
    c2.step(0.001, m.position[:7], np.zeros(7), pressed)
    ok, why = c2.zero_ft()
    assert not ok and why.startswith("in contact: compensated force 8 N")


def test_start_up_zeroing_holds_the_arm_and_finds_the_bias():
    """zero_ft_at_start (the profile): the arm is held by G(q) for 30 ms, the law then
    starts; the bias found is the simulated one within 0.1 N (30 noisy readings)."""
    plant = panda_plant()
    c = panda_controller()
    run = offline.run(c, plant, 0.2)
    assert c.wrist.law_start == pytest.approx(ws.ZERO_START_WINDOW_S + 1e-3, abs=1.5e-3)
    assert np.abs(c.wrist.bias - BIAS)[:3].max() < 0.1
    held = run.time < c.wrist.law_start
    assert np.abs(run.velocity[held, :7]).max() < 1e-3          # still while averaging
    steps = np.abs(np.diff(run.command, axis=0)).max(axis=1)
    print(f"largest command step over the hold and the blend-in: {steps.max():.3f} N m/ms")


def test_an_activation_after_the_start_does_not_zero_in_contact():
    """A lifecycle activation (Controller.reset) once states were seen: no start-up hold
    or zeroing (the arm may press on something by then), the bias in use is kept."""
    plant = panda_plant()
    c = panda_controller()
    offline.run(c, plant, 0.2)                    # zeroed at start, wiping, in contact
    bias = c.wrist.bias.copy()
    c.reset(keep_time=False)
    assert not c.wrist.holding and not c.wrist.at_start and c.wrist.law_start == 0.0
    offline.run(c, plant, 0.05)
    assert np.array_equal(c.wrist.bias, bias)


# -- the wiping task: true contact force ----------------------------------------------------------
@pytest.fixture(scope="module")
def wiping():
    return {mode: offline.run_scheme(CONTROLLER, 6.0, overrides, robot="panda_ft")
            for mode, overrides in (("on", {}), ("off", {
                "sensor_frame": "", "tool_mass": 0.0, "tool_com": [0.0] * 3,
                "zero_ft_at_start": False}))}


def test_compensated_wiping_holds_the_true_force(wiping):
    """Measured 9.935 N over the last half (the requirement: 10 N +- 1 N)."""
    run = wiping["on"]
    late = run.time >= 3.0
    f = run.true_force[late, 2]
    print(f"compensation on: true normal force {f.mean():.3f} N (std {f.std():.3f}), the "
          f"law's reading {run.column('f_z')[late].mean():.3f} N")
    assert abs(f.mean() - robots.WIPE_FORCE) < 0.15
    assert run.true_force[run.time >= 0.05, 2].min() > 0.0      # contact never lost


def test_without_compensation_the_wiping_fails(wiping):
    """The sensor's reading taken as the base-frame force: before the guarded approach,
    true mean 6.5 N, std 35 N, peaks of 293 N; with it (the robot profiles approach until
    contact), a 209 N peak, then a joint at its limit and the tool off the table (0 N over
    3-6 s). On a robot that compensates its own gravity (the profiles now) the tool's weight
    and the bias read as a contact at once: the law holds the tool where it stands, just
    touching (true force at most 0.31 N, 0 N over 3-6 s). Either way far from the 10 N asked."""
    run = wiping["off"]
    f = run.true_force[run.time >= 3.0, 2]
    print(f"compensation off: true normal force mean {f.mean():.2f} N, std {f.std():.2f} N, "
          f"max {run.true_force[:, 2].max():.1f} N")
    assert abs(f.mean() - robots.WIPE_FORCE) > 5.0


# -- identification -------------------------------------------------------------------------------
def test_least_squares_recovers_an_exact_tool():
    rng = np.random.default_rng(3)
    mass, com, bias = 1.3, np.array([0.02, -0.01, 0.08]), rng.normal(size=6)
    g = np.array([9.81 * d / np.linalg.norm(d) for d in rng.normal(size=(5, 3))])
    w = np.array([np.concatenate([mass * gi + bias[:3], np.cross(com, mass * gi) + bias[3:]])
                  for gi in g])
    est = identify_tool.estimate(g, w)
    assert est.mass == pytest.approx(mass, abs=1e-12)
    assert np.allclose(est.com, com, atol=1e-12) and np.allclose(est.bias, bias, atol=1e-12)
    with pytest.raises(ValueError, match="span less than 3"):
        identify_tool.estimate(np.tile([0.0, 0.0, 9.81], (4, 1)), np.zeros((4, 6)))


def test_identification_on_the_noisy_simulated_sensor():
    """Requirement: mass within 2 %, centre of mass within 5 mm on the noisy sensor. Shorter
    poses than the tool's defaults (2 s settle, 0.5 s average) to keep the test short;
    measured here: printed."""
    est, truth = identify_tool.identify_in_simulator("panda_ft", 2.0, 0.5)
    mass_err = abs(est.mass - truth["tool_mass"]) / truth["tool_mass"]
    com_err = float(np.linalg.norm(est.com - np.array(truth["tool_com"])))
    print(f"identified: mass {100 * mass_err:.3f} % off, com {1e3 * com_err:.3f} mm off, "
          f"bias {np.abs(est.bias - truth['ft_bias']).max():.4f} off")
    assert mass_err < 0.005 and com_err < 1e-3
    assert np.abs(est.bias - np.array(truth["ft_bias"]))[:3].max() < 0.05


def test_cr_identify_tool_refuses_bad_input_in_one_line(capsys, tmp_path):
    assert identify_tool.main(["--robot", "nope", "--out", str(tmp_path / "t.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cr_identify_tool: unknown robot 'nope'") and err.count("\n") == 1
    assert identify_tool.main(["--average", "0", "--out", str(tmp_path / "t.yaml")]) == 2
    assert "--average" in capsys.readouterr().err


def test_the_params_file_is_a_ros_params_file_the_controller_takes():
    from cr_control.core import ros_yaml

    est = identify_tool.ToolEstimate(0.7, np.array([0.0, 0.001, 0.06]), np.arange(6.0), 0.01,
                                     0.001)
    text = identify_tool.params_file(CONTROLLER, "panda_link8", est, "test")
    values = ros_yaml.load(text)[CONTROLLER]["ros__parameters"]
    c = panda_controller(**values)
    assert c.wrist.mass == pytest.approx(0.7) and math.isclose(c.values["ft_bias"][5], 5.0)
