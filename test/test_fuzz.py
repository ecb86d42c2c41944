"""cr_fuzz: its verdicts and its command line. Its real-time runs are
``make fuzz`` (docs/safety.md has the table): real-time outcomes are not asserted in tests.

The fuzz table's other rows are tests of their own: parameter bounds
(test_parameter_bounds), a law's non-finite or saturated output (test_controller_guards),
a second commander (test_plant_guards), a second state source, a 10 MB state and a 1e12 N
wrench (test_controller_guards), joins (test_join_stalls), the command lines
(test_cli_guards) and SIGINT (test_sigint); docs/safety.md maps each row to its test.
"""

import math
import subprocess
import sys

import numpy as np
import pytest
from robot_data import needs_erd

from cr_control import robots
from cr_control.tools import fuzz, fuzz_verdict

BASE = fuzz_verdict.Row("baseline", True, True, 1.0, False, True, 3.0)


def row(**changes) -> fuzz_verdict.Row:
    values = dict(case="x", alive=True, finite=True, max_speed=1.0, safe_stop=False,
                  resumed=True, miss_ms=3.0)
    values.update(changes)
    return fuzz_verdict.Row(**values)


CASE = fuzz.Case("x", "x", lambda intruder: None)
TIGHT = fuzz.Case("x", "x", lambda intruder: None, miss_margin=2.0)


@pytest.mark.parametrize("changes, reason", [
    ({}, None),
    ({"alive": False}, "a process died"),
    ({"finite": False}, "non-finite state"),
    ({"safe_stop": True}, "safe stop"),
    ({"resumed": False}, "controller not commanding"),
    ({"max_speed": 1.2 * 1.0 + 0.05 + 1e-9}, "max |q'|"),
    ({"max_speed": math.nan}, "max |q'|"),
])
def test_verdict_names_the_first_failure(changes, reason):
    got = fuzz_verdict.verdict(row(**changes), CASE, BASE)
    assert got == "survived" if reason is None else got.startswith(f"FAILED: {reason}")


def test_the_speed_bound_is_the_baselines_with_its_margin():
    assert fuzz_verdict.verdict(row(max_speed=1.25), CASE, BASE) == "survived"
    assert fuzz_verdict.verdict(row(max_speed=1.26), CASE, BASE).startswith("FAILED")


def test_missed_cycles_are_judged_only_where_the_case_says():
    assert fuzz_verdict.verdict(row(miss_ms=5.0), TIGHT, BASE) == "survived"
    assert fuzz_verdict.verdict(row(miss_ms=6.0), TIGHT, BASE).startswith("FAILED: missed 6 ms")
    assert fuzz_verdict.verdict(row(miss_ms=600.0), CASE, BASE) == "survived"


def test_every_row_of_the_issue_is_a_case():
    names = set(fuzz.CASE_NAMES)
    assert {"Q_c_1e308", "reference_frequency_1e308", "reference_amplitude_1000", "Q_c_1e6_values",
            "second_commander", "second_commander_1e308", "second_state_source",
            "huge_joint_state", "wrench_1e12", "joining_nodes", "staying_node",
            "refused_flood", "unknown_parameter"} <= names
    assert fuzz.CASE_NAMES[0] == "baseline"


def test_the_round_two_session_cases_run_on_the_robot_after_its_baseline():
    """Targets out of reach, along the table, into it and diagonally down, wrench targets,
    the zeroing walk and the silent intruder: the robot suite, judged against its own
    baseline on panda_ft."""
    robot = [case for case in fuzz.CASES if case.suite == "robot"]
    assert {case.name for case in robot} == {
        "robot_baseline", "target_10_m", "target_1e300_m", "target_along_table", "target_deep",
        "target_diagonal", "target_quaternion_1e200", "target_nan", "wrench_target_1e6",
        "wrench_pull_away", "zeroing_walk", "silent_intruder"}
    assert fuzz.SUITES["robot"] == ("robot_baseline", "panda_ft", None)
    assert {case.name for case in robot if not case.speed_judged} == {
        "target_10_m", "target_1e300_m", "target_along_table", "target_deep", "target_diagonal",
        "target_quaternion_1e200", "wrench_pull_away", "zeroing_walk"}
    assert {case.name for case in robot if case.force_judged} == {
        "target_along_table", "target_deep", "target_diagonal", "target_nan",
        "wrench_pull_away", "zeroing_walk"}
    assert [case.name for case in robot if case.prepare is not None] == ["silent_intruder"]
    assert all(case.suite == "session" for case in fuzz.CASES[:len(fuzz.CASES) - len(robot)])


