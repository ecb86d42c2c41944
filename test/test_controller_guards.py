"""Hostile input, the controller's part: no parameter, message or second publisher may run the arm
away or stall the loop.

- A law whose output is non-finite or sits at its limit for more than max_bad_cycles cycles
  in a row stops commanding (one error line; the plant's watchdog then brakes) and resumes
  with its first good output; cycles held because of bad input leave the count alone; the
  thesis runs that saturate (fjr_robust_adaptive with the measured q_m'') never stop.
- An oversized JointState is dropped before it is parsed, and counted.
- States from a second /joint_states publisher are ignored and counted; another publisher
  is followed only after the followed one's silence.
- A wrench above max_sensor_force (or not finite) is a sensor fault: the last sane one is
  used, counted, logged once.

Offline on Controller.step, and callback by callback on a node that is never spun (its
messages are handed to the callbacks: deterministic, no real time).
"""

import math
import os
import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import WrenchStamped
from rclpy.context import Context
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from cr_control import offline
from cr_control.core import topics
from cr_control.nodes import controller_node
from cr_control.nodes.controller_node import SOURCE_SILENCE_S, ControllerNode
from cr_control.nodes.raw_messages import joint_state_max_bytes
from cr_control.schemes import command_gate
from cr_control.schemes.controller import ACCEPTED, COMMAND_NOT_FINITE, accept_cycle
from cr_control.schemes.registry import make_controller
from cr_sim.plants.registry import make_plant

PERIOD = 1e-3
MAX_BAD = 50        # the default max_bad_cycles
RESUME_CYCLES = command_gate.RESUME_CYCLES


# -- the law's output (offline) ----------------------------------------------------------
class Logs:
    """Where a controller's warning, error and info lines go."""

    def __init__(self, ctl):
        self.warning, self.error, self.info = [], [], []
        ctl.log_warning, ctl.log_error, ctl.log_info = (self.warning.append, self.error.append,
                                                        self.info.append)


def settled(scheme="adaptive_impedance", scenario="compliant_plane", cycles=200, **overrides):
    """A controller after ``cycles`` closed-loop cycles on its plant, its lines collected."""
    ctl, plant = make_controller(scheme, overrides or None), make_plant(scenario)
    logs = Logs(ctl)
    for _ in range(cycles):
        m = plant.measurement()
        plant.step(ctl.step(m.time, m.position, m.velocity, m.force).command, PERIOD)
    assert ctl.commanding and ctl.bad_run == 0 and not logs.error
    return ctl, plant, logs


def poison(ctl, what="command"):
    """Make the law's output non-finite from now on (its command, or its internal state);
    returns the undo."""
    compute = ctl.compute

    def poisoned(*args):
        out = compute(*args)
        if what == "command":
            out.command[:] = math.nan
        else:
            ctl.internal[-1] = math.inf
        return out

    ctl.compute = poisoned
    return lambda: setattr(ctl, "compute", compute)


def hold_still(ctl, plant, cycles, start=1):
    """Step ``cycles`` states of the plant's current measurement (stamps one period apart);
    the list of ``commanding`` after each."""
    m = plant.measurement()
    commanding = []
    for k in range(start, start + cycles):
        ctl.step(m.time + k * PERIOD, m.position, m.velocity, m.force)
        commanding.append(ctl.commanding)
    return commanding


@pytest.mark.parametrize("what", ["command", "internal"])
def test_a_law_failing_for_good_stops_commanding_after_exactly_max_bad_cycles(what):
    ctl, plant, logs = settled()
    poison(ctl, what)
    commanding = hold_still(ctl, plant, 3 * MAX_BAD)
    assert commanding == [True] * MAX_BAD + [False] * (2 * MAX_BAD)
    assert ctl.stops == 1 and ctl.bad_run == 3 * MAX_BAD
    assert len(logs.error) == 1, logs.error
    line = logs.error[0]
    assert line.startswith("adaptive_impedance: more than 50 cycles in a row (max_bad_cycles) "
                           "with a non-finite or saturated output (")
    assert "braking (the braking command is published in its place)" in line
    assert ("non-finite command" if what == "command" else "internal state not finite") in line


