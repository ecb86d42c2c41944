"""Contact-ready task-space control: a guarded approach, target timeouts and a
contact-stability monitor, inside the compiled reference of every task-space scheme
(:func:`cr_control.schemes.blocks.references.desired_motion`). Their state lives in the
packed reference state, so they cost a few floating-point operations per cycle.

Guarded approach (``approach_speed`` v_a > 0). From the first state the reference leaves
the start position r_0 along the unit approach direction u (task rows: ``approach_direction``,
or by default -f_d/|f_d|, against the desired contact force, i.e. into the surface the law
expects; the chapter 5 laws: against their plane's normal):

    r_d = r_0 + s u,  r_d' = s' u,  s' = v_a smoothstep(t / T_a) min(1, (D - s)/(v_a T_a))

(T_a = APPROACH_RAMP_S: the speed ramps in, and it brakes over the last v_a T_a of the
``approach_distance`` D), with the desired force zero and the scheme's path frozen. Contact
is the force on the tool against u above ``contact_threshold`` for CONTACT_CONFIRM_CYCLES (5)
cycles in a row: -u^T f > f_c (a noisy sensor crosses f_c now and then). From then the
scheme runs as if it had started at that instant at that point: its path is relative to the
contact point (a relative reference) and the desired force is ramped in over
``force_ramp_time`` from f_c (not from zero, which would let the impedance laws of chapter 5
push off the contact just made: :func:`contact_ramp`). If no contact comes within D the
reference holds r_0 + D u (it never pushes into the void), logged once and reported in the
status (``approach_phase`` 3); contact found later still engages the law.

Impact damping (``impact_damping_scale`` d_i, ``impact_damping_time`` T_i). Once contact is
confirmed the law's damping is scaled up by d_i within 5 ms, and back to nominal over T_i
(:func:`impact_damping`): the tool's kinetic energy is taken out during the impact instead
of being returned by the surface's elasticity. Without it a 3 cm/s approach bounces off a
50 kN/m table for 30-110 ms (a Panda, every task-space scheme of this package).

Contact made again (v_a > 0). Out of contact (the force along the desired one below
``contact_threshold``), the force admittance of :mod:`.references` moves the reference at
v_a at most (:func:`free_speed`): a wrench target that pulled the tool off the table and
then pushes again brings it back at the approach's speed, not at the admittance's (f_d /
d_a: a Panda came back from a 5 cm pull-away and hit at 17.6 N for a 10 N target).

Target timeouts (``target_timeout`` T_o > 0). A target is stale once the control cycle's
own time (the state stamps, so lockstep and the offline loop are deterministic) is more
than T_o past the cycle that first saw it. A stale pose target is replaced by the filtered
reference pose at that moment (the critically damped target filter brings r_d' to zero
from there: no jump, an overshoot of at most |r_d'|/(e w_f)); a stale wrench target is
scaled down to zero by smoothstep(w), w falling from 1 to 0 over ``wrench_timeout_decay``
T_w. A fresh target resumes at once for the pose (through the filter) and ramps the wrench
back (w rising at the same rate): no jump beyond what the law asks.

Contact-stability monitor (``stability_monitor``). The contact force along the expected
normal f_n = -u^T f (|f| without a direction) goes through two cascaded first-order
high-passes at MONITOR_HIGHPASS_HZ (5 Hz; removes the force ramp, the tracking and
the slow adaptation: a 1 s smoothstep ramp to 10 N leaves 0.06 N) and its mean square is
averaged over a sliding exponential window of MONITOR_WINDOW_S (0.1 s):

    E <- E + (dt / T_win) (y^2 - E),   rms = sqrt(E)

Chatter, once the desired force is fully ramped in (the ramp-in and the approach are
transients by design; the NN law learns the arm's weight then), is rms >
``stability_threshold`` (N) while the filtered force also changes sign at
least MONITOR_MIN_CROSSINGS times per second (an exponential average over
MONITOR_CROSSING_WINDOW_S): a sustained oscillation of 5 Hz or faster, not the ring-out of
a step (a contact made at once, a push-off: one or two sign changes). Then the stiffness scale k falls towards
``stability_stiffness_scale`` k_min within MONITOR_DROP_S and the damping scale is
d = 1 + (d_max - 1)(1 - k)/(1 - k_min) (d_max = ``stability_damping_scale``); once rms has
stayed below half the threshold for MONITOR_CALM_S, k rises back to 1 over
``stability_restore_time``. The scales multiply the law's impedance: 3.32's B_hat e and
A_hat e' (and the force admittance's damping d_a), 5.7's k_m and d_m, 3.48/3.76's K_s
(damping) and the admittance's d_a.

Joint oscillation (the same monitor, in joint space). A transport delay or late answers
make the lightest joint oscillate first (the damping a loop of inertia M tolerates at period
T and delay d falls as M / T: the Panda's joint 7, a few 1e-3 kg m^2, oscillated at 1.75x
its velocity limit with a 3 ms delay while the contact force stayed at 10 N, so the force
channel saw nothing). Its velocity (``oscillation_joint``, the joint of smallest inertia,
chosen when the gains are packed) goes through the same two high-passes and window, as a
fraction of its URDF velocity limit: ``joint_oscillation`` (the RMS, 0.71 x the amplitude of
a sine), with its own sign-change rate. Above JOINT_OSCILLATION_THRESHOLD with at least
MONITOR_MIN_CROSSINGS sign changes per second, the joint-space gains (the orientation and
posture impedances: :func:`cr_control.schemes.blocks.task_space.null_space_torque`) are
scaled down to ``stability_stiffness_scale`` within MONITOR_DROP_S (``joint_scale``), and
restored over ``stability_restore_time`` once calm for MONITOR_CALM_S: with a delay it is
the damping gain itself that destabilises, so both stiffness and damping go down. With
``stability_monitor`` off it is measured and never acts. Cost: ten floating-point
operations per cycle.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param

#: The approach speed ramps in over this time and brakes over the last v_a times it (s).
APPROACH_RAMP_S = 0.1
#: The approach has stopped (no contact) once it is this close to approach_distance (m).
APPROACH_DONE_M = 1e-4
#: Monitor: high-pass corner (Hz), window (s), how fast the stiffness drops (s), how long the
#: force must stay calm before restoring (s).
MONITOR_HIGHPASS_HZ = 5.0
MONITOR_WINDOW_S = 0.1
MONITOR_DROP_S = 0.05
MONITOR_CALM_S = 0.5
#: Monitor: sign changes of the high-passed force per second (averaged over
#: MONITOR_CROSSING_WINDOW_S) needed besides the RMS: an oscillation of 5 Hz or faster. A step
#: (a contact made at once, a push-off) rings out with one or two sign changes: at most
#: 8 per s over 0.25 s.
MONITOR_CROSSING_WINDOW_S = 0.25
MONITOR_MIN_CROSSINGS = 10.0
#: Joint oscillation: the RMS of the lightest joint's high-passed velocity, as a fraction of
#: its velocity limit, above which the joint-space gains are scaled down (the wiping tasks
#: stay below 0.005; the 3 ms Panda oscillation reached ~1.2).
JOINT_OSCILLATION_THRESHOLD = 0.1

#: approach_phase values in the status.
OFF, APPROACHING, IN_CONTACT, NO_CONTACT = 0.0, 1.0, 2.0, 3.0
#: target_stale bits in the status.
POSE_STALE, WRENCH_STALE = 1.0, 2.0
#: Cycles in a row above contact_threshold that make a contact (5 ms at 1 kHz).
CONTACT_CONFIRM_CYCLES = 5
#: The impact damping rises over this time after contact (s): a step of the law's damping
#: would step the joint torques.
IMPACT_RISE_S = 0.01
#: The impact has rung out once its damping scale is within this of nominal (the monitor arms).
IMPACT_SETTLED = 1.05


def guard_parameters(m: int) -> list[Param]:
    """The approach, timeout and monitor parameters of a task-space scheme on m axes."""
    return [
        Param("approach_speed", 0.0, "Guarded approach: speed (m/s) at which the reference "
              "moves from the start along approach_direction until contact; 0 = off (the "
              "scheme starts in contact, as in the thesis). At most 0.5 m/s (a collaborative "
              "arm's speed limit near people is 0.25).", "nonnegative", read_only=True, bound=0.5),
        Param("contact_threshold", 2.0, "Guarded approach: contact once the force on the tool "
              "against approach_direction exceeds this (N); then the desired force is ramped "
              "in (force_ramp_time) and the law takes over from the contact point.",
              "positive", bound=Bound.FORCE),
        Param("approach_distance", 0.1, "Guarded approach: longest travel (m); without contact "
              "within it the reference stops there and holds (logged; approach_phase 3).",
              "positive", bound=2.0),
        Param("approach_direction", [0.0] * m, "Guarded approach: direction of travel (task "
              "axes, normalised); zeros = against desired_force (into the surface the law "
              "expects; the chapter 5 laws: against their plane's normal).", "vector", m,
              bound=Bound.SCALE),
        Param("target_timeout", 0.5, "~/target_pose and ~/target_wrench go stale this long "
              "(s, control-cycle time) after the cycle that first saw them: a stale pose is "
              "held where the reference is, a stale wrench decays to zero "
              "(wrench_timeout_decay); 0 = never stale.", "nonnegative", bound=3600.0),
        Param("wrench_timeout_decay", 1.0, "A stale target wrench decays to zero over this "
              "time (s, smoothstep); a fresh one ramps back at the same rate.", "nonnegative",
              bound=60.0),
        Param("stability_monitor", True, "Contact-stability monitor: on sustained oscillation "
              "of the contact force (stability_threshold) the law's stiffness is lowered and "
              "its damping raised, restored slowly once calm.", "bool"),
        Param("stability_threshold", 2.0, "Monitor: RMS (N) of the contact force above 5 Hz "
              "over a 0.1 s window that counts as chatter, while it changes sign >= 10 times "
              "per s (the wiping tasks stay below 1 N).",
              "positive", bound=Bound.FORCE),
        Param("stability_stiffness_scale", 0.2, "Monitor: the law's stiffness is scaled down "
              "to this on chatter (0.01-1).", "positive", bound=1.0),
        Param("stability_damping_scale", 6.0, "Monitor: the law's damping is scaled up to this "
              "on chatter (1-10; a one-cycle-late force measurement on a stiff contact acts as "
              "a negative damping of about K_e dt / 2, which this must outweigh).", "positive",
              bound=10.0),
        Param("stability_restore_time", 5.0, "Monitor: once calm for 0.5 s, the stiffness and "
              "damping return to nominal over this time (s).", "positive", bound=600.0),
        Param("impact_damping_scale", 10.0, "Guarded approach: the law's damping is scaled up "
              "to this once contact is confirmed and returns to nominal over "
              "impact_damping_time, so the impact's energy is taken out instead of bouncing the "
              "tool off a stiff surface (1 = off; 1-20).", "positive", bound=20.0),
        Param("impact_damping_time", 0.3, "Guarded approach: the impact damping returns to "
              "nominal over this time (s, smoothstep) after contact; 0 = off.", "nonnegative",
              bound=10.0),
    ]


def guard_gains(m: int) -> Layout:
    """Packed guard parameters (names = parameter names; approach_direction normalised), then
    the joint the joint-oscillation channel watches (-1: none) and its velocity limit."""
    return Layout(approach_speed=1, contact_threshold=1, approach_distance=1,
                  approach_direction=m, target_timeout=1, wrench_timeout_decay=1,
                  stability_monitor=1, stability_threshold=1, stability_stiffness_scale=1,
                  stability_damping_scale=1, stability_restore_time=1, impact_damping_scale=1,
                  impact_damping_time=1, oscillation_joint=1, oscillation_limit=1)


def guard_state(m: int) -> Layout:
    """The guard's state: approach (phase, t_contact, s, s', u), timeouts (pose and wrench
    first-seen times, stale bits, wrench scale w, held pose), an event counter the Python
    side logs from, the monitor (filter, energy, scales, calm time, detections), and its
    joint channel (filter, energy, crossings, scale, calm time, active, primed)."""
    return Layout(phase=1, t_contact=1, s=1, s_dot=1, u=m, pose_t=1, wrench_t=1, stale=1,
                  wrench_scale=1, events=1, hold_position=m, hold_quaternion=4, x_prev=1,
                  y1=1, y2=1, energy=1, k=1, d=1, calm=1, active=1, detections=1, primed=1,
                  wrench_seq=1, crossings=1, since_contact=1, joint_x_prev=1, joint_y1=1,
                  joint_y2=1, joint_energy=1, joint_crossings=1, joint_scale=1, joint_calm=1,
                  joint_active=1, joint_primed=1)


#: Status fields the guard adds to every task-space scheme.
GUARD_STATUS_FIELDS = ["approach_phase", "target_stale", "oscillation_rms", "stiffness_scale",
                       "damping_scale", "joint_oscillation", "joint_scale"]
GUARD_STATUS_SIZE = 7


@njit(cache=True, error_model="numpy")
def guard_sizes(m):
    """(gains, state) sizes of :func:`guard_gains` and :func:`guard_state` for m axes."""
    return m + 14, 2 * m + 35


# offsets of the joint channel, + m in the guard gains (after impact_damping_time), + 2 m in
# the guard state (after since_contact)
_G_JOINT = 12
_S_JOINT = 26


# offsets in the guard gains (after approach_direction: + m)
_G_SPEED, _G_THRESHOLD, _G_DISTANCE, _G_DIRECTION = 0, 1, 2, 3
# offsets in the guard state
_S_PHASE, _S_T_CONTACT, _S_S, _S_S_DOT, _S_U = 0, 1, 2, 3, 4


@njit(cache=True, error_model="numpy")
def _after_u(m):
    """(pose_t, wrench_t, stale, wrench_scale, events, hold_position, hold_quaternion,
    monitor) offsets in the guard state."""
    return 4 + m, 5 + m, 6 + m, 7 + m, 8 + m, 9 + m, 9 + 2 * m, 13 + 2 * m


@njit(cache=True, error_model="numpy")
def guard_start(g, s, m):
    """At the first state: the phase (approach or off), the direction u (zero if none is
    known yet), the wrench scale 1, the monitor's scales 1."""
    s[_S_PHASE] = APPROACHING if g[_G_SPEED] > 0.0 else OFF
    s[_S_U:_S_U + m] = g[_G_DIRECTION:_G_DIRECTION + m]
    _, _, _, o_ws, _, _, _, o_mon = _after_u(m)
    s[o_ws] = 1.0
    s[o_mon + 4], s[o_mon + 5] = 1.0, 1.0
    s[_S_JOINT + 2 * m + 5] = 1.0                    # the joint channel's scale


