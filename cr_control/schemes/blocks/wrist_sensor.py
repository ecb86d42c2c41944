"""A wrist force/torque sensor carrying a tool: the contact force the law needs, in the base
frame, from what the sensor measures in its own frame.

The sensor sits at the flange (frame S, ``sensor_frame``: ``panda_link8``, ``tool0``) and
reads, in S, the contact wrench plus the tool's weight plus a bias (the plant's model,
:mod:`cr_sim.plants.urdf_surface`). The law receives

    f = R_S (F_S - b_F) - m g                                                   (1)

- R_S: rotation base <- S at the measured joints q, from the controller's own compiled
  chain (:mod:`cr_control.models.spatial_chain`): R_S = R_n(q) R_nS, R_n the last joint's
  frame and R_nS the constant placement of S on it (S must ride on the tip's body);
- F_S: the measured force (S), b_F the force bias (S), m = ``tool_mass``, g = ``gravity``.

Neglected by default: the tool's inertial force m a_c (a_c the classical acceleration of its
centre of mass; the torque is not used by the law). At the wiping task's speeds (a 5 cm
circle at 1 rad/s, orientation held) |a_c| = r w^2 = 0.05 m/s^2: 0.035 N on the 0.7 kg
tool, 0.35 % of the 10 N pressed; a_c = 1.4 m/s^2 would be needed for 1 N. With
``tool_acceleration_compensation`` it is added, f += m a_c, a_c by the backward difference
of the centre of mass's velocity J_c(q) q' between cycles (:func:`com_velocity`; checked
against the simulated sensor's exact a_c to 0.1 m/s^2 during the NN law's start, where the
tool falls at 10 m/s^2); off by default because it differences the joint-velocity noise.
The law takes the force only; the torque enters the bias and the tool identification:
T_S = c x (m R_S^T g) + b_T + (contact torque), c = ``tool_com`` (S).

Bias, blended. The bias b (6: force, torque, S) in use at time t is

    b(t) = b_0 + s((t - t_b) / T_b) (b_1 - b_0),   s(x) = 3x^2 - 2x^3 on [0, 1]      (2)

(smoothstep: no jump in b, nor in its rate at both ends), so a new bias b_1 found at t_b
reaches the law over T_b = ZERO_BLEND_S and the commanded torque does not jump.

Zeroing (``~/zero_ft``, :meth:`WristSensor.request_zero`): average the wrench W_S over
ZERO_WINDOW_S (0.2 s, 200 readings at 1 kHz: the 0.2 N noise averages to 0.014 N) together
with the weight the model predicts at each reading, w = [m R_S^T g; c x m R_S^T g]; the new
bias is b_1 = mean(W_S - w); then (2). "Out of contact" is judged, when asked, by what the
controller knows: the joints are still (|q'| <= ZERO_MAX_JOINT_SPEED), the law asks no
contact force (|f_d| <= ZERO_MAX_DESIRED_FORCE: a law asking for more presses on purpose)
and the compensated force with the bias in use is small (|f| <= ZERO_MAX_FORCE); the
zeroing is abandoned, keeping the old bias, if the joints move during the window or the new
force bias differs from the old by more than ZERO_MAX_FORCE. A contact lighter than
ZERO_MAX_FORCE cannot be told from a bias by the sensor alone: zero with the tool in the air
(or touching at zero force).

Those checks compare with the bias in use, so zeroings repeated while the tool touches
something would walk the bias step by step, each step a contact force under ZERO_MAX_FORCE
taken for bias (measured before this bound, the Panda asked for 4.5 N and zeroed every
0.2 s for 3 s: the robust scheme took 4 of 14 calls, the force bias walked from +3 N to
-13 N and the law read 3.6 N of a true 19.8 N). So a new force bias is also compared with the
FIRST one (:attr:`WristSensor.first_bias`: ``ft_bias``, or the start-up zeroing's, or the
last forced one) and refused, at the call when the last reading already tells (the bias the
contact would make, b + R_S^T f) and else when the window ends, if they differ by more than
``zero_ft_max_change`` (5 N by default: room for the slow drift of a strain-gauge sensor's
bias with temperature over a session, see "Model based in situ calibration with temperature
compensation of 6 axis force torque sensors", arXiv:1812.00650, and half the robots' 10 N
task, so a walk can never take more than that). ``~/zero_ft_force`` (``force=True``) is the
operator saying the tool touches nothing: only "no state", "moving", "a zeroing under way"
and "the law asks for a contact force" refuse it, and its bias becomes the first one. Every
refusal and abandonment is logged, at most one line every WARN_EVERY_S (5 s) with the count
of those held back in between (:class:`RateLimitedLog`).

At start-up (``zero_ft_at_start``, for a task that starts still, touching at zero force
or in the air, such as the robots' wiping task): the controller first holds the arm still
(:attr:`WristSensor.holding`: gravity compensation from the URDF model with the tool, what a
robot's driver does before a controller takes over) while the bias is averaged over the
ZERO_START_WINDOW_S (30 ms) after the first reading; the law starts when it ends, its clock
from zero then (:attr:`WristSensor.law_start`), its command blended in from G(q) over
HOLD_BLEND_S (50 ms, smoothstep). The first reading is left out: it may be
taken before any command held the arm (the simulator's is, with the tool's inertial wrench
of a zero torque in it). Zeroing while the law already runs instead carries its start
transient: measured on the Panda's wiping task, whose path starts at 5 cm/s, 0.65 N of the
normal force ended up in the bias.

Cost: one compiled call per cycle (the wrench copied, |q'|, the rotation pass over n joints,
(1), (2)): ~3 us on the Panda (test/test_wrist_compensation.py's micro-timing, printed, on
the loaded 2-core machine); its compute p50 in the offline loop 33 us without, 38 us with.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin
from numba import njit

from cr_control.core import rate_limited_log as core_log
from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.spatial_chain import (
    AXIS,
    HEADER,
    KIND,
    PER_JOINT,
    POS,
    PRISMATIC_KIND,
    ROT,
    rotate_about_axis_into,
)

#: Averaging window of a zeroing (s).
ZERO_WINDOW_S = 0.2
#: Averaging window of the start-up zeroing (s).
ZERO_START_WINDOW_S = 0.03
#: After the start-up hold the law's command is blended in from G(q) over this time (s):
#: the law's first command differs from the URDF model's G(q) by its model error (4.2 N m
#: on the Panda for the robust scheme's 10 %-light model), a jump otherwise.
HOLD_BLEND_S = 0.05
#: A new bias is blended in over this time (s), by (2).
ZERO_BLEND_S = 0.5
#: "Still": joint speed |q'| (Euclidean, rad/s) at most this during a zeroing.
ZERO_MAX_JOINT_SPEED = 0.05
#: "Out of contact": compensated force and the bias change from the bias in use at most
#: this (N).
ZERO_MAX_FORCE = 5.0
#: "The law asks no contact force": |f_d| at most this (N).
ZERO_MAX_DESIRED_FORCE = 0.5
#: Refusals and abandonments of zeroings are logged at most this often (s), with a count.
WARN_EVERY_S = 5.0

PARAMETERS = [
    Param("sensor_frame", "", "Frame of the force/torque sensor's wrench (a link riding on "
          "tip_link's body: panda_link8, tool0); every wrench must name it in its frame_id. "
          "Empty: an ideal sensor measuring the contact force in the base frame (the thesis "
          "plants; no compensation).", "string", read_only=True),
    Param("wrench_sign", 1, "Sign convention of the wrench read: 1 = the wrench the "
          "environment exerts on the tool (a wrist sensor through force_torque_sensor_broadcaster, "
          "UR's TCP sensor); -1 = the reaction, the wrench the robot exerts on the environment "
          "(as franka users report Franka's estimated external wrench, O_F_ext_hat_K / "
          "K_F_ext_hat_K). The wrench is multiplied by it before anything else.", "integer",
          read_only=True, bound=1.0),
    Param("tool_mass", 0.0, "Mass of everything the sensor carries (kg; cr_identify_tool "
          "estimates it): its weight m g is taken off the measured force and, with "
          "sensor_frame, it replaces what the URDF mounts beyond the sensor in the arm's "
          "model.", "nonnegative", read_only=True, bound=Bound.MASS),
    Param("tool_com", [0.0, 0.0, 0.0], "The tool's centre of mass in the sensor frame (m): "
          "its weight's moment (zeroing, torque bias) and its place in the arm's model.",
          "vector", 3, read_only=True, bound=Bound.LENGTH),
    Param("ft_bias", [0.0] * 6, "The sensor's bias at start, sensor frame: fx, fy, fz (N), "
          "tx, ty, tz (N m); ~/zero_ft replaces it.", "vector", 6, read_only=True,
          bound=Bound.FORCE),
    Param("tool_acceleration_compensation", False, "Also add m a_c to the contact force, a_c "
          "the tool's centre-of-mass acceleration by the backward difference of its velocity "
          "from the measured joint velocities (for motions of metres per second squared; it "
          "differences velocity noise: 1e-3 rad/s on an 0.8 m arm is ~1 m/s^2, 0.7 N on a "
          "0.7 kg tool).", "bool", read_only=True),
    Param("zero_ft_at_start", False, "Zero the sensor at start (the task starts still, "
          "touching at zero force or in the air): the arm is held still by gravity "
          f"compensation while the sensor is averaged over {ZERO_START_WINDOW_S:g} s, then "
          "the law starts.", "bool", read_only=True),
    Param("zero_ft_max_change", 5.0, "~/zero_ft refuses a new force bias farther than this "
          "(N) from the first one (ft_bias, the start-up zeroing's or the last forced one), "
          "so repeated zeroings cannot walk the bias away while the tool touches something; "
          "~/zero_ft_force takes it anyway. 5 N: room for a strain-gauge sensor's slow drift, "
          "half the robots' 10 N task.", "nonnegative", bound=Bound.FORCE),
]
NAMES = tuple(p.name for p in PARAMETERS)

#: Layout of the packed compensation ``comp``: [m, g (3), R_nS (9, row-major), b_0 (6),
#: b_1 (6), t_b, T_b, p_nc (3: the tool's centre of mass in the last joint's frame),
#: v_c (3: its last velocity, base frame), t of v_c, inertial (1: compensate m a_c)].
MASS_AT, G_AT, RNS_AT, B0_AT, B1_AT, TB_AT, TBLEND_AT = 0, 1, 4, 13, 19, 25, 26
PNC_AT, VC_AT, TVC_AT, INERTIAL_AT, COMP_SIZE = 27, 30, 33, 34, 35
#: Longest step (s) the tool's acceleration is differenced over; beyond it a_c = 0.
MAX_DIFFERENCE_S = 0.01


@njit(cache=True, error_model="numpy")
def sensor_rotation_into(chain, R_nS, q, R):
    """R (9, row-major) = R_n(q) R_nS: the sensor frame's rotation in the base frame, from the
    rotations of the packed chain alone (R_i = R_{i-1} R^pl_i E_i(q_i))."""
    n = int(chain[0])
    a = np.empty(9)
    for r in range(9):
        a[r] = 1.0 if r % 4 == 0 else 0.0
    b = np.empty(9)
    for i in range(n):
        k = HEADER + PER_JOINT * i
        for r in range(3):                                   # b = a R^pl_i
            a0, a1, a2 = a[3 * r], a[3 * r + 1], a[3 * r + 2]
            for c in range(3):
                b[3 * r + c] = (a0 * chain[k + ROT + c] + a1 * chain[k + ROT + 3 + c]
                                + a2 * chain[k + ROT + 6 + c])
        if chain[k + KIND] == PRISMATIC_KIND:
            a[:] = b
            continue
        ax, ay, az = chain[k + AXIS], chain[k + AXIS + 1], chain[k + AXIS + 2]
        c, s = math.cos(q[i]), math.sin(q[i])
        t = 1.0 - c
        e00, e01, e02 = c + t * ax * ax, t * ax * ay - s * az, t * ax * az + s * ay
        e10, e11, e12 = t * ax * ay + s * az, c + t * ay * ay, t * ay * az - s * ax
        e20, e21, e22 = t * ax * az - s * ay, t * ay * az + s * ax, c + t * az * az
        for r in range(3):                                   # a = b E_i
            b0, b1, b2 = b[3 * r], b[3 * r + 1], b[3 * r + 2]
            a[3 * r] = b0 * e00 + b1 * e10 + b2 * e20
            a[3 * r + 1] = b0 * e01 + b1 * e11 + b2 * e21
            a[3 * r + 2] = b0 * e02 + b1 * e12 + b2 * e22
    for r in range(3):
        for c in range(3):
            R[3 * r + c] = (a[3 * r] * R_nS[c] + a[3 * r + 1] * R_nS[3 + c]
                            + a[3 * r + 2] * R_nS[6 + c])


@njit(cache=True, error_model="numpy")
def com_velocity(chain, p_nc, q, v):
    """v_c = sum_i J_c,i q'_i (base frame): the velocity of the point p_nc of the last
    joint's body (revolute: z_i x (p_c - p_i), prismatic: z_i), by the forward pass
    R_i = R_{i-1} R^pl_i E_i(q_i), p_i = p_{i-1} + R_{i-1} p^pl_i (+ z_i q_i)."""
    n = int(chain[0])
    R = np.empty(9)
    b = np.empty(9)
    p = np.zeros(3)
    for r in range(9):
        R[r] = 1.0 if r % 4 == 0 else 0.0
    zs = np.empty((n, 3))
    ps = np.empty((n, 3))
    prismatic = np.empty(n)
    for i in range(n):
        k = HEADER + PER_JOINT * i
        px, py, pz = chain[k + POS], chain[k + POS + 1], chain[k + POS + 2]
        p0 = p[0] + R[0] * px + R[1] * py + R[2] * pz
        p1 = p[1] + R[3] * px + R[4] * py + R[5] * pz
        p2 = p[2] + R[6] * px + R[7] * py + R[8] * pz
        for r in range(3):
            a0, a1, a2 = R[3 * r], R[3 * r + 1], R[3 * r + 2]
            for c in range(3):
                b[3 * r + c] = (a0 * chain[k + ROT + c] + a1 * chain[k + ROT + 3 + c]
                                + a2 * chain[k + ROT + 6 + c])
        ax, ay, az = chain[k + AXIS], chain[k + AXIS + 1], chain[k + AXIS + 2]
        zx = b[0] * ax + b[1] * ay + b[2] * az
        zy = b[3] * ax + b[4] * ay + b[5] * az
        zz = b[6] * ax + b[7] * ay + b[8] * az
        zs[i, 0], zs[i, 1], zs[i, 2] = zx, zy, zz
        if chain[k + KIND] == PRISMATIC_KIND:
            prismatic[i] = 1.0
            p0 += zx * q[i]
            p1 += zy * q[i]
            p2 += zz * q[i]
            R[:] = b
        else:
            prismatic[i] = 0.0
            rotate_about_axis_into(b, R, ax, ay, az, q[i])
        p[0], p[1], p[2] = p0, p1, p2
        ps[i, 0], ps[i, 1], ps[i, 2] = p0, p1, p2
    cx = p[0] + R[0] * p_nc[0] + R[1] * p_nc[1] + R[2] * p_nc[2]
    cy = p[1] + R[3] * p_nc[0] + R[4] * p_nc[1] + R[5] * p_nc[2]
    cz = p[2] + R[6] * p_nc[0] + R[7] * p_nc[1] + R[8] * p_nc[2]
    vx = vy = vz = 0.0
    for i in range(n):
        zx, zy, zz = zs[i, 0], zs[i, 1], zs[i, 2]
        if prismatic[i] != 0.0:
            vx += zx * v[i]
            vy += zy * v[i]
            vz += zz * v[i]
        else:
            dx, dy, dz = cx - ps[i, 0], cy - ps[i, 1], cz - ps[i, 2]
            vx += (zy * dz - zz * dy) * v[i]
            vy += (zz * dx - zx * dz) * v[i]
            vz += (zx * dy - zy * dx) * v[i]
    return vx, vy, vz


@njit(cache=True, error_model="numpy")
def blend(x):
    """s(x) = 3x^2 - 2x^3 on [0, 1], 0 below, 1 above (2)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, error_model="numpy")