def test_commanding_resumes_after_resume_cycles_good_outputs_not_the_first():
    """Hysteretic (command_gate): after the stop, RESUME_CYCLES (200) good outputs of fresh
    states in a row, not the first one (which let a law alternate between braking and
    commanding every 70 ms); the law's internal state does not move meanwhile (dt = 0)."""
    ctl, plant, logs = settled()
    undo = poison(ctl)
    assert hold_still(ctl, plant, MAX_BAD + 5)[-1] is False
    undo()
    held = ctl.internal.copy()
    start = MAX_BAD + 6
    assert hold_still(ctl, plant, RESUME_CYCLES - 1, start) == [False] * (RESUME_CYCLES - 1)
    assert np.array_equal(ctl.internal, held)          # nothing integrated while stopped
    assert hold_still(ctl, plant, 6, start + RESUME_CYCLES - 1) == [True] * 6
    assert ctl.bad_run == 0 and ctl.stops == 1
    assert len(logs.info) == 1 and "commanding resumes" in logs.info[0]
    assert f"after {RESUME_CYCLES} cycles in a row with fresh states" in logs.error[0]
    assert not np.array_equal(ctl.internal, held)     # integrating again once resumed


def test_a_transient_non_finite_output_never_stops_commanding():
    ctl, plant, logs = settled()
    undo = poison(ctl)
    assert all(hold_still(ctl, plant, MAX_BAD))          # exactly max_bad_cycles: tolerated
    undo()
    assert hold_still(ctl, plant, 1, start=MAX_BAD + 1) == [True] and ctl.bad_run == 0
    poison(ctl)                                          # the count starts again
    assert all(hold_still(ctl, plant, MAX_BAD, start=MAX_BAD + 2))
    assert ctl.stops == 0 and not logs.error


def test_bad_input_alone_never_stops_commanding_nor_resets_the_count():
    ctl, plant, _ = settled()
    m = plant.measurement()
    nan = np.array([math.nan, 0.0])
    for k in range(1, 1001):                             # a NaN state for a second: held
        out = ctl.step(m.time + k * PERIOD, nan, m.velocity, m.force)
        assert out.status[ctl.status_fields.index("held") - 1] == 1.0 and ctl.commanding
    assert ctl.bad_run == 0 and ctl.stops == 0
    # the law failing, NaN states in between: they neither count nor clear the law's run
    ctl, plant, _ = settled()
    poison(ctl)
    m = plant.measurement()
    stamps = iter(m.time + k * PERIOD for k in range(1, 1000))
    for _ in range(30):
        ctl.step(next(stamps), m.position, m.velocity, m.force)
    for _ in range(10):
        ctl.step(next(stamps), nan, m.velocity, m.force)
    assert ctl.bad_run == 30
    for _ in range(MAX_BAD - 30):
        ctl.step(next(stamps), m.position, m.velocity, m.force)
    assert ctl.commanding
    ctl.step(next(stamps), m.position, m.velocity, m.force)
    assert not ctl.commanding and ctl.bad_run == MAX_BAD + 1


@pytest.mark.parametrize("overrides, limit", [
    ({"max_effort": 0.3}, "max_effort 0.3, URDF effort 20"),       # clipped by accept_cycle
    ({"reference_offset": [0.3, 0.3]}, "max_effort 100, URDF effort 20"),   # by the kernel
])
def test_a_law_pinned_at_its_limit_stops_commanding(overrides, limit):
    """The arm far from its reference (0.3 m), or max_effort far below gravity: the command
    sits at a limit on one side (the task-space kernel clips at the URDF's 20 N m before
    Controller.step sees the command: detected against command_limits too)."""
    ctl = make_controller("adaptive_impedance", overrides)
    plant = make_plant("compliant_plane")
    logs = Logs(ctl)
    np.testing.assert_array_equal(ctl.command_limits, [20.0, 20.0])
    commanding, pinned = [], 0
    for _ in range(300):
        m = plant.measurement()
        out = ctl.step(m.time, m.position, m.velocity, m.force)
        plant.step(out.command, PERIOD)
        commanding.append(ctl.commanding)
        if not ctl.commanding:      # this cycle's output is the brake, not the law's
            break
        pinned = pinned + 1 if np.isclose(np.abs(out.command).max(), min(
            ctl.values["max_effort"], 20.0)) else 0
    assert commanding[-1] is False and commanding.count(False) == 1
    assert pinned >= MAX_BAD                             # every counted cycle at the clip
    assert len(logs.error) == 1 and f"(its limit: {limit})" in logs.error[0], logs.error