@njit(cache=True, error_model="numpy")
def event(s, m):
    """Count an event for the Python side to log."""
    s[_after_u(m)[4]] += 1.0


@njit(cache=True, error_model="numpy")
def approach(g, s, t, dt, r, r_start, force, target_force, has_target_force):
    """One cycle of the guarded approach while the phase is APPROACHING or NO_CONTACT;
    returns (in_contact_now, r_d, r_d', r_d''). ``r_start`` is the start position r_0 (it is
    replaced by the contact point by the caller on contact)."""
    m = r.shape[0]
    u = s[_S_U:_S_U + m]
    norm = math.sqrt(np.sum(u * u))
    if norm == 0.0 and has_target_force:            # no direction given: against the target
        tf = math.sqrt(np.sum(target_force * target_force))
        if tf > 0.0:
            u[:] = -target_force / tf
            norm = 1.0
    # Contact once the force has been above the threshold for CONTACT_CONFIRM_CYCLES cycles in
    # a row (counted in t_contact until then): a wrist sensor's noise (0.2 N) crosses a 0.5 N
    # threshold now and then, never CONTACT_CONFIRM_CYCLES times running.
    if norm > 0.0 and -np.sum(u * force) > g[_G_THRESHOLD]:
        s[_S_T_CONTACT] += 1.0
        if s[_S_T_CONTACT] >= CONTACT_CONFIRM_CYCLES:
            s[_S_PHASE] = IN_CONTACT
            s[_S_T_CONTACT] = t
            event(s, m)
            return True, r.copy(), np.zeros(m), np.zeros(m)
    else:
        s[_S_T_CONTACT] = 0.0
    speed, distance = g[_G_SPEED], g[_G_DISTANCE]
    travelled, old = s[_S_S], s[_S_S_DOT]
    new = 0.0
    if s[_S_PHASE] == APPROACHING and norm > 0.0 and dt > 0.0:
        ramp_in = t / APPROACH_RAMP_S
        ramp_in = ramp_in * ramp_in * (3.0 - 2.0 * ramp_in) if ramp_in < 1.0 else 1.0
        brake = min(1.0, max(0.0, (distance - travelled) / (speed * APPROACH_RAMP_S)))
        new = speed * ramp_in * brake
        travelled = min(distance, travelled + dt * new)
        s[_S_S], s[_S_S_DOT] = travelled, new
        if distance - travelled < APPROACH_DONE_M:
            s[_S_PHASE], s[_S_S_DOT], new = NO_CONTACT, 0.0, 0.0
            event(s, m)
    acc = (new - old) / dt if dt > 0.0 else 0.0
    return False, r_start + travelled * u, new * u, acc * u


