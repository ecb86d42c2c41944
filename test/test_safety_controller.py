"""Controller robustness: absurd inputs held and recovered from, clamped
integration steps, restored internal state, status reporting the command sent.

Unit tests on the Controller base through a real scheme (no ROS).
"""

import math
import warnings

import numpy as np
import pytest

from cr_control.core.parameters import resolve
from cr_control.schemes.controller import COMMON_PARAMETERS, Controller, ControlOutput, admit_state
from cr_control.schemes.registry import make_controller
from cr_sim.plants.registry import make_plant

PERIOD = 1e-3
#: The largest change of any estimate from one cycle to the next in a clean 5 s run of
#: adaptive_impedance is 0.145; a fault may cost a few cycles' worth of change, no more.
CYCLE_CHANGE = 0.15
ESTIMATES = ["A_hat_11", "A_hat_22", "B_hat_11", "B_hat_22", "c_hat_x", "c_hat_y"]


def value(ctl, out, field):
    return out.status[ctl.status_fields.index(field) - 1]


def run_closed_loop(ctl, plant, steps, stamp_offset=0.0):
    """Step plant and controller ``steps`` times; the last output."""
    out = None
    for _ in range(steps):
        m = plant.measurement()
        out = ctl.step(m.time + stamp_offset, m.position, m.velocity, m.force)
        plant.step(out.command, PERIOD)
    return out


@pytest.fixture
def running():
    """adaptive_impedance on its plant after 0.5 s, numpy warnings turned into errors."""
    ctl, plant = make_controller("adaptive_impedance"), make_plant("compliant_plane")
    held = []
    ctl.log_warning = held.append
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # no numpy warning may escape
        run_closed_loop(ctl, plant, 500)
        yield ctl, plant, held


def estimates(ctl, out):
    return np.array([value(ctl, out, f) for f in ESTIMATES])


@pytest.mark.parametrize("bad", [1e300, -1e300, 1e3])
def test_absurd_position_is_held_and_the_next_good_state_gives_a_fresh_command(running, bad):
    ctl, plant, held = running
    m = plant.measurement()
    good = ctl.step(m.time, m.position, m.velocity, m.force)
    before = estimates(ctl, good)
    out = ctl.step(m.time + PERIOD, np.array([bad, 0.0]), m.velocity, m.force)
    assert value(ctl, out, "held") == 1.0
    assert np.array_equal(out.command, good.command)
    assert held and "absurd" in held[-1]
    plant.step(good.command, PERIOD)
    m = plant.measurement()
    recovered = ctl.step(m.time + PERIOD, m.position, m.velocity, m.force)  # next good state
    assert value(ctl, recovered, "held") == 0.0
    assert np.isfinite(recovered.command).all() and np.isfinite(recovered.status).all()
    assert np.abs(estimates(ctl, recovered) - before).max() < 2 * CYCLE_CHANGE


def test_absurd_velocity_is_held(running):
    ctl, plant, _ = running
    m = plant.measurement()
    out = ctl.step(m.time, m.position, np.array([0.0, 1e6]), m.force)
    assert value(ctl, out, "held") == 1.0


def test_a_one_second_gap_is_not_integrated_as_one_step(running):
    """Found once: A_hat_11 jumped 45 -> 120 over a 1 s gap. Now the gap cycle is held and the
    stepping restarts after it: the integrals advance by one period; only the
    proportional adaptation terms react to the error against a reference that moved on
    by 1 s (measured: 1.1), so no estimate moves by more than 2."""
    ctl, plant, _ = running
    m = plant.measurement()
    before = ctl.step(m.time, m.position, m.velocity, m.force)
    plant.step(before.command, PERIOD)
    m = plant.measurement()
    gap = ctl.step(m.time + 1.0, m.position, m.velocity, m.force)
    assert value(ctl, gap, "held") == 1.0
    after = run_closed_loop(ctl, plant, 1, stamp_offset=1.0)
    assert value(ctl, after, "held") == 0.0
    assert np.abs(estimates(ctl, after) - estimates(ctl, before)).max() < 2.0
    # and the loop keeps working on the shifted clock
    later = run_closed_loop(ctl, plant, 200, stamp_offset=1.0)
    assert value(ctl, later, "held") == 0.0 and np.isfinite(later.command).all()


