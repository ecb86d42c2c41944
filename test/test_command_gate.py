"""The give-up and resume rule (cr_control.schemes.command_gate): hysteretic, so a law never
alternates between braking and commanding every few cycles; while stopped it integrates
nothing and its clock stands. Scripted stamps, no plant needed for the rule itself."""

from __future__ import annotations

import numpy as np
import pytest

from cr_control.schemes import command_gate as cg
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.registry import make_controller
from cr_sim.plants.registry import make_plant

T = 1e-3


def decisions(gate: cg.CommandGate, steps: list[tuple[float, int]]) -> list[int]:
    """Feed (stamp step in periods, the law's bad-cycle run) pairs; the events."""
    stamp, events = 0.0, []
    gate.stamp(stamp)
    for periods, run in steps:
        stamp += periods * T
        gate.stamp(stamp)
        events.append(gate.cycle(run))
    return events


def test_late_bursts_give_up_once_and_resume_once():
    """100 fresh cycles; then late answers in bursts (a state 30 periods after the last, then
    49 fresh ones, ten times over); then fresh states. One stop (at the first late state),
    no resume while the bursts come back within RESUME_CYCLES, one resume exactly
    RESUME_CYCLES fresh cycles after the last late one."""
    steps = [(1, 0)] * 100 + ([(30, 0)] + [(1, 0)] * 49) * 10 + [(1, 0)] * 300
    gate = cg.CommandGate(50)
    events = decisions(gate, steps)
    happened = [(k, e) for k, e in enumerate(events) if e != cg.NONE]
    last_late = 100 + 9 * 50
    assert happened == [(100, cg.STOP_LATE), (last_late + cg.RESUME_CYCLES, cg.RESUME)]
    assert gate.late_states == 10 and gate.max_age == pytest.approx(30.0)
    assert gate.period == pytest.approx(T)


def test_a_law_saturating_on_and_off_stops_once_not_every_70_ms():
    """The flail as it was seen: the law saturated for 51 cycles, was good for 19, saturated
    again... The old rule (stop above max_bad_cycles, resume at the first good output)
    alternated every 70 cycles; this one stops once and resumes once the output has been
    good for RESUME_CYCLES cycles in a row."""
    pattern = [(1, k) for k in range(1, 52)] + [(1, 0)] * 19
    steps = pattern * 10 + [(1, 0)] * 250
    events = decisions(cg.CommandGate(50), steps)
    happened = [(k, e) for k, e in enumerate(events) if e != cg.NONE]
    last_bad = 9 * 70 + 50
    assert happened == [(50, cg.STOP_BAD), (last_bad + cg.RESUME_CYCLES, cg.RESUME)]
    old = []                                   # the rule before, on the same pattern
    commanding = True
    for _, run in steps:
        if run > 50 and commanding:
            commanding = False
            old.append("stop")
        elif run == 0 and not commanding:
            commanding = True
            old.append("resume")
    assert old.count("stop") == 10 and old.count("resume") == 10


def test_ages_between_fresh_and_late_neither_stop_nor_resume():
    """The hysteresis in the age: 5 periods (between FRESH_STATE_CYCLES 2 and
    LATE_STATE_CYCLES 10) stops nothing while commanding, and resets the fresh run while
    stopped."""
    gate = cg.CommandGate(50)
    assert set(decisions(gate, [(1, 0)] * 10 + [(5, 0)] * 100)) == {cg.NONE}
    gate.stop()
    events = decisions(gate, ([(1, 0)] * 150 + [(5, 0)]) * 3 + [(1, 0)] * cg.RESUME_CYCLES)
    assert events.count(cg.RESUME) == 1 and events[-1] == cg.RESUME


def integrators(ctl) -> np.ndarray:
    """What adaptive_impedance integrates: its reference's state (filters, admittance,
    guard) and the adaptation's reference model and integrals (3.8, 3.11-3.14); the
    estimates A_hat, B_hat, c_hat also have parts proportional to the measured error."""
    law = ctl.internal[ctl.reference_state.size:]
    x_m, integrals = impedance.state_views(law, 2)[:2]
    return np.concatenate([ctl.internal[:ctl.reference_state.size], x_m, integrals.ravel()])


def test_the_controller_brakes_once_on_a_late_state_holds_its_law_and_its_clock():
    """adaptive_impedance on its thesis plant, settled 1 s; then a state 30 ms late: one
    error line, the brake; what the law integrates does not move while stopped (dt = 0)
    and its clock stands, so after RESUME_CYCLES fresh states it resumes where it stopped:
    its reference moves by one cycle's worth, not by the 200 ms it stood."""
    ctl, plant = make_controller("adaptive_impedance"), make_plant("compliant_plane")
    errors, infos = [], []
    ctl.log_error, ctl.log_info = errors.append, infos.append
    for _ in range(1000):
        m = plant.measurement()
        plant.step(ctl.step(m.time, m.position, m.velocity, m.force).command, T)
    m = plant.measurement()
    stamp = m.time + 0.030                      # 30 periods late
    out = ctl.step(stamp, m.position, m.velocity, m.force)
    assert not ctl.commanding and ctl.stops == 1 and len(errors) == 1
    assert "a state 31 periods (31 ms) after the last one, more than 10" in errors[0]
    assert "braking" in errors[0]
    brake = ctl.braking(m.position, m.velocity)
    np.testing.assert_array_equal(out.command, brake)
    held, stood = integrators(ctl), out.reference.copy()
    for k in range(1, cg.RESUME_CYCLES):
        plant.step(out.command, T)
        m = plant.measurement()
        out = ctl.step(stamp + k * T, m.position, m.velocity, m.force)
        assert not ctl.commanding
        np.testing.assert_array_equal(integrators(ctl), held)
        np.testing.assert_array_equal(out.reference, stood)       # the clock stands
    plant.step(out.command, T)
    m = plant.measurement()
    ctl.step(stamp + cg.RESUME_CYCLES * T, m.position, m.velocity, m.force)
    assert ctl.commanding and len(infos) == 1 and "commanding resumes" in infos[0]
    plant.step(out.command, T)
    m = plant.measurement()
    out = ctl.step(stamp + (cg.RESUME_CYCLES + 1) * T, m.position, m.velocity, m.force)
    moved = np.abs(out.reference[:2] - stood[:2]).max()
    print(f"reference moved {moved * 1e3:.4f} mm over the resume")
    assert moved < 1e-3 * 2 * 0.2               # one cycle of the 0.2 m/s path at most
    assert ctl.stops == 1 and len(errors) == 1