@njit(cache=True, error_model="numpy")
def free_speed(g, force_along):
    """The force admittance's speed bound (module docstring: contact made again): v_a while
    the force along the desired one, ``force_along``, is below the contact threshold; inf
    in contact or without a guarded approach."""
    if g[_G_SPEED] > 0.0 and abs(force_along) < g[_G_THRESHOLD]:
        return g[_G_SPEED]
    return np.inf


@njit(cache=True, error_model="numpy")
def stale_pose(g, s, t, m, seq):
    """Whether the pose target (counter ``seq``, 0 = none) is stale at t; marks a fresh
    target's first cycle and the fresh -> stale transition (an event). Returns (stale,
    just_now): just_now when it went stale this cycle (the caller stores the held pose)."""
    o_pt, _, o_stale, _, _, _, _, _ = _after_u(m)
    timeout = g[_G_DIRECTION + m]
    stale_now = timeout > 0.0 and seq != 0.0 and t - s[o_pt] > timeout
    was = (int(s[o_stale]) & 1) != 0
    if stale_now and not was:
        s[o_stale] += POSE_STALE
        event(s, m)
        return True, True
    if not stale_now and was:
        s[o_stale] -= POSE_STALE
        event(s, m)
    return stale_now, False


@njit(cache=True, error_model="numpy")
def wrench_factor(g, s, t, dt, m, seq):
    """The factor smoothstep(w) on a target wrench (module docstring), w stepped by dt."""
    _, o_wt, o_stale, o_ws, _, _, _, _ = _after_u(m)
    timeout, decay = g[_G_DIRECTION + m], g[_G_DIRECTION + m + 1]
    stale_now = timeout > 0.0 and seq != 0.0 and t - s[o_wt] > timeout
    was = (int(s[o_stale]) & 2) != 0
    if stale_now != was:
        s[o_stale] += WRENCH_STALE if stale_now else -WRENCH_STALE
        event(s, m)
    w = s[o_ws]
    step = 1.0 if decay <= 0.0 else dt / decay
    w = max(0.0, w - step) if stale_now else min(1.0, w + step)
    s[o_ws] = w
    return w * w * (3.0 - 2.0 * w)


