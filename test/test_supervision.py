"""The supervision objects alone, without ROS (milliseconds): the one rate-limited logger
and the one single-source guard both nodes use."""

from __future__ import annotations

import math

import pytest

from cr_control.core.rate_limited_log import RateLimitedLog, logger_emit
from cr_control.supervision.single_source import SingleSource, expected_names, full_node_name

PLANT, INTRUDER, SPARE = b"P" * 16, b"I" * 16, b"S" * 16


class Clock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def recording_log(period_s: float = 5.0, clock=None):
    lines: list[tuple[str, str]] = []
    log = RateLimitedLog(lambda severity, text: lines.append((severity, text)), period_s,
                         clock or Clock())
    return log, lines


def test_one_line_per_key_and_period_with_the_suppressed_count():
    clock = Clock()
    log, lines = recording_log(5.0, clock)
    built = []
    for i in range(100):                      # 100 faults in 1 s: one line
        clock.t += 0.01
        log("size", "error", lambda i=i: built.append(i) or f"fault {i}")
    assert lines == [("error", "fault 0")] and built == [0]   # texts built only when emitted
    assert log("other", "warn", "another key") and len(lines) == 2
    clock.t += 5.0
    assert log("size", "error", "fault again")
    assert lines[-1] == ("error", "fault again (99 more since the last such line)")
    assert log.counts["size"] == 101 and log.suppressed("size") == 0
    clock.t += 1.0
    assert not log("size", "error", "x") and log.suppressed("size") == 1


def test_an_infinite_period_logs_each_key_once_and_a_negative_one_is_refused():
    log, lines = recording_log(math.inf)
    for _ in range(3):
        log("once", "warn", "only once")
    assert lines == [("warn", "only once")] and log.suppressed("once") == 2
    with pytest.raises(ValueError):
        RateLimitedLog(lambda s, t: None, -1.0)
    with pytest.raises(ValueError):
        RateLimitedLog(lambda s, t: None, math.nan)


def test_logger_emit_calls_one_method_per_severity():
    got = []

    class Logger:
        def __getattr__(self, name):
            return lambda text: got.append((name, text))

    emit = logger_emit(Logger())
    for severity in ("error", "warn", "info", "debug"):
        emit(severity, severity[0])
    assert got == [("error", "e"), ("warn", "w"), ("info", "i"), ("debug", "d")]


def test_names_of_a_parameter():
    assert expected_names("/plant") == {"/plant"}
    assert expected_names(" plant , /ns/robot,") == {"/plant", "/ns/robot"}
    assert expected_names("") == frozenset() and expected_names([]) == frozenset()
    assert full_node_name("/", "plant") == "/plant" and full_node_name("/ns", "c") == "/ns/c"


def guard(expected=("/plant",), silence=2.0, graph=None, clock=None):
    graph = {PLANT: "/plant", INTRUDER: "/intruder"} if graph is None else graph
    lookups: list[bytes] = []
    log, lines = recording_log(5.0, clock)

    def name_of(gid):
        lookups.append(gid)
        return graph.get(gid)

    g = SingleSource("/joint_states", expected, silence, name_of, log, what="states",
                     parameter="state_source", counter="states_foreign", clock=clock or Clock())
    return g, lookups, lines


def test_a_silent_publisher_is_never_followed_the_first_valid_one_is():
    g, _, _ = guard(expected=())
    # an intruder matched first but silent: nothing follows from matching alone
    assert g.source is None
    assert g.admit(PLANT, 0.0)
    g.heard(PLANT, 0.0)
    assert g.source == PLANT and g.refused == 0


def test_only_the_expected_node_is_followed_and_each_refusal_counted():
    clock = Clock()
    g, lookups, lines = guard(clock=clock)
    for k in range(50):                       # the intruder's states come first
        assert not g.admit(INTRUDER, 0.001 * k)
    assert g.source is None and g.refused == g.unexpected == 50
    assert lookups == [INTRUDER]              # looked up once, cached
    assert len([1 for _, text in lines if "refused unread" in text]) == 1
    assert "only '/plant' is followed (parameter state_source)" in lines[0][1]
    assert "node '/intruder'" in lines[0][1] and "counted in states_foreign" in lines[0][1]
    assert g.admit(PLANT, 0.05)
    g.heard(PLANT, 0.05)
    assert g.source == PLANT and lines[-1] == ("info", f"/joint_states: following node "
                                                       f"'/plant' (gid {PLANT.hex()})")
    # followed: the intruder is foreign now (refused without a lookup), even when the
    # plant falls silent: the rule still refuses its node
    assert not g.admit(INTRUDER, 0.06)
    assert not g.admit(INTRUDER, 10.0)
    assert g.refused == 52 and g.unexpected == 51 and g.source == PLANT


