"""The controller's start-up check of its answers' round trip (cr_control.supervision.delay_watch)
against the delay its gains tolerate: the profiles' measured margins, the rule's figure where
none is given, one line once when the answers are later than that, none in lockstep."""

import numpy as np
import pytest

from cr_control import robots
from cr_control.schemes.registry import make_controller
from cr_control.supervision.delay_watch import DelayWatch, delay_watch_for


def feed(watch: DelayWatch, lateness_s: np.ndarray) -> list[str]:
    lines = []
    for k, late in enumerate(lateness_s):
        stamp = 1_700_000_000.0 + k * watch.period
        line = watch.answered(stamp, stamp + late)
        if line is not None:
            lines.append(line)
    return lines


def test_answers_in_time_say_nothing():
    watch = DelayWatch(1e-3, 1, 8)
    rng = np.random.default_rng(0)
    assert feed(watch, rng.uniform(0.0, 0.9e-3, 3000)) == []
    assert watch.done and watch.measured == 1


def test_late_answers_are_said_once():
    watch = DelayWatch(1e-3, 1, 8)
    late = np.full(3000, 0.3e-3)
    late[::50] = 12e-3                      # 2 % of the answers 12 ms late: the p99 is
    lines = feed(watch, late)
    assert len(lines) == 1 and watch.measured == 13
    assert "13 cycles" in lines[0] and "beyond the 8" in lines[0] and "\n" not in lines[0]


def test_stamps_on_another_clock_are_not_measured():
    watch = DelayWatch(1e-3, 1, 8)
    assert watch.answered(12.0, 1_700_000_000.0) is None and watch.done
    assert watch.measured is None


@pytest.mark.parametrize("robot", ["panda", "ur5"])
def test_the_profiles_margins_and_the_rules_figure(robot):
    values = robots.controller_values(robots.robot(robot), "impedance")
    ctl = make_controller("impedance", values)
    assert ctl.tolerated_delay == robots.DELAY_MARGIN_CYCLES[robot]["impedance"]
    ruled = make_controller("impedance", {**values, "tolerated_delay_cycles": 0})
    # the rule's edge for the joint-space gains in force: 6 cycles, the joint limit guard's
    # damping at its bound (stable with a gain margin of 2 at 3 cycles; the wrist's at 7)
    assert ruled.tolerated_delay == 6
    watch = delay_watch_for(ctl, lockstep=False)
    assert watch is not None and watch.declared == 1 and watch.tolerated == ctl.tolerated_delay
    assert delay_watch_for(ctl, lockstep=True) is None
    assert make_controller("impedance", {}).tolerated_delay is None       # the thesis arm