@njit(cache=True, error_model="numpy")
def saw_target(s, m, pose, t):
    """A fresh target (pose or wrench) was first seen at t."""
    o_pt, o_wt, _, _, _, _, _, _ = _after_u(m)
    s[o_pt if pose else o_wt] = t


@njit(cache=True, error_model="numpy")
def fresh_wrench(s, m, seq, t):
    """Stamp the first cycle of a new target wrench (counter ``seq``)."""
    o = 23 + 2 * m
    if s[o] != seq:
        s[o] = seq
        saw_target(s, m, False, t)


@njit(cache=True, error_model="numpy")
def pose_is_stale(s, m):
    """Whether the pose target is stale (set by :func:`stale_pose`)."""
    return (int(s[_after_u(m)[2]]) & 1) != 0


@njit(cache=True, error_model="numpy")
def hold_views(s, m):
    """(held position, held quaternion) views of the guard state."""
    _, _, _, _, _, o_hp, o_hq, _ = _after_u(m)
    return s[o_hp:o_hp + m], s[o_hq:o_hq + 4]


@njit(cache=True, error_model="numpy")
def direction(s, m):
    """The unit direction into the surface u (a view; zeros while none is known)."""
    return s[_S_U:_S_U + m]


@njit(cache=True, error_model="numpy")
def speed(g):
    """The guarded approach's speed v_a (0: no approach)."""
    return g[_G_SPEED]