def test_an_unknown_gid_is_refused_and_looked_up_again_only_after_a_while():
    clock = Clock()
    graph: dict[bytes, str] = {}
    g, lookups, _ = guard(graph=graph, clock=clock)
    for _ in range(1000):                     # a flood before the graph knows the plant
        assert not g.admit(PLANT, 0.0)
    assert len(lookups) == 1 and g.unexpected == 1000
    graph[PLANT] = "/plant"
    assert not g.admit(PLANT, 0.0)            # not asked again yet
    clock.t += 0.06
    assert g.admit(PLANT, 0.0) and len(lookups) == 2
    g.known(SPARE, "/plant")                  # named by the periodic graph check: no lookup
    assert g.name(SPARE) == "/plant" and len(lookups) == 2


def test_handover_only_after_the_silence_and_only_to_an_expected_node():
    g, _, lines = guard(expected=("/plant",), graph={PLANT: "/plant", SPARE: "/plant",
                                                     INTRUDER: "/intruder"})
    g.heard(PLANT, 0.0) if g.admit(PLANT, 0.0) else None
    assert not g.admit(SPARE, 1.0)            # a restarted plant while the first is alive
    assert g.refused == 1 and g.unexpected == 0
    assert not g.admit(INTRUDER, 2.5)         # the first silent 2.5 s: still not the intruder
    assert g.admit(SPARE, 2.5)
    g.heard(SPARE, 2.5)
    assert g.source == SPARE and g.handovers == 1
    assert lines[-1][0] == "warn" and "delivered nothing for 2.5 s" in lines[-1][1]
    assert not g.admit(PLANT, 2.6)            # the old one is foreign now


def test_a_publisher_that_cannot_be_known_is_admitted():
    g, _, _ = guard()
    assert g.admit(None, 0.0) and g.admit(b"", 0.0)
    g.heard(None, 0.0)
    assert g.source is None and g.refused == 0


def test_the_plant_expects_the_controllers_of_this_package_by_default():
    from cr_control.schemes.registry import SCHEMES
    from cr_control.supervision.plant_commander import (
        COMMANDER_PARAMETER,
        CONTROLLER_NODES,
        commander_guard,
    )

    assert sorted(CONTROLLER_NODES) == sorted(SCHEMES)
    lines = []
    graph = {PLANT: "/adaptive_impedance", INTRUDER: "/fuzz_intruder"}
    g = commander_guard(COMMANDER_PARAMETER.default, 50, graph.get,
                        lambda severity, text: lines.append((severity, text)))
    for k in range(1000):                     # the intruder's 1e308 commands, first
        assert not g.admit(INTRUDER, k)
    assert g.admit(PLANT, 1000)
    g.heard(PLANT, 1000)
    assert not g.admit(INTRUDER, 1001) and not g.admit(INTRUDER, 5000)
    assert g.refused == 1002 and g.source == PLANT
    refusals = [text for _, text in lines if "refused unread" in text]
    assert len(refusals) == 2                 # once per kind: by the rule, then foreign
    assert "node '/fuzz_intruder'" in refusals[0] and "commands_foreign" in refusals[0]


# -- the controller's input guards, without ROS (fake readers: the policy, not the CDR) ----
def controller_inputs(expected=("/plant",), lockstep=False, graph=None, advertises=False,
                      sensor_frame=""):
    from types import SimpleNamespace

    import numpy as np

    from cr_control.supervision.controller_inputs import ControllerInputs, Readers

    graph = {PLANT: "/plant", INTRUDER: "/intruder"} if graph is None else graph
    log, lines = recording_log()
    source = SingleSource("/joint_states", expected, 2.0, graph.get, log, what="states")

    def fields(data):                         # b"k,names...": stamp k ms, positions 1, 2, ...
        if not data.startswith(b"s"):
            return None
        k, *names = data[1:].decode().split(",")
        n = len(names)
        return SimpleNamespace(sec=7, nanosec=int(k) * 1_000_000, name=tuple(names),
                               position=tuple(float(i + 1) for i in range(n)),
                               velocity=(0.0,) * n)

    def wrench(data):
        if not data.startswith(b"w"):
            return None
        frame, *force = data[1:].decode().split(",")
        return SimpleNamespace(sec=7, nanosec=0, force=tuple(map(float, force)),
                               torque=(0.0, 0.0, 0.0), frame_id=frame)

    readers = Readers(fields, wrench, lambda data: None, lambda data: None, 64, 4, 64, 64)
    inputs = ControllerInputs(readers, ("joint1", "joint2"),
                              {"max_sensor_force": 1000.0, "sensor_frame": sensor_frame},
                              np.full(0, np.nan), (), source, log, lockstep,
                              lambda: advertises, "test")
    inputs.interface = "ok"
    inputs.active = True
    return inputs, lines