def compensate_into(chain, comp, t, q, v, wrench, w, R, bias, force):
    """(1) with the bias of (2) at t: ``force`` (3, base frame) from ``wrench`` (force, or
    force and torque, S; copied into ``w`` (6), the torque 0 if not given); also writes R_S
    (9) into ``R`` and the bias in use (6) into ``bias``; returns |q'|. With ``comp``'s
    inertial flag, plus m a_c (3), a_c the backward difference of the tool's centre-of-mass
    velocity (:func:`com_velocity`) since the last call."""
    k = min(wrench.shape[0], 6)
    for i in range(6):
        w[i] = wrench[i] if i < k else 0.0
    speed = 0.0
    for i in range(v.shape[0]):
        speed += v[i] * v[i]
    wrench = w
    sensor_rotation_into(chain, comp[RNS_AT:RNS_AT + 9], q, R)
    T = comp[TBLEND_AT]
    s = blend((t - comp[TB_AT]) / T) if T > 0.0 else 1.0
    for i in range(6):
        bias[i] = comp[B0_AT + i] + s * (comp[B1_AT + i] - comp[B0_AT + i])
    m = comp[MASS_AT]
    fx, fy, fz = wrench[0] - bias[0], wrench[1] - bias[1], wrench[2] - bias[2]
    for r in range(3):
        force[r] = R[3 * r] * fx + R[3 * r + 1] * fy + R[3 * r + 2] * fz - m * comp[G_AT + r]
    if comp[INERTIAL_AT] != 0.0:
        vx, vy, vz = com_velocity(chain, comp[PNC_AT:PNC_AT + 3], q, v)
        h = t - comp[TVC_AT]
        if 0.0 < h <= MAX_DIFFERENCE_S:
            force[0] += m * (vx - comp[VC_AT]) / h
            force[1] += m * (vy - comp[VC_AT + 1]) / h
            force[2] += m * (vz - comp[VC_AT + 2]) / h
        comp[VC_AT], comp[VC_AT + 1], comp[VC_AT + 2], comp[TVC_AT] = vx, vy, vz, t
    return math.sqrt(speed)