@njit(cache=True, error_model="numpy")
def phase_of(s):
    return s[_S_PHASE]


@njit(cache=True, error_model="numpy")
def trajectory_time(s, t):
    """The scheme's own time: t, or the time since contact after a guarded approach."""
    return t - s[_S_T_CONTACT] if s[_S_PHASE] == IN_CONTACT else t


@njit(cache=True, error_model="numpy")
def monitor(g, s, force, f_d, dt, armed):
    """One cycle of the contact-stability monitor (module docstring) on the measured force
    (task rows) and of the impact damping (:func:`impact_damping`); returns (stiffness
    scale, damping scale). It detects only while ``armed`` (the desired force fully ramped
    in: the ramp-in and the approach are transients by design, and the NN law learns the
    arm's weight then) or once a guarded approach has made contact and its impact has rung
    out (the impact damping back within IMPACT_SETTLED of nominal): a stiff contact can
    chatter while the force is still ramping in (the shipped stiff-table case bounced to
    the plant's 50 N reflex at 0.59 s, before the ramp's end), and a ramp never changes
    sign 10 times a second; the ringing of a 3 cm/s impact on a 50 kN/m table did, for a
    few tenths of a second."""
    d_i = impact_damping(g, s, force.shape[0], dt)
    k, d = _chatter(g, s, force, f_d, dt,
                    armed or (s[_S_PHASE] == IN_CONTACT and d_i < IMPACT_SETTLED))
    d = max(d, d_i)
    s[_after_u(force.shape[0])[7] + 5] = d
    return k, d


