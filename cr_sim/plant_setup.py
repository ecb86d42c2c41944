"""What the plant node is set up with before its first step, without ROS: its parameters,
its command limits (libfranka's torque and torque-rate limits, the URDF's), the command it
holds before a controller answers, and a warm-up of a spare plant's compiled kernels."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cr_control.core import topics
from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.brake import MAX_BRAKE_STEP
from cr_sim.plants.base import CommandLimiter, Plant
from cr_sim.plants.registry import SCENARIOS
from cr_sim.transport_delay import MAX_DELAY_CYCLES, TransportDelay

NODE_PARAMETERS = [
    Param("mode", "realtime", "realtime: wall-clock timer; lockstep: step on each command.",
          "choice", choices=("realtime", "lockstep"), read_only=True),
    # 10 kHz: beyond the fastest robot interfaces (1-8 kHz).
    Param("rate_hz", 1000.0, "Control rate (Hz): ticks per second in realtime, 1/period in "
          "lockstep.", "positive", read_only=True, bound=1e4),
    Param("duration", 0.0, "Simulated seconds to run before stopping; 0 = until stopped.",
          "nonnegative", read_only=True, bound=Bound.TIME),
    Param("wait_for_recorder", False, "Start only after the recorder says it is ready "
          f"({topics.RECORDER_READY}), so a recording misses nothing.", "bool", read_only=True),
    Param("contact_wrench_every", 1, "Publish the true contact wrench (analysis only) every "
          "this many states (integer >= 1); cr_session sets 10 in real time, where each "
          "publish costs the 1 kHz loop (as the controllers' diagnostics_every).", "integer",
          read_only=True, bound=1000),
    Param("lockstep_resend_s", 1.0, "Lockstep: republish the state if no command came for "
          "this long (wall s).", "positive", read_only=True, bound=60.0),
    Param("watchdog_missed_cycles", 100, "Realtime watchdog: consecutive ticks without a new "
          "command (the last one is reused meanwhile) before watchdog_reaction, >= 1. 100 = "
          "0.1 s at 1 kHz (libfranka: 20 on a real-time kernel): controller stalls of 20-60 ms "
          "were seen on a loaded 2-core machine, and a false stop needs a manual resume. Also "
          "twice that many periods of wall time over at least a tenth of the ticks: a plant whose "
          "ticks slowed down stops in time too.",
          "integer", read_only=True, bound=10000),      # 10 s at 1 kHz
    Param("watchdog_reaction", "safe_stop", "What the watchdog does: safe_stop (brakes: "
          "gravity held, joints damped to rest and held there, until resume is set), hold "
          "(keep applying the last command, logged) or disabled (not 'off': YAML reads that as "
          "false).", "choice", choices=("safe_stop", "hold", "disabled"), read_only=True),
    Param("brake_frequency", 50.0, "Safe stop of effort plants: natural frequency w_b "
          "(rad/s) of the brakes tau = G(q) - M(q) (2 w_b q' + w_b^2 (q - q_stop)), q_stop = "
          "q + q'/w_b when braking began: every joint, whatever its inertia, slows as "
          "e^(-w_b t) and is held where it stops. At most "
          f"{MAX_BRAKE_STEP:g} x rate_hz (a torque held for a period brakes stably only so).",
          "positive", read_only=True, bound=Bound.BANDWIDTH),
    Param("resume", False, "Set to true to leave a safe stop (the plant applies commands "
          "again and sets this back to false). Never happens by itself.", "bool"),
    Param("effort_limit", [0.0], "Joint effort limits (N m): one value for every joint or "
          "one per joint; 0 = the URDF's <limit effort>. Commands beyond are clipped.",
          "nonnegative_vector", read_only=True, bound=Bound.EFFORT),
    # 1e9 N m/s (1e6 N m per 1 ms cycle): no limit in practice, which is how the
    # comparisons with the offline loop (which has none) open it up; fjr_robust_adaptive's
    # thesis runs need 1e5.
    Param("effort_rate_limit", 1000.0, "Torque-rate limit (N m/s) between consecutive "
          "commands (libfranka: 1000); commands beyond are clipped. 0 = none (a "
          "forward_command_controller, MuJoCo's actuators: not every driver limits it).",
          "nonnegative", read_only=True, bound=1e9),
    Param("command_delay_cycles", 0, "Transport delay (integer >= 0): the command applied at "
          "a step is the one held this many periods before, as a driver applies the answer to "
          "a state a cycle or more later (libfranka: the next 1 kHz cycle, 1; ur_robot_driver's "
          "effort interface: the next 2 ms RTDE cycle, 1; the robot profiles set their "
          "driver's). 0: the answer to a state acts from that state on (the thesis's "
          "simulations).", "integer", read_only=True, bound=MAX_DELAY_CYCLES),
    Param("late_burst_probability", 0.0, "Late answers: each cycle outside a burst starts "
          "one with this probability (a seeded draw: lockstep and the offline loop draw "
          "the same); during it the driver keeps applying the last command it applied, then "
          "catches up. 0 = none; 0.01 with bursts of 20-70 cycles is a Python controller on "
          "a loaded machine.", "nonnegative", read_only=True, bound=1.0),
    Param("late_burst_min_cycles", 20, "Shortest late burst (cycles, integer >= 1).",
          "integer", read_only=True, bound=MAX_DELAY_CYCLES),
    Param("late_burst_max_cycles", 70, "Longest late burst (cycles, integer >= "
          "late_burst_min_cycles); each burst's length is drawn uniformly in between.",
          "integer", read_only=True, bound=MAX_DELAY_CYCLES),
    Param("late_burst_seed", 0, "Seed of the late bursts' draws.", "integer", read_only=True,
          bound=Bound.SEED),
    Param("command_handover_cycles", 50, "One commander at a time (ros2_control, libfranka): "
          "commands from "
          "any other publisher on /joint_commands are refused (counted in commands_foreign) "
          "until the commander has sent nothing for this many cycles (realtime: ticks; "
          "lockstep: this many periods of wall time); then the next valid command's publisher "
          "takes over. >= 1. 50 = 50 ms at 1 kHz: below the watchdog's 100, so a restarted "
          "controller takes over before the safe stop; above the 20-60 ms stalls of a loaded "
          "controller, so a stalled one is not displaced by a stray publisher.", "integer",
          read_only=True, bound=10000),
]


SCENARIO_PARAMETER = Param("scenario", "compliant_plane", "Simulated scenario.", "choice",
                           choices=tuple(SCENARIOS), read_only=True)


def plant_parameters(scenario: str) -> list[Param]:
    """Every parameter of the plant node running ``scenario``, in declaration order."""
    specs = SCENARIOS[scenario][0]
    return [replace(SCENARIO_PARAMETER, default=scenario), *NODE_PARAMETERS, *specs]


def check_settings(settings: dict) -> None:
    """ParameterError for node settings that cannot work together: a cycle count below one
    (below zero for the delay), late bursts shorter at most than at least, or brakes too fast
    for the rate (a brake torque held for a period is stable only up to ``MAX_BRAKE_STEP`` x
    rate_hz)."""
    for name in ("watchdog_missed_cycles", "command_handover_cycles", "contact_wrench_every",
                 "late_burst_min_cycles"):
        if settings[name] < 1:
            raise ParameterError(f"parameter {name} must be >= 1")
    if settings["command_delay_cycles"] < 0:
        raise ParameterError("parameter command_delay_cycles must be >= 0")
    if settings["late_burst_max_cycles"] < settings["late_burst_min_cycles"]:
        raise ParameterError(
            f"late_burst_max_cycles {settings['late_burst_max_cycles']} is below "
            f"late_burst_min_cycles {settings['late_burst_min_cycles']}")
    brake, rate = settings["brake_frequency"], settings["rate_hz"]
    if brake * (1.0 / rate) > MAX_BRAKE_STEP:        # as the node's period
        raise ParameterError(
            f"brake_frequency {brake:g} rad/s is too high for rate_hz {rate:g}: a brake torque "
            f"held for a period is stable only up to brake_frequency = {MAX_BRAKE_STEP:g} x "
            f"rate_hz ({MAX_BRAKE_STEP * rate:g} rad/s here)")


def command_limiter(plant: Plant, settings: dict, period: float) -> CommandLimiter:
    """The plant's command limits: effort bounds (``effort_limit``, else the URDF's) and
    the torque-rate limit; position plants: the URDF's position and velocity limits; velocity
    plants: the URDF's velocity limits and the plant's acceleration limits as their rate.

    A joint with no known effort limit (no URDF and none given) is left unbounded, with
    no rate limit either: the node warns at start (see :func:`unlimited_joints`).
    """
    limits = plant.joint_limits()
    n = len(plant.command_joints)
    if plant.command_interface == "position":
        return CommandLimiter(limits.lower, limits.upper, limits.velocity, period)
    if plant.command_interface == "velocity":     # the velocity limits, the acceleration's as rate
        acceleration = getattr(plant, "acceleration_limits", lambda: np.full(n, np.inf))()
        return CommandLimiter(-limits.velocity, limits.velocity, acceleration, period)
    given = list(settings["effort_limit"])
    if len(given) not in (1, n):
        raise ParameterError(f"effort_limit needs 1 or {n} values, got {len(given)}")
    effort = []
    for i in range(n):
        value = given[0] if len(given) == 1 else given[i]
        urdf = float(limits.effort[i])
        effort.append(value if value > 0.0 else (urdf if 0.0 < urdf < np.inf else np.inf))
    rate_limit = settings["effort_rate_limit"] or np.inf          # 0: none
    rate = [rate_limit if e < np.inf else np.inf for e in effort]
    return CommandLimiter([-e for e in effort], effort, rate, period)


def transport_delay(settings: dict) -> TransportDelay:
    """The driver's transport delay and late bursts the node's settings ask for
    (``command_delay_cycles``, ``late_burst_*``)."""
    return TransportDelay(settings["command_delay_cycles"], settings["late_burst_probability"],
                          (settings["late_burst_min_cycles"], settings["late_burst_max_cycles"]),
                          settings["late_burst_seed"])


def unlimited_joints(plant: Plant, limiter: CommandLimiter) -> list[str]:
    """Joints whose commands the limiter does not bound."""
    return [name for name, lo, hi in zip(plant.command_joints, limiter.lower, limiter.upper, strict=True)
            if lo == -np.inf and hi == np.inf]


def unlimited_note(plant: Plant, limiter: CommandLimiter) -> str | None:
    """The node's warning at start for joints whose commands are not bounded (None: all are)."""
    unbounded = unlimited_joints(plant, limiter)
    if not unbounded:
        return None
    return (f"no command limit known for {unbounded} (no URDF limit): commands to them are not "
            "bounded" + ("; set effort_limit" if plant.command_interface == "effort" else ""))