def sensor_placement(chain_model, sensor_frame: str) -> pin.SE3:
    """The placement (R_nS, p_nS) of ``sensor_frame`` in the chain's last joint frame;
    ParameterError (one line) if the URDF has no such frame or it does not ride on the tip's
    body (the last joint of the chain moves it, and nothing else)."""
    model = chain_model.model
    if not model.existFrame(sensor_frame):
        raise ParameterError(f"sensor_frame {sensor_frame!r} is not a frame of the URDF")
    frame = model.frames[model.getFrameId(sensor_frame)]
    tip = model.frames[chain_model.tip]
    if frame.parentJoint != tip.parentJoint:
        raise ParameterError(f"sensor_frame {sensor_frame!r} does not ride on tip_link "
                             f"{tip.name!r}'s body (the wrist sensor sits between the last "
                             "joint and the tool)")
    return pin.SE3(frame.placement)


class RateLimitedLog(core_log.RateLimitedLog):
    """The one rate-limited logger (:mod:`cr_control.core.rate_limited_log`) for one kind of
    line, called as ``log(write, message)``: ``write`` is where the line goes (the law's
    warning logger, which the node sets after the law is built); one line at most every
    ``every`` seconds of ``clock``, saying how many were held back since the last one."""

    def __init__(self, every: float = WARN_EVERY_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(lambda _severity, text: self._write(text), every, clock)
        self._write: Callable[[str], None] = print

    @property
    def count(self) -> int:
        """Lines asked for in all (logged or held back)."""
        return self.counts.get("line", 0)

    def __call__(self, log: Callable[[str], None], message: str) -> bool:  # type: ignore[override]
        """Log ``message`` through ``log`` unless one was logged less than ``every`` ago;
        True if logged."""
        self._write = log
        return super().__call__("line", "warn", message)


def weight_wrench(R: np.ndarray, mass: float, com: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """w = [m R^T g; c x m R^T g] (6, sensor frame) for R (3 x 3, base <- S)."""
    force = mass * (R.T @ gravity)
    return np.concatenate([force, np.cross(com, force)])


class WristSensor:
    """The compensation (1)-(2) and the zeroing state of one controller (module docstring).

    ``active`` is False for the ideal sensor with nothing to compensate (no sensor frame,
    no tool mass, no bias, no zeroing): the law then reads the wrench's force unchanged,
    bit for bit."""

    def __init__(self, values: dict, model) -> None:
        self.chain = model.chain
        frame = values["sensor_frame"]
        self.sensor_frame = frame
        placement = sensor_placement(model.chain_model, frame) if frame else None
        # no sensor frame: the base frame (R_S = I): R_nS = R_n(q)^T is not constant, so the
        # kernel is given the identity through a chain of no joints
        self._ideal_chain = np.array([0.0, *values["gravity"]])
        self._rotation_chain = self.chain if frame else self._ideal_chain
        self.comp = np.zeros(COMP_SIZE)
        self.comp[RNS_AT:RNS_AT + 9] = (np.eye(3) if placement is None
                                        else placement.rotation).reshape(9)
        if placement is not None:
            self.comp[PNC_AT:PNC_AT + 3] = placement.act(np.array(values["tool_com"], float))
            self.comp[INERTIAL_AT] = float(values["tool_mass"] > 0.0
                                           and values["tool_acceleration_compensation"])
        self.comp[TVC_AT] = -math.inf
        self.comp[G_AT:G_AT + 3] = values["gravity"]
        self.comp[B0_AT:B0_AT + 6] = self.comp[B1_AT:B1_AT + 6] = values["ft_bias"]
        self.gravity = np.array(values["gravity"], dtype=float)
        self.set_tool(values)
        self.at_start = bool(values["zero_ft_at_start"])
        self.active = bool(frame or values["tool_mass"] > 0.0 or any(values["ft_bias"])
                           or self.at_start)
        self.R = np.zeros(9)
        self.bias = np.array(values["ft_bias"], dtype=float)
        #: The bias a zeroing's result is compared with (module docstring): ft_bias, then
        #: the start-up zeroing's, or the last forced one.
        self.first_bias = self.bias.copy()
        self.force = np.zeros(3)
        self._wrench = np.zeros(6)
        self._zero: dict | None = None      # the zeroing under way: window end, sums
        self._started = False
        #: The law's clock starts here (s, controller time): the end of the start-up zeroing.
        self.law_start = 0.0
        self.last_t = math.nan
        self.last_speed = math.inf
        self.zero_count = 0
        self.log = print
        #: Where refusals and abandonments go (rate-limited by :attr:`refusals`).
        self.warn = print
        self.refusals = RateLimitedLog()
        #: The last (t, q', force) of an inactive sensor (:meth:`observe`), or None.
        self._seen: tuple | None = None

    def set_tool(self, values: dict) -> None:
        """Take tool_mass and tool_com."""
        self.comp[MASS_AT] = values["tool_mass"]
        self.mass = float(values["tool_mass"])
        self.com = np.array(values["tool_com"], dtype=float)
        if self.mass > 0.0:
            self.active = True

    # -- the cycle -------------------------------------------------------------------------
    def compensate(self, t: float, q: np.ndarray, v: np.ndarray, wrench: np.ndarray) -> np.ndarray:
        """(1)-(2) at t: the contact force (3, base frame) for the law; ``wrench`` the
        sensor's force (3) or force and torque (6). Runs the zeroing when one is under way."""
        w = self._wrench
        self.last_speed = compensate_into(self._rotation_chain, self.comp, t, q, v, wrench, w,
                                          self.R, self.bias, self.force)
        self.last_t = t
        if self.at_start and not self._started:
            # the first reading may be taken before any command held the arm: not averaged
            self._started = True
            self._begin_zero(t + 1e-9, ZERO_START_WINDOW_S, check=False)
            self.force[:] = 0.0
            return self.force
        if self._zero is not None:
            start = not self._zero["check"]
            self._zeroing(t, w)
            if start:
                if self._zero is None:      # the start-up bias: in use from now on
                    self._set_bias_now(self.comp[B1_AT:B1_AT + 6].copy())
                    self.first_bias = self.comp[B1_AT:B1_AT + 6].copy()
                    self.law_start = t
                    compensate_into(self._rotation_chain, self.comp, t, q, v, w, w, self.R,
                                    self.bias, self.force)
                else:
                    self.force[:] = 0.0     # held still, touching at zero force
        return self.force

    def observe(self, t: float, v: np.ndarray, force: np.ndarray) -> None:
        """The last state of an inactive sensor (nothing to compensate: the force as the law
        reads it, base frame): kept by reference for :meth:`request_zero`, nothing computed
        on the cycle. Zeroing then zeroes that force as it is, in the base frame: Franka's
        estimated wrench (the ``panda`` profile), as franka_ros's force example controller
        takes the external torque it starts with as the bias ("Bias correction for the
        current external torque")."""
        self._seen = (t, v, force)

    def _take_seen(self) -> None:
        """The inactive sensor's last state as the active one's (R_S = I: the base frame)."""
        t, v, force = self._seen
        self.last_t = float(t)
        self.last_speed = float(np.linalg.norm(v))
        self.force[:] = np.asarray(force, dtype=float)[:3]
        self.R[:] = np.eye(3).reshape(9)

    def skip_start(self) -> None:
        """An activation after states were seen (a lifecycle switch, possibly in contact):
        no start-up zeroing or hold, the bias in use kept (a property of the sensor, not of
        the law) and the law's clock from the activation."""
        self.at_start = False
        self._zero = None
        self.law_start = 0.0
        self._set_bias_now(self.bias.copy())

    @property
    def holding(self) -> bool:
        """True during the start-up zeroing: the arm is to be held still, the law waits."""
        return self.at_start and (not self._started or (self._zero is not None
                                                         and not self._zero["check"]))

    def _weight(self) -> np.ndarray:
        return weight_wrench(self.R.reshape(3, 3), self.mass, self.com, self.gravity)

    def _set_bias_now(self, b: np.ndarray) -> None:
        self.comp[B0_AT:B0_AT + 6] = self.comp[B1_AT:B1_AT + 6] = b
        self.comp[TBLEND_AT] = 0.0

    # -- zeroing ---------------------------------------------------------------------------
    @property
    def zeroing(self) -> bool:
        """True while a zeroing averages or blends its bias in."""
        blending = (self.comp[TBLEND_AT] > 0.0
                    and self.last_t < self.comp[TB_AT] + self.comp[TBLEND_AT])
        return self._zero is not None or bool(blending)

    def request_zero(self, desired_force: np.ndarray | None = None, max_change: float = 5.0,
                     force: bool = False) -> tuple[bool, str]:
        """Start a zeroing (``~/zero_ft``; ``force``: ``~/zero_ft_force``): (accepted,
        message). Refused while one runs, before the first state, while the joints move,
        while the law asks for a contact force, and unless forced while in contact or when
        the bias the last reading makes is farther than ``max_change`` (N) from the first
        one (module docstring). Only the answer says why; the log is left to the caller
        (:meth:`refused`). An inactive sensor (nothing compensated yet) judges by its last
        observed state (:meth:`observe`) and becomes active once a zeroing is accepted."""
        if not self.active and self._seen is not None:
            self._take_seen()
        if not math.isfinite(self.last_t):
            return False, "no state and wrench yet: nothing to zero"
        if self.zeroing:
            return False, "a zeroing is already under way"
        if self.last_speed > ZERO_MAX_JOINT_SPEED:
            return False, (f"moving: |q'| = {self.last_speed:.3g} rad/s > "
                           f"{ZERO_MAX_JOINT_SPEED:g} rad/s; zero while still")
        f = float(np.linalg.norm(self.force))
        if not force and f > ZERO_MAX_FORCE:
            return False, (f"in contact: compensated force {f:.3g} N > {ZERO_MAX_FORCE:g} N; "
                           "zero out of contact")
        f_d = 0.0 if desired_force is None else float(np.linalg.norm(desired_force))
        if f_d > ZERO_MAX_DESIRED_FORCE:
            return False, (f"the law asks for a contact force of {f_d:.3g} N (> "
                           f"{ZERO_MAX_DESIRED_FORCE:g} N): zero out of contact")
        if not force:
            # the bias the contact now read would make: b + R_S^T f (force part)
            drift = float(np.linalg.norm(self.bias[:3] + self.R.reshape(3, 3).T @ self.force
                                         - self.first_bias[:3]))
            if drift > max_change:
                return False, self._too_far(drift, max_change)
        self._begin_zero(self.last_t, ZERO_WINDOW_S, check=True, force=force,
                         max_change=max_change)
        self.active = True
        return True, (f"zeroing{' (forced)' if force else ''}: averaging the sensor over "
                      f"{ZERO_WINDOW_S:g} s, then blending the new bias in over "
                      f"{ZERO_BLEND_S:g} s")

    def refused(self, message: str) -> None:
        """Log a refused or abandoned zeroing (rate-limited, :class:`RateLimitedLog`)."""
        self.refusals(self.warn, message)

    def _too_far(self, drift: float, max_change: float) -> str:
        return (f"the force bias would move {drift:.3g} N from the first one "
                f"{np.round(self.first_bias[:3], 3).tolist()} N (> zero_ft_max_change "
                f"{max_change:g} N): a contact taken for bias? Zero with the tool touching "
                "nothing; ~/zero_ft_force takes it anyway")

    def _begin_zero(self, t: float, window: float, check: bool, force: bool = False,
                    max_change: float = math.inf) -> None:
        self._zero = {"begin": t, "end": t + window - 1e-9, "sum": np.zeros(6), "count": 0,
                      "check": check, "force": force, "max_change": max_change}

    def _zeroing(self, t: float, w: np.ndarray) -> None:
        z = self._zero
        if t < z["begin"]:
            return
        if z["check"] and self.last_speed > ZERO_MAX_JOINT_SPEED:
            self._zero = None
            self.refused(f"zero_ft abandoned: the joints moved (|q'| = {self.last_speed:.3g} "
                         "rad/s); the bias stays as it was")
            return
        z["sum"] += w - self._weight()
        z["count"] += 1
        if t < z["end"]:
            return
        self._zero = None
        new = z["sum"] / z["count"]
        old = self.bias.copy()
        change = float(np.linalg.norm(new[:3] - old[:3]))
        if z["check"] and not z["force"] and change > ZERO_MAX_FORCE:
            self.refused(f"zero_ft abandoned: the force bias would change by {change:.3g} N > "
                         f"{ZERO_MAX_FORCE:g} N (a contact?); the bias stays as it was")
            return
        drift = float(np.linalg.norm(new[:3] - self.first_bias[:3]))
        if z["check"] and not z["force"] and drift > z["max_change"]:
            self.refused(f"zero_ft abandoned: {self._too_far(drift, z['max_change'])}; the "
                         "bias stays as it was")
            return
        if z["force"]:
            self.first_bias = new.copy()
        self.comp[B0_AT:B0_AT + 6] = old
        self.comp[B1_AT:B1_AT + 6] = new
        self.comp[TB_AT] = t
        self.comp[TBLEND_AT] = ZERO_BLEND_S
        self.zero_count += 1
        self.log(f"zero_ft: new bias {np.round(new, 4).tolist()} (force N, torque N m, "
                 f"{self.sensor_frame or 'base frame'}) from {z['count']} readings, blended in "
                 f"over {ZERO_BLEND_S:g} s" + ("; forced: the first bias from now on"
                                              if z["force"] else ""))


def frame_rotation(chain_model, q: np.ndarray, frame: str) -> np.ndarray:
    """R (base <- ``frame``) at chain positions q by Pinocchio (tests, tools; not the cycle)."""
    model = chain_model.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, chain_model.configuration(np.asarray(q, dtype=float)))
    return data.oMf[model.getFrameId(frame)].rotation.copy()