@njit(cache=True, error_model="numpy")
def impact_damping(g, s, m, dt):
    """The damping scale of a guarded approach's impact: from the confirmed contact (t_c the
    time since)

        d_i = 1 + (d_max - 1) (s' / v_a)^2 min(1, t_c / T_r) (1 - smoothstep(t_c / T_i))

    with d_max = ``impact_damping_scale``, T_i = ``impact_damping_time``, a rise over
    T_r = IMPACT_RISE_S (a step of the damping would step the joint torques) and the
    approach's speed s' at contact against v_a = ``approach_speed`` (the impact's energy goes
    with its square: a tool that starts touching has none to take out); 1 without an
    approach. A tool that meets a surface of stiffness K_e at speed v with the arm's effective
    mass m_e rebounds (restitution exp(-zeta pi / sqrt(1 - zeta^2))) unless the damping takes
    the energy out during the impact's half-period pi sqrt(m_e / K_e), zeta = D / (2 sqrt(K_e
    m_e)): on a table of 50 kN/m a 2.5 kg tool needs D of several hundred N s/m, far more than
    a compliant impedance has. It is velocity feedback (no force delay), stable while
    D dt / m_e < 2."""
    o = _after_u(m)[7]
    d_max, t_i = g[_G_DIRECTION + m + 7], g[_G_DIRECTION + m + 8]
    if t_i <= 0.0 or s[_S_PHASE] != IN_CONTACT:
        return 1.0
    s[o + 12] += dt
    t_c = s[o + 12]
    w = min(1.0, t_c / t_i)
    speed = s[_S_S_DOT] / g[_G_SPEED]     # the approach's speed at contact, of v_a
    return 1.0 + ((d_max - 1.0) * min(1.0, speed * speed) * min(1.0, t_c / IMPACT_RISE_S)
                  * (1.0 - w * w * (3.0 - 2.0 * w)))