class _Sender:
    """Stands in for the fuzz's Intruder: records the pose targets a case sends."""

    def __init__(self, robot):
        self.robot, self.sent = robot, []

    on_table = fuzz.Intruder.on_table

    def target_pose(self, position, quaternion):
        self.sent.append((position, quaternion))


@needs_erd
@pytest.mark.parametrize("robot", [None, "ur5_ft"])
def test_the_table_targets_are_relative_to_the_robots_home_tip(robot):
    """Along the table at the tool's height, 0.5 m below it, 10 m back, beside and down."""
    home = robots.home_tip(robots.robot(robot or "panda_ft"))
    offsets = {"target_along_table": [10.0, 0.0, 0.0], "target_deep": [0.0, 0.0, -0.5],
               "target_diagonal": [-10.0, 10.0, -10.0]}
    cases = {case.name: case for case in fuzz.CASES}
    for name, offset in offsets.items():
        sender = _Sender(robot)
        cases[name].send(sender)
        (position, _), = sender.sent
        assert np.allclose(position, home + offset)


def test_force_and_speed_are_judged_where_the_case_says():
    base = fuzz_verdict.Row("robot_baseline", True, True, 1.0, False, True, 3.0, max_force=10.0)
    pressing = fuzz.Case("x", "x", lambda intruder: None, suite="robot", force_judged=True)
    moving = fuzz.Case("x", "x", lambda intruder: None, suite="robot", speed_judged=False)
    assert fuzz_verdict.verdict(row(max_force=14.0), pressing, base) == "survived"      # <= 1.2 x 10 + 2
    assert fuzz_verdict.verdict(row(max_force=14.1), pressing, base).startswith("FAILED: max |f| 14.1 N")
    assert fuzz_verdict.verdict(row(max_force=math.nan), pressing, base).startswith("FAILED: max |f|")
    assert fuzz_verdict.verdict(row(max_force=40.0), CASE, base) == "survived"
    assert fuzz_verdict.verdict(row(max_speed=3.0), moving, base) == "survived"
    assert fuzz_verdict.verdict(row(max_speed=3.0), CASE, base).startswith("FAILED: max |q'|")
    itself = fuzz.Case("robot_baseline", "x", lambda intruder: None, suite="robot")
    assert fuzz_verdict.verdict(row(max_speed=3.0), itself, base) == "survived"      # not against itself


def test_the_table_has_a_force_column():
    text = fuzz.format_rows([row(case="baseline", max_force=12.34, verdict="survived")],
                            {"baseline": fuzz.CASES[0]})
    assert "max|f| N" in text.splitlines()[0] and "    12.3 " in text.splitlines()[2]


@pytest.mark.ros
@pytest.mark.parametrize("args, message", [
    (["--cases", "nope"], "unknown case(s) nope"),
    (["--suite", "nope"], "unknown suite(s) nope"),
    (["--duration", "1"], "--duration must be"),
    (["--robot", "r2d2"], "unknown robot"),
])
def test_bad_command_lines_are_one_line_and_exit_2(args, message):
    got = subprocess.run([sys.executable, "-m", "cr_control.tools.fuzz", *args],
                         capture_output=True, text=True, timeout=60)
    assert got.returncode == 2 and message in got.stderr
    assert "Traceback" not in got.stderr and len(got.stderr.strip().splitlines()) == 1


