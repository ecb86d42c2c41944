"""What both chapter 6 schemes share: their parameters (joints, geometry, desired motion,
lambda_d), the packed block of those gains, the measured quantities every cycle starts from,
and the layout of what they publish.

Joints: the plant ``flexible_joint_surface`` publishes link joints (joint1, joint2: q_l) and
motor joints (joint1_motor, joint2_motor: q_m); the schemes read all four
(``state_joint_names``, in that order) and command the motor torques tau_m (6.2).

Measured every cycle (assumption 6.3): q_l, q_l', q_m, q_m' from the joint state and
lambda = n . f from the wrench (the plant reports the contact force n lambda with the unit
surface normal n, so lambda is the normal force in N; 6.4-6.5).

Desired motion (section 6.3): r_d(t) = c + a cos(w t + phi) per axis (x_d = -0.1 cos 2t,
y_d = 0.35 - 0.1 cos 2t), on the surface x - y + 0.35 = 0 (not the printed
0.25; docs/thesis.md), through the inverse kinematics on the branch sin(theta2) < 0, with its
time derivatives up to order 4 taken exactly (Taylor jets,
:func:`cr_control.schemes.flexible_joint.flexible_joint_model.desired_motion_jets`), never by finite
differences. lambda_d = 2 N.

Published: the task-space reference and status of every scheme (topics.REFERENCE_FIELDS,
STATUS_FIELDS: r_d, v_d, a_d, f_d = n lambda_d; r, v, f, e, f_err, tau_1/2 = tau_m), then
the link-space reference (REFERENCE below) and the common status (STATUS below) before the
scheme's own fields.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, matrix
from cr_control.core.topics import REFERENCE_FIELDS, STATUS_FIELDS
from cr_control.schemes.controller import COMMON_PARAMETERS, Controller
from cr_control.schemes.flexible_joint.flexible_joint_model import constraint_into, desired_motion_jets

MOTOR_JOINTS = ["joint1_motor", "joint2_motor"]
STATE_JOINTS = ["joint1", "joint2", *MOTOR_JOINTS]

#: The common joint_names parameter (commanded joints) with the motors as its default.
JOINT_NAMES_PARAMETER = next(dataclasses.replace(
    p, default=MOTOR_JOINTS, description="Motor joints commanded (tau_m of 6.2), in command order.")
    for p in COMMON_PARAMETERS if p.name == "joint_names")

#: Link-space reference fields after the task-space ones.
REFERENCE = REFERENCE_FIELDS + ["q_ld_1", "q_ld_2", "qdot_ld_1", "qdot_ld_2", "qddot_ld_1",
                                "qddot_ld_2", "lambda_d"]
#: Status fields of both schemes after the task-space ones (lambda, its error, the link
#: position errors, the constraint value Phi(q_l)).
STATUS = ["lambda", "e_lambda", "e_q_1", "e_q_2", "phi"]
#: Sizes and offsets the kernels use (numba freezes them as constants): the reference
#: after its stamp, and where STATUS starts in the status (after the task-space fields,
#: tau, compute time and held).
N_REFERENCE = len(REFERENCE) - 1
STATUS_AT = len(STATUS_FIELDS) - 1
EXTRAS_AT = STATUS_AT + len(STATUS)

PARAMETERS = [
    Param("state_joint_names", STATE_JOINTS, "Joints read from /joint_states: links q_l, then "
          "motors q_m (6.3), in this order.", "string_list", read_only=True),
    Param("link_length", [0.3, 0.3], "Link lengths l1, l2 (m) (section 6.3; docs/thesis.md).",
          "positive_vector", 2, read_only=True, bound=Bound.LENGTH),
    Param("surface_normal", [1.0, -1.0], "Raw normal n of the rigid surface n . r + c = 0 "
          "(x - y + 0.35 = 0, docs/thesis.md); normalised, so lambda is the normal force (N).",
          "vector", 2, read_only=True, bound=Bound.SCALE),
    Param("surface_offset", 0.35, "c of the surface n . r + c = 0 (m, raw normal).",
          read_only=True, bound=Bound.LENGTH),
    Param("elbow_sign", -1.0, "Inverse-kinematics branch of q_ld: sign of sin(theta2) "
          "(section 6.3: sin(theta2d) < 0).", read_only=True, bound=Bound.SIGN),
    Param("path_centre", [0.0, 0.35], "Desired path r_d = c + a cos(w t + phi): c (m) "
          "(section 6.3).", "vector", 2, bound=Bound.LENGTH),
    Param("path_amplitude", [-0.1, -0.1], "r_d: a (m) (x_d = -0.1 cos 2t).", "vector", 2, bound=Bound.LENGTH),
    Param("path_frequency", 2.0, "r_d: w (rad/s).", "nonnegative", bound=Bound.MOTION_FREQUENCY),
    Param("path_phase", 0.0, "r_d: phi (rad).", "finite", bound=Bound.PHASE),
    Param("lambda_d", 2.0, "Desired constraint force lambda_d (N) (section 6.3).", "finite",
          bound=Bound.FORCE),
]


class FlexibleJointController(Controller):
    """Base of the chapter 6 schemes: reads the link and motor joints (``state_joint_names``),
    commands the two motors, publishes REFERENCE and STATUS before its own fields."""

    reference_fields = REFERENCE
    command_status_fields = ["tau_1", "tau_2"]
    JOINT_NAMES_PARAMETER = JOINT_NAMES_PARAMETER

    def __init__(self, values: dict):
        super().__init__(values)
        if self.n_joints != 2 or self.n_state != 4:
            raise ValueError(f"{self.scheme} commands 2 motors and reads 4 joints, got "
                             f"{self.values['joint_names']} and {self.state_joint_names}")


def k_e_parameter(default: float) -> Param:
    """K_e of r = e' + K_e e (6.14, 6.76) with ``default`` on the diagonal."""
    return Param("K_e", matrix(2, default), "K_e of r = e' + K_e e (6.14, 6.76) (1/s); the "
                 "robust scheme uses its (1,1) entry (n - m = 1).", "spd", 2, bound=Bound.GAIN)