@njit(cache=True, error_model="numpy")
def _chatter(g, s, force, f_d, dt, armed):
    """The contact-stability monitor alone (module docstring); with ``stability_monitor`` off
    it measures (oscillation_rms, for the status and the start check's diagnosis) and
    never reacts."""
    m = force.shape[0]
    o = _after_u(m)[7]
    u = s[_S_U:_S_U + m]
    if np.sum(u * u) > 0.0:
        x = -np.sum(u * force)
    else:
        fd = math.sqrt(np.sum(f_d * f_d))
        x = np.sum(f_d * force) / fd if fd > 0.0 else math.sqrt(np.sum(force * force))
    if s[o + 9] == 0.0 or dt <= 0.0:                 # primed: start the filter at the signal
        if s[o + 9] == 0.0:
            s[o], s[o + 9] = x, 1.0
        return s[o + 4], s[o + 5]
    tau = 1.0 / (2.0 * math.pi * MONITOR_HIGHPASS_HZ)
    a = tau / (tau + dt)
    y1_old = s[o + 1]
    y1 = a * (y1_old + x - s[o])
    y2 = a * (s[o + 2] + y1 - y1_old)
    crossed = 1.0 if y2 * s[o + 2] < 0.0 else 0.0
    rate = s[o + 11] + (crossed - dt * s[o + 11]) / MONITOR_CROSSING_WINDOW_S
    s[o + 11] = rate
    s[o], s[o + 1], s[o + 2] = x, y1, y2
    energy = s[o + 3] + dt / MONITOR_WINDOW_S * (y2 * y2 - s[o + 3])
    s[o + 3] = energy
    if g[_G_DIRECTION + m + 2] <= 0.0:               # stability_monitor off: measured only
        return 1.0, 1.0
    threshold = g[_G_DIRECTION + m + 3]
    k_min, d_max = g[_G_DIRECTION + m + 4], g[_G_DIRECTION + m + 5]
    k = s[o + 4]
    rms = math.sqrt(energy)
    if rms > threshold and rate >= MONITOR_MIN_CROSSINGS and armed:
        s[o + 6] = 0.0                               # calm time
        if s[o + 7] == 0.0:
            s[o + 7] = 1.0
            s[o + 8] += 1.0
            event(s, m)
        k = max(k_min, k - dt / MONITOR_DROP_S * (1.0 - k_min))
    elif rms < 0.5 * threshold:
        s[o + 6] += dt
        if s[o + 6] > MONITOR_CALM_S and k < 1.0:
            k = min(1.0, k + dt / g[_G_DIRECTION + m + 6] * (1.0 - k_min))
            if k == 1.0 and s[o + 7] != 0.0:
                s[o + 7] = 0.0
                event(s, m)
    d = 1.0 + (d_max - 1.0) * (1.0 - k) / (1.0 - k_min) if k_min < 1.0 else 1.0
    s[o + 4], s[o + 5] = k, d
    return k, d


@njit(cache=True, error_model="numpy")
def contact_ramp(g, s, ramp, f_full):
    """The force ramp after a guarded approach starts at the contact threshold, not at zero:
    rho + (1 - rho) ramp with rho = min(1, f_c / |f_d|), so the law neither lets go of the
    contact it has just made nor pushes off from it; ``ramp`` itself otherwise."""
    if s[_S_PHASE] != IN_CONTACT or not f_full > 0.0:
        return ramp
    rho = min(1.0, g[_G_THRESHOLD] / f_full)
    return rho + (1.0 - rho) * ramp


@njit(cache=True, error_model="numpy")
def scales(s, m):
    """(stiffness scale, damping scale) the monitor set this cycle (1, 1 when calm or off)."""
    o = _after_u(m)[7]
    return s[o + 4], s[o + 5]


