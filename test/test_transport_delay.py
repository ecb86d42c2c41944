"""The driver's transport delay and late bursts (cr_sim.transport_delay): exact delays,
seeded bursts that repeat, nothing non-finite; the plant's supervisor applies it to the
commands and not to its brakes; an offline run with a delay is the undelayed plant driven
by the same commands shifted by exactly that many cycles; the robot profiles carry their
driver's delay into the offline loop and the plant's params files."""

import numpy as np
import pytest

from cr_control import offline, robots
from cr_control.offline.build import node_delay
from cr_control.tools.config_files import robot_files
from cr_sim.loop_stats import SAFE_STOP_CONTACT_FORCE
from cr_sim.plant_setup import NODE_PARAMETERS, check_settings, command_limiter, transport_delay
from cr_sim.plants.registry import make_plant
from cr_sim.supervisor import PlantSupervisor
from cr_sim.transport_delay import TransportDelay

DEFAULTS = {p.name: p.default for p in NODE_PARAMETERS}


def commands(count: int, n: int = 3) -> list[np.ndarray]:
    """``count`` distinct commands of ``n`` values (command k holds k, k + 0.1, ...)."""
    return [k + 0.1 * np.arange(n) for k in range(count)]


@pytest.mark.parametrize("cycles", [0, 1, 2, 5])
def test_the_delay_is_exact(cycles):
    delay = TransportDelay(cycles)
    given = commands(40)
    out = [delay(c).copy() for c in given]
    for k, applied in enumerate(out):
        assert np.array_equal(applied, given[max(k - cycles, 0)])   # the first before history


def test_no_delay_passes_the_same_object():
    delay = TransportDelay()
    c = np.array([1.0, 2.0])
    assert delay.passes_through and delay(c) is c


def test_the_delayed_commands_are_copies():
    """A caller that reuses its array (a controller's output buffer) does not change what
    the driver applies later."""
    delay = TransportDelay(2)
    buffer = np.zeros(2)
    out = []
    for k in range(6):
        buffer[:] = k
        out.append(delay(buffer).copy())
    assert [a[0] for a in out] == [0.0, 0.0, 0.0, 1.0, 2.0, 3.0]


def bursty(seed: int, cycles: int = 1, p: float = 0.02) -> tuple[TransportDelay, list[np.ndarray]]:
    delay = TransportDelay(cycles, p, (20, 70), seed)
    return delay, [delay(c).copy() for c in commands(5000)]


def test_bursts_are_seeded_bounded_and_catch_up():
    delay, out = bursty(7)
    again = bursty(7)[1]
    other = bursty(8)[1]
    assert all(np.array_equal(a, b) for a, b in zip(out, again, strict=True))
    assert not all(np.array_equal(a, b) for a, b in zip(out, other, strict=True))
    index = np.array([a[0] for a in out])               # command k holds k
    lag = np.arange(len(index)) - index
    # outside bursts the plain delay; in a burst the last applied held, growing the lag
    assert lag[0] == 0 and lag[1:].min() == 1 and delay.bursts > 10
    assert np.count_nonzero(lag > 1) == delay.late_cycles
    # each burst: the same command for 20-70 cycles (the lag climbs by one a cycle), then
    # the delayed stream again (the lag drops back to 1)
    runs, run = [], 0
    for k in range(1, len(lag)):
        if lag[k] > 1:
            assert index[k] == index[k - 1] and lag[k] == lag[k - 1] + 1
            run += 1
        elif run:
            runs.append(run)
            run = 0
    assert runs and min(runs) >= 20 and max(runs) <= 70
    assert len(runs) in (delay.bursts, delay.bursts - 1)   # the last may still be under way


def test_never_a_nan():
    rng = np.random.default_rng(3)
    delay = TransportDelay(3, 0.05, (1, 5), 11)
    given = [rng.normal(size=4) * 10.0 ** rng.integers(-300, 300) for _ in range(3000)]
    seen = {g.tobytes() for g in given}
    for g in given:
        out = delay(g)
        assert np.all(np.isfinite(out)) and out.tobytes() in seen


@pytest.mark.parametrize("args", [(-1,), (0, -0.1), (0, 1.5), (0, 0.1, (0, 5)),
                                  (0, 0.1, (5, 4)), (20000,)])
def test_impossible_settings_are_refused(args):
    with pytest.raises(ValueError):
        TransportDelay(*args)


def test_the_plant_nodes_settings():
    settings = {**DEFAULTS, "command_delay_cycles": 2, "late_burst_probability": 0.01,
                "late_burst_min_cycles": 3, "late_burst_max_cycles": 4, "late_burst_seed": 9}
    check_settings(settings)
    delay = transport_delay(settings)
    assert (delay.cycles, delay.burst_probability, delay.burst_cycles, delay.seed) == (
        2, 0.01, (3, 4), 9)
    for wrong in ({"command_delay_cycles": -1}, {"late_burst_min_cycles": 0},
                  {"late_burst_min_cycles": 5, "late_burst_max_cycles": 4}):
        with pytest.raises(ValueError):
            check_settings({**DEFAULTS, **wrong})


