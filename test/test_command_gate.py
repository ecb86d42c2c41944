"""The give-up and resume rule (cr_control.schemes.command_gate): hysteretic, so a law never
alternates between braking and commanding every few cycles; while stopped it integrates
nothing and its clock stands. Scripted stamps, no plant needed for the rule itself."""

from __future__ import annotations

import math

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


def test_answers_late_on_average_give_up_once_and_resume_once():
    """100 fresh cycles, then a controller answering every 4th state only (the command in
    force stands 4 periods each time) for 600 cycles, then every state again. One stop, once
    the age averaged over 100 states passes 3 (after 110 late answers); no resume while the
    lateness lasts; one resume RESUME_CYCLES fresh cycles after the average is back below
    1.5 (179 states after the last late one). A state 250 periods late stops at once."""
    steps = [(1, 0)] * 100 + [(4, 0)] * 600 + [(1, 0)] * 800
    gate = cg.CommandGate(50)
    events = decisions(gate, steps)
    happened = [(k, e) for k, e in enumerate(events) if e != cg.NONE]
    print(happened)
    assert [e for _, e in happened] == [cg.STOP_LATE, cg.RESUME]
    (stop, _), (resume, _) = happened
    assert stop == pytest.approx(100 + 100 * math.log(3.0), abs=2)          # 210
    assert resume == pytest.approx(700 + 100 * math.log(6.0) + cg.RESUME_CYCLES, abs=3)  # 1077
    assert gate.period == pytest.approx(T)
    assert decisions(cg.CommandGate(50), [(1, 0)] * 10 + [(250, 0)])[-1] == cg.STOP_LATE
    assert decisions(cg.CommandGate(50), [(1, 0)] * 10 + [(61, 0)])[-1] == cg.NONE


def test_stalls_of_tens_of_ms_on_a_few_per_cent_of_the_cycles_do_not_stop_it():
    """A 30-period stall every 50 cycles (the late bursts of a loaded machine: 37 % of the
    time late, each stall alone under LATE_STATE_CYCLES): the average age stays near 1.6,
    under LATE_MEAN_CYCLES: the law goes on (the hysteresis keeps it from chattering if its
    output saturates)."""
    gate = cg.CommandGate(50)
    events = decisions(gate, [(1, 0)] * 100 + ([(30, 0)] + [(1, 0)] * 49) * 20)
    assert set(events) == {cg.NONE} and gate.commanding
    assert gate.late_states == 0 and 1.3 < gate.mean_age < 2.0


def late_bursts(fraction: float, seconds: float, seed: int) -> list[tuple[float, int]]:
    """Stamp steps of a node that falls behind in bursts of 20-70 periods on about
    ``fraction`` of the cycles (cr_sim.transport_delay's draws: each cycle outside a burst
    starts one with probability fraction / (45 (1 - fraction))): a node that answers late
    answers only the newest state, so each burst shows as one state n periods after the last."""
    rng = np.random.default_rng(seed)
    p = fraction / (45.0 * (1.0 - fraction))
    steps, k = [], 0
    while k < seconds / T:
        n = int(rng.integers(20, 71)) if rng.random() < p else 1
        steps.append((n, 0))
        k += n
    return steps


@pytest.mark.parametrize("fraction", [0.01, 0.043])
def test_late_bursts_on_a_few_per_cent_of_the_cycles_never_stop_it(fraction):
    """Bursts of 20-70 ms late on 1 % of the cycles (and 4.3 %: 0.001 bursts per cycle), a
    minute of them: no state alone beyond LATE_STATE_CYCLES, the average age below 2
    periods (LATE_MEAN_CYCLES 3): the law goes on commanding, not a stop."""
    gate = cg.CommandGate(50)
    stamp, most = 0.0, 0.0
    gate.stamp(stamp)
    events = []
    for periods, run in late_bursts(fraction, 60.0, 0):
        stamp += periods * T
        gate.stamp(stamp)
        events.append(gate.cycle(run))
        most = max(most, gate.mean_age)
    print(f"{fraction:.1%} late: the average age at most {most:.2f} periods")
    assert set(events) == {cg.NONE} and gate.commanding
    assert gate.late_states == 0 and gate.max_age <= 70.0 + 1e-9 and most < 2.0