@njit(cache=True, error_model="numpy")
def joint_monitor(g, s, v, dt, m):
    """One cycle of the joint channel (module docstring: joint oscillation) on the joint
    velocities ``v``; returns the joint-space gains' scale."""
    o, j = _S_JOINT + 2 * m, int(g[_G_JOINT + m])
    if j < 0:
        return 1.0
    limit = g[_G_JOINT + m + 1]
    x = v[j] / limit if limit > 0.0 and math.isfinite(limit) else v[j]
    if s[o + 8] == 0.0 or dt <= 0.0:                 # primed: start the filter at the signal
        if s[o + 8] == 0.0:
            s[o], s[o + 8] = x, 1.0
        return s[o + 5]
    tau = 1.0 / (2.0 * math.pi * MONITOR_HIGHPASS_HZ)
    a = tau / (tau + dt)
    y1_old = s[o + 1]
    y1 = a * (y1_old + x - s[o])
    y2 = a * (s[o + 2] + y1 - y1_old)
    crossed = 1.0 if y2 * s[o + 2] < 0.0 else 0.0
    rate = s[o + 4] + (crossed - dt * s[o + 4]) / MONITOR_CROSSING_WINDOW_S
    s[o + 4] = rate
    s[o], s[o + 1], s[o + 2] = x, y1, y2
    energy = s[o + 3] + dt / MONITOR_WINDOW_S * (y2 * y2 - s[o + 3])
    s[o + 3] = energy
    if g[_G_DIRECTION + m + 2] <= 0.0:               # stability_monitor off: measured only
        return 1.0
    k_min = g[_G_DIRECTION + m + 4]
    k = s[o + 5]
    rms = math.sqrt(max(0.0, energy))
    if rms > JOINT_OSCILLATION_THRESHOLD and rate >= MONITOR_MIN_CROSSINGS:
        s[o + 6] = 0.0                               # calm time
        if s[o + 7] == 0.0:
            s[o + 7] = 1.0
            event(s, m)
        k = max(k_min, k - dt / MONITOR_DROP_S * (1.0 - k_min))
    elif rms < 0.5 * JOINT_OSCILLATION_THRESHOLD:
        s[o + 6] += dt
        if s[o + 6] > MONITOR_CALM_S and k < 1.0:
            k = min(1.0, k + dt / g[_G_DIRECTION + m + 6] * (1.0 - k_min))
            if k == 1.0 and s[o + 7] != 0.0:
                s[o + 7] = 0.0
                event(s, m)
    s[o + 5] = k
    return k


@njit(cache=True, error_model="numpy")
def joint_scale(s, m):
    """The joint-space gains' scale the joint channel set (1 when calm or off)."""
    return s[_S_JOINT + 2 * m + 5]


@njit(cache=True, error_model="numpy")
def write_status(s, m, out):
    """GUARD_STATUS_FIELDS into ``out``."""
    _, _, o_stale, _, _, _, _, o = _after_u(m)
    out[0], out[1] = s[_S_PHASE], s[o_stale]
    out[2], out[3], out[4] = math.sqrt(max(0.0, s[o + 3])), s[o + 4], s[o + 5]
    j = _S_JOINT + 2 * m
    out[5], out[6] = math.sqrt(max(0.0, s[j + 3])), s[j + 5]


def guard_gain_values(values: dict, m: int, default_direction: np.ndarray,
                      oscillation_joint: int = -1, oscillation_limit: float = 1.0) -> dict:
    """The packed values: approach_direction normalised, or ``default_direction`` (unit or
    zero) when it is zero; the joint the joint channel watches (-1: none) and its velocity
    limit."""
    u = np.asarray(values["approach_direction"], dtype=float)
    norm = float(np.linalg.norm(u))
    u = u / norm if norm > 0.0 else default_direction
    return {**values, "approach_direction": u,
            "stability_monitor": float(values["stability_monitor"]),
            "oscillation_joint": float(oscillation_joint),
            "oscillation_limit": float(oscillation_limit)}


def event_state(internal: np.ndarray, at: int, m: int) -> tuple[float, float, float, float,
                                                                 float]:
    """(phase, stale bits, monitor active, detections, joint channel active) of the guard
    state at ``at``."""
    o = at + 13 + 2 * m
    return (float(internal[at]), float(internal[at + 6 + m]), float(internal[o + 7]),
            float(internal[o + 8]), float(internal[at + _S_JOINT + 2 * m + 7]))