def test_commanding_at_the_end_is_judged_against_the_baselines_windows():
    """A stopped controller (~0 % fresh, or commands_stopped) is not commanding; a loaded
    machine's 80 % is, when the baseline's median window was 85 %; 40 % against 97 % is not."""
    import numpy as np

    fresh, running, stopped = np.array([0.9, 0.8]), np.zeros(2), np.array([0.0, 1.0])
    assert fuzz_verdict.commanding_at_end(fresh, running, reference=0.85)
    assert not fuzz_verdict.commanding_at_end(fresh, stopped, reference=0.85)
    assert not fuzz_verdict.commanding_at_end(np.array([0.9, 0.02]), running, reference=0.85)
    assert not fuzz_verdict.commanding_at_end(np.array([0.9, 0.4]), running, reference=0.97)   # < 48.5 %
    assert not fuzz_verdict.commanding_at_end(np.array([]), np.array([]), reference=0.85)
    # The plant's closing report (17 cycles, 0 %) is not judged; a full window of 0 % is.
    assert fuzz_verdict.commanding_at_end(np.array([0.9, 0.0]), running, 0.85, cycles=np.array([990, 17]))
    assert not fuzz_verdict.commanding_at_end(np.array([0.0, 0.9]), running, 0.85, cycles=np.array([990, 17]))


# -- the delay, position and gains suites ------------------------------------------------

def test_each_session_suite_has_its_baseline_and_cases_of_its_own():
    """Every suite's baseline is one of its cases; every case name once; the new suites'
    cases are the ones users asked for, and what they are judged by."""
    names = [case.name for case in fuzz.ALL_CASES]
    assert len(set(names)) == len(names) == len(fuzz.CASE_NAMES)
    for suite, (baseline, _, _) in fuzz.SESSION_SUITES.items():
        assert {case.suite for case in fuzz.ALL_CASES if case.name == baseline} == {suite}
    by_suite = {suite: {c.name: c for c in fuzz.ALL_CASES if c.suite == suite}
                for suite in fuzz.SESSION_SUITES}
    assert fuzz.SESSION_SUITES["delay"].robot == "panda_ft"
    assert fuzz.SESSION_SUITES["position"].robot == "ur5_position"
    assert fuzz.SESSION_SUITES["gains"] == ("gains_baseline", "panda", "adaptive_impedance")
    assert fuzz.SESSION_SUITES["gains_impedance"].scheme == "impedance"
    assert {"delay_3_cycles", "late_bursts_1pct", "late_bursts_5pct"} <= set(by_suite["delay"])
    assert {"position_absurd_gains", "position_target_10_m", "position_target_1e300_m",
            "position_target_nan", "position_wrench_1e12", "position_stalled_controller"} \
        <= set(by_suite["position"])
    assert all(c.commands_judged for c in by_suite["position"].values())
    assert all(c.speed_limit_share == 0.5 and c.force_judged and c.session_args
               for name, c in by_suite["delay"].items() if name != "delay_baseline")
    for suite in ("gains", "gains_impedance"):
        cases = [c for name, c in by_suite[suite].items() if "baseline" not in name]
        assert len(cases) == 6
        assert all(c.speed_limit_share == 1.0 and c.force_limit == 15.0 for c in cases)


@needs_erd
@pytest.mark.parametrize("name", [c.name for c in fuzz.ALL_CASES if c.session_args])
def test_a_cases_session_arguments_are_parameters_its_session_takes(tmp_path, name):
    from cr_control.tools.session import SessionConfig, session_parameters

    case = next(c for c in fuzz.ALL_CASES if c.name == name)
    suite = fuzz.SESSION_SUITES[case.suite]
    cfg = SessionConfig(scheme=suite.scheme or "adaptive_impedance", robot=suite.robot,
                        overrides=list(case.session_args))
    plant = session_parameters(cfg, tmp_path / "x.mcap")["plant"]
    for text in case.session_args:
        key, value = text.split("=")
        assert str(plant[key.removeprefix("plant.")]) == value


