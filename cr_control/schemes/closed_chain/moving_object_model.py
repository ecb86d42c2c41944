"""Shared blocks of the chapter 2 schemes: kinematics of the closed chain, the regressor
Psi and parameters P of section 2.4, the desired motion (2.106-2.107) and its inverse
kinematics, and the layout of what both schemes publish.

Independent coordinates q^1 = [theta1, theta2] (2.101); the object coordinate follows from
the constraint n_c . r_co = 0 (2.94 with n_c = (n_x, n_y), default (1, -1)/sqrt(2)):

    q2(q^1) = x_c + rho (y_c - b),  rho = n_y / n_x          (2.102: x_c - y_c + b)
    L = [I ; dq2/dq^1] = [I ; J_1[0] + rho J_1[1]]        (3 x 2; the printed L for rho = -1)
    J^{1T} n_c = [J_1^T n_c ; -n_x]                          (A = I, J_2 = [1 0]^T)

(2.18-2.20; Property 2.1: L^T J^{1T} n_c = 0). L is 3 x 2, so "L^-T" of (2.27) and (2.74)
is a right inverse of L^T: X = L (L^T L)^-1, L^T X = I (docs/thesis.md).

Regressor (2.21) of the reduced model M^1 q_r'' + C^1 q_r' + G^1 = Psi P with
P = [p1, m2 d1 l2, I2 + m2 l2^2, (m1 l1 + m2 d1) g, m2 l2 g, M2 d1, M2 d2]; true values
with the corrected geometry (docs/thesis.md): [0.6135, 0.0045, 0.30225, 0.441, 0.147, 0.06, 0.06].
Psi as printed in section 2.4 except Psi_11 = q_r1'' (printed theta1''); the object row in
the general form for any rho (the printed Psi_36, Psi_37 for rho = -1):

    Psi_36 = -(s1 - rho c1) q_r1'' - (c1 + rho s1) theta1' q_r1'
    Psi_37 = -(s12 - rho c12)(q_r1'' + q_r2'') - (c12 + rho s12)(theta1' + theta2')(q_r1' + q_r2')

Desired motion (2.106-2.107): x_co = y_co = -A_c cos(w_c t + phi_c) (A_c = 1/12, w_c = 1,
phi_c = 2) on the line, x_o = c_o - A_o sin(w_o t + phi_o) (c_o = A_o = 0.1, w_o = 4,
phi_o = 12); the contact point r_c = (x_o + x_co, b + y_co) through the corrected
inverse kinematics (2.97-2.100 with atan2, branch sin theta2 > 0; docs/thesis.md), and the
derivatives exactly: q_d' = J_1^-1 r_c', q_d'' = J_1^-1 (r_c'' - J_1' q_d').
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, matrix
from cr_control.core.topics import REFERENCE_FIELDS
from cr_control.schemes.controller import COMMON_PARAMETERS, Controller

#: The true P of section 2.4 with the corrected geometry (docs/thesis.md).
TRUE_P = np.array([0.6135, 0.0045, 0.30225, 0.441, 0.147, 0.06, 0.06])
#: P as printed in the thesis (p1, p2, p4, p5 rounded or wrong; shown for comparison).
PRINTED_P = np.array([0.6, 0.04, 0.3, 0.44, 0.15, 0.06, 0.06])

JOINT_NAMES = ["joint1", "joint2", "object_x"]
#: The common joint_names parameter with the chapter 2 joints as its default.
JOINT_NAMES_PARAMETER = next(dataclasses.replace(p, default=JOINT_NAMES)
                             for p in COMMON_PARAMETERS if p.name == "joint_names")

#: Kinematics, desired motion and the gains shared by both schemes.
GEOMETRY_PARAMETERS = [
    Param("link_length", [0.3, 0.3], "Link lengths d1, d2 of manipulator 1 (m) (kinematics).",
          "positive_vector", 2, read_only=True, bound=Bound.LENGTH),
    Param("base_position", [0.2, 0.0], "Base of manipulator 1, (a, 0) (m).", "vector", 2,
          read_only=True, bound=Bound.LENGTH),
    Param("object_height", 0.5, "Height b of the object frame (m).", read_only=True, bound=Bound.LENGTH),
    Param("constraint_normal", [1.0, -1.0], "Normal of the line on the object, object frame "
          "(2.94: x_co - y_co = 0); normalised to n_c. Needs n_x != 0 and n_y != 0.", "vector", 2,
          read_only=True, bound=Bound.SCALE),
    Param("elbow_sign", 1.0, "Inverse-kinematics branch of q_d: sign of sin(theta2) "
          "(s2 > 0: docs/thesis.md).", read_only=True, bound=Bound.SIGN),
]

MOTION_PARAMETERS = [
    Param("contact_amplitude", 1.0 / 12.0, "x_co = -A_c cos(w_c t + phi_c): A_c (m) (2.106).",
          "nonnegative", bound=Bound.LENGTH),
    Param("contact_frequency", 1.0, "x_co: w_c (rad/s) (2.106).", "nonnegative",
          bound=Bound.MOTION_FREQUENCY),
    Param("contact_phase", 2.0, "x_co: phi_c (rad) (2.106).", "finite", bound=Bound.PHASE),
    Param("object_centre", 0.1, "x_o = c_o - A_o sin(w_o t + phi_o): c_o (m) (2.107).", "finite",
          bound=Bound.LENGTH),
    Param("object_amplitude", 0.1, "x_o: A_o (m) (2.107).", "nonnegative", bound=Bound.LENGTH),
    Param("object_frequency", 4.0, "x_o: w_o (rad/s) (2.107).", "nonnegative", bound=Bound.MOTION_FREQUENCY),
    Param("object_phase", 12.0, "x_o: phi_o (rad) (2.107).", "finite", bound=Bound.PHASE),
    Param("lambda_d", 2.0, "Desired contact force lambda_d (N) (2.4).", "finite", bound=Bound.FORCE),
]


def gain_parameters() -> list[Param]:
    """K_e, K, k_lambda of (2.24-2.27) with the section 2.4 values."""
    return [
        Param("K_e", matrix(2, 20.0), "K_e of r^1 = e^1' + K_e e^1 (2.24) (1/s).", "spd", 2,
              bound=Bound.GAIN),
        Param("K", matrix(2, 15.0), "K of the feedback L^-T K r^1 (2.27).", "spd", 2, bound=Bound.GAIN),
        Param("k_lambda", 15.0, "k_lambda of the force integral (2.27) (1/s).", "positive", bound=Bound.GAIN),
    ]


#: Packed shared gains: geometry, desired motion, K_e, K, k_lambda.
COMMON = Layout(link_length=2, base_position=2, object_height=1, normal=2, elbow_sign=1,
                motion=8, K_e=(2, 2), K=(2, 2), k_lambda=1)
_LEN, _BASE, _B, _N, _ELBOW, _MOTION, _KE, _K, _KL = (
    COMMON.offset(k) for k in ("link_length", "base_position", "object_height", "normal",
                               "elbow_sign", "motion", "K_e", "K", "k_lambda"))


def pack_common(values: dict, out: np.ndarray) -> None:
    """Fill the COMMON block of a scheme's gains from converted parameter values."""
    n = np.asarray(values["constraint_normal"], dtype=float)
    norm = math.hypot(n[0], n[1])
    if not norm > 0.0 or n[0] == 0.0 or n[1] == 0.0:
        raise ValueError("constraint_normal needs non-zero x and y components")
    COMMON.pack({
        "link_length": values["link_length"], "base_position": values["base_position"],
        "object_height": values["object_height"], "normal": n / norm,
        "elbow_sign": 1.0 if values["elbow_sign"] >= 0.0 else -1.0,
        "motion": [values[p.name] for p in MOTION_PARAMETERS],
        "K_e": values["K_e"], "K": values["K"], "k_lambda": values["k_lambda"]}, out)


