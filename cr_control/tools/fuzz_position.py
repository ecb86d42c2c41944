"""cr_fuzz's ``position`` suite: a UR5 that takes joint positions (``ur5_position``: the
admittance outer loop in the controller, a forward_position_controller and joint servos in
the plant), or any profile given as ``--robot`` (``xarm7``, ``panda_position``). Absurd gains
set live, far and NaN pose targets, a 1e12 N wrench and a controller process stopped for
0.5 s (SIGSTOP, then SIGCONT).

Every case is judged, besides the session suites' rules against this suite's baseline, by
what the controller sends the robot: the commanded joint positions (the recorded
/joint_commands' ``position``) finite, and never more than one control period of the
joint's URDF velocity limit apart from one message to the next (``jump``: the largest step
in units of that, at most 1). A forward_position_controller passes each position on to the
robot's servo as it comes, so a larger step asks the joint to move faster than it can.
"""

from __future__ import annotations

import math
import os
import signal
import time

from cr_control.tools.fuzz_case import Case, Suite, nothing, plant_args

SUITES = {"position": Suite("position_baseline", "ur5_position")}
#: How long the stalled controller's process stays stopped (s).
STALL_S = 0.5
#: Absurd values set live, one request each: the law's gains, the outer loop's.
ABSURD_GAINS = (
    ("Q_c", [1e12, 1e12, 1e12]), ("orientation_stiffness", [1e12] * 3),
    ("orientation_damping", [0.0] * 3), ("posture_stiffness", -1.0), ("posture_damping", math.inf),
    ("force_admittance_mass", 1e-300), ("force_admittance_damping", 1e308),
    ("ik_damping", 1e-300), ("ik_damping", math.nan), ("max_lead", 1e6), ("anchor_gain", 1e308),
)


def absurd_gains(intruder, every_s: float = 0.1) -> None:
    """Each of ABSURD_GAINS in a request of its own, ``every_s`` apart (a parameter the
    session's scheme does not have is answered as unknown); a note names any accepted."""
    accepted = []
    for name, value in ABSURD_GAINS:
        future = intruder.set_parameters({name: value})
        if future.done() and future.result().results[0].successful:
            accepted.append(f"{name} {_text(value)}")
        intruder.spin_until(lambda: False, every_s)
    intruder.notes.append("accepted: " + (", ".join(accepted) or "none"))


def _text(value) -> str:
    """A gain's value in short: 1e+12, [1e+12, 1e+12, 1e+12] as 3 x 1e+12."""
    if isinstance(value, list):
        return f"{len(value)} x {value[0]:g}"
    return f"{value:g}"


def stall_controller(intruder, seconds: float = STALL_S) -> None:
    """Stop the controller's process (SIGSTOP) for ``seconds``, then let it go on (SIGCONT)."""
    name = intruder.controller.lstrip("/")
    process = intruder.session.processes.get(name)
    if process is None or process.poll() is not None:
        raise RuntimeError(f"no running process {name!r} in the session (a composed one?)")
    os.kill(process.pid, signal.SIGSTOP)
    try:
        time.sleep(seconds)
    finally:
        os.kill(process.pid, signal.SIGCONT)
    intruder.notes.append(f"pid {process.pid} stopped {seconds:g} s")


def _position_case(name: str, what: str, send, **changes) -> Case:
    return Case(name, what, send, suite="position", commands_judged=True, **changes)


CASES = [
    _position_case("position_baseline", "nothing (the run the position cases are judged "
                   "against)", nothing),
    _position_case("position_absurd_gains", "absurd gains set live, one request each: "
                   + ", ".join(f"{name} {_text(value)}" for name, value in ABSURD_GAINS),
                   absurd_gains),
    _position_case("position_target_10_m", "a pose target 10 m up, 2 s at 10 Hz",
                   lambda x: x.target_pose([0.0, 0.0, 10.0], [0.0, 1.0, 0.0, 0.0]),
                   speed_judged=False),
    _position_case("position_target_1e300_m", "a pose target at 1e300 m, 2 s at 10 Hz",
                   lambda x: x.target_pose([1e300, -1e300, 1e300], [0.0, 1.0, 0.0, 0.0]),
                   speed_judged=False),
    _position_case("position_target_nan", "a pose target of NaN, 2 s at 10 Hz",
                   lambda x: x.target_pose([math.nan, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0]),
                   force_judged=True),
    _position_case("position_wrench_1e12", "a wrench of 1e12 N on the sensor's topic, 1 s",
                   lambda x: x.wrench(1e12)),
    # A forward_position_controller holds the last position it got: the plant's watchdog
    # holds too (its default, a safe stop after 100 missed cycles, would brake at 0.2 s).
    _position_case("position_stalled_controller", f"the controller's process stopped {STALL_S:g} s "
                   "(SIGSTOP, SIGCONT); the driver holds the last position (plant "
                   "watchdog_reaction hold)", stall_controller,
                   session_args=plant_args(watchdog_reaction="hold"), extra_s=1.0),
]
