"""The desired motion and force of a task-space scheme, with exact derivatives.

Three sources, one after the other:

1. The scheme's own trajectory, per position axis (3.93; 5.21-5.22 with phases)

       r_d(t) = offset - amplitude * cos(w t + phase)     (+ the start position r(0) if
       r_d'   = amplitude * w sin(w t + phase)              ``reference_relative``)
       r_d''  = amplitude * w^2 cos(w t + phase)

   The thesis's paths are absolute; on any other robot the default is relative with zero
   amplitude: the controller holds the position it starts in. A path that starts moving
   (the wiping circle: r_d' = a w along one axis at t = 0) starts from rest when
   ``reference_ramp_time`` T > 0: it runs on its own time tau, whose rate is ramped in,

       tau' = S(t / T),  S(x) = 3 x^2 - 2 x^3 (1 from t = T on),
       tau  = T (x^3 - x^4 / 2) for x = t / T <= 1, t - T / 2 after,
       r_d(tau),  r_d' tau',  r_d'' tau'^2 + r_d' tau''   (tau'' = 6 x (1 - x) / T),

   so r_d' and r_d'' start at zero instead of stepping when contact is found (a step the
   chapter 3 laws answered with 3-5 N m on the Panda's joints), and the path lags its
   unramped self by T / 2 from then on. T = 0: the thesis's path, at full speed from t = 0.
2. A target pose (``~/target_pose``): from the first one on, r_d follows the latest target
   through a critically damped filter of natural frequency w_f (``target_filter_frequency``),

       r_d'' = w_f^2 (p_target - r_d) - 2 w_f r_d',

   started from the trajectory's r_d, r_d' at that moment, so a new target never jumps the
   reference (Mayr's controller #5: "tries to move very fast on a new reference"). A far
   target would still be approached fast (peak speed w_f d / e for a step d: 1.8 m/s for
   1 m at w_f = 5 rad/s, above the Panda's 1.7 m/s Cartesian limit), so the filter is given
   the target at most L = 2 v_max / w_f ahead of r_d (v_max = ``target_max_speed``): its
   speed then rises to w_f L / 2 = v_max without overshoot and stays there until the target
   is within L, where the filter ends critically damped as before (a step within L, and so
   any streamed path slower than v_max, is followed exactly as without it). Before that,
   each cycle, the target is held within a depth into the surface, a lead along it and an
   angle of the measured tip (:mod:`.target_bounds`: the normal force stays the force
   loop's, however far or deep the target). The desired
   orientation (the tip's orientation at the first state until a target arrives) follows
   the same filter on SO(3): w_d' = w_f^2 log(q_target q_d^-1) - 2 w_f w_d, q_d advanced by
   exp(w_d dt). Where the arm cannot follow, the filter waits for it: the pace
   p = clip((PACE_STOP - s) / (PACE_STOP - PACE_FULL), 0, 1), s the largest ratio of a
   joint's speed to its URDF velocity limit, scales v_max and the orientation's pull
   (w_f^2 p log(...)). Up to PACE_FULL of every limit nothing changes; from PACE_STOP on
   the reference is given no further target and decelerates as the filter does. A target
   at the edge of the reach (a Panda stretched straight up, its wrist turned to point the
   tool down) asks fast joints for a slow tip: followed at 0.5 m/s, joint 4 passed its
   2.175 rad/s limit 2.1 s after a target 10 m up (offline, Panda).
3. The desired force f_d: ``desired_force``, or the latest ``~/target_wrench``, ramped in
   over ``force_ramp_time`` from the first state (a robot that starts touching the table
   must not be kicked into it: the admittance below would start at (f_d - f)/m_a). Each
   target wrench is approached at ``target_force_rate`` N/s at most, the first from the
   desired force until then: a target flipping sign at every cycle (500 Hz on a UR) drove
   the NN scheme on the UR5 into a limit cycle that outlived the flips (up to 74 N true,
   the tool then off the table); rate-limited it is a dither of rate x dt. Taken as it
   came, a first target of 30 N (10 N before) kicked the Panda's joint 6 to 1.08 rad/s
   in a real-time session. A force
   admittance on the reference makes the position laws of chapter 3 (which regulate
   position, the force following from the environment: 3.5) hold a force: along
   n_f = f_d/|f_d| the reference is moved by delta,

       m_a delta'' + d_a delta' = n_f^T (f_d - f),   r_d <- r_d - delta n_f  (and r_d', r_d''),

   |delta| <= ``force_admittance_limit``; off while ``force_admittance_damping`` is 0 (the
   thesis runs). In steady contact n_f^T f = |f_d| whatever the surface's stiffness. When
   f_d turns, the shift made, delta n_f, is kept as far as it lies along the new n_f (a
   sign flip keeps r_d where it is). At the limit, pushed further out, delta stands still
   and so does the reference: its velocity and acceleration along n_f are zero (an
   acceleration reported there while r_d stood still was a constant error the law's c_hat
   (3.11) integrated: a -10 N "pull away" target held 20 s in the air wound it to
   13 m/s^2, and the tool came back pressing 206 N).

The filter and the admittance are advanced by one classical RK4 step over each cycle's dt
(the force held over the step) before the values are read.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

from cr_control.core.packing import Layout, take, views_layout
from cr_control.core.parameters import Bound, Param
from cr_control.core.so3 import (
    quaternion_conjugate,
    quaternion_exp,
    quaternion_from_matrix,
    quaternion_multiply,
    rotation_vector,
)
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.blocks import target_bounds as bounds

#: max_target_force's default (N).
MAX_TARGET_FORCE = 100.0


def reference_parameters(m: int, offset: list[float], amplitude: list[float],
                         phase: list[float], frequency: float, relative: bool,
                         desired_force: list[float] | None, what: str) -> list[Param]:
    """Parameters of the desired motion and force on an m-axis position task, with the
    defaults given (``what`` names their source: a thesis section or "hold"); no
    ``desired_force`` parameter if its default is None (a law with its own, 5.9)."""
    force = [] if desired_force is None else [
        Param("desired_force", desired_force, "Desired contact force f_d on the robot (N), base "
              "frame (3.5); ~/target_wrench replaces it.", "vector", m, bound=Bound.FORCE)]
    return [
        Param("reference_offset", offset, "r_d = offset - amplitude*cos(w t + phase) per axis: "
              f"offset (m) ({what}).", "vector", m, bound=Bound.LENGTH),
        Param("reference_amplitude", amplitude, "r_d: amplitude per axis (m).", "vector", m,
              bound=Bound.LENGTH),
        Param("reference_phase", phase, "r_d: phase per axis (rad).", "vector", m, bound=Bound.PHASE),
        Param("reference_frequency", frequency, "r_d: angular frequency w (rad/s).",
              "nonnegative", bound=Bound.MOTION_FREQUENCY),
        Param("reference_relative", relative, "r_d's offset is relative to the tip position at "
              "the first state (true) or absolute in the base frame (false).", "bool"),
        Param("reference_ramp_time", 0.0, "The path starts from rest: its own time runs at a "
              "rate ramped in over this time (s; smoothstep, so r_d' and r_d'' start at 0 and "
              "the path lags by half of it from then on); 0 = at full speed from the start, as "
              "in the thesis. Set at start.", "nonnegative", bound=Bound.TIME, read_only=True),
        *force,
        Param("force_ramp_time", 0.0, "The desired force is ramped in over this time from the "
              "first state (s; smoothstep 3 s^2 - 2 s^3, no jump in f_d or its rate); 0 = at "
              "once, as in the thesis.", "nonnegative", bound=Bound.TIME),
        Param("target_filter_frequency", 5.0, "Targets from ~/target_pose are followed through "
              "a critically damped filter of this natural frequency (rad/s).", "positive",
              bound=Bound.BANDWIDTH),
        Param("target_max_speed", 0.5, "The reference follows a ~/target_pose at most this "
              "fast (m/s): the target filter is given the target at most 2 v_max / w_f ahead "
              "(a step within that is followed as before). 0.5 m/s: approach_speed's bound, "
              "twice the 0.25 m/s of a collaborative arm near people.", "positive",
              bound=Bound.SPEED),
        Param("target_force_rate", 100.0, "The force given to the law approaches each "
              "~/target_wrench at most this fast (N/s), the first one from desired_force: a "
              "10 N step takes 0.1 s, and a target flipping sign every cycle moves it by rate "
              "x dt.", "positive",
              bound=1e5),
        Param("max_target_force", MAX_TARGET_FORCE, "A ~/target_wrench force above this (N, "
              "Euclidean norm) is scaled down to it (logged); 100 N: a hard push by hand, 5x "
              "the robots' 10 N wiping task (their profiles set 50 N).", "positive",
              bound=Bound.FORCE),
        Param("force_admittance_mass", 1.0, "Force admittance on the reference: mass m_a "
              "(kg) of m_a delta'' + d_a delta' = n_f^T (f_d - f).", "positive", bound=Bound.MASS),
        Param("force_admittance_damping", 0.0, "Force admittance on the reference: damping "
              "d_a (N s/m); 0 = off (the thesis's laws as printed).", "nonnegative", bound=Bound.GAIN),
        Param("force_admittance_limit", 0.05, "Force admittance: largest shift |delta| of the "
              "reference along the desired force (m).", "nonnegative", bound=Bound.LENGTH),
        *guard.guard_parameters(m),
    ]


#: Targets set by the node (one float vector): a pose counter (0 = none yet), its position
#: (3) and quaternion [w, x, y, z]; a wrench counter (0 = none yet) and its force (3).
#: The target filter's pace (module docstring): full up to this fraction of every joint's
#: URDF velocity limit, stopped from PACE_STOP (below the joint limit guard's brake at 0.8).
PACE_FULL = 0.2
PACE_STOP = 0.4
TARGETS = Layout(pose_seq=1, position=3, quaternion=4, wrench_seq=1, force=3)
_T_POSE_SEQ, _T_POS, _T_QUAT, _T_WRENCH_SEQ, _T_FORCE = (TARGETS.offset(n) for n in TARGETS.shapes)
#: An empty vector: the blocks' views of it are empty, where they end is their size.
_NOTHING = np.zeros(0)


#: One cycle's desired motion (:func:`desired_motion`) on the task's m position axes:
#: position r, velocity r', acceleration r'' and force f_d (m each), orientation quat
#: [w, x, y, z] and angular velocity w (base frame), the null-space posture (n), and the
#: force ramp's factor now (1 once ramped in; 0 during a guarded approach).
DesiredMotion = namedtuple("DesiredMotion", ["r", "v", "a", "f", "quat", "w", "posture", "ramp"])

#: The desired motion's packed gains, block by block (names = parameter names; the posture
#: comes here too: it is held like the start pose; ``guard``: :func:`contact_guard.guard_gains`).
ReferenceGains = namedtuple("ReferenceGains", [
    "reference_offset", "reference_amplitude", "reference_phase", "reference_frequency",
    "reference_relative", "desired_force", "force_ramp_time", "target_filter_frequency",
    "force_admittance_mass", "force_admittance_damping", "force_admittance_limit", "posture",
    "posture_given", "guard", "target_max_speed", "target_force_rate", "reference_ramp_time"])

#: The desired motion's internal state, block by block: started (0/1), the start position,
#: orientation and joint positions, the last target pose's counter, the target filter
#: (r_f, v_f, quat_f, w_f), the admittance's [delta, delta'], the contact guard's state
#: (:func:`contact_guard.guard_state`), the direction n_f the admittance last ran along, the
#: force given to the law (f_target, slewed) and whether it is set.
ReferenceState = namedtuple("ReferenceState", [
    "started", "r_start", "quat_start", "q_start", "pose_seq", "r_f", "v_f", "quat_f", "w_f",
    "delta", "guard", "n_f", "f_target", "f_target_set"])


@njit(cache=True, error_model="numpy")
def reference_gains_views(gains, m, n):
    """(:data:`ReferenceGains` views of ``gains`` for m axes and n joints, where they end)."""
    offset, k = take(gains, 0, m)
    amplitude, k = take(gains, k, m)
    phase, k = take(gains, k, m)
    frequency, k = take(gains, k, 1)
    relative, k = take(gains, k, 1)
    desired_force, k = take(gains, k, m)
    ramp_time, k = take(gains, k, 1)
    filter_frequency, k = take(gains, k, 1)
    admittance_mass, k = take(gains, k, 1)
    admittance_damping, k = take(gains, k, 1)
    admittance_limit, k = take(gains, k, 1)
    posture, k = take(gains, k, n)
    posture_given, k = take(gains, k, 1)
    guard_gains, k = take(gains, k, guard.guard_sizes(m)[0])
    max_speed, k = take(gains, k, 1)
    force_rate, k = take(gains, k, 1)
    path_ramp_time, k = take(gains, k, 1)
    return ReferenceGains(offset, amplitude, phase, frequency, relative, desired_force,
                          ramp_time, filter_frequency, admittance_mass, admittance_damping,
                          admittance_limit, posture, posture_given, guard_gains, max_speed,
                          force_rate, path_ramp_time), k


@njit(cache=True, error_model="numpy")
def reference_state_views(state, m, n):
    """(:data:`ReferenceState` views of ``state`` for m axes and n joints, where they end:
    the scheme's own state follows)."""
    started, k = take(state, 0, 1)
    r_start, k = take(state, k, m)
    quat_start, k = take(state, k, 4)
    q_start, k = take(state, k, n)
    pose_seq, k = take(state, k, 1)
    r_f, k = take(state, k, m)
    v_f, k = take(state, k, m)
    quat_f, k = take(state, k, 4)
    w_f, k = take(state, k, 3)
    delta, k = take(state, k, 2)
    guard_state, k = take(state, k, guard.guard_sizes(m)[1])
    n_f, k = take(state, k, m)
    f_target, k = take(state, k, m)
    f_target_set, k = take(state, k, 1)
    return ReferenceState(started, r_start, quat_start, q_start, pose_seq, r_f, v_f, quat_f,
                          w_f, delta, guard_state, n_f, f_target, f_target_set), k


def reference_gains(m: int, n: int) -> Layout:
    """Packed reference parameters for m axes and n joints (:data:`ReferenceGains`)."""
    return views_layout(reference_gains_views, m, n)


def reference_state(m: int, n: int) -> Layout:
    """The desired motion's internal state for m axes and n joints (:data:`ReferenceState`)."""
    return views_layout(reference_state_views, m, n)


@njit(cache=True, error_model="numpy")
def reference_gains_size(m, n):
    """reference_gains(m, n).size, for kernels."""
    return reference_gains_views(_NOTHING, m, n)[1]


@njit(cache=True, error_model="numpy")
def guard_state_of(state, m, n):
    """The guard's block (:mod:`contact_guard`) of a packed reference state (a view)."""
    return reference_state_views(state, m, n)[0].guard


@njit(cache=True, error_model="numpy")
def guard_gains_of(gains, m, n):
    """The guard's block (:mod:`contact_guard`) of packed reference gains (a view)."""
    return reference_gains_views(gains, m, n)[0].guard


@njit(cache=True, error_model="numpy")
def cosine_reference(offset, amplitude, phase, w, t):
    """(r_d, r_d', r_d'') of r_d(t) = offset - amplitude * cos(w t + phase), per axis, exact
    derivatives (3.93: x_d = -0.1 cos 2t, y_d = 0.35 - 0.1 cos 2t; 5.21-5.22 with phases)."""
    n = offset.shape[0]
    r, v, a = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        c, s = math.cos(w * t + phase[i]), math.sin(w * t + phase[i])
        r[i] = offset[i] - amplitude[i] * c
        v[i] = amplitude[i] * w * s
        a[i] = amplitude[i] * w * w * c
    return r, v, a


@njit(cache=True, error_model="numpy")
def path_time(t, ramp):
    """(tau, tau', tau'') of the path's own time at t, its rate ramped in over ``ramp`` s
    (module docstring, source 1; ``ramp`` 0: tau = t)."""
    if ramp <= 0.0:
        return t, 1.0, 0.0
    if t >= ramp:
        return t - 0.5 * ramp, 1.0, 0.0
    x = max(t, 0.0) / ramp
    return ramp * x * x * x * (1.0 - 0.5 * x), smoothstep(x), 6.0 * x * (1.0 - x) / ramp


@njit(cache=True, error_model="numpy")
def smoothstep(x):
    """3 x^2 - 2 x^3 on [0, 1] (0 before, 1 after): a ramp with zero slope at both ends."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, error_model="numpy")
def _filter_step(x, v, target, w, dt):
    """One RK4 step of x'' = w^2 (target - x) - 2 w x' (target held)."""
    def f(x, v):
        return v, w * w * (target - x) - 2.0 * w * v
    k1x, k1v = f(x, v)
    k2x, k2v = f(x + 0.5 * dt * k1x, v + 0.5 * dt * k1v)
    k3x, k3v = f(x + 0.5 * dt * k2x, v + 0.5 * dt * k2v)
    k4x, k4v = f(x + dt * k3x, v + dt * k3v)
    return (x + dt / 6.0 * (k1x + 2.0 * (k2x + k3x) + k4x),
            v + dt / 6.0 * (k1v + 2.0 * (k2v + k3v) + k4v))


@njit(cache=True, error_model="numpy")
def _admittance_step(delta, delta_dot, push, m_a, d_a, limit, dt):
    """One RK4 step of m_a delta'' + d_a delta' = push (held), |delta| <= limit."""
    def acc(dd):
        return (push - d_a * dd) / m_a
    k1x, k1v = delta_dot, acc(delta_dot)
    k2x, k2v = delta_dot + 0.5 * dt * k1v, acc(delta_dot + 0.5 * dt * k1v)
    k3x, k3v = delta_dot + 0.5 * dt * k2v, acc(delta_dot + 0.5 * dt * k2v)
    k4x, k4v = delta_dot + dt * k3v, acc(delta_dot + dt * k3v)
    delta += dt / 6.0 * (k1x + 2.0 * (k2x + k3x) + k4x)
    delta_dot += dt / 6.0 * (k1v + 2.0 * (k2v + k3v) + k4v)
    if abs(delta) > limit:
        delta, delta_dot = math.copysign(limit, delta), 0.0
    return delta, delta_dot


@njit(cache=True, error_model="numpy")
def _slewed_target(given, given_set, f_target, rate, dt, before):
    """The target force the law is given (``given``, in place), approached at ``rate`` N/s
    at most (Euclidean): the first one from ``before``, the desired force until then
    (``given_set[0]`` 0 until then), each later one from the last given."""
    if given_set[0] == 0.0:
        given[:] = before
        given_set[0] = 1.0
    if dt > 0.0:
        step = f_target - given
        size = math.sqrt(np.sum(step * step))
        if size > rate * dt:
            step *= rate * dt / size
        given += step
    return given.copy()


@njit(cache=True, error_model="numpy")
def _turn_admittance(delta, n_last, n_f):
    """A desired force that turned (n_f is not the direction the admittance last ran
    along, ``n_last``; zeros before the first time) keeps the shift it made, delta n_last,
    as far as it lies along the new n_f: delta <- delta (n_last . n_f), delta' likewise (a
    sign flip keeps r_d where it is instead of moving it by 2 delta: after a -10 N "pull"
    target held at the limit, +10 N moved r_d 10 cm, from 5 cm above the table to 5 cm into
    it, and the NN scheme hit the table with 28 N). ``delta`` = [delta, delta'], in place;
    ``n_last`` becomes n_f."""
    m = n_f.shape[0]
    turned, started, c = False, False, 0.0
    for i in range(m):
        turned = turned or n_last[i] != n_f[i]
        started = started or n_last[i] != 0.0
        c += n_last[i] * n_f[i]
    if turned:
        if started:
            delta[0] *= c
            delta[1] *= c
        n_last[:] = n_f


@njit(cache=True, error_model="numpy")
def _admittance_stopped(delta, push, limit):
    """True where the admittance's shift is held at its limit and pushed further out: it
    does not move (delta' = 0, delta'' = 0)."""
    return abs(delta) >= limit and (limit <= 0.0 or push * delta >= 0.0)


@njit(cache=True, error_model="numpy")
def target_pace(velocity_limit, v):
    """The target filter's pace p in [0, 1] at joint velocities ``v`` (module docstring):
    1 up to PACE_FULL of every joint's velocity limit, 0 from PACE_STOP of any."""
    s = 0.0
    for i in range(v.shape[0]):
        s = max(s, abs(v[i]) / velocity_limit[i])
    return min(1.0, max(0.0, (PACE_STOP - s) / (PACE_STOP - PACE_FULL)))


@njit(cache=True, error_model="numpy")
def _leash(target, x, v_max, w):
    """The target the filter is given: ``target``, or the point 2 v_max / w from ``x``
    towards it if it is farther (module docstring)."""
    length = 2.0 * v_max / w
    gap = target - x
    distance = math.sqrt(np.sum(gap * gap))
    if distance <= length:
        return target
    return x + gap * (length / distance)


@njit(cache=True, error_model="numpy")
def _bounded(g, s, target, r, m, w_f):
    """The target position at most the depth and lead of :mod:`.target_bounds` from the
    measured tip r (u: the guard's direction into the surface)."""
    return bounds.bounded_position(target, r, guard.direction(s.guard, m),
                                   bounds.depth_bound(guard.speed(g.guard), w_f),
                                   bounds.LEAD_S * g.target_max_speed[0] / w_f)


@njit(cache=True, error_model="numpy")
def _rows_of(x, rows, m):
    out = np.empty(m)
    for i in range(m):
        out[i] = x[int(rows[i])]
    return out


@njit(cache=True, error_model="numpy")
def desired_motion(rows, gains, state, targets, t, dt, r, R, q, force, pace=1.0):
    """The :data:`DesiredMotion` at time t (module docstring); its ramp is for laws with a
    desired force of their own.

    ``rows`` are the position rows of the task, ``gains`` / ``state`` the packed
    :data:`ReferenceGains` / :data:`ReferenceState` blocks, ``targets`` the TARGETS vector;
    r, R, q are the measured tip position (task rows), tip rotation and joint positions,
    ``force`` the measured force on the task rows (for the admittance, the approach and the
    monitor), ``pace`` the target filter's (:func:`target_pace`). The guarded approach, the
    target timeouts and the contact-stability monitor are
    :mod:`cr_control.schemes.blocks.contact_guard`'s."""
    m, n = r.shape[0], q.shape[0]
    g = reference_gains_views(gains, m, n)[0]
    s = reference_state_views(state, m, n)[0]
    if s.started[0] == 0.0:
        s.started[0] = 1.0
        s.r_start[:] = r
        s.quat_start[:] = quaternion_from_matrix(R)
        s.q_start[:] = q
        s.quat_f[:] = s.quat_start
        guard.guard_start(g.guard, s.guard, m)
    has_wrench = targets[_T_WRENCH_SEQ] != 0.0
    f_target = _rows_of(targets[_T_FORCE:_T_FORCE + 3], rows, m)
    phase = guard.phase_of(s.guard)
    if phase == guard.APPROACHING or phase == guard.NO_CONTACT:
        touched, r_a, v_a, a_a = guard.approach(g.guard, s.guard, t, dt, r, s.r_start, force,
                                                f_target, has_wrench)
        if touched:                  # the scheme starts now, here: its path from this point
            s.r_start[:] = r
        else:
            guard.monitor(g.guard, s.guard, force, np.zeros(m), dt, False)
            return DesiredMotion(r_a, v_a, a_a, np.zeros(m), s.quat_start.copy(), np.zeros(3),
                                 (g.posture if g.posture_given[0] > 0.0 else s.q_start).copy(),
                                 0.0)
    t_path = guard.trajectory_time(s.guard, t)
    offset = g.reference_offset.copy()
    if g.reference_relative[0] > 0.0:
        offset += s.r_start
    tau, tau_dot, tau_ddot = path_time(t_path, g.reference_ramp_time[0])
    r_d, v_d, a_d = cosine_reference(offset, g.reference_amplitude, g.reference_phase,
                                     g.reference_frequency[0], tau)
    if tau_dot != 1.0 or tau_ddot != 0.0:          # ramping in (never without a ramp)
        a_d = a_d * (tau_dot * tau_dot) + v_d * tau_ddot
        v_d = v_d * tau_dot
    quat_d, w_d = s.quat_f.copy(), s.w_f.copy()
    w_f = g.target_filter_frequency[0]
    v_max = g.target_max_speed[0] * pace
    hold_r, hold_q = guard.hold_views(s.guard, m)
    if targets[_T_POSE_SEQ] != s.pose_seq[0]:
        if s.pose_seq[0] == 0.0:                # first target: start from the trajectory
            s.r_f[:], s.v_f[:] = r_d, v_d
        s.pose_seq[0] = targets[_T_POSE_SEQ]
        guard.saw_target(s.guard, m, True, t)
        guard.stale_pose(g.guard, s.guard, t, m, s.pose_seq[0])
    else:
        stale, just_now = guard.stale_pose(g.guard, s.guard, t, m, s.pose_seq[0])
        if just_now:                            # hold where the reference is
            hold_r[:] = s.r_f
            hold_q[:] = s.quat_f
        if s.pose_seq[0] != 0.0 and dt > 0.0:
            if stale:
                target, target_q = hold_r.copy(), hold_q.copy()
            else:
                target = _rows_of(targets[_T_POS:_T_POS + 3], rows, m)
                target_q = targets[_T_QUAT:_T_QUAT + 4].copy()
            target = _leash(_bounded(g, s, target, r, m, w_f), s.r_f, v_max, w_f)
            target_q = bounds.bounded_orientation(target_q, R, bounds.MAX_LEAD_ANGLE)
            x, xd = _filter_step(s.r_f, s.v_f, target, w_f, dt)
            s.r_f[:], s.v_f[:] = x, xd
            w_rot = s.w_f
            err = rotation_vector(quaternion_multiply(target_q, quaternion_conjugate(s.quat_f)))
            w_rot += dt * (w_f * w_f * pace * err - 2.0 * w_f * w_rot)
            s.quat_f[:] = quaternion_multiply(quaternion_exp(dt * w_rot), s.quat_f)
            quat_d, w_d = s.quat_f.copy(), w_rot.copy()
    if s.pose_seq[0] != 0.0:
        if guard.pose_is_stale(s.guard, m):
            target = hold_r.copy()
        else:
            target = _rows_of(targets[_T_POS:_T_POS + 3], rows, m)
        r_d, v_d = s.r_f.copy(), s.v_f.copy()
        target = _leash(_bounded(g, s, target, r, m, w_f), r_d, v_max, w_f)
        a_d = w_f * w_f * (target - r_d) - 2.0 * w_f * v_d
    f_d = g.desired_force.copy()
    if has_wrench:
        guard.fresh_wrench(s.guard, m, targets[_T_WRENCH_SEQ], t)
        f_d = (_slewed_target(s.f_target, s.f_target_set, f_target, g.target_force_rate[0], dt,
                              f_d)
               * guard.wrench_factor(g.guard, s.guard, t, dt, m, targets[_T_WRENCH_SEQ]))
    ramp_time = g.force_ramp_time[0]
    ramp = smoothstep(t_path / ramp_time) if ramp_time > 0.0 else 1.0
    f_d *= guard.contact_ramp(g.guard, s.guard, ramp, math.sqrt(np.sum(f_d * f_d)))
    _, d_s = guard.monitor(g.guard, s.guard, force, f_d, dt, ramp >= 1.0)
    d_a = g.force_admittance_damping[0] * d_s
    limit = g.force_admittance_limit[0]
    f_norm = math.sqrt(np.sum(f_d * f_d))
    if d_a > 0.0 and f_norm > 0.0:
        n_f = f_d / f_norm
        m_a = g.force_admittance_mass[0]
        push = np.sum(n_f * (f_d - force))
        _turn_admittance(s.delta, s.n_f, n_f)
        delta, delta_dot = s.delta[0], s.delta[1]
        free = guard.free_speed(g.guard, np.sum(n_f * force))
        if dt > 0.0:
            before = delta
            delta, delta_dot = _admittance_step(delta, delta_dot, push, m_a, d_a, limit, dt)
            if abs(delta_dot) > free:            # out of contact: at the approach's speed
                delta_dot = math.copysign(free, delta_dot)
                delta = min(max(before + delta_dot * dt, -limit), limit)
            s.delta[0], s.delta[1] = delta, delta_dot
        r_d -= delta * n_f
        v_d -= delta_dot * n_f
        if not (_admittance_stopped(delta, push, limit) or abs(delta_dot) >= free):
            a_d -= (push - d_a * delta_dot) / m_a * n_f
    posture = g.posture if g.posture_given[0] > 0.0 else s.q_start
    return DesiredMotion(r_d, v_d, a_d, f_d, quat_d, w_d, posture.copy(), ramp)