# -- kinematics --------------------------------------------------------------------------
@njit(cache=True)
def arm_kinematics(g, q, v):
    """(r_c (world), J_1, J_1' q') of manipulator 1 at (q, q') (q: its 2 joints)."""
    d1, d2 = g[_LEN], g[_LEN + 1]
    c1, s1 = math.cos(q[0]), math.sin(q[0])
    c12, s12 = math.cos(q[0] + q[1]), math.sin(q[0] + q[1])
    w1, w12 = v[0], v[0] + v[1]
    r = np.empty(2)
    r[0] = g[_BASE] + d1 * c1 + d2 * c12
    r[1] = g[_BASE + 1] + d1 * s1 + d2 * s12
    J = np.empty((2, 2))
    J[0, 0], J[0, 1] = -d1 * s1 - d2 * s12, -d2 * s12
    J[1, 0], J[1, 1] = d1 * c1 + d2 * c12, d2 * c12
    jdv = np.empty(2)
    jdv[0] = -d1 * c1 * w1 * w1 - d2 * c12 * w12 * w12
    jdv[1] = -d1 * s1 * w1 * w1 - d2 * s12 * w12 * w12
    return r, J, jdv


@njit(cache=True)
def closed_chain(g, q, v):
    """(L (3x2), L' (3x2), J^{1T} n_c (3), X = L (L^T L)^-1 (3x2)) at (q^1, q^1')."""
    d1, d2 = g[_LEN], g[_LEN + 1]
    nx, ny = g[_N], g[_N + 1]
    rho = ny / nx
    c1, s1 = math.cos(q[0]), math.sin(q[0])
    c12, s12 = math.cos(q[0] + q[1]), math.sin(q[0] + q[1])
    w1, w12 = v[0], v[0] + v[1]
    L = np.zeros((3, 2))
    Ld = np.zeros((3, 2))
    L[0, 0] = L[1, 1] = 1.0
    L[2, 0] = -d1 * (s1 - rho * c1) - d2 * (s12 - rho * c12)
    L[2, 1] = -d2 * (s12 - rho * c12)
    Ld[2, 0] = -d1 * (c1 + rho * s1) * w1 - d2 * (c12 + rho * s12) * w12
    Ld[2, 1] = -d2 * (c12 + rho * s12) * w12
    jtn = np.empty(3)
    jtn[0] = nx * (-d1 * s1 - d2 * s12) + ny * (d1 * c1 + d2 * c12)
    jtn[1] = nx * (-d2 * s12) + ny * (d2 * c12)
    jtn[2] = -nx
    # X = L (L^T L)^-1, L^T L = I + l l^T (l = last row of L)
    a, b = L[2, 0], L[2, 1]
    m00, m01, m11 = 1.0 + a * a, a * b, 1.0 + b * b
    det = m00 * m11 - m01 * m01
    i00, i01, i11 = m11 / det, -m01 / det, m00 / det
    X = np.empty((3, 2))
    for i in range(3):
        X[i, 0] = L[i, 0] * i00 + L[i, 1] * i01
        X[i, 1] = L[i, 0] * i01 + L[i, 1] * i11
    return L, Ld, jtn, X