@pytest.mark.parametrize("jump", [1e6, -5.0])
def test_a_bogus_stamp_is_held_and_recovered_from(running, jump):
    ctl, plant, held = running
    m = plant.measurement()
    before = ctl.step(m.time, m.position, m.velocity, m.force)
    plant.step(before.command, PERIOD)
    m = plant.measurement()
    out = ctl.step(m.time + jump, m.position, m.velocity, m.force)
    assert value(ctl, out, "held") == 1.0
    assert "stamp" in held[-1]
    # Normal stamps again: the first one re-anchors (held), the next is computed.
    outs = [run_closed_loop(ctl, plant, 1) for _ in range(3)]
    assert [value(ctl, o, "held") for o in outs][-1] == 0.0
    assert sum(value(ctl, o, "held") for o in outs) <= 1
    assert np.abs(estimates(ctl, outs[-1]) - estimates(ctl, before)).max() < 4 * CYCLE_CHANGE


def test_integration_steps_are_clamped_to_max_dt():
    seen = []

    class Probe(Integrator):
        def compute(self, t, dt, q, v, force):
            seen.append(dt)
            return super().compute(t, dt, q, v, force)

    ctl = Probe(resolve(Integrator.parameters(), {"max_dt": 0.002, "max_stamp_gap": 0.05}))
    q = np.zeros(2)
    for stamp in (0.0, 0.001, 0.011, 0.0115):
        ctl.step(stamp, q, q, np.zeros(3))
    assert seen == pytest.approx([0.0, 0.001, 0.002, 0.0005])


class Integrator(Controller):
    """A minimal scheme that has adopted ``internal``: integrates q[0]; force[0] = 666
    poisons its state (a stand-in for an estimate blowing up)."""

    scheme = "integrator"

    def __init__(self, values):
        super().__init__(values)
        self.internal = np.array([1.0, 2.0])
        self.integral = self.internal[:1]          # a view, as schemes keep them

    def compute(self, t, dt, q, v, force):
        self.integral += dt * (q[0] + 1.0)
        if force[0] == 666.0:
            self.internal[1] = math.inf
        command = -self.internal.copy()
        status = np.zeros(len(self.status_fields) - 1)
        return ControlOutput(command, np.zeros(len(self.reference_fields) - 1), status)


def test_non_finite_internal_state_is_restored_and_the_controller_recovers():
    ctl = Integrator(resolve(COMMON_PARAMETERS))
    warned = []
    ctl.log_warning = warned.append
    q, f = np.zeros(2), np.zeros(3)
    for k in range(5):
        good = ctl.step(k * PERIOD, q, q, f)
    last_good = ctl.internal.copy()
    view = ctl.integral
    bad = ctl.step(5 * PERIOD, q, q, np.array([666.0, 0.0, 0.0]))
    assert bad.status[ctl.status_fields.index("held") - 1] == 1.0
    assert np.array_equal(bad.command, good.command)
    assert np.array_equal(ctl.internal, last_good) and ctl.integral is view   # in place
    assert ctl.restored_cycles == 1 and "internal state" in warned[-1]
    again = ctl.step(6 * PERIOD, q, q, f)
    assert again.status[ctl.status_fields.index("held") - 1] == 0.0
    assert np.isfinite(ctl.internal).all() and ctl.internal[0] > last_good[0]