def test_accept_cycle_counts_each_element_at_its_limit_on_one_side():
    """accept_cycle against the rule written out: per element, cycles in a row at its limit
    (min(max_effort, limits[j])) on the same side; the other side counts from 1 again; a
    held cycle counts for every element."""
    n, limits = 2, np.array([20.0, np.inf])
    guard, internal = np.zeros(2 * n), np.zeros(0)
    slots = np.zeros(0, dtype=np.int64)

    def cycle(command, max_effort=100.0):
        command = np.array(command, dtype=float)
        return accept_cycle(n, max_effort, limits, internal, internal.copy(), command,
                            np.zeros(4), slots, guard)

    assert cycle([20.0, 5.0]) == (ACCEPTED, 1)           # at the URDF effort
    assert cycle([25.0, 5.0]) == (ACCEPTED, 2)           # beyond it (a kernel clips it there)
    assert cycle([-20.0, 5.0]) == (ACCEPTED, 1)          # the other side: from 1 again
    assert cycle([math.nan, 0.0]) == (COMMAND_NOT_FINITE, 2)   # held: counts for both
    assert cycle([-20.0, 1e9]) == (ACCEPTED, 3)          # element 2 clipped at max_effort 100
    assert cycle([0.0, 100.0]) == (ACCEPTED, 3)          # element 2: at +100 since the hold
    assert cycle([0.0, 99.0]) == (ACCEPTED, 0)
    for k in range(1000):                                # chatter between the clips: never > 1
        assert cycle([20.0 if k % 2 else -20.0, 0.0])[1] == 1


@pytest.mark.parametrize("ks", [10.0, 100.0])
def test_the_saturating_thesis_run_never_stops_commanding(ks):
    """fjr_robust_adaptive with the measured q_m'' (section 6.3.1, J_m = 0.5 I): its torque
    chatters between the +-100 N m clips on every cycle for 20 s (test_fjr_robust_adaptive);
    one joint stays at one clip for at most 10 (K_s = 10 I) and 24 (K_s = 100 I, the worst)
    cycles in a row, well below max_bad_cycles. Measured: 10 and 24."""
    ctl = make_controller("fjr_robust_adaptive", {"motor_acceleration": "measured"})
    plant = make_plant("flexible_joint_surface", {"joint_stiffness": [ks, ks],
                                                  "motor_inertia": [0.5, 0.5]})
    logs = Logs(ctl)
    runs = []
    step = ctl.step

    def step_and_note(*args):
        out = step(*args)
        runs.append(ctl.bad_run)
        return out

    ctl.step = step_and_note
    r = offline.run(ctl, plant, 20.0)
    clipped = float((np.abs(r.command) >= 100.0).any(axis=1).mean())
    print(f"\nK_s = {ks:g}: a command at the clip in {100 * clipped:.1f} % of the cycles, "
          f"longest run at one clip {max(runs)} cycles")
    assert clipped > 0.9                                 # it does sit at the clip
    assert ctl.stops == 0 and ctl.commanding and max(runs) <= 30 and not logs.error


# -- the node's inputs (callback by callback) ---------------------------------------------
@pytest.fixture
def node():
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    # states of the test's own GIDs, no graph behind them: the first valid publisher is
    # followed (state_source empty; the rule by node name: test_state_source)
    controller = ControllerNode("adaptive_impedance", context=context, parameter_overrides=[
        rclpy.parameter.Parameter("state_source", value="")])
    controller.published = []
    controller.command_pub.publish = controller.published.append     # what reaches the plant
    yield controller
    controller.destroy_node()
    rclpy.shutdown(context=context)


def state(k, position=(3.0358, -2.4401), names=("joint1", "joint2")) -> bytes:
    """A serialized JointState stamped k periods after 7 s."""
    msg = JointState(name=list(names), position=list(position), velocity=[0.0] * len(names))
    msg.header.stamp.sec, msg.header.stamp.nanosec = 7, k * 1_000_000
    return serialize_message(msg)


def status(node) -> dict[str, float]:
    """The node's last status by field name."""
    fields = node.controller.status_fields + topics.NODE_STATUS_FIELDS
    return dict(zip(fields, node._status_out, strict=True))


GID_A, GID_B = bytes(range(16)), bytes(range(16, 32))


@pytest.mark.ros
def test_a_node_whose_law_fails_brakes_through_the_command_topic(node):
    """A forward_command_controller keeps the last command it got: a controller whose law
    failed for good keeps publishing, and what it publishes is its braking command (finite,
    other than the held one), not the law's last output."""
    node._on_joint_state(state(0), GID_A)
    poison(node.controller)
    for k in range(1, MAX_BAD + 11):
        node._on_joint_state(state(k), GID_A)
    assert len(node.published) == 1 + MAX_BAD + 10          # the good one, held ones, brakes
    assert status(node)["commands_stopped"] == 1.0
    held, brake = (np.array(deserialize_message(node.published[i], JointState).effort)
                   for i in (MAX_BAD, -1))
    assert np.all(np.isfinite(brake)) and not np.array_equal(brake, held)
    node._on_joint_state(state(MAX_BAD + 10), GID_A)        # a repeated state: the same brake
    assert node.published[-1] == node.published[-2]