@njit(cache=True)
def regressor(g, q, v, qr_dot, qr_ddot):
    """Psi(q^1, q^1', q_r', q_r'') (3 x 7) of section 2.4 with Psi_11 = q_r1'' (docs/thesis.md)."""
    nx, ny = g[_N], g[_N + 1]
    rho = ny / nx
    c1, s1 = math.cos(q[0]), math.sin(q[0])
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    c12, s12 = math.cos(q[0] + q[1]), math.sin(q[0] + q[1])
    t1, t2 = v[0], v[1]
    a1, a2 = qr_ddot[0], qr_ddot[1]
    b1, b2 = qr_dot[0], qr_dot[1]
    P = np.zeros((3, 7))
    P[0, 0] = a1
    P[0, 1] = 2.0 * c2 * a1 + c2 * a2 - s2 * (t1 + t2) * b2 - s2 * t2 * b1
    P[0, 2] = a2
    P[0, 3] = c1
    P[0, 4] = c12
    P[1, 1] = c2 * a1 + s2 * t1 * b1
    P[1, 2] = a1 + a2
    P[1, 4] = c12
    P[2, 5] = -(s1 - rho * c1) * a1 - (c1 + rho * s1) * t1 * b1
    P[2, 6] = -(s12 - rho * c12) * (a1 + a2) - (c12 + rho * s12) * (t1 + t2) * (b1 + b2)
    return P