def test_the_late_bursts_are_the_plants_seeded_draws():
    """~1 % and ~5 % of the cycles late over 10 s at 1 kHz, the same every time."""
    from cr_control.tools import fuzz_delay

    assert fuzz_delay.burst_draws(fuzz_delay.BURSTS_1PCT, 10_000) == (2, 90)
    started, late = fuzz_delay.burst_draws(fuzz_delay.BURSTS_5PCT, 10_000)
    assert started == 11 and 0.04 < late / 10_000 < 0.06


def test_a_commanded_position_jump_beyond_one_period_of_the_velocity_limit_is_flagged():
    limits, period = np.array([2.0, 4.0]), 0.002          # one period: 4 mrad and 8 mrad
    smooth = np.array([[0.0, 0.0], [0.004, -0.008], [0.008, -0.016]])
    assert fuzz_verdict.command_steps(smooth, limits, period) == (True, pytest.approx(1.0))
    jumped = np.vstack([smooth, [[0.008, 0.5]]])
    assert fuzz_verdict.command_steps(jumped, limits, period)[1] == pytest.approx(0.516 / 0.008)
    assert fuzz_verdict.command_steps(np.vstack([smooth, [[math.nan, 0.0]]]), limits, period)[0] is False
    judged = fuzz.Case("x", "x", lambda intruder: None, commands_judged=True)
    position = dict(interface="position", commands_finite=True)
    assert fuzz_verdict.verdict(row(command_jump=1.0, **position), judged, BASE) == "survived"
    assert fuzz_verdict.verdict(row(command_jump=1.01, **position), judged, BASE).startswith(
        "FAILED: a commanded position jumped 1.01 periods")
    assert fuzz_verdict.verdict(row(command_jump=math.nan, **position), judged, BASE).startswith("FAILED")
    assert fuzz_verdict.verdict(row(interface="position", commands_finite=False), judged, BASE) == \
        "FAILED: a non-finite commanded position"
    assert fuzz_verdict.verdict(row(command_jump=9.0, interface="effort"), judged, BASE) == "survived"


def test_speed_and_force_are_judged_against_the_robots_limits_where_the_case_says():
    held = fuzz.Case("x", "x", lambda intruder: None, speed_limit_share=0.5, force_limit=15.0)
    assert fuzz_verdict.verdict(row(speed_share=0.5, max_force=15.0), held, BASE) == "survived"
    assert fuzz_verdict.verdict(row(speed_share=0.51, max_force=1.0), held, BASE) == \
        "FAILED: a joint at 0.51 of its velocity limit > 0.5"
    assert fuzz_verdict.verdict(row(speed_share=0.1, max_force=15.1), held, BASE) == \
        "FAILED: max |f| 15.1 N > 15 N"
    assert fuzz_verdict.verdict(row(), held, BASE).startswith("FAILED: a joint at nan")
    assert fuzz_verdict.verdict(row(speed_share=3.0, max_force=99.0), CASE, BASE) == "survived"


@pytest.mark.parametrize("side, now, expected", [("most", 2.0, 37.5), ("least", 80.0, 37.5),
                                                 ("most", 2.0, 100.0), ("least", 80.0, 0.0)])
def test_the_extreme_is_bisected_through_the_answers(side, now, expected):
    """Taken from ``now`` towards the bound (100) or the floor (0), every request between the
    last taken size and the extreme; the last taken size is the extreme to 1e-6."""
    from cr_control.tools.fuzz_gains import bisect_extreme

    taken = []

    def accepted(size: float) -> bool:
        ok = expected in (0.0, 100.0) or (size <= expected if side == "most" else size >= expected)
        taken.extend([size] if ok else [])
        return ok

    got = bisect_extreme(accepted, now, 100.0, 0.0, side)
    assert got == pytest.approx(expected, rel=1e-6, abs=1e-9) and got == taken[-1]
    assert taken == sorted(taken, reverse=side == "least")       # only ever towards it
