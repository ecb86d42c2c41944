"""The plant's supervision without ROS (cr_sim.supervisor): command checks, one commander,
the watchdog's reaction, the reflexes, safe stop and resume, and the run's early ends, each
driven call by call with the wall time given (no node, no clock waits); then the offline
loop, which steps through the same object: the chapter 3 plane at K_e = 1500 N/m trips the
contact-force reflex offline as a lockstep session does, and a sweep point says "stopped".
"""

import math

import numpy as np
import pytest
from plant_harness import Log

from cr_control import offline
from cr_control.core import topics
from cr_control.experiments import evaluate
from cr_sim.loop_stats import (
    SAFE_STOP_CONTACT_FORCE,
    SAFE_STOP_JOINT_VELOCITY,
    SAFE_STOP_NONE,
    SAFE_STOP_WATCHDOG,
)
from cr_sim.plant_setup import NODE_PARAMETERS, command_limiter, initial_command
from cr_sim.plants.registry import make_plant
from cr_sim.supervisor import (
    EXIT_ENDED,
    FIRST_COMMAND_TIMEOUT_S,
    MAX_COMMAND_BYTES,
    PlantSupervisor,
)

PERIOD = 1e-3
NAMES = ("joint1", "joint2")
A, B = b"A" * 16, b"B" * 16
DEFAULTS = {p.name: p.default for p in NODE_PARAMETERS}


class Command:
    """A command's fields, as the node reads them from a JointState."""

    def __init__(self, effort=(), names=NAMES, position=(), frame_id=""):
        self.name, self.effort, self.position = tuple(names), tuple(effort), tuple(position)
        self.frame_id = frame_id


def supervisor(lockstep: bool = False, limits: bool = True, **kwargs):
    """A supervisor of the chapter 3 plant with the node's default settings, and its log."""
    plant = make_plant("compliant_plane", kwargs.pop("plant", {}))
    log = Log()
    limiter = command_limiter(plant, DEFAULTS, PERIOD) if limits else None
    sup = PlantSupervisor(plant, PERIOD, limiter, lockstep=lockstep,
                          command=initial_command(plant), logger=lambda: log,
                          scenario="compliant_plane", **kwargs)
    return sup, log


def command(sup: PlantSupervisor, gid: bytes, now: float = 0.0, **fields) -> bool:
    return sup.admit(gid, 100, now) and sup.accept(Command(**fields), gid, now)


def pressed(sup: PlantSupervisor, depth: float) -> None:
    """The ch. 3 arm at rest ``depth`` (m) inside the plane x - y + 0.25 = 0."""
    r = np.array([-0.05, 0.2]) + depth * np.array([-1.0, 1.0]) / math.sqrt(2.0)
    sup.plant.reset_state(sup.plant.arm.inverse_kinematics(r, -1.0))


# -- command checks ----------------------------------------------------------------------------
def test_commands_are_checked_limited_and_the_last_good_one_stays():
    sup, log = supervisor()
    assert command(sup, A, effort=[1.0, 2.0]) and sup.command.tolist() == [1.0, 2.0]
    assert command(sup, A, effort=[3.5, 1.5], names=("joint2", "joint1"))     # reordered
    assert sup.command.tolist() == [1.5, 2.0 + 1.0]    # 1000 N m/s x 1 ms from the last
    assert sup.stats.commands_clipped == 1
    refused = [Command(effort=[1.0]), Command(effort=[1.0, 2.0], names=("joint1", "x")),
               Command(effort=[math.nan, 0.0]), Command(position=[0.1, 0.2]), None]
    for msg in refused:
        assert not sup.accept(msg, A, 0.0)
    assert sup.command.tolist() == [1.5, 3.0] and sup.stats.commands_refused == 5
    assert log.count("refused a command (it names ['joint1', 'joint2'] with 1 efforts") == 1
    assert log.count("refused a command") == 1             # one line per 5 s, the count in it
    wrong, log = supervisor()
    assert not wrong.accept(Command(position=[0.1, 0.2]), A, 0.0)
    assert log.count("it carries positions but this plant takes efforts (scenario "
                     "compliant_plane)") == 1


def test_an_oversized_command_is_refused_unread_and_logged_once():
    sup, log = supervisor()
    assert not sup.admit(A, MAX_COMMAND_BYTES + 1, 0.0)
    assert not sup.admit(A, 10_000_000, 0.0)
    assert sup.admit(A, MAX_COMMAND_BYTES, 0.0)
    assert sup.stats.commands_oversized == 2 and log.count("unread") == 1


def test_without_limits_the_command_is_held_as_given():
    sup, _ = supervisor(limits=False)
    assert command(sup, A, effort=[1e4, -1e4]) and sup.command.tolist() == [1e4, -1e4]
    assert not command(sup, A, effort=[math.inf, 0.0]) and sup.stats.commands_refused == 1