@njit(cache=True)
def reduced_dynamics(g, P, q, v):
    """M^1 (3x2), C^1 (3x2), G^1 (3) of (2.20) for parameters P (closed form of 2.103-2.104
    in terms of P; M^1 = M L, C^1 = M L' + C L, G^1 = G): Psi P = M^1 q_r'' + C^1 q_r' + G^1."""
    nx, ny = g[_N], g[_N + 1]
    rho = ny / nx
    c1, s1 = math.cos(q[0]), math.sin(q[0])
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    c12, s12 = math.cos(q[0] + q[1]), math.sin(q[0] + q[1])
    t1, t12 = v[0], v[0] + v[1]
    M = np.zeros((3, 2))
    C = np.zeros((3, 2))
    G = np.zeros(3)
    M[0, 0], M[0, 1] = P[0] + 2.0 * P[1] * c2, P[2] + P[1] * c2
    M[1, 0], M[1, 1] = P[2] + P[1] * c2, P[2]
    h = P[1] * s2
    C[0, 0], C[0, 1] = -h * v[1], -h * t12
    C[1, 0] = h * t1
    u1, u12 = -(s1 - rho * c1), -(s12 - rho * c12)
    w1, w12 = -(c1 + rho * s1), -(c12 + rho * s12)
    M[2, 0], M[2, 1] = P[5] * u1 + P[6] * u12, P[6] * u12
    C[2, 0], C[2, 1] = P[5] * w1 * t1 + P[6] * w12 * t12, P[6] * w12 * t12
    G[0], G[1] = P[3] * c1 + P[4] * c12, P[4] * c12
    return M, C, G


@njit(cache=True)
def norm_3x2(A):
    """Spectral norm (largest singular value) of a 3x2 matrix: sqrt of the largest eigenvalue
    of the 2x2 A^T A, closed form."""
    a = b = c = 0.0
    for i in range(3):
        a += A[i, 0] * A[i, 0]
        b += A[i, 0] * A[i, 1]
        c += A[i, 1] * A[i, 1]
    return math.sqrt(0.5 * (a + c) + math.sqrt(0.25 * (a - c) ** 2 + b * b))


# -- desired motion -----------------------------------------------------------------------
@njit(cache=True)
def desired_motion(g, t):
    """(q_d (3), q_d' (3), q_d'' (3), r_cd, r_cd', r_cd'' (world), x_co, y_co) at t."""
    A_c, w_c, p_c = g[_MOTION], g[_MOTION + 1], g[_MOTION + 2]
    c_o, A_o, w_o, p_o = g[_MOTION + 3], g[_MOTION + 4], g[_MOTION + 5], g[_MOTION + 6]
    rho = -g[_N] / g[_N + 1]                        # y_co = rho x_co on the line
    cc, sc = math.cos(w_c * t + p_c), math.sin(w_c * t + p_c)
    x_co, v_co, a_co = -A_c * cc, A_c * w_c * sc, A_c * w_c * w_c * cc
    co, so = math.cos(w_o * t + p_o), math.sin(w_o * t + p_o)
    x_o, v_o, a_o = c_o - A_o * so, -A_o * w_o * co, A_o * w_o * w_o * so
    r = np.empty(2)
    rd = np.empty(2)
    rdd = np.empty(2)
    r[0], r[1] = x_o + x_co, g[_B] + rho * x_co
    rd[0], rd[1] = v_o + v_co, rho * v_co
    rdd[0], rdd[1] = a_o + a_co, rho * a_co
    d1, d2 = g[_LEN], g[_LEN + 1]
    x, y = r[0] - g[_BASE], r[1] - g[_BASE + 1]
    rr = x * x + y * y
    c2 = (rr - d1 * d1 - d2 * d2) / (2.0 * d1 * d2)
    c2 = min(1.0, max(-1.0, c2))                     # out of reach: stretched (never here)
    s2 = g[_ELBOW] * math.sqrt(1.0 - c2 * c2)
    c1 = ((d1 + d2 * c2) * x + d2 * s2 * y) / rr    # (2.100) corrected
    s1 = ((d1 + d2 * c2) * y - d2 * s2 * x) / rr    # (2.99)
    q = np.empty(3)
    qd = np.empty(3)
    qdd = np.empty(3)
    q[0], q[1], q[2] = math.atan2(s1, c1), math.atan2(s2, c2), x_o
    _, J, _ = arm_kinematics(g, q[:2], np.zeros(2))
    det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
    qd[0] = (J[1, 1] * rd[0] - J[0, 1] * rd[1]) / det
    qd[1] = (-J[1, 0] * rd[0] + J[0, 0] * rd[1]) / det
    qd[2] = v_o
    _, _, jdv = arm_kinematics(g, q[:2], qd[:2])
    e0, e1 = rdd[0] - jdv[0], rdd[1] - jdv[1]
    qdd[0] = (J[1, 1] * e0 - J[0, 1] * e1) / det
    qdd[1] = (-J[1, 0] * e0 + J[0, 0] * e1) / det
    qdd[2] = a_o
    return q, qd, qdd, r, rd, rdd, x_co, rho * x_co


