"""The realtime plant node's stepping, driven callback by callback (no spinning, no clock
waits): a command that answers the latest state integrates its period on arrival, the
tick then only publishes, and the states are exactly those of stepping the plant with
the commands the node applied."""

import os
from pathlib import Path

import numpy as np
import pytest
import rclpy
from plant_harness import tick
from rclpy.context import Context
from rclpy.serialization import serialize_message
from robot_data import needs_erd
from sensor_msgs.msg import JointState

from cr_sim.plant_node import PlantNode
from cr_sim.plants.registry import SCENARIOS

PERIOD = 1e-3


@pytest.fixture
def node():
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    plant_node = PlantNode(context=context)
    plant_node._started = True
    yield plant_node
    plant_node.destroy_node()
    rclpy.shutdown(context=context)


def reference_plant():
    """A second plant of the node's default scenario, with default parameters."""
    specs, factory = SCENARIOS["compliant_plane"]
    return factory({p.name: p.default for p in specs})


def answer(node: PlantNode, effort: list[float], stamp: int | None = None) -> None:
    """Deliver a command stamped like the latest state (or ``stamp``, ns)."""
    msg = JointState(name=list(node.command_names), effort=effort)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(
        node.state_stamp if stamp is None else stamp, 1_000_000_000)
    node._on_command(serialize_message(msg))    # the subscription is raw: bytes


@pytest.mark.ros
def test_an_answer_steps_on_arrival_and_the_tick_only_publishes(node):
    ref = reference_plant()
    tick(node, 1)                                  # first state, with the initial command
    ref.step(node.command.copy(), PERIOD)
    first = node.state_stamp
    assert node.plant.time == pytest.approx(PERIOD)

    answer(node, [0.5, -0.3])
    assert node.plant.time == pytest.approx(2 * PERIOD)   # integrated on arrival
    ref.step(node.command.copy(), PERIOD)
    assert node.state_stamp == first                       # ... but not yet published

    answer(node, [0.7, -0.1])                      # a second answer to the same state
    assert node.plant.time == pytest.approx(2 * PERIOD)   # no second step ahead
    second_command = node.command.copy()

    tick(node, 1)                                  # publishes the state integrated ahead
    assert node.plant.time == pytest.approx(2 * PERIOD)
    assert node.state_stamp != first
    np.testing.assert_array_equal(node.plant.state, ref.state)
    assert node.stats.total_fresh == 1

    tick(node, 1)                                  # no answer: the held (second) command
    ref.step(second_command, PERIOD)
    assert node.plant.time == pytest.approx(3 * PERIOD)
    np.testing.assert_array_equal(node.plant.state, ref.state)
    assert node.stats.total_cycles == 3 and node.stats.total_fresh == 1


@pytest.mark.ros
def test_a_late_tick_integrates_the_rest_and_a_stale_answer_waits_for_the_tick(node):
    ref = reference_plant()
    tick(node, 1)
    ref.step(node.command.copy(), PERIOD)

    answer(node, [0.4, 0.2])
    applied = node.command.copy()
    tick(node, 3)                                  # late: three periods, one done ahead
    for _ in range(3):
        ref.step(applied, PERIOD)
    assert node.plant.time == pytest.approx(4 * PERIOD)
    np.testing.assert_array_equal(node.plant.state, ref.state)

    stale = node.state_stamp - 1_000_000           # answers no published state
    answer(node, [0.6, 0.1], stamp=stale)
    assert node.plant.time == pytest.approx(4 * PERIOD)   # applied, but not ahead
    tick(node, 1)
    ref.step(node.command.copy(), PERIOD)
    np.testing.assert_array_equal(node.plant.state, ref.state)
    assert node.stats.total_fresh == 1


@pytest.mark.ros
def test_the_second_report_is_done_one_chore_per_idle_slot_never_in_one_callback(node):
    """The once-a-second report (~1.5 ms in one piece, a late tick every second) is queued:
    each step ahead runs one piece after answering; with no step ahead (no answer, a safe
    stop) a tick runs one that waited more than CHORE_WAIT_TICKS; the window is reported
    once, when its piece runs."""
    from cr_control.core import topics
    from cr_sim.plant_report import CHORE_WAIT_TICKS

    fresh_share = topics.PLANT_TIMING_FIELDS.index("window_fresh_share")
    published = []
    node.timing_pub.publish = lambda msg: published.append(list(msg.data))
    tick(node, 1)
    node._publish_timing()                         # the 1 s timer: four chores queued
    assert len(node.report.chores) == 4 and published == []
    answer(node, [0.1, 0.0])                       # step ahead, then the first chore
    assert len(node.report.chores) == 3 and published == []
    tick(node, 1)
    answer(node, [0.1, 0.0])                       # the second: /plant/timing published
    assert len(node.report.chores) == 2 and len(published) == 1
    assert published[0][fresh_share] == pytest.approx(0.5)   # window_fresh_share: 1 of 2 ticks fresh
    for _ in range(CHORE_WAIT_TICKS):              # no answers: ticks only
        tick(node, 1)
    assert len(node.report.chores) == 2                  # waited CHORE_WAIT_TICKS ticks
    tick(node, 1)
    assert len(node.report.chores) == 1                  # the tick ran one (no idle slot came)
    assert len(published) == 1                     # the window was reported once

    node.lockstep = True
    node._publish_timing()                         # lockstep: no real-time slot to wait for
    assert len(published) == 2