#: Packed shared gains.
COMMON = Layout(link_length=2, normal=2, offset=1, elbow_sign=1, centre=2, amplitude=2,
                omega=1, phase=1, lambda_d=1, K_e=(2, 2))
_LEN, _N, _OFF, _ELBOW, _C, _A, _W, _PHI, _LD, _KE = (
    COMMON.offset(k) for k in ("link_length", "normal", "offset", "elbow_sign", "centre",
                               "amplitude", "omega", "phase", "lambda_d", "K_e"))
#: Where a scheme's own gains start in its gains vector.
OWN = COMMON.size


def pack_common(values: dict, out: np.ndarray) -> None:
    """Fill the COMMON block of a scheme's gains from converted parameter values (the
    normal and offset are normalised here: n . r + c = 0 with |n| = 1)."""
    n = np.asarray(values["surface_normal"], dtype=float)
    norm = math.hypot(n[0], n[1])
    if not norm > 0.0:
        raise ValueError("surface_normal must not be zero")
    COMMON.pack({
        "link_length": values["link_length"], "normal": n / norm,
        "offset": values["surface_offset"] / norm,
        "elbow_sign": 1.0 if values["elbow_sign"] >= 0.0 else -1.0,
        "centre": values["path_centre"], "amplitude": values["path_amplitude"],
        "omega": values["path_frequency"], "phase": values["path_phase"],
        "lambda_d": values["lambda_d"], "K_e": values["K_e"]}, out)


@njit(cache=True, error_model="numpy")
def desired(g, t, qjet):
    """q_ld and its derivatives (rows 0..4 of ``qjet``, 5 x 2) at t (section 6.3)."""
    desired_motion_jets(t, g[_C:_C + 2], g[_A:_A + 2], g[_W], g[_PHI], g[_LEN:_LEN + 2],
                        g[_ELBOW], qjet)