# -- what both schemes publish ------------------------------------------------------------
#: Reference fields: the contract's task-space ones (r_d = desired contact point, world;
#: f_d = n_c lambda_d, the desired force on the end effector) and the chapter 2 ones.
REFERENCE = REFERENCE_FIELDS + ["x_o_d", "x_co_d", "y_co_d", "q_d_1", "q_d_2", "q_d_3",
                                "qdot_d_1", "qdot_d_2", "qdot_d_3", "lambda_d"]
N_REFERENCE = len(REFERENCE) - 1

#: Status fields after the contract's (r = contact point from the measured joints, f the
#: measured force, e = r_d - r): the third effort, lambda = n_c . f and its error and
#: integral, the object and on-object positions and errors, e^1 = q_d^1 - q^1, r^1.
STATUS = ["tau_3", "lambda", "lambda_err", "lambda_integral", "x_o", "x_o_err", "x_co",
          "x_co_err", "e1_1", "e1_2", "r1_1", "r1_2"]
N_STATUS_COMMON = 14   # topics.STATUS_FIELDS without stamp (r..tau_2, compute_time_us, held)
EXTRAS_AT = N_STATUS_COMMON + len(STATUS)


class MovingObjectController(Controller):
    """Base of the chapter 2 schemes: commands the arm's two joints and the object axis,
    publishes REFERENCE and STATUS before its own fields."""

    reference_fields = REFERENCE
    command_status_fields = ["tau_1", "tau_2", "tau_3"]
    JOINT_NAMES_PARAMETER = JOINT_NAMES_PARAMETER

    def __init__(self, values: dict):
        super().__init__(values)
        if self.n_joints != 3:
            raise ValueError(f"{self.scheme} commands 3 joints, got {self.values['joint_names']}")


@njit(cache=True)
def control_front(g, state_integral, t, dt, q, v, force):
    """What both laws compute first: desired motion, errors (2.22-2.26), closed-chain
    kinematics, the measured lambda = n_c . f and the force integral (updated with dt).

    Returns (qd, qd_dot, q1, v1, e, r1, qr_dot, qr_ddot, L, Ld, jtn, X, lam, lam_cmd,
    motion) with lam_cmd = lambda_d + k_lambda int e_lambda, motion = (r_cd, r_cd', r_cd'',
    x_co_d, y_co_d)."""
    qd, qd_dot, qd_ddot, r_cd, rd_cd, rdd_cd, x_co_d, y_co_d = desired_motion(g, t)
    q1, v1 = q[:2].copy(), v[:2].copy()
    Ke = g[_KE:_KE + 4].reshape((2, 2))
    e = np.empty(2)
    e_dot = np.empty(2)
    for i in range(2):
        e[i], e_dot[i] = qd[i] - q1[i], qd_dot[i] - v1[i]
    qr_dot = np.empty(2)
    qr_ddot = np.empty(2)
    r1 = np.empty(2)
    for i in range(2):
        ke = Ke[i, 0] * e[0] + Ke[i, 1] * e[1]
        ked = Ke[i, 0] * e_dot[0] + Ke[i, 1] * e_dot[1]
        qr_dot[i] = qd_dot[i] + ke          # (2.25)
        qr_ddot[i] = qd_ddot[i] + ked
        r1[i] = e_dot[i] + ke               # (2.24)
    L, Ld, jtn, X = closed_chain(g, q1, v1)
    lam = g[_N] * force[0] + g[_N + 1] * force[1]
    lambda_d = g[_MOTION + 7]
    state_integral[0] += dt * (lambda_d - lam)
    lam_cmd = lambda_d + g[_KL] * state_integral[0]
    return (qd, qd_dot, q1, v1, e, r1, qr_dot, qr_ddot, L, Ld, jtn, X, lam, lam_cmd,
            (r_cd, rd_cd, rdd_cd, x_co_d, y_co_d))