def s(k: int, names: str = "joint1,joint2") -> bytes:
    return f"s{k},{names}".encode()


def test_the_controller_inputs_answer_only_the_plants_valid_states():
    from cr_control.supervision.controller_inputs import ANSWER, NOTHING, REPEAT

    inputs, lines = controller_inputs()
    assert inputs.state(s(0), INTRUDER, None, 0.0) == NOTHING          # the rule: not /plant
    assert inputs.state(b"x" * 65, PLANT, None, 0.0) == NOTHING        # too long: unread
    assert inputs.state(None, PLANT, 10_000_000, 0.0) == NOTHING       # not even copied
    assert inputs.inputs_oversized == 2 and inputs.states_foreign == 1
    assert inputs.state(b"garbage", PLANT, None, 0.001) == NOTHING     # unreadable
    assert inputs.state(s(1, "joint2,joint1"), PLANT, None, 0.002) == ANSWER
    assert inputs.position.tolist() == [2.0, 1.0] and inputs.t == 7.001   # law's joint order
    assert inputs.state(s(1, "joint2,joint1"), PLANT, None, 0.003) == REPEAT
    assert inputs.state(s(2), INTRUDER, None, 0.004) == NOTHING
    assert inputs.states_foreign == 2
    assert inputs.state(s(3), PLANT, None, 0.005, newer_queued=True) == NOTHING
    assert inputs.states_skipped == 1
    assert inputs.state(s(4, "joint1,elbow"), PLANT, None, 0.006) == ANSWER   # held by the law
    assert inputs.position.size == 0
    assert any("lacks some of" in text for _, text in lines)


def test_inactive_a_state_is_read_once_then_the_newest_kept_for_activation():
    from cr_control.supervision.controller_inputs import ANSWER, NOTHING, OBSERVE

    inputs, _ = controller_inputs()
    inputs.active = False
    reads = []
    read = inputs.read_state
    inputs.read_state = lambda data: reads.append(data) or read(data)
    assert inputs.state(s(0), PLANT, None, 0.0) == OBSERVE and inputs.t == 7.0
    for k in range(1, 50):
        assert inputs.state(s(k), PLANT, None, k * 1e-3) == NOTHING
    assert len(reads) == 1
    held = inputs.activate()
    assert held == (s(49), PLANT, None)
    assert inputs.state(*held[:3], 0.05) == ANSWER and inputs.stamp == (7, 49_000_000)


def test_a_state_before_the_plants_interface_waits_in_lockstep_only():
    from cr_control.supervision.controller_inputs import ANSWER, NOTHING

    for lockstep in (False, True):
        inputs, _ = controller_inputs(lockstep=lockstep, advertises=True)
        inputs.interface = "unknown"
        assert inputs.state(s(0), PLANT, None, 0.0) == NOTHING
        waiting = inputs.interface_known(True)
        assert (waiting is not None) == lockstep
        if waiting:
            assert inputs.state(*waiting, 0.001) == ANSWER
    inputs, _ = controller_inputs(advertises=True)
    inputs.interface_known(False)                                      # refused: never
    assert inputs.state(s(0), PLANT, None, 0.0) == NOTHING and inputs.interface == "refused"


def test_a_lockstep_state_is_judged_again_once_the_graph_names_its_publisher():
    from cr_control.supervision.controller_inputs import ANSWER, NOTHING

    graph: dict[bytes, str] = {}
    inputs, _ = controller_inputs(lockstep=True, graph=graph)
    assert inputs.state(s(0), PLANT, None, 0.0) == NOTHING
    graph[PLANT] = "/plant"
    inputs.source.known(PLANT, "/plant")                                # the watch's tick
    held = inputs.named()
    assert held == (s(0), PLANT, None) and inputs.named() is None
    assert inputs.state(*held, 0.1) == ANSWER


def test_a_wrench_of_another_frame_or_beyond_max_sensor_force_is_a_sensor_fault():
    inputs, lines = controller_inputs(sensor_frame="ft")
    inputs.wrench_message(b"wft,4,-3,0")
    assert inputs.force.tolist() == [4.0, -3.0, 0.0] and inputs.wrench_seen
    for bad in (b"wft,1e12,0,0", b"wft,nan,0,0", b"wft,inf,0,0", b"wtool,1,0,0"):
        inputs.wrench_message(bad)
    assert inputs.force.tolist() == [4.0, -3.0, 0.0] and inputs.sensor_faults == 4
    inputs.wrench_message(b"w" + b"x" * 64)                           # beyond its bound
    inputs.wrench_message(b"not a wrench")
    assert inputs.inputs_oversized == 1 and inputs.sensor_faults == 4
    assert sum("sensor fault" in text for _, text in lines) == 1      # one line per episode