def test_late_bursts_on_30_per_cent_of_the_cycles_stop_it_once_at_a_time():
    """Bursts of 20-70 ms on 30 % of the cycles: the average age passes 3 now and then, and
    each time the law stops once and resumes once, RESUME_CYCLES fresh states at least after
    the stop; never stop and resume every few cycles (a minute: two such episodes)."""
    events = decisions(cg.CommandGate(50), late_bursts(0.3, 60.0, 0))
    happened = [(k, e) for k, e in enumerate(events) if e != cg.NONE]
    print(happened)
    assert [e for _, e in happened] == [cg.STOP_LATE, cg.RESUME] * (len(happened) // 2)
    assert 1 <= len(happened) // 2 <= 3
    gaps = np.diff([k for k, _ in happened])
    assert gaps.min() >= cg.RESUME_CYCLES


def test_a_wall_clock_stamp_jitter_is_no_lateness():
    """A real-time plant stamps with the wall clock: steps of 0.4-1.6 ms around 1 ms. The
    period estimate settles at the mean step (not the smallest: 0.4 ms would make every
    on-time state 2.5 periods old), and nothing stops."""
    rng = np.random.default_rng(0)
    gate = cg.CommandGate(50)
    events = decisions(gate, [(step, 0) for step in rng.uniform(0.4, 1.6, 3000)])
    assert set(events) == {cg.NONE}
    assert gate.period == pytest.approx(T, rel=0.05) and gate.mean_age < 1.2


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
    """The hysteresis in the age: while stopped, a state 5 periods late (above
    FRESH_STATE_CYCLES 3, below LATE_STATE_CYCLES 200) resets the fresh run."""
    gate = cg.CommandGate(50)
    assert set(decisions(gate, [(1, 0)] * 10 + [(5, 0)] * 3)) == {cg.NONE}
    gate.stop()
    events = decisions(gate, ([(1, 0)] * 150 + [(5, 0)]) * 3 + [(1, 0)] * cg.RESUME_CYCLES)
    assert events.count(cg.RESUME) == 1 and events[-1] == cg.RESUME


def test_a_given_control_period_is_used():
    """A controller that declares its period (control_period) is not estimated: 2 ms steps
    at a declared 1 ms are 2 periods old."""
    gate = cg.CommandGate(50, period=T)
    decisions(gate, [(2, 0)] * 10)
    assert gate.period == T and gate.age == pytest.approx(2.0)


def integrators(ctl) -> np.ndarray:
    """What adaptive_impedance integrates: its reference's state (filters, admittance,
    guard) and the adaptation's reference model and integrals (3.8, 3.11-3.14); the
    estimates A_hat, B_hat, c_hat also have parts proportional to the measured error."""
    law = ctl.internal[ctl.reference_state.size:]
    x_m, integrals = impedance.state_views(law, 2)[:2]
    return np.concatenate([ctl.internal[:ctl.reference_state.size], x_m, integrals.ravel()])


def test_the_controller_brakes_once_on_a_late_state_holds_its_law_and_its_clock():
    """adaptive_impedance on its thesis plant, settled 1 s; then a state 250 ms late (beyond
    max_stamp_gap: held, and LATE_STATE_CYCLES): one error line, the brake from the next
    state; what the law integrates does not move while stopped (dt = 0) and its clock
    stands, so after RESUME_CYCLES fresh states (and the average age back under 1.5) it
    resumes where it stopped: its reference moves by one cycle's worth, not by the time it
    stood."""
    ctl, plant = make_controller("adaptive_impedance"), make_plant("compliant_plane")
    errors, infos = [], []
    ctl.log_error, ctl.log_info = errors.append, infos.append
    for _ in range(1000):
        m = plant.measurement()
        plant.step(ctl.step(m.time, m.position, m.velocity, m.force).command, T)
    m = plant.measurement()
    stamp = m.time + 0.250                      # 250 periods late
    out = ctl.step(stamp, m.position, m.velocity, m.force)
    assert not ctl.commanding and ctl.stops == 1 and len(errors) == 1
    assert "a state 251 periods (251 ms) after the last one, more than 200" in errors[0]
    assert "braking" in errors[0]
    brake = ctl.braking(m.position, m.velocity)
    np.testing.assert_array_equal(out.command, brake)
    k, held, stood = 0, None, None
    while not ctl.commanding:
        k += 1
        plant.step(out.command, T)
        m = plant.measurement()
        out = ctl.step(stamp + k * T, m.position, m.velocity, m.force)
        if held is None:
            held, stood = integrators(ctl), out.reference.copy()
        elif not ctl.commanding:
            np.testing.assert_array_equal(integrators(ctl), held)
            np.testing.assert_array_equal(out.reference, stood)       # the clock stands
        assert k < 1000
    print(f"resumed after {k} states")
    assert cg.RESUME_CYCLES <= k <= cg.RESUME_CYCLES + 200     # the average's 161 first
    assert len(infos) == 1 and "commanding resumes" in infos[0]
    plant.step(out.command, T)
    m = plant.measurement()
    out = ctl.step(stamp + (k + 1) * T, m.position, m.velocity, m.force)
    moved = np.abs(out.reference[:2] - stood[:2]).max()
    print(f"reference moved {moved * 1e3:.4f} mm over the resume")
    assert moved < 1e-3 * 2 * 0.2               # two cycles of the 0.2 m/s path at most
    assert ctl.stops == 1 and len(errors) == 1


def test_stop_and_resume_lines_go_to_an_rclpy_logger():
    """rclpy's logger refuses two severities from one line of code: the stop (error) and the
    resume (info) each have their own call site, so a node that stops and resumes does not
    raise (it did: 'Logger severity cannot be changed between calls')."""
    import rclpy.logging

    logger = rclpy.logging.get_logger("test_command_gate")
    ctl, plant = make_controller("adaptive_impedance"), make_plant("compliant_plane")
    ctl.log_error, ctl.log_info = logger.error, logger.info
    m = plant.measurement()
    ctl.step(m.time, m.position, m.velocity, m.force)
    ctl.step(m.time + 0.250, m.position, m.velocity, m.force)       # late: stop (error)
    assert not ctl.commanding
    k = 1
    while not ctl.commanding and k < 1000:                          # resume (info)
        ctl.step(m.time + 0.250 + k * T, m.position, m.velocity, m.force)
        k += 1
    assert ctl.commanding and ctl.stops == 1
