"""A wrist force/torque sensor carrying a tool: the contact force the law needs, in the base
frame, from what the sensor measures in its own frame (issue 24, item 2).

The sensor sits at the flange (frame S, ``sensor_frame``: ``panda_link8``, ``tool0``) and
reads, in S, the contact wrench plus the tool's weight plus a bias (the plant's model,
:mod:`cr_sim.plants.urdf_surface`). The law receives

    f = R_S (F_S - b_F) - m g                                                   (1)

- R_S: rotation base <- S at the measured joints q, from the controller's own compiled
  chain (:mod:`cr_control.models.spatial_chain`): R_S = R_n(q) R_nS, R_n the last joint's
  frame and R_nS the constant placement of S on it (S must ride on the tip's body);
- F_S: the measured force (S), b_F the force bias (S), m = ``tool_mass``, g = ``gravity``.

Neglected: the tool's inertial wrench m a_c (and the gyroscopic torque). At the wiping task's
speeds (a 5 cm circle at 1 rad/s, orientation held) |a_c| = r w^2 = 0.05 m/s^2: 0.035 N on the
0.7 kg tool, 0.35 % of the 10 N pressed; a_c = 1.4 m/s^2 would be needed for 1 N.
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
contact force (|f_d| <= ZERO_MAX_FORCE) and the compensated force with the bias in use is
small (|f| <= ZERO_MAX_FORCE); the zeroing is abandoned, keeping the old bias, if the joints
move during the window or the new force bias differs from the old by more than
ZERO_MAX_FORCE. A contact lighter than ZERO_MAX_FORCE cannot be told from a bias by the
sensor alone: zero with the tool in the air (or touching at zero force).

At start-up (``zero_ft_at_start``, for a task that starts touching at zero force, such as
the robots' wiping task): the bias is the average of W_S - w over the ZERO_START_WINDOW_S
(50 ms) after the first reading, and the law is given f = 0 until then (the premise:
touching at zero force); the first reading itself is left out (it is taken before any
command holds the arm: the tool's inertial wrench is in it, 7 N on the simulated Panda).
The window is short because the wiping task's desired force ramps in from the first state
(0.5 N after 50 ms).

Cost: one compiled call per cycle, the rotation pass over n joints and (1), (2): measured
in test/test_wrist_compensation.py's micro-timing (printed).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from numba import njit

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.spatial_chain import AXIS, HEADER, KIND, PER_JOINT, PRISMATIC_KIND, ROT

#: Averaging window of a zeroing (s).
ZERO_WINDOW_S = 0.2
#: Averaging window of the start-up zeroing (s).
ZERO_START_WINDOW_S = 0.01
#: A new bias is blended in over this time (s), by (2).
ZERO_BLEND_S = 0.5
#: "Still": joint speed |q'| (Euclidean, rad/s) at most this during a zeroing.
ZERO_MAX_JOINT_SPEED = 0.05
#: "Out of contact": compensated force, desired force and the bias change at most this (N).
ZERO_MAX_FORCE = 5.0

PARAMETERS = [
    Param("sensor_frame", "", "Frame of the force/torque sensor's wrench (a link riding on "
          "tip_link's body: panda_link8, tool0); every wrench must name it in its frame_id. "
          "Empty: an ideal sensor measuring the contact force in the base frame (the thesis "
          "plants; no compensation).", "string", read_only=True),
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
    Param("zero_ft_at_start", False, "Zero the sensor on the first states (the task starts "
          "touching at zero force, or in the air, and still): the bias is the average over the "
          f"{ZERO_START_WINDOW_S:g} s after the first reading, the law is given zero force "
          "until then.", "bool", read_only=True),
]
NAMES = tuple(p.name for p in PARAMETERS)

#: Layout of the packed compensation ``comp``: [m, g (3), R_nS (9, row-major), b_0 (6),
#: b_1 (6), t_b, T_b].
MASS_AT, G_AT, RNS_AT, B0_AT, B1_AT, TB_AT, TBLEND_AT, COMP_SIZE = 0, 1, 4, 13, 19, 25, 26, 27


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
def blend(x):
    """s(x) = 3x^2 - 2x^3 on [0, 1], 0 below, 1 above (2)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, error_model="numpy")
def compensate_into(chain, comp, t, q, wrench, R, bias, force):
    """(1) with the bias of (2) at t: ``force`` (3, base frame) from ``wrench`` (force and
    torque, S); also writes R_S (9) into ``R`` and the bias in use (6) into ``bias``."""
    sensor_rotation_into(chain, comp[RNS_AT:RNS_AT + 9], q, R)
    T = comp[TBLEND_AT]
    s = blend((t - comp[TB_AT]) / T) if T > 0.0 else 1.0
    for i in range(6):
        bias[i] = comp[B0_AT + i] + s * (comp[B1_AT + i] - comp[B0_AT + i])
    m = comp[MASS_AT]
    fx, fy, fz = wrench[0] - bias[0], wrench[1] - bias[1], wrench[2] - bias[2]
    for r in range(3):
        force[r] = R[3 * r] * fx + R[3 * r + 1] * fy + R[3 * r + 2] * fz - m * comp[G_AT + r]