def test_a_torque_rate_limit_of_zero_is_none():
    plant = make_plant("urdf_surface", {k: v for k, v in robots.plant_values(
        robots.robot("panda")).items() if k != "scenario"})
    limited = command_limiter(plant, DEFAULTS, 1e-3)
    free = command_limiter(plant, {**DEFAULTS, "effort_rate_limit": 0.0}, 1e-3)
    step = [50.0] * 7
    assert limited.limit(step, [0.0] * 7)[0] == pytest.approx(1.0)     # 1000 N m/s x 1 ms
    assert free.limit(step, [0.0] * 7)[:4] == [50.0] * 4               # only the bounds
    assert free.limit(step, [0.0] * 7)[4:] == [12.0] * 3               # the wrist's 12 N m


# -- in the supervisor and the offline loop ------------------------------------------------------
class Recorder:
    """Records what the supervisor applies to the ch. 3 plant."""

    def __init__(self, plant):
        self.plant, self.applied = plant, []
        step = plant.step

        def record(command, period):
            self.applied.append(np.array(command, dtype=float))
            step(command, period)
        plant.step = record


def test_the_supervisor_delays_commands_and_not_its_brakes():
    plant = make_plant("compliant_plane", {})
    rec = Recorder(plant)
    sup = PlantSupervisor(plant, 1e-3, None, command=np.zeros(2), delay=TransportDelay(2))
    assert "transport delay 2 cycles" in sup.describe()
    for k in range(5):
        sup.hold(np.array([k + 1.0, 0.0]))
        sup.step()
    assert [a[0] for a in rec.applied] == [1.0, 1.0, 1.0, 2.0, 3.0]
    sup.engage(SAFE_STOP_CONTACT_FORCE, "test")
    brakes = []
    for _ in range(3):
        sup.step()
        brakes.append(sup.command.copy())
        assert np.array_equal(rec.applied[-1], sup.command)      # the brake, at once
    sup.resume()
    for _ in range(3):
        sup.hold(np.array([9.0, 0.0]))
        sup.step()
    # resumed: the stream held the brakes, not the commands from before the stop
    assert np.array_equal(rec.applied[-3], brakes[1]) and np.array_equal(rec.applied[-2], brakes[2])
    assert rec.applied[-1].tolist() == [9.0, 0.0]


def test_a_delayed_offline_run_is_the_plant_driven_by_the_shifted_commands():
    """Offline on the Panda, 2 cycles of delay: the delayed run's states are those of the
    undelayed plant given the controller's commands two cycles later (the first one held
    before), bit for bit; and they differ from an undelayed closed loop's."""
    cycles, duration, period = 2, 0.3, 1e-3
    controller, plant = offline.build_scheme("adaptive_impedance", robot="panda")
    delayed = offline.run(controller, plant, duration, period, supervise=False,
                          delay=TransportDelay(cycles))
    controller, plant = offline.build_scheme("adaptive_impedance", robot="panda")
    undelayed = offline.run(controller, plant, duration, period, supervise=False)
    _, replay = offline.build_scheme("adaptive_impedance", robot="panda")
    shifted = np.concatenate([np.repeat(delayed.command[:1], cycles, axis=0),
                              delayed.command[:-cycles]])
    positions = []
    for command in shifted:
        positions.append(replay.measurement().position.copy())
        replay.step(command, period)
    assert np.array_equal(np.array(positions), delayed.position)
    assert np.abs(undelayed.position - delayed.position).max() > 1e-9


def test_robot_profiles_carry_their_drivers_delay():
    assert robots.robot("panda").command_delay_cycles == 1
    assert robots.robot("ur5").command_delay_cycles == 1
    for name in robots.ROBOTS:
        assert node_delay("impedance", name).cycles == robots.robot(name).command_delay_cycles
        assert "command_delay_cycles: 1\n" in robot_files()[f"robots/{name}/plant.yaml"]
    assert node_delay("impedance", "panda", {"command_delay_cycles": 3}).cycles == 3
    assert node_delay("adaptive_impedance", None).passes_through      # thesis plants: none


def test_run_scheme_takes_the_delay_as_a_plant_override():
    """On a robot the profile's delay by default; a plant override sets another; the plant
    node's settings never reach the scenario's parameters."""
    base = offline.run_scheme("impedance", 0.2, robot="panda")
    same = offline.run_scheme("impedance", 0.2, robot="panda",
                              plant_overrides={"command_delay_cycles": 1})
    none = offline.run_scheme("impedance", 0.2, robot="panda",
                              plant_overrides={"command_delay_cycles": 0,
                                               "effort_rate_limit": 0.0})
    assert np.array_equal(base.position, same.position)
    assert not np.array_equal(base.position, none.position)