@pytest.mark.ros
def test_a_deactivated_node_brakes_until_another_controller_commands(node):
    """Deactivated, a task-space controller answers every state with its brake (marked
    frame_id "brake": the plant follows another expected controller at once), not with its
    last command and not with silence (a forward_command_controller would hold the last
    command forever); another controller's command after its first brake ends it; activated
    again, the law commands."""
    moving = {"position": (3.0, -2.4)}
    node._on_joint_state(state(0, **moving), GID_A)
    law = deserialize_message(node.published[-1], JointState)
    assert law.header.frame_id == ""
    node.trigger_deactivate()
    assert not node.active
    # another's command before this node's first brake (the plant, following this node,
    # refused it): braking goes on, or a lockstep plant would wait for nobody
    node.out.seen(serialize_message(JointState(name=["joint1", "joint2"], effort=[1.0, 2.0])))
    assert node.out.braking
    vel = JointState(name=["joint1", "joint2"], position=[3.0, -2.4], velocity=[0.5, -0.5])
    for k in range(1, 4):
        vel.header.stamp.sec, vel.header.stamp.nanosec = 7, k * 1_000_000
        node._on_joint_state(serialize_message(vel), GID_A)
    brakes = [deserialize_message(m, JointState) for m in node.published[1:]]
    assert len(brakes) == 3 and all(b.header.frame_id == topics.BRAKE_FRAME_ID for b in brakes)
    assert all(np.all(np.isfinite(b.effort)) for b in brakes)
    assert not np.allclose(brakes[-1].effort, law.effort)
    node.out.seen(node.published[-1])                # its own brake: braking goes on
    node._on_joint_state(state(4, **moving), GID_A)
    assert len(node.published) == 5
    node.out.seen(serialize_message(JointState(name=["joint1", "joint2"],
                                                       effort=[1.0, 2.0])))
    node._on_joint_state(state(5, **moving), GID_A)           # another commands: silent
    assert len(node.published) == 5
    node.trigger_activate()
    node._on_joint_state(state(6, **moving), GID_A)
    assert deserialize_message(node.published[-1], JointState).header.frame_id == ""


@pytest.mark.ros
def test_an_oversized_joint_state_is_dropped_unparsed(node, monkeypatch):
    """One 10 MB JointState (640 000 names, as in the issue: the reader spent 1.8 s on it):
    dropped on its length, never parsed; as the sender-aware subscription hands it over
    (not copied: length only) as well. Measured: 2-50 us in the callback (the first one also
    logs its one line: 2-10 ms, rclpy's logger)."""
    big = serialize_message(JointState(name=[f"j{i:09d}" for i in range(640_000)]))
    assert len(big) > 10_000_000
    parsed = []
    read = node.inputs.read_state
    monkeypatch.setattr(node.inputs, "read_state", lambda data: parsed.append(len(data)) or read(data))
    node._on_joint_state(state(0), GID_A)
    node._on_joint_state(big, GID_A)                         # logged (once per 5 s)
    start = time.perf_counter()
    node._on_joint_state(big, GID_A)
    took = time.perf_counter() - start
    node._on_joint_state(None, GID_A, len(big))
    # under the byte bound but with more names than any arm: dropped on its name count
    many = state(1, position=[0.0] * 300, names=[f"j{i}" for i in range(300)])
    assert len(many) < joint_state_max_bytes()
    node._on_joint_state(many, GID_A)
    print(f"\n10 MB JointState dropped in {took * 1e6:.1f} us")   # a figure, not a verdict
    assert parsed == [len(state(0))] and node.inputs.inputs_oversized == 4
    node._on_joint_state(state(2), GID_A)                    # the next good state: answered
    assert len(node.published) == 2 and status(node)["inputs_oversized"] == 4