# -- one commander -------------------------------------------------------------------------------
def test_one_commander_until_it_is_silent_for_the_handover_cycles():
    sup, log = supervisor(handover_cycles=5)
    sup.tick(0.0)
    assert command(sup, A, effort=[1.0, 1.0])
    refused = 0
    for k in range(10):
        sup.tick(k * PERIOD)
        refused += not command(sup, B, effort=[2.0, 2.0])
    assert refused == 4 and sup.stats.commands_foreign == 4       # B took over at silence 5
    assert sup.commander == B and sup.stats.commander_handovers == 1
    assert log.count("commands from a publisher unknown to the graph (gid 4242") == 1
    assert log.count("refused unread") == 1 and log.count("handover: commands now from") == 1
    assert not command(sup, A, effort=[3.0, 3.0]) and sup.command.tolist() == [2.0, 2.0]


def test_a_commander_that_brakes_gives_way_at_once():
    """A controller deactivated in a live switch brakes (frame_id "brake"): the next expected
    commander is followed from its first valid command, without the silence; a normal
    command of the followed one takes the way back."""
    sup, log = supervisor(limits=False, handover_cycles=50)
    sup.tick(0.0)
    assert command(sup, A, effort=[1.0, 1.0])
    assert not command(sup, B, effort=[2.0, 2.0])          # A commands: B refused
    assert command(sup, A, effort=[0.5, 0.5], frame_id=topics.BRAKE_FRAME_ID)
    assert sup.command.tolist() == [0.5, 0.5]                 # the brake is applied...
    assert command(sup, B, effort=[2.0, 2.0])                 # ...until B's first command
    assert sup.commander == B and sup.command.tolist() == [2.0, 2.0]
    assert not command(sup, A, effort=[0.4, 0.4], frame_id=topics.BRAKE_FRAME_ID)
    assert log.count("gave way (handover 1)") == 1
    assert command(sup, B, effort=[2.0, 2.0]) and not sup.guard.yielded


def test_lockstep_counts_the_silence_in_periods_of_wall_time():
    sup, _ = supervisor(lockstep=True, handover_cycles=20)
    assert command(sup, A, 10.0, effort=[1.0, 1.0])
    assert not command(sup, B, 10.0 + 19.5 * PERIOD, effort=[2.0, 2.0])
    assert command(sup, B, 10.0 + 20.5 * PERIOD, effort=[2.0, 2.0]) and sup.commander == B


# -- watchdog, reflexes, safe stop ---------------------------------------------------------------
@pytest.mark.parametrize("reaction", ["safe_stop", "hold", "disabled"])
def test_the_watchdog_reacts_after_the_missed_cycles(reaction):
    sup, log = supervisor(watchdog_missed_cycles=3, watchdog_reaction=reaction)
    sup.tick(0.0)
    assert command(sup, A, effort=[0.5, 0.5])
    for k in range(1, 4):
        sup.tick(k * PERIOD)
        assert not sup.safe_stop
    sup.tick(4 * PERIOD)
    assert sup.safe_stop == (reaction == "safe_stop")
    assert sup.stop_reason == (SAFE_STOP_WATCHDOG if reaction == "safe_stop" else SAFE_STOP_NONE)
    assert log.count("no new command for 3 consecutive cycles") == (reaction != "disabled")
    assert sup.stats.window_max_missed_run == 3


def test_the_force_reflex_brakes_once_and_resume_ends_it():
    sup, log = supervisor(plant={"max_contact_force": 2.0})
    assert command(sup, A, effort=[0.1, 0.1])
    sup.step()
    assert not sup.safe_stop
    pressed(sup, 0.02)                           # 150 N/m x 20 mm = 3 N > 2 N
    sup.step()
    assert sup.safe_stop and sup.stop_reason == SAFE_STOP_CONTACT_FORCE
    assert sup.stop_time == pytest.approx(2 * PERIOD) and sup.stats.safe_stop == 1.0
    assert sup.stop_text == "REFLEX: contact force 3 N > max_contact_force 2 N"
    errors = [m for level, m in log.lines if level == "error"]
    assert len(errors) == 1 and errors[0].startswith(
        "REFLEX: contact force 3 N > max_contact_force 2 N at t = 0.002 s: safe stop, braking")
    for _ in range(10):                          # commands taken, not applied: the brakes are
        assert command(sup, A, effort=[5.0, 5.0])
        brake = sup.limiter.bound(sup.plant.safe_stop_command())
        sup.step()
        assert sup.command.tolist() == pytest.approx(brake)
    assert log.count("REFLEX") == 1
    sup.plant.reset_state(sup.plant.arm.inverse_kinematics([0.1, 0.2], -1.0))
    sup.resume()
    assert not sup.safe_stop and sup.stats.safe_stop_reason == SAFE_STOP_NONE
    assert command(sup, A, effort=[0.0, 0.0]) and sup.command.tolist() == [0.0, 0.0]
    sup.resume()
    assert log.count("no safe stop is engaged") == 1


