"""What a task-space controller does when it gives up, through the robot's real interface.

A real robot's command interface (ros2_control's forward_command_controller, libfranka's
torque callback) applies the last command it got for as long as no new one comes: "stop
commanding" is not a safe stop there. So a controller that gives up keeps publishing a
braking command, computed each cycle from the measured state:

    tau_b = G_b(q) - M(q) (2 w_b q' + w_b^2 (q - q_b))

a joint-space PD scaled by the URDF's mass matrix M(q) (every joint a critically damped
second-order system of natural frequency w_b = ``brake_frequency``, whatever its inertia:
a damping fixed in N m s/rad that brakes the Panda's elbow would make its light wrist
chatter, K_d dt / M_77 > 2), holding the joints near q_b, where braking began. G_b is the
arm's and the tool's gravity where the robot does not add it itself, else zero. The law
is :func:`cr_control.models.brake.brake_torque`, which the simulated robot's safe stop
uses too.

The start check finds a gravity setting that does not match the robot, or a grossly wrong
model, in the controller's first ``start_check_time`` seconds: while the law holds the arm
or approaches at ``approach_speed``, the tip must not move faster than its reference by
more than ``start_speed_error``, nor any joint faster than 0.4 of its URDF velocity limit. A
controller that adds g(q) on a robot that adds it too lifts the arm against gravity; one
that leaves it out on a robot that does not lets the arm fall: the direction of the tip's
velocity error along gravity names the likely cause. A law asked a contact force at once
(``approach_speed`` 0) pushes the tip through free space: then that is named first. The
brake then holds gravity only if the robot likely does not. With the contact-stability
monitor off (``stability_monitor`` false), a contact force that oscillates in that time as
the monitor would detect it (above ``stability_threshold``, changing sign at least
MONITOR_MIN_CROSSINGS times a second: not an impact's ring-out) stops the controller too,
naming the chatter: behind a position servo a bouncing tool need not move its tip fast
enough for the speed check (a Panda on its position interface bounced on a 100 kN/m table
for 10 s, contact lost every cycle of the bounce, its tip never 0.15 m/s off its reference).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from cr_control.core.parameters import Bound, Param
from cr_control.models.brake import brake_torque
from cr_control.schemes.blocks.contact_guard import MONITOR_MIN_CROSSINGS

#: The start check also stops a joint faster than this fraction of its URDF velocity limit
#: (braking then keeps every joint below half its limit).
JOINT_SPEED_FRACTION = 0.4

def parameters(thesis: bool) -> list[Param]:
    """The start check's and the brake's parameters; the start check is off on the thesis's
    arm, whose runs start 71 mm off their path (chapter 3) and converge faster than an
    approach (the plant there is the thesis's, with its gravity known)."""
    return [replace(PARAMETERS[0], default=0.0) if thesis else PARAMETERS[0], *PARAMETERS[1:]]


PARAMETERS = [
    Param("start_check_time", 1.0, "Start check: for this long (s) after the first state the "
          "tip must not move faster than its reference by more than start_speed_error, nor a "
          "joint faster than 0.4 of its URDF velocity limit; else the controller brakes, saying "
          "why (a gravity setting that does not match the robot, or a grossly wrong model); "
          "0 = off (the default on the thesis's arm).", "nonnegative", bound=60.0),
    Param("start_speed_error", 0.15, "Start check: largest tip speed beyond the reference's "
          "(m/s); 3 x the robots' approach_speed.", "positive", bound=Bound.SPEED),
    Param("brake_frequency", 10.0, "Braking command of a controller that gives up: natural "
          "frequency w_b (rad/s) of tau = G - M(q) (2 w_b q' + w_b^2 (q - q_b)), critically "
          "damped on every joint whatever its inertia.", "positive", bound=1000.0),
]


@dataclass(frozen=True)
class Mismatch:
    """A failed start check: the one line to log and whether the brake should hold gravity."""

    message: str
    brake_holds_gravity: bool


def start_check(scheme: str, t: float, tip_speed_error: np.ndarray, gravity: np.ndarray,
                joint_speed: np.ndarray, joint_names: list[str], velocity_limit: np.ndarray,
                values: dict, contact_rms: float = 0.0,
                contact_crossings: float = 0.0) -> Mismatch | None:
    """The start check at controller time ``t`` (module docstring): None while it passes.

    ``tip_speed_error`` = r' - r_d' (base frame, the position axes), ``gravity`` the same
    axes of the gravity vector, ``joint_speed`` q' and ``velocity_limit`` (inf: none) in
    ``joint_names`` order; ``contact_rms`` the contact-stability monitor's oscillation RMS
    (N): above its ``stability_threshold`` the tip bounces on a contact, and the cause named
    is that, not gravity; ``contact_crossings`` its filtered force's sign changes per second
    (with the monitor off, chatter by the monitor's rule stops the controller too)."""
    window = values["start_check_time"]
    if not 0.0 <= t < window:
        return None
    speed = math.sqrt(float(tip_speed_error @ tip_speed_error))
    fast = [(abs(float(w)) / lim, name, float(w), float(lim))
            for w, name, lim in zip(joint_speed, joint_names, velocity_limit, strict=True)
            if 0.0 < lim < math.inf and abs(w) > JOINT_SPEED_FRACTION * lim]
    limit = values["start_speed_error"]
    robot_adds = bool(values["robot_compensates_gravity"])
    threshold = values.get("stability_threshold", math.inf)
    chatters = (not values.get("stability_monitor", True) and contact_rms > threshold
                and contact_crossings >= MONITOR_MIN_CROSSINGS)
    if speed <= limit and not fast:
        if not chatters:
            return None
        return Mismatch(
            f"{scheme}: the contact force oscillates ({contact_rms:.3g} N RMS, above "
            f"stability_threshold {threshold:g} N) at t = {t:.3f} s with stability_monitor off "
            "(start check): the contact is too stiff for these gains; turn stability_monitor "
            "on, or lower the gains. Braking until reactivated", not robot_adds)
    g_norm = math.sqrt(float(gravity @ gravity))
    along = float(tip_speed_error @ gravity) / g_norm if g_norm > 0.0 else 0.0
    what = (f"the tip moves {speed:.3g} m/s off its reference at t = {t:.3f} s (start check: "
            f"{limit:g} m/s)")
    if fast:
        _, name, w, lim = max(fast)
        what += f", {name} at {w:+.3g} rad/s (limit {lim:g})"
    if contact_rms > values.get("stability_threshold", math.inf):
        cause = (f"the contact force oscillates ({contact_rms:.3g} N RMS): the contact is too "
                 "stiff for these gains; keep stability_monitor on, or lower the gains")
        holds = not robot_adds
    elif values.get("approach_speed", 1.0) == 0.0 and np.any(values.get("desired_force", 0.0)):
        cause = (f"the force target pushes the tip through free space (desired_force "
                 f"{[float(f) for f in values['desired_force']]} asked at once, approach_speed "
                 "0): give approach_speed for a guarded approach, or desired_force zero; "
                 "else check robot_compensates_gravity")
        holds = not robot_adds
    elif along < -0.5 * speed and not robot_adds:
        cause = ("rising against gravity: the robot likely compensates gravity itself; set "
                 "robot_compensates_gravity: true")
        holds = False
    elif along > 0.5 * speed and robot_adds:
        cause = ("falling with gravity: the robot likely does not compensate gravity; set "
                 "robot_compensates_gravity: false")
        holds = True
    else:
        cause = ("check robot_compensates_gravity first, then the model (model_mass_scale, "
                 "tool_mass) and the gains")
        holds = not robot_adds
    return Mismatch(f"{scheme}: {what}: {cause}. Braking until reactivated", holds)


__all__ = ["JOINT_SPEED_FRACTION", "PARAMETERS", "Mismatch", "brake_torque", "start_check"]