@pytest.mark.ros
def test_states_from_a_second_publisher_are_ignored_until_the_first_falls_silent(node, monkeypatch):
    warned = []
    monkeypatch.setattr(node.get_logger(), "warn", lambda msg, **_: warned.append(msg))
    node._on_joint_state(state(0), GID_A)                    # the first answered: followed
    assert node.state_source.source == GID_A and len(node.published) == 1
    parsed = []
    read = node.inputs.read_state
    monkeypatch.setattr(node.inputs, "read_state", lambda data: parsed.append(1) or read(data))
    for k in range(1, 101):                                  # 100 foreign, well-formed states
        node._on_joint_state(state(k, position=(0.0, 0.0)), GID_B)
        if k % 10 == 0:
            node._on_joint_state(state(k), GID_A)
    assert node.inputs.states_foreign == 100 and len(node.published) == 11 and len(parsed) == 10
    assert sum("refused unread" in w for w in warned) == 1
    command = deserialize_message(node.published[-1], JointState)
    assert (command.header.stamp.sec, command.header.stamp.nanosec) == (7, 100_000_000)
    # the followed one silent for SOURCE_SILENCE_S: the other is followed from its next state
    node.state_source.last_heard -= SOURCE_SILENCE_S + 0.01
    node._on_joint_state(state(101, position=(3.0, -2.4)), GID_B)
    assert node.state_source.source == GID_B and node.inputs.source_handovers == 1
    assert len(node.published) == 12
    node._on_joint_state(state(102), GID_A)                  # now the old one is foreign
    assert node.inputs.states_foreign == 101 and len(node.published) == 12
    assert status(node)["states_foreign"] == 100 and status(node)["source_handovers"] == 1


@pytest.mark.ros
def test_a_node_behind_its_plant_answers_only_the_newest_state(node):
    """Real time: states taken in one wake-up with a newer one of the same sender behind
    them are skipped (the plant holds a command for its latest state only); the newest is
    answered, and its law step spans the skipped ones."""
    node._on_joint_state(state(0), GID_A)
    assert len(node.published) == 1 and node._state_sub is not None
    node._state_sub.newer_queued = True                       # as take_data() sets it
    for k in (1, 2, 3):
        node._on_joint_state(state(k), GID_A)
    node._state_sub.newer_queued = False
    assert node.inputs.states_skipped == 3 and len(node.published) == 1
    node._on_joint_state(state(4), GID_A)
    command = deserialize_message(node.published[-1], JointState)
    assert len(node.published) == 2 and command.header.stamp.nanosec == 4_000_000


@pytest.mark.ros
def test_an_inactive_node_reads_one_state_and_answers_the_newest_at_activation(node, monkeypatch):
    """Inactive (a live switch's second scheme, or a deactivated one whose brake another
    controller relieved): the first state is read (the law's time origin), the later ones
    of that source are only kept, not deserialised; no command while inactive; at
    activation the newest is read and answered."""
    node.trigger_deactivate()
    node._on_joint_state(state(0), GID_A)                    # its brake
    node.out.seen(serialize_message(JointState(name=["joint1", "joint2"], effort=[1.0, 2.0])))
    assert not node.active and not node.out.braking
    node.published.clear()
    reads = []
    read = node.inputs.read_state
    monkeypatch.setattr(node.inputs, "read_state", lambda data: reads.append(data) or read(data))
    for k in range(50):
        node._on_joint_state(state(k), GID_A)
    assert len(reads) == 1 and node.published == []
    assert node.controller._t0 == pytest.approx(7.0)
    node.trigger_activate()
    assert len(reads) == 2 and len(node.published) == 1
    assert deserialize_message(node.published[0], JointState).header.stamp.nanosec == 49_000_000
    node._on_joint_state(state(50), GID_A)                    # active: every state read
    assert len(reads) == 3 and len(node.published) == 2


@pytest.mark.ros
def test_a_wrench_beyond_max_sensor_force_is_a_sensor_fault(node, monkeypatch):
    warned = []
    monkeypatch.setattr(node.get_logger(), "warn", lambda msg, **_: warned.append(msg))

    def wrench(fx, fy=0.0):
        msg = WrenchStamped()
        msg.wrench.force.x, msg.wrench.force.y = fx, fy
        return serialize_message(msg)

    node.inputs.wrench_message(wrench(4.0, -3.0))
    for bad in (1e12, -1e12, math.nan, math.inf, 1e200):
        node.inputs.wrench_message(wrench(bad))
        assert node.inputs.force.tolist() == [4.0, -3.0, 0.0]       # the last sane reading
    assert node.inputs.sensor_faults == 5 and len(warned) == 1 and "max_sensor_force 1000" in warned[0]
    node.inputs.wrench_message(wrench(600.0, 800.0))                    # |f| = 1000 N: on the bound, sane
    assert node.inputs.force.tolist() == [600.0, 800.0, 0.0]
    node._on_joint_state(state(0), GID_A)
    assert status(node)["sensor_faults"] == 5 and len(node.published) == 1


def test_max_bad_cycles_below_one_is_refused():
    assert "max_bad_cycles" in controller_node.COUNT_PARAMETERS
    result = ControllerNode._check_counts([rclpy.parameter.Parameter("max_bad_cycles", value=0)])
    assert not result.successful and "max_bad_cycles must be >= 1" in result.reason