class _Clock:
    """A stand-in for time.monotonic, moved by hand."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def slow_ticks(node: PlantNode, clock: _Clock, count: int, spacing_s: float) -> None:
    """``count`` ticks ``spacing_s`` apart by ``clock`` (a plant whose publishes block)."""
    for _ in range(count):
        clock.now += spacing_s
        node._tick()


@pytest.mark.ros
def test_the_watchdog_trips_on_wall_time_when_the_ticks_slow_down(node, monkeypatch):
    """A plant ticking at 33 Hz (publishes blocked on a dead reader) after its controller's
    last command: the safe stop comes after watchdog.WALL_FACTOR times watchdog_missed_cycles
    periods of wall time (200 ms here; at tick 10, 30 ms apart: watchdog.WALL_MIN_SHARE of
    the 100), not after 100 ticks (3 s). One long tick of the plant's own, answered at once, trips nothing."""
    import cr_sim.plant_node as plant_node

    clock = _Clock()
    monkeypatch.setattr(plant_node.time, "monotonic", clock)
    assert node.watchdog.missed_limit == 100 and node.watchdog.wall_min_ticks == 10
    node._last_tick = clock.now
    slow_ticks(node, clock, 1, PERIOD)
    answer(node, [0.1, 0.0])
    slow_ticks(node, clock, 1, PERIOD)               # the tick sees the command: armed

    slow_ticks(node, clock, 1, 0.5)                  # the plant's own 0.5 s stall ...
    answer(node, [0.1, 0.0])                         # ... answered at once
    slow_ticks(node, clock, 1, PERIOD)
    assert not node.safe_stop and node.watchdog.run == 0

    slow_ticks(node, clock, 9, 0.03)                 # the controller is gone
    assert not node.safe_stop                        # 270 ms, but 9 ticks < 10
    slow_ticks(node, clock, 1, 0.03)
    assert node.safe_stop and node.watchdog.run == 10
    assert node.stats.safe_stop_reason == 1          # the watchdog


WARM_UP_PROBE = """
import sys, time
import numba, rclpy
from rclpy.context import Context
from cr_sim.plant_node import PlantNode

def loaded() -> dict:
    out = {}
    for name, module in list(sys.modules.items()):
        if name.startswith(("cr_sim", "cr_control")):
            for attr, value in vars(module).items():
                if isinstance(value, numba.core.dispatcher.Dispatcher):
                    out[f"{name}.{attr}"] = len(value.signatures)
    return out

context = Context()
rclpy.init(context=context, args=["--ros-args", *sys.argv[1:]])
node = PlantNode(context=context)
before = loaded()
node._started = True
node._last_tick = time.monotonic() - 1e-3
node._tick()
after = loaded()
print(sum(n > 0 for n in before.values()), sorted(k for k in after if after[k] != before.get(k)))
node.destroy_node()
rclpy.shutdown(context=context)
"""


@pytest.mark.ros
@needs_erd
@pytest.mark.parametrize("robot", ["panda", "ur5"])
def test_a_realtime_plant_loads_its_kernels_before_its_first_tick(ros_env, robot):
    """A fresh real-time plant process (the robot's wiping task): no compiled kernel is
    loaded by its first tick (the spare plant's steps loaded them while the node was built;
    the Panda's first tick took 25-30 ms before, the largest of its first second's late
    ticks)."""
    import subprocess
    import sys

    params = Path(__file__).parents[1] / "config" / "robots" / robot / "plant.yaml"
    run = subprocess.run([sys.executable, "-c", WARM_UP_PROBE, "--params-file", str(params)], env=ros_env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    loaded_before, loaded_by_the_tick = run.stdout.strip().splitlines()[-1].split(" ", 1)
    assert int(loaded_before) > 0                    # the plant has kernels, loaded already
    assert loaded_by_the_tick == "[]"


def test_the_watchdog_counts_ticks_and_wall_time_and_says_so_once():
    """cr_sim.watchdog without a node: unarmed until the first command; 100 quick ticks
    trip it once; 10 ticks 30 ms apart trip it (the wall-time rule: 300 >= 200 ms); 9 do
    not; 99 ticks 2 ms apart (198 ms) do not, the 100th does (the tick count first: a
    plant losing some ticks brakes after the ticks the parameter states); a command and a
    disarm start over."""
    from cr_sim.watchdog import Watchdog

    dog = Watchdog(100, 1e-3)
    assert all(dog.tick(t * 1e-3, False) is None for t in range(500))      # not armed
    assert dog.tick(1.0, True) is None
    reasons = [dog.tick(1.0 + k * 1e-3, False) for k in range(1, 201)]
    assert [k for k, r in enumerate(reasons, 1) if r] == [100]             # once, at 100
    assert "100 consecutive cycles in 100 ms" in reasons[99]
    dog.tick(2.0, True)
    assert [dog.tick(2.0 + 0.03 * k, False) for k in range(1, 10)] == [None] * 9
    assert "10 consecutive cycles in 300 ms" in dog.tick(2.3, False)
    dog.tick(3.0, True)
    assert [dog.tick(3.0 + 0.002 * k, False) for k in range(1, 100)] == [None] * 99
    assert "100 consecutive cycles in 200 ms" in dog.tick(3.2, False)
    dog.disarm()
    assert dog.run == 0 and dog.tick(9.0, False) is None                   # until a command