@njit(cache=True, error_model="numpy")
def surface(g, q, v, out):
    """Phi, J_Phi, L, L', Phi', J_Phi' at the links (q, q') into ``out`` (10)
    (:func:`constraint_into`; normal and offset already normalised)."""
    constraint_into(q, v, g[_LEN:_LEN + 2], g[_N:_N + 2], g[_OFF], out)


@njit(cache=True, error_model="numpy")
def measured_lambda(g, force):
    """lambda = n . f (the plant reports n lambda)."""
    return g[_N] * force[0] + g[_N + 1] * force[1]


@njit(cache=True, error_model="numpy")
def write_output(g, out, tau, qjet, q, v, force, phi):
    """Fill [command tau_m (2) | reference (REFERENCE after stamp) | status: task-space
    fields, tau_1/2, zeros for timing/held, then STATUS]; returns the status view from the
    first scheme-specific field on (for the caller to fill)."""
    l1, l2 = g[_LEN], g[_LEN + 1]
    nx, ny = g[_N], g[_N + 1]
    lambda_d = g[_LD]
    out[0], out[1] = tau[0], tau[1]
    ref = out[2:2 + N_REFERENCE]
    qd, qd_dot, qd_ddot = qjet[0], qjet[1], qjet[2]
    rd, vd, ad = tool(l1, l2, qd, qd_dot, qd_ddot)
    ref[0], ref[1], ref[2], ref[3], ref[4], ref[5] = rd[0], rd[1], vd[0], vd[1], ad[0], ad[1]
    ref[6], ref[7] = nx * lambda_d, ny * lambda_d
    ref[8], ref[9], ref[10], ref[11] = qd[0], qd[1], qd_dot[0], qd_dot[1]
    ref[12], ref[13], ref[14] = qd_ddot[0], qd_ddot[1], lambda_d
    st = out[2 + N_REFERENCE:]
    zero = np.zeros(2)
    r, r_dot, _ = tool(l1, l2, q[:2], v[:2], zero)
    lam = nx * force[0] + ny * force[1]
    st[:] = 0.0
    st[0], st[1], st[2], st[3] = r[0], r[1], r_dot[0], r_dot[1]
    st[4], st[5] = force[0], force[1]
    st[6], st[7] = rd[0] - r[0], rd[1] - r[1]
    st[8], st[9] = nx * lambda_d - force[0], ny * lambda_d - force[1]
    st[10], st[11] = tau[0], tau[1]
    # st[12], st[13]: compute_time_us and held, filled by the Controller base
    common = st[STATUS_AT:]
    common[0], common[1] = lam, lambda_d - lam
    common[2], common[3] = qd[0] - q[0], qd[1] - q[1]
    common[4] = phi
    return st[EXTRAS_AT:]


@njit(cache=True, error_model="numpy")
def tool(l1, l2, q, qd, qdd):
    """End-effector position, velocity and acceleration of the 2-link arm (base at the
    origin) at joint positions q, velocities qd, accelerations qdd."""
    c1, s1 = math.cos(q[0]), math.sin(q[0])
    c12, s12 = math.cos(q[0] + q[1]), math.sin(q[0] + q[1])
    w1, w12 = qd[0], qd[0] + qd[1]
    a1, a12 = qdd[0], qdd[0] + qdd[1]
    r = np.empty(2)
    v = np.empty(2)
    a = np.empty(2)
    r[0], r[1] = l1 * c1 + l2 * c12, l1 * s1 + l2 * s12
    v[0] = -l1 * s1 * w1 - l2 * s12 * w12
    v[1] = l1 * c1 * w1 + l2 * c12 * w12
    a[0] = -l1 * (s1 * a1 + c1 * w1 * w1) - l2 * (s12 * a12 + c12 * w12 * w12)
    a[1] = l1 * (c1 * a1 - s1 * w1 * w1) + l2 * (c12 * a12 - s12 * w12 * w12)
    return r, v, a