def sensor_placement(chain_model, sensor_frame: str) -> np.ndarray:
    """R_nS (3 x 3): the rotation of ``sensor_frame`` in the chain's last joint frame;
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
    return np.array(frame.placement.rotation)


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
        R_nS = sensor_placement(model.chain_model, frame) if frame else None
        # no sensor frame: the base frame (R_S = I): R_nS = R_n(q)^T is not constant, so the
        # kernel is given the identity through a chain of no joints
        self._ideal_chain = np.array([0.0, *values["gravity"]])
        self._rotation_chain = self.chain if frame else self._ideal_chain
        self.comp = np.zeros(COMP_SIZE)
        self.comp[RNS_AT:RNS_AT + 9] = (np.eye(3) if R_nS is None else R_nS).reshape(9)
        self.comp[G_AT:G_AT + 3] = values["gravity"]
        self.comp[B0_AT:B0_AT + 6] = self.comp[B1_AT:B1_AT + 6] = values["ft_bias"]
        self.gravity = np.array(values["gravity"], dtype=float)
        self.set_tool(values)
        self.at_start = bool(values["zero_ft_at_start"])
        self.active = bool(frame or values["tool_mass"] > 0.0 or any(values["ft_bias"])
                           or self.at_start)
        self.R = np.zeros(9)
        self.bias = np.array(values["ft_bias"], dtype=float)
        self.force = np.zeros(3)
        self._wrench = np.zeros(6)
        self._zero: dict | None = None      # the zeroing under way: window end, sums
        self._started = False
        self.last_t = math.nan
        self.last_speed = math.inf
        self.zero_count = 0
        self.log = print

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
        k = min(wrench.shape[0], 6)
        w[:k] = wrench[:k]
        compensate_into(self._rotation_chain, self.comp, t, q, w, self.R, self.bias, self.force)
        self.last_t = t
        self.last_speed = float(np.sqrt(v @ v))
        if self.at_start and not self._started:
            # the first reading is taken before any command held the arm: not averaged
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
                    compensate_into(self._rotation_chain, self.comp, t, q, w, self.R,
                                    self.bias, self.force)
                else:
                    self.force[:] = 0.0     # touching at zero force: the premise
        return self.force

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

    def request_zero(self, desired_force: np.ndarray | None = None) -> tuple[bool, str]:
        """Start a zeroing (``~/zero_ft``): (accepted, message). Refused while one runs,
        before the first state, while the joints move or while in contact (module docstring)."""
        if not math.isfinite(self.last_t):
            return False, "no state and wrench yet: nothing to zero"
        if self.zeroing:
            return False, "a zeroing is already under way"
        if self.last_speed > ZERO_MAX_JOINT_SPEED:
            return False, (f"moving: |q'| = {self.last_speed:.3g} rad/s > "
                           f"{ZERO_MAX_JOINT_SPEED:g} rad/s; zero while still")
        f = float(np.linalg.norm(self.force))
        if f > ZERO_MAX_FORCE:
            return False, (f"in contact: compensated force {f:.3g} N > {ZERO_MAX_FORCE:g} N; "
                           "zero out of contact")
        if desired_force is not None and float(np.linalg.norm(desired_force)) > ZERO_MAX_FORCE:
            return False, (f"the law asks for a contact force of "
                           f"{float(np.linalg.norm(desired_force)):.3g} N: zero out of contact")
        self._begin_zero(self.last_t, ZERO_WINDOW_S, check=True)
        self.active = True
        return True, (f"zeroing: averaging the sensor over {ZERO_WINDOW_S:g} s, then blending "
                      f"the new bias in over {ZERO_BLEND_S:g} s")

    def _begin_zero(self, t: float, window: float, check: bool) -> None:
        self._zero = {"begin": t, "end": t + window - 1e-9, "sum": np.zeros(6), "count": 0,
                      "check": check}

    def _zeroing(self, t: float, w: np.ndarray) -> None:
        z = self._zero
        if t < z["begin"]:
            return
        if z["check"] and self.last_speed > ZERO_MAX_JOINT_SPEED:
            self._zero = None
            self.log(f"zero_ft abandoned: the joints moved (|q'| = {self.last_speed:.3g} rad/s); "
                     "the bias stays as it was")
            return
        z["sum"] += w - self._weight()
        z["count"] += 1
        if t < z["end"]:
            return
        self._zero = None
        new = z["sum"] / z["count"]
        old = self.bias.copy()
        change = float(np.linalg.norm(new[:3] - old[:3]))
        if z["check"] and change > ZERO_MAX_FORCE:
            self.log(f"zero_ft abandoned: the force bias would change by {change:.3g} N > "
                     f"{ZERO_MAX_FORCE:g} N (a contact?); the bias stays as it was")
            return
        self.comp[B0_AT:B0_AT + 6] = old
        self.comp[B1_AT:B1_AT + 6] = new
        self.comp[TB_AT] = t
        self.comp[TBLEND_AT] = ZERO_BLEND_S
        self.zero_count += 1
        self.log(f"zero_ft: new bias {np.round(new, 4).tolist()} (force N, torque N m, "
                 f"{self.sensor_frame or 'base frame'}) from {z['count']} readings, blended in "
                 f"over {ZERO_BLEND_S:g} s")


def frame_rotation(chain_model, q: np.ndarray, frame: str) -> np.ndarray:
    """R (base <- ``frame``) at chain positions q by Pinocchio (tests, tools; not the cycle)."""
    model = chain_model.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, chain_model.configuration(np.asarray(q, dtype=float)))
    return data.oMf[model.getFrameId(frame)].rotation.copy()