def test_non_finite_internal_state_at_the_first_cycle_goes_back_to_the_initial_value():
    ctl = Integrator(resolve(COMMON_PARAMETERS))
    ctl.log_warning = lambda _: None
    out = ctl.step(0.0, np.zeros(2), np.zeros(2), np.array([666.0, 0.0, 0.0]))
    assert out.status[ctl.status_fields.index("held") - 1] == 1.0
    assert list(ctl.internal) == [1.0, 2.0]
    assert list(out.command) == [0.0, 0.0]


def test_status_reports_the_clipped_command():
    ctl = make_controller("adaptive_impedance", {"max_effort": 0.3})
    plant = make_plant("compliant_plane")
    out = run_closed_loop(ctl, plant, 1)
    assert np.abs(out.command).max() == pytest.approx(0.3)
    sent = [value(ctl, out, "tau_1"), value(ctl, out, "tau_2")]
    assert sent == list(out.command)


def test_repeated_faults_are_logged_rate_limited():
    ctl = Integrator(resolve(COMMON_PARAMETERS))
    warned = []
    ctl.log_warning = warned.append
    for k in range(1000):
        ctl.step(k * PERIOD, np.array([math.nan, 0.0]), np.zeros(2), np.zeros(3))
    assert ctl.held_cycles == 1000 and len(warned) == 1


def test_faults_in_a_row_keep_the_last_accepted_output_intact(running):
    """The kernel writes into the spare of two output vectors: cycles refused one after
    another must not overwrite the accepted cycle the held command comes from."""
    ctl, plant, held = running
    m = plant.measurement()
    good = ctl.step(m.time + PERIOD, m.position, m.velocity, m.force)
    kept = (good.command.copy(), good.reference.copy(), good.status.copy())
    compute = ctl.compute

    def poisoned(*args):
        out = compute(*args)
        ctl.internal[0] = np.nan
        return out

    ctl.compute = poisoned
    for k in range(2, 5):
        out = ctl.step(m.time + k * PERIOD, m.position, m.velocity, m.force)
        assert value(ctl, out, "held") == 1.0
        assert np.array_equal(out.command, kept[0])
        assert np.array_equal(good.command, kept[0]) and np.array_equal(good.reference, kept[1])
    assert ctl.restored_cycles == 3
    ctl.compute = compute
    again = ctl.step(m.time + 5 * PERIOD, m.position, m.velocity, m.force)
    assert value(ctl, again, "held") == 0.0 and np.isfinite(again.command).all()


@pytest.mark.parametrize("q, v, force, admitted", [
    ([0.3, 1.2], [0.1, -0.2], [0.0, 5.0, 0.0], True),
    ([60.0, 80.0], [0.0, 0.0], [0.0, 0.0, 0.0], True),       # |q| = 100: on the bound
    ([60.0, 80.1], [0.0, 0.0], [0.0, 0.0, 0.0], False),
    ([0.0, 0.0], [1e200, 1e200], [0.0, 0.0, 0.0], False),    # no overflow warning
    ([0.0, np.nan], [0.0, 0.0], [0.0, 0.0, 0.0], False),
    ([0.0, 0.0], [0.0, 0.0], [0.0, -np.inf, 0.0], False),
    ([0.0, 0.0, 0.0], [0.0, 0.0], [0.0, 0.0, 0.0], False),   # wrong size
    ([0.0, 0.0], [0.0, 0.0], [0.0], False),                 # one force component
])
def test_admit_state_agrees_with_the_stated_rule(q, v, force, admitted):
    """admit_state (compiled) against the rule of Controller.step written out in numpy."""
    q, v, force = (np.array(x, dtype=float) for x in (q, v, force))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert admit_state(2, 100.0, 100.0, 0.5, q, v, force) is admitted
        if q.shape == v.shape == (2,) and force.shape[0] >= 2:
            with np.errstate(over="ignore"):
                rule = bool(np.hypot(*q) <= 100.0 and np.hypot(*v) <= 100.0
                            and np.isfinite(force).all())
            assert rule is admitted