@njit(cache=True)
def feedback(g, X, r1, extra):
    """L^-T (K r^1 + extra) with L^-T = X the right inverse of L^T (3)."""
    K = g[_K:_K + 4].reshape((2, 2))
    u = np.empty(2)
    for i in range(2):
        u[i] = K[i, 0] * r1[0] + K[i, 1] * r1[1] + extra[i]
    out = np.empty(3)
    for i in range(3):
        out[i] = X[i, 0] * u[0] + X[i, 1] * u[1]
    return out


@njit(cache=True)
def write_output(g, out, tau, qd, qd_dot, q, v, force, e, r1, lam, integral, motion):
    """Fill [command (3) | reference (N_REFERENCE) | status (EXTRAS_AT + scheme fields)];
    the scheme's own status fields (from EXTRAS_AT) are left for the caller; timing and held
    are zeroed for the base class."""
    r_cd, rd_cd, rdd_cd, x_co_d, y_co_d = motion
    nx, ny = g[_N], g[_N + 1]
    lambda_d = g[_MOTION + 7]
    out[0], out[1], out[2] = tau[0], tau[1], tau[2]
    ref = out[3:3 + N_REFERENCE]
    ref[0], ref[1], ref[2], ref[3] = r_cd[0], r_cd[1], rd_cd[0], rd_cd[1]
    ref[4], ref[5] = rdd_cd[0], rdd_cd[1]
    ref[6], ref[7] = nx * lambda_d, ny * lambda_d
    ref[8], ref[9], ref[10] = qd[2], x_co_d, y_co_d
    ref[11], ref[12], ref[13] = qd[0], qd[1], qd[2]
    ref[14], ref[15], ref[16] = qd_dot[0], qd_dot[1], qd_dot[2]
    ref[17] = lambda_d
    st = out[3 + N_REFERENCE:]
    r, J, _ = arm_kinematics(g, q[:2], v[:2])
    st[0], st[1] = r[0], r[1]
    st[2] = J[0, 0] * v[0] + J[0, 1] * v[1]
    st[3] = J[1, 0] * v[0] + J[1, 1] * v[1]
    st[4], st[5] = force[0], force[1]
    st[6], st[7] = r_cd[0] - r[0], r_cd[1] - r[1]
    st[8], st[9] = nx * lambda_d - force[0], ny * lambda_d - force[1]
    st[10], st[11] = tau[0], tau[1]
    st[12] = st[13] = 0.0
    x_co = r[0] - q[2]                                   # contact point on the object
    st[14], st[15], st[16], st[17] = tau[2], lam, lambda_d - lam, integral
    st[18], st[19], st[20], st[21] = q[2], qd[2] - q[2], x_co, x_co_d - x_co
    st[22], st[23], st[24], st[25] = e[0], e[1], r1[0], r1[1]
    return st


def scheme_parameters(extra: list[Param]) -> list[Param]:
    """Geometry, desired motion, K_e, K, k_lambda, then the scheme's own parameters."""
    return GEOMETRY_PARAMETERS + MOTION_PARAMETERS + gain_parameters() + extra
