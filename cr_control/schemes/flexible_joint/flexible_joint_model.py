"""Shared numerical blocks of the chapter 6 schemes (robust adaptive 6.58, singular
perturbation 6.78 + 6.102-6.106) for the 2-link flexible-joint arm on a rigid surface.

Pure math, compiled (numba, cached), no ROS; every kernel writes into caller-provided
arrays. Link angles q = q_l = [theta1, theta2]; the arm moves in the vertical plane with
its base at the origin and gravity along -y. Geometry (docs/thesis.md, "Link geometry": ch. 6
swaps the thesis letters d and l): link lengths l1 = l2 = 0.3 m, centres of mass mid-link.

Model (6.1), Property 6.4 and the regressor (6.120), which is right as printed:

    M(q) x' + C(q, q') x + G(q) = Psi(x', x, q', q) p,    p = [p1 .. p5]  (6.119)
    M11 = p1 + 2 p2 c2,  M12 = p3 + p2 c2,  M22 = p3,
    C = -p2 s2 [[q2', q1' + q2'], [-q1', 0]]  (Christoffel form, M' = C + C^T),
    G = [p4 c1 + p5 c12, p5 c12];
    TRUE_P = [0.6135, 0.0045, 0.30225, 0.441, 0.147] (m = 0.1 kg, I = 0.3 kg m^2, g = 9.8).

Blocks:
    regressor_into            Psi (2 x 5) of (6.120)
    expanded_regressor_into   the 2 x 10 block form of section 6.3 (Property 6.5), for
                              p10 = [p; p] (expand_parameters)
    mass_regressor_into       Psi_M(q, v) p = M(q) v
    rest_regressor_into       Psi_N(q, q') p = G(q) - C(q, q')^T q'
    filtered_regressor_*      W of (6.99) without q'' (derivation below)
    mass_matrix_from_p        M_hat(q) from an estimate p_hat (k_c M_hat r of 6.102)
    constraint_into           Phi, J_Phi, L (6.8, corrected 6.118), L', Phi', J_Phi'
    desired_motion_jets       q_ld and its first four derivatives, exactly (jets)
    regressor_jets_into       Psi_d = Psi(q_ld'', q_ld', q_ld', q_ld) and 2 derivatives
                              (6.62-6.67, and beta of 6.79)
    force_jets_into           f_d = J_Phi(q_ld)^T lambda_d and 2 derivatives (6.62-6.64)

Filtered regressor (6.96-6.99) without the link acceleration. Since M' = C + C^T,

    Psi(q'', q', q', q) p = d/dt (M(q) q') + G - C^T q' = d/dt (Psi_M(q, q') p) + Psi_N(q, q') p.

With w(s) = alpha / (s + alpha) (impulse response alpha e^{-alpha t}) and f = Psi_M(q, q'):
L{w * f'} = alpha s/(s + alpha) F(s) - w(s) f(0) = alpha F - alpha w(s) F - w(s) f(0), i.e.

    w * f' = alpha f - alpha (w * f) - alpha e^{-alpha t} f(0),

so W = w * Psi(q'', q', q', q) = alpha Psi_M(q, q') + Fw, where Fw is the filter state

    Fw' = alpha (u - Fw),  u = -alpha Psi_M(q, q') + Psi_N(q, q')   (filtered_regressor_input_into)
    Fw(0) = -alpha Psi_M(q(0), q'(0))   (= 0 from rest, q'(0) = 0; filtered_regressor_initial_into)

and W(0) = 0 as the convolution over [0, 0] must be. W = alpha Psi_M + Fw is
filtered_regressor_into. The same filter applied to K_s theta + J^T lambda gives z (6.100).

Rigid surface (6.116 corrected, docs/thesis.md): the desired path lies on x - y + 0.35 = 0, not
on the printed x - y + 0.25 = 0, so the constraint is n_raw . p + c = 0 with n_raw = (1, -1),
c = 0.35. The kernels take the RAW (n_raw, c) and normalise inside:

    n = n_raw / |n_raw|,   Phi(q) = n . p_tool(q) + c / |n_raw|,   J_Phi = n^T J_kin(q)

so that lambda in f = J_Phi^T lambda (6.5) is the normal force in newtons. Passing an already
normalised pair (n, c / |n_raw|) gives identical results. Partition q^1 = theta1,
q^2 = theta2 (section 6.3): L = [1, -J_Phi1 / J_Phi2] (6.8); for the default surface
L2 = -1 - l1 (s1 + c1) / (l2 (s12 + c12)) (the thesis prints a product s12 c12; docs/thesis.md).

Desired motion (section 6.3): r_d(t) = centre + amplitude cos(omega t + phase) per axis,
x_d = -0.1 cos 2t, y_d = 0.35 - 0.1 cos 2t, through the inverse kinematics on the branch
sign(sin theta2) = elbow_sign (-1 in ch. 6):
    c2 = (|r|^2 - l1^2 - l2^2) / (2 l1 l2),  theta2 = elbow_sign acos(c2),
    theta1 = atan2(y, x) - atan2(l2 s2, l1 + l2 c2),
all evaluated in jets (cr_control.schemes.blocks.jets), so q_ld', q_ld'' ... are exact: they equal
J_kin^-1 r_d' and J_kin^-1 (r_d'' - J_kin' q_ld') (docs/thesis.md; the printed
"q_ld' = J(q_ld) r_d'" misses the inverse). Derivative arrays ("qjet") are laid out
row k = k-th time derivative, column = joint: shape (K+1, 2), K = 4 for the schemes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import overload

from cr_control.schemes.blocks.jets import (
    jet_acos,
    jet_add,
    jet_atan2,
    jet_from_derivatives,
    jet_mul,
    jet_scale,
    jet_shift,
    jet_sin_cos,
    jet_sub,
    jet_to_derivatives,
)

#: p of (6.119) with the corrected geometry (docs/thesis.md, "Link geometry").
TRUE_P = np.array([0.6135, 0.0045, 0.30225, 0.441, 0.147])
#: Initial estimate p_hat(0) of section 6.3.
P_HAT_0 = np.array([0.092, 0.0007, 0.045, 0.066, 0.022])
N_P = 5

#: Section 6.3 defaults, with the corrections of docs/thesis.md (chapter 6).
LINK_LENGTH = np.array([0.3, 0.3])
SURFACE_NORMAL = np.array([1.0, -1.0])          # raw n_raw of n_raw . p + c = 0
SURFACE_OFFSET = 0.35                           # raw c (the printed 6.116 has 0.25)
PRINTED_SURFACE_OFFSET = 0.25
MOTION_CENTRE = np.array([0.0, 0.35])
MOTION_AMPLITUDE = np.array([-0.1, -0.1])
MOTION_OMEGA = 2.0
MOTION_PHASE = 0.0
ELBOW_SIGN = -1.0
LAMBDA_D = 2.0
#: q_l(0): theta1 = 2.85 as printed, theta2 on the corrected surface (docs/thesis.md).
Q_L0 = np.array([2.85, -2.1202])

#: Layout of constraint_into's output.
CONSTRAINT_SIZE = 10
PHI, J_PHI, L_VEC, L_DOT, PHI_DOT, J_PHI_DOT = 0, 1, 3, 5, 7, 8


def _per_axis(v, i):  # pragma: no cover - only its numba overload runs
    """v[i] for a per-axis array, v for a scalar (or a 1-element array)."""
    raise NotImplementedError


@overload(_per_axis)
def _per_axis_overload(v, i):
    if isinstance(v, types.Array):
        return lambda v, i: float(v[i]) if v.shape[0] > 1 else float(v[0])
    if isinstance(v, (types.Float, types.Integer)):
        return lambda v, i: float(v)
    return None


# -- regressors ----------------------------------------------------------------------------
@njit(cache=True, error_model="numpy")
def regressor_into(xdot, x, qdot, q, out):
    """out (2 x 5) = Psi(x', x, q', q) of (6.120): Psi p = M(q) x' + C(q, q') x + G(q)."""
    c1 = math.cos(q[0])
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    c12 = math.cos(q[0] + q[1])
    out[0, 0] = xdot[0]
    out[0, 1] = 2.0 * c2 * xdot[0] + c2 * xdot[1] - s2 * (qdot[0] + qdot[1]) * x[1] - s2 * qdot[1] * x[0]
    out[0, 2] = xdot[1]
    out[0, 3] = c1
    out[0, 4] = c12
    out[1, 0] = 0.0
    out[1, 1] = c2 * xdot[0] + s2 * qdot[0] * x[0]
    out[1, 2] = xdot[1] + xdot[0]
    out[1, 3] = 0.0
    out[1, 4] = c12


@njit(cache=True, error_model="numpy")
def expanded_regressor_into(xdot, x, qdot, q, out):
    """out (2 x 10) = [[Psi_1., 0], [0, Psi_2.]] (section 6.3, Property 6.5): out [p; p] = Psi p."""
    out[:, :] = 0.0
    regressor_into(xdot, x, qdot, q, out[:, :N_P])
    for j in range(N_P):
        out[1, N_P + j] = out[1, j]
        out[1, j] = 0.0


@njit(cache=True, error_model="numpy")
def expand_parameters(p, out):
    """out (10) = [p; p], the parameter vector of the expanded regressor (section 6.3)."""
    for j in range(N_P):
        out[j] = p[j]
        out[N_P + j] = p[j]


@njit(cache=True, error_model="numpy")
def mass_regressor_into(q, v, out):
    """out (2 x 5) = Psi_M(q, v): Psi_M p = M(q) v."""
    c2 = math.cos(q[1])
    out[0, 0] = v[0]
    out[0, 1] = 2.0 * c2 * v[0] + c2 * v[1]
    out[0, 2] = v[1]
    out[0, 3] = 0.0
    out[0, 4] = 0.0
    out[1, 0] = 0.0
    out[1, 1] = c2 * v[0]
    out[1, 2] = v[0] + v[1]
    out[1, 3] = 0.0
    out[1, 4] = 0.0


@njit(cache=True, error_model="numpy")
def rest_regressor_into(q, qdot, out):
    """out (2 x 5) = Psi_N(q, q'): Psi_N p = G(q) - C(q, q')^T q' (C^T q' = [0, -p2 s2 q1'(q1' + q2')]).

    Psi(q'', q', q', q) p = d/dt(Psi_M(q, q') p) + Psi_N(q, q') p.
    """
    c1 = math.cos(q[0])
    s2 = math.sin(q[1])
    c12 = math.cos(q[0] + q[1])
    out[0, 0] = 0.0
    out[0, 1] = 0.0
    out[0, 2] = 0.0
    out[0, 3] = c1
    out[0, 4] = c12
    out[1, 0] = 0.0
    out[1, 1] = s2 * qdot[0] * (qdot[0] + qdot[1])
    out[1, 2] = 0.0
    out[1, 3] = 0.0
    out[1, 4] = c12


@njit(cache=True, error_model="numpy")
def filtered_regressor_input_into(q, qdot, alpha, out):
    """out (2 x 5) = u = -alpha Psi_M(q, q') + Psi_N(q, q'), the input of the filter state
    Fw' = alpha (u - Fw) with W = alpha Psi_M(q, q') + Fw (6.99; module docstring)."""
    c1 = math.cos(q[0])
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    c12 = math.cos(q[0] + q[1])
    v0, v1 = qdot[0], qdot[1]
    out[0, 0] = -alpha * v0
    out[0, 1] = -alpha * (2.0 * c2 * v0 + c2 * v1)
    out[0, 2] = -alpha * v1
    out[0, 3] = c1
    out[0, 4] = c12
    out[1, 0] = 0.0
    out[1, 1] = -alpha * c2 * v0 + s2 * v0 * (v0 + v1)
    out[1, 2] = -alpha * (v0 + v1)
    out[1, 3] = 0.0
    out[1, 4] = c12


@njit(cache=True, error_model="numpy")
def filtered_regressor_into(q, qdot, alpha, Fw, out):
    """out (2 x 5) = W = alpha Psi_M(q, q') + Fw (6.99) from the filter state Fw."""
    mass_regressor_into(q, qdot, out)
    for i in range(2):
        for j in range(N_P):
            out[i, j] = alpha * out[i, j] + Fw[i, j]


@njit(cache=True, error_model="numpy")
def filtered_regressor_initial_into(q0, qdot0, alpha, out):
    """out (2 x 5) = Fw(0) = -alpha Psi_M(q(0), q'(0)) (zero when starting at rest)."""
    mass_regressor_into(q0, qdot0, out)
    for i in range(2):
        for j in range(N_P):
            out[i, j] = -alpha * out[i, j]


@njit(cache=True, error_model="numpy")
def mass_matrix_from_p(q, p, out):
    """out (2 x 2) = M(q) for the parameters p (an estimate p_hat gives M_hat of 6.102)."""
    c2 = math.cos(q[1])
    out[0, 0] = p[0] + 2.0 * p[1] * c2
    out[0, 1] = p[2] + p[1] * c2
    out[1, 0] = out[0, 1]
    out[1, 1] = p[2]


# -- the rigid surface ---------------------------------------------------------------------
@njit(cache=True, error_model="numpy")
def constraint_into(q, qdot, link_length, normal, offset, out):
    """Surface n_raw . p_tool + c = 0 (raw normal and offset, normalised inside) at (q, q').

    out (10): [0] Phi = n . p + c/|n_raw|, [1:3] J_Phi = n^T J_kin (1 x 2 row),
    [3:5] L = [1, -J_Phi1/J_Phi2] (6.8), [5:7] L', [7] Phi' = J_Phi q', [8:10] J_Phi'.
    """
    norm = math.hypot(normal[0], normal[1])
    nx, ny = normal[0] / norm, normal[1] / norm
    l1, l2 = link_length[0], link_length[1]
    c1, s1 = math.cos(q[0]), math.sin(q[0])
    c12, s12 = math.cos(q[0] + q[1]), math.sin(q[0] + q[1])
    w1, w12 = qdot[0], qdot[0] + qdot[1]
    # n . (l1 (c1, s1) + l2 (c12, s12)) and its derivatives along q'
    a1 = nx * c1 + ny * s1        # n . e1
    b1 = -nx * s1 + ny * c1       # n . e1', e1' = (-s1, c1)
    a12 = nx * c12 + ny * s12
    b12 = -nx * s12 + ny * c12
    out[PHI] = l1 * a1 + l2 * a12 + offset / norm
    j1 = l1 * b1 + l2 * b12
    j2 = l2 * b12
    out[J_PHI] = j1
    out[J_PHI + 1] = j2
    jd1 = -l1 * a1 * w1 - l2 * a12 * w12
    jd2 = -l2 * a12 * w12
    out[J_PHI_DOT] = jd1
    out[J_PHI_DOT + 1] = jd2
    out[PHI_DOT] = j1 * qdot[0] + j2 * qdot[1]
    out[L_VEC] = 1.0
    out[L_VEC + 1] = -j1 / j2
    out[L_DOT] = 0.0
    out[L_DOT + 1] = -(jd1 * j2 - j1 * jd2) / (j2 * j2)


# -- desired motion and its exact derivatives ------------------------------------------------
@njit(cache=True, error_model="numpy")
def desired_motion_jets(t, centre, amplitude, omega, phase, link_length, elbow_sign, out):
    """out (K+1 x 2), row k = d^k q_ld / dt^k at t (K = 4 for the schemes; any K >= 0).

    r_d = centre + amplitude cos(omega t + phase) per axis (omega, phase: scalars or per-axis
    arrays), inverse kinematics on the branch sign(sin theta2) = elbow_sign, all in jets.
    NaN rows when r_d is out of reach (|c2| > 1).
    """
    n = out.shape[0]
    w = np.empty((14, n))
    arg, s, c = w[0], w[1], w[2]
    x, y = w[3], w[4]
    for i in range(2):
        r = x if i == 0 else y
        om = _per_axis(omega, i)
        arg[:] = 0.0
        arg[0] = om * t + _per_axis(phase, i)
        if n > 1:
            arg[1] = om
        jet_sin_cos(arg, s, c)
        jet_scale(c, _per_axis(amplitude, i), r)
        r[0] += _per_axis(centre, i)
    l1, l2 = link_length[0], link_length[1]
    rr, tmp = w[5], w[6]
    jet_mul(x, x, rr)
    jet_mul(y, y, tmp)
    jet_add(rr, tmp, rr)
    c2 = w[7]
    jet_shift(rr, -(l1 * l1 + l2 * l2), c2)
    jet_scale(c2, 1.0 / (2.0 * l1 * l2), c2)
    if not abs(c2[0]) <= 1.0:
        out[:, :] = math.nan
        return
    th2, s2 = w[8], w[9]
    jet_acos(c2, th2, s2)
    if elbow_sign < 0.0:
        jet_scale(th2, -1.0, th2)
        jet_scale(s2, -1.0, s2)
    th1, ky, kx, beta = w[10], w[11], w[12], w[13]
    jet_atan2(y, x, th1)
    jet_scale(s2, l2, ky)
    jet_scale(c2, l2, kx)
    kx[0] += l1
    jet_atan2(ky, kx, beta)
    jet_sub(th1, beta, th1)
    jet_to_derivatives(th1, out[:, 0])
    jet_to_derivatives(th2, out[:, 1])


@njit(cache=True, error_model="numpy")
def regressor_jets_into(qjet, out):
    """out (N x 2 x 5), row k = d^k/dt^k Psi_d, Psi_d(t) = Psi(q_ld'', q_ld', q_ld', q_ld)
    (6.62-6.67), from qjet = [q_ld, q_ld', ...] with at least N + 2 rows (N = 3: Psi_d,
    Psi_d', Psi_d'' from q_ld .. q_ld'''')."""
    n = out.shape[0]
    w = np.empty((18, n))
    q1, q2, q12 = w[0], w[1], w[2]
    v1, v2, a1, a2 = w[3], w[4], w[5], w[6]
    jet_from_derivatives(qjet[:, 0], q1)
    jet_from_derivatives(qjet[:, 1], q2)
    jet_add(q1, q2, q12)
    jet_from_derivatives(qjet[1:, 0], v1)
    jet_from_derivatives(qjet[1:, 1], v2)
    jet_from_derivatives(qjet[2:, 0], a1)
    jet_from_derivatives(qjet[2:, 1], a2)
    s1, c1, s2, c2, s12, c12 = w[7], w[8], w[9], w[10], w[11], w[12]
    jet_sin_cos(q1, s1, c1)
    jet_sin_cos(q2, s2, c2)
    jet_sin_cos(q12, s12, c12)
    psi12, psi22, u, t = w[13], w[14], w[15], w[16]
    # Psi12 = c2 (2 a1 + a2) - s2 v2 (2 v1 + v2)
    jet_scale(a1, 2.0, u)
    jet_add(u, a2, u)
    jet_mul(c2, u, psi12)
    jet_scale(v1, 2.0, u)
    jet_add(u, v2, u)
    jet_mul(u, v2, u)
    jet_mul(u, s2, u)
    jet_sub(psi12, u, psi12)
    # Psi22 = c2 a1 + s2 v1^2
    jet_mul(c2, a1, psi22)
    jet_mul(v1, v1, t)
    jet_mul(t, s2, t)
    jet_add(psi22, t, psi22)
    jet_add(a1, a2, u)                                  # Psi23 = a1 + a2
    for col, jet in enumerate((a1, psi12, a2, c1, c12)):
        jet_to_derivatives(jet, out[:, 0, col])
    jet_to_derivatives(psi22, out[:, 1, 1])
    jet_to_derivatives(u, out[:, 1, 2])
    jet_to_derivatives(c12, out[:, 1, 4])
    out[:, 1, 0] = 0.0
    out[:, 1, 3] = 0.0


@njit(cache=True, error_model="numpy")
def force_jets_into(qjet, link_length, normal, offset, lambda_d, out):
    """out (N x 2), row k = d^k/dt^k f_d, f_d = J_Phi(q_ld)^T lambda_d (6.62-6.64) with a
    constant lambda_d, from qjet with at least N rows. (normal, offset) as in
    constraint_into (raw; the offset does not enter J_Phi)."""
    n = out.shape[0]
    norm = math.hypot(normal[0], normal[1])
    nx, ny = normal[0] / norm, normal[1] / norm
    l1, l2 = link_length[0], link_length[1]
    w = np.empty((8, n))
    q1, q12 = w[0], w[1]
    jet_from_derivatives(qjet[:, 0], q1)
    jet_from_derivatives(qjet[:, 1], q12)
    jet_add(q1, q12, q12)
    s1, c1, s12, c12 = w[2], w[3], w[4], w[5]
    jet_sin_cos(q1, s1, c1)
    jet_sin_cos(q12, s12, c12)
    f1, f2 = w[6], w[7]                                 # f_d = J_Phi^T lambda_d as jets
    for k in range(n):
        f2[k] = lambda_d * l2 * (-nx * s12[k] + ny * c12[k])
        f1[k] = lambda_d * l1 * (-nx * s1[k] + ny * c1[k]) + f2[k]
    jet_to_derivatives(f1, out[:, 0])
    jet_to_derivatives(f2, out[:, 1])