def test_the_velocity_reflex_and_a_non_finite_state():
    sup, log = supervisor()
    sup.plant.reset_state(sup.plant.state[:2], [10.5, 0.0])
    sup.step()
    assert sup.stop_reason == SAFE_STOP_JOINT_VELOCITY
    assert log.count("REFLEX: joint joint1 velocity 10.") == 1
    sup.plant.reset_state(sup.plant.state[:2], [math.nan, 0.0])
    sup.step()
    assert sup.ended.startswith("NON-FINITE: the plant's state is not finite") and sup.exit_code == 1


# -- early ends ------------------------------------------------------------------------------------
def test_no_valid_command_after_the_start_ends_the_run_in_one_line():
    sup, log = supervisor()
    sup.start(100.0)
    assert not command(sup, A, 101.0, effort=[1.0])          # refused: does not count
    sup.tick(100.0 + FIRST_COMMAND_TIMEOUT_S - 0.01)
    assert sup.ended is None
    sup.tick(100.0 + FIRST_COMMAND_TIMEOUT_S)
    assert sup.exit_code == EXIT_ENDED
    assert sup.ended == (f"ENDED: no valid command within {FIRST_COMMAND_TIMEOUT_S:g} s of the "
                         "start (1 refused, the last: it names ['joint1', 'joint2'] with 1 efforts "
                         "and 0 "
                         "positions; the plant's commanded joints are ['joint1', 'joint2']): the "
                         "plant stops, exit code 3")
    sup.tick(200.0)
    assert log.count("ENDED") == 1
    quiet, _ = supervisor(lockstep=True)                    # lockstep: its idle timer
    quiet.start(0.0)
    quiet.idle(FIRST_COMMAND_TIMEOUT_S + 1.0)
    assert quiet.ended.endswith("(none came): the plant stops, exit code 3")
    never, _ = supervisor()                                  # not started: no such rule
    never.tick(1e6)
    assert never.ended is None


def test_a_lockstep_safe_stop_without_commands_ends_the_run():
    sup, log = supervisor(lockstep=True, idle_s=2.0, plant={"max_contact_force": 2.0})
    sup.start(0.0)
    assert command(sup, A, 0.5, effort=[0.1, 0.1])
    sup.step()
    sup.idle(5.0)                                # silent, but not in a safe stop: waits
    assert sup.ended is None
    pressed(sup, 0.02)
    assert command(sup, A, 6.0, effort=[0.1, 0.1])
    sup.step()
    assert sup.safe_stop
    sup.idle(7.9)
    assert sup.ended is None
    sup.idle(8.0)
    assert sup.exit_code == EXIT_ENDED and sup.ended == (
        "ENDED: in a safe stop (contact force reflex at t = 0.002 s) and no command for 2.0 s: "
        "the controller stopped commanding; the plant stops at t = 0.002 s, exit code 3")


# -- the offline loop -----------------------------------------------------------------------------
#: The chapter 3 plane 10 x stiffer than the thesis's: the contact force overshoots the
#: 50 N reflex limit (lockstep: a safe stop at 0.5 s).
STIFF = {"stiffness": 1500.0}


def test_offline_stops_on_the_reflex_and_a_sweep_point_says_so():
    run = offline.run_scheme("adaptive_impedance", 1.0, plant_overrides=STIFF)
    assert run.safe_stop_reason == SAFE_STOP_CONTACT_FORCE
    assert run.safe_stop_text.startswith("REFLEX: contact force ")
    assert 0.3 < run.safe_stop_at < 0.7
    k = int(round(run.safe_stop_at / PERIOD))
    force = np.sqrt(np.nansum(run.true_force ** 2, axis=1))    # the plane's force is 2-D
    assert force[k - 1] <= 50.0 < force[k]                # the first state beyond the limit
    assert force[k + 200:].max() < 50.0                   # braked: never beyond it again
    controller, plant = offline.build_scheme("adaptive_impedance", plant_overrides=STIFF)
    free = offline.run(controller, plant, 1.0, supervise=False)   # the same up to the trip
    np.testing.assert_array_equal(free.position[:k + 1], run.position[:k + 1])
    assert not np.array_equal(free.position[k + 1], run.position[k + 1])
    point = evaluate.run_point("adaptive_impedance", None, 1.0, {}, STIFF)
    assert point["status"] == "stopped"
    assert point["reason"] == f"{run.safe_stop_text} at t = {run.safe_stop_at:.3f} s"


def test_offline_without_a_reflex_is_the_loop_without_supervision_bit_for_bit():
    supervised = offline.run_scheme("adaptive_impedance", 0.5)
    controller, plant = offline.build_scheme("adaptive_impedance")
    plain = offline.run(controller, plant, 0.5, supervise=False)
    assert supervised.safe_stop_reason == SAFE_STOP_NONE and math.isnan(supervised.safe_stop_at)
    for name in ("position", "velocity", "force", "command", "reference"):
        np.testing.assert_array_equal(getattr(supervised, name), getattr(plain, name))
    for field in supervised.status_fields[1:]:
        if "time" not in field:                        # compute times: wall clock
            np.testing.assert_array_equal(supervised.column(field), plain.column(field))