def warm_up(spare: Plant, period: float) -> None:
    """Run a spare plant of the node's scenario through what ticks and a safe stop call
    (steps, measurement, sensors, reflex checks, true contact wrench, brakes), so that the
    real plant's first tick does not pay for loading its compiled kernels: the Panda's
    first tick took 25-30 ms (numba's cache, and numpy.ma imported by numba's typeof), the
    largest of the late ticks that cost its first second ~20 ticks (2026-11-26)."""
    command = initial_command(spare)
    for _ in range(2):
        spare.step(command, period)
    spare.measurement()
    if spare.sensor_fields:                   # published only then (one plant keeps an array)
        spare.sensors()
    spare.contact_force_magnitude()
    spare.true_velocity()
    truth = getattr(spare, "contact_wrench", None)
    if callable(truth):
        truth()
    spare.begin_safe_stop()
    spare.step(np.asarray(spare.safe_stop_command(), dtype=float), period)


def initial_command(plant: Plant) -> np.ndarray:
    """What the plant holds before the first command: its own held input where it has one
    (``plant.held``; the ch. 4 plant starts in equilibrium with delta_c = delta), else the
    current positions for position plants (hold still), and for effort plants the gravity
    torque G(q) where the plant knows it (the arm is held as a real arm's brakes or its own
    gravity compensation hold it until a controller takes over), else zero efforts.
    A realtime plant steps with it until a controller answers (a few ms: a 20 kg arm under
    zero torque reached 0.84 rad/s at the Panda's elbow before the first command; zero
    positions would pull the ch. 4 end effector off the constraint)."""
    n = len(plant.command_joints)
    held = getattr(plant, "held", None)
    if held is not None and np.shape(held) == (n,) and np.all(np.isfinite(held)):
        return np.array(held, dtype=float)
    if plant.command_interface == "position":
        return np.array(plant.measurement().position, dtype=float)
    # a plant's noise-free position where it has one: no noise drawn (the offline loop draws
    # none here, so lockstep stays bit for bit with a noisy sensor)
    true_position = getattr(plant, "true_position", None)
    position = true_position() if callable(true_position) else plant.measurement().position
    gravity = plant.gravity_torque(np.asarray(position, dtype=float))
    if gravity is not None and gravity.shape == (n,) and np.all(np.isfinite(gravity)):
        return gravity
    return np.zeros(n)
