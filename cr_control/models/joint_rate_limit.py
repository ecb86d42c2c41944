"""A stream of joint position or velocity commands held inside the joints' limits, as a
robot's controller holds it: the simulated joint servo applies it to what it is sent, and the
admittance outer loop to what it sends, so that a stream that leaves the controller inside
the limits passes the robot unchanged.

Per joint, every period T, from the last limited command's position p, velocity v and
acceleration a (:func:`rate_limit`):

1. a position command x is first clipped into [lower, upper] and read as the velocity
   (x - p)/T; a velocity command is that velocity;
2. the velocity is clipped into +-v_max and, where an acceleration limit A is given, to
   about +-sqrt(2 A d), d the distance left to the position limit it moves towards (room to
   stop there at A, exact for a stream of periods: :func:`stop_speed`; without A: the step
   that reaches the limit);
3. the acceleration (v_target - v)/T is clipped to +-A and, where a jerk limit J is given,
   first to a +- J T (a jerk-limited stream), then to the bounds (J/A)(v_bound - v) that let
   the velocity reach its bound without overshoot;
4. v' = v + a' T, p' = p + v' T (clipped into the position limits; v' follows such a clip).

Steps 3-4 are libfranka's rate limiter for joint positions and velocities
(``franka::limitRate``: the velocity, acceleration and jerk of the finite differences, with
the velocity-safe acceleration bounds), which franka_ros2 applies to its joint position
interface; without a jerk limit they are the saturation ros2_control's joint_limits package
applies (``JointSaturationLimiter``: position, velocity and acceleration between
consecutive commands). Step 2's stopping distance keeps a command that runs into a
position limit from arriving there at speed. A command is never integrated into a jump:
whatever is asked, the stream's velocity, acceleration and jerk stay inside their limits.
Like the drivers' limiters, it does not plan: a far position command is passed at speed and
come back to (the admittance outer loop never asks for one: its virtual arm is moved onto
what the limiter lets through).

State (3 n): [p, v, a]; limits (5 n): [lower, upper, v_max, A, J], inf where none.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Rows of the packed limits: lower, upper, velocity, acceleration, jerk.
LIMIT_ROWS = 5


def packed_limits(lower, upper, velocity, acceleration, jerk) -> np.ndarray:
    """The limits :func:`rate_limit` reads (5 n), inf (or -inf) where a limit is not given."""
    rows = [np.asarray(x, dtype=float) for x in (lower, upper, velocity, acceleration, jerk)]
    n = rows[0].size
    if any(r.shape != (n,) for r in rows):
        raise ValueError("every limit needs one value per joint")
    return np.concatenate(rows)


def per_joint(values, n: int, name: str) -> np.ndarray:
    """A limit parameter as one value per joint: empty -> inf (none), one value -> every
    joint, n values -> as given (ValueError otherwise)."""
    given = np.asarray(values, dtype=float).ravel()
    if given.size == 0:
        return np.full(n, np.inf)
    if given.size == 1:
        return np.full(n, float(given[0]))
    if given.size != n:
        raise ValueError(f"{name} needs 1 or {n} values (one per joint), got {given.size}")
    return given.copy()


@njit(cache=True, error_model="numpy")
def stop_speed(amax, jmax, T, distance):
    """The highest speed from which steps of T, each slower by amax T, stop within
    ``distance`` (>= 0): v T / 2 + v^2 / (2 amax) = d, i.e. sqrt(2 amax d) made exact for a
    stream of periods (the speed n amax T stops in n steps over amax T^2 n (n + 1) / 2);
    with a jerk limit jmax, v (T / 2 + amax / jmax) + v^2 / (2 amax) = d: the deceleration
    takes amax / jmax to build up, during which the joint may still move at v."""
    lag = 0.5 * T + (amax / jmax if jmax < math.inf else 0.0)
    half = amax * lag
    return -half + math.sqrt(half * half + 2.0 * amax * max(distance, 0.0))


@njit(cache=True, error_model="numpy")
def rate_limit(state, limits, command, velocity_command, period, out):
    """One period of the limiter (module docstring): the limited position (or, with
    ``velocity_command``, velocity) of every joint into ``out``; ``state`` [p, v, a] is
    advanced. Returns the number of joints whose command was changed by more than 1e-9
    (rad or rad/s). A non-finite command leaves the state and ``out`` as the last period's
    continuation (the joint keeps its velocity, within the limits) and counts as changed."""
    n = command.shape[0]
    T = period
    changed = 0
    inf = math.inf
    for j in range(n):
        p, v, a = state[j], state[n + j], state[2 * n + j]
        lo, hi = limits[j], limits[n + j]
        vmax, amax, jmax = limits[2 * n + j], limits[3 * n + j], limits[4 * n + j]
        c = command[j]
        finite = math.isfinite(c)
        if not finite:
            v_cmd = v
        elif velocity_command:
            v_cmd = c
        else:
            v_cmd = (min(max(c, lo), hi) - p) / T
        # 2. velocity bounds, with room to stop before the position limits
        v_hi, v_lo = vmax, -vmax
        if amax < inf:
            v_hi = min(v_hi, stop_speed(amax, jmax, T, hi - p))
            v_lo = max(v_lo, -stop_speed(amax, jmax, T, p - lo))
        else:
            v_hi = min(v_hi, (hi - p) / T)
            v_lo = max(v_lo, (lo - p) / T)
        v_t = min(max(v_cmd, v_lo), v_hi)
        # 3. acceleration and jerk
        a_new = (v_t - v) / T
        if jmax < inf:
            a_new = min(max(a_new, a - jmax * T), a + jmax * T)
            if amax < inf:
                ratio = jmax / amax
                a_new = min(max(a_new, max(-amax, ratio * (v_lo - v))), min(amax, ratio * (v_hi - v)))
        elif amax < inf:
            a_new = min(max(a_new, -amax), amax)
        # 4. integrate, inside the position limits
        v_new = v + a_new * T
        p_new = p + v_new * T
        if p_new > hi or p_new < lo:
            p_new = min(max(p_new, lo), hi)
            v_new = (p_new - p) / T
            a_new = (v_new - v) / T
        if not finite or abs(v_new - v_cmd) > 1e-9:
            changed += 1
        state[j], state[n + j], state[2 * n + j] = p_new, v_new, a_new
        out[j] = v_new if velocity_command else p_new
    return changed


def limiter_state(position, velocity=None) -> np.ndarray:
    """A limiter at rest (or moving at ``velocity``) at ``position``: [p, v, 0]."""
    p = np.asarray(position, dtype=float)
    v = np.zeros(p.size) if velocity is None else np.asarray(velocity, dtype=float)
    return np.concatenate([p, v, np.zeros(p.size)])
