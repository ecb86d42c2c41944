"""The real-time plant's wall clock in steps (cr_sim/realtime_clock.py), without ROS."""

import pytest

from cr_sim.realtime_clock import CatchUp, PublishTimes


def test_whole_periods_with_the_remainder_carried():
    clock = CatchUp(1e-3, 20)
    assert [clock.periods(e) for e in (1.4e-3, 1.4e-3, 1.4e-3)] == [1, 2, 1]   # 4.2 ms in 4
    assert clock.carry == pytest.approx(0.2e-3)
    assert clock.periods(0.1e-3) == 1            # never fewer than one a tick
    assert clock.carry == pytest.approx(-0.7e-3)
    assert clock.dropped_s == 0.0


def test_a_gap_is_clamped_and_the_rest_dropped():
    clock = CatchUp(1e-3, 20)
    assert clock.periods(0.5) == 20
    assert clock.dropped_s == pytest.approx(0.48)
    assert clock.carry == 0.0
    assert clock.periods(1e-3) == 1


def test_each_state_answered_once_and_only_while_kept():
    sent = PublishTimes(size=4)
    for k in range(6):
        sent.sent(k, 10.0 + k)
    assert sent.answered(5) == 15.0
    assert sent.answered(5) is None                # one round trip per state
    assert sent.answered(1) is None                # overwritten: only the last 4 are kept
    assert sent.answered(2) == 12.0
