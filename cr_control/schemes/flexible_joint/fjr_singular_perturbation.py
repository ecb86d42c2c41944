"""Singular-perturbation position/force control of a constrained flexible-joint robot with
known joint stiffness K_s and motor inertia J_m (thesis sections 6.2.1-6.2.3, simulated in
6.3.2): the composite control (6.78) with the slow-timescale exponentially stable adaptive
control (6.102-6.106).

Desired motor motion with the estimate p_hat (6.65-6.67), from the exact jets of the
desired link motion (Psi_d = Psi(q_ld'', q_ld', q_ld', q_ld), f_d = J_Phi(q_ld)^T lambda_d
and their first two time derivatives, exact: no finite differences):

    q_md_hat   = K_s^-1 (Psi_d   p_hat - f_d  ) + q_ld                              (6.65)
    q_md_hat'  = K_s^-1 (Psi_d'  p_hat - f_d' ) + q_ld'                             (6.66)
    q_md_hat'' = K_s^-1 (Psi_d'' p_hat - f_d'') + q_ld''                            (6.67)

p_hat is held constant in (6.66), (6.67): the thesis calls the three "independent"
(no differentiation relation between them). Errors (6.73-6.77):

    e_m_hat = q_md_hat - q_m,  e_m_hat' = q_md_hat' - q_m'
    e = q_ld - q_l,  e_lambda = lambda_d - lambda,  r = e' + K_e e,
    q_r' = q_ld' + K_e e,  q_r'' = q_ld'' + K_e e'

Composite control (6.78), with hats where the thesis prints tildes:

    tau_m = tau_s + J_m (q_md_hat'' + K_v e_m_hat' + K_p e_m_hat) - J_Phi(q_l)^T e_lambda

(6.78) is printed with q_md~'' and e_m~' (the estimation errors of 6.69-6.70, which need
the unknown p). Its rewriting (6.79), tau_m = tau_s + J_m (q_md'' + K_v e_m' + K_p e_m)
+ beta p~ - J^T e_lambda with beta = -J_m K_s^-1 (Psi_d'' + K_v Psi_d' + K_p Psi_d), holds
only with the hats q_md_hat'' and e_m_hat' (6.67, 6.74); so the hats are used. For gain
matrices that do not commute with K_s^-1 the same rewriting gives
beta = -J_m (K_s^-1 Psi_d'' + K_v K_s^-1 Psi_d' + K_p K_s^-1 Psi_d), which is what is
computed (the printed form for diagonal gains, as in the thesis).

Slow control and adaptation (theorem 6.2.2):

    tau_s = Psi(q_r'', q_r', q_l', q_l) p_hat + k_c M_hat(q_l) r                   (6.102)
    p_hat' = Gamma^-1 (Psi_s^T r + gamma_1 W^T z~)                                  (6.103)
    Gamma' = -gamma(t) Gamma + 2 gamma_2 W^T W                                      (6.104)
    Psi_s = Psi(q_r'' + k_c r, q_r', q_l', q_l) - beta                              (6.105)
    gamma(t) = gamma_0 (1 - ||Gamma^-1|| / k_0)                                     (6.106)

with the filter w(s) = alpha / (s + alpha) (6.96): z = w * (K_s theta + J_Phi^T lambda)
(6.97; theta = q_m - q_l, lambda measured), the filter state Z' = alpha (K_s (q_m - q_l) +
J_Phi(q_l)^T lambda - Z), Z(0) = 0; the filtered regressor W = w * Psi(q_l'', q_l', q_l',
q_l) (6.99) without q_l'': W = alpha Psi_M(q_l, q_l') + F_w, F_w' = alpha (-alpha Psi_M +
Psi_N - F_w), F_w(0) = -alpha Psi_M(q_l(0), q_l'(0)) (zero from rest; derivation in
:mod:`cr_control.schemes.flexible_joint.flexible_joint_model`), so W(0) = 0 and z = W p exactly in
continuous time (6.100); z_hat = W p_hat (6.101), z~ = Z - z_hat. ||Gamma^-1|| is the
spectral norm of the s.p.d. Gamma^-1, 1 / lambda_min(Gamma).

Discretisation: p_hat and Gamma by explicit Euler with each cycle's dt; the two filters
(Z and F_w, driven alike) by the trapezoidal rule (Tustin) over the inputs of this and the
last cycle, X_k = ((1 - a) X_k-1 + a (u_k + u_k-1)) / (1 + a), a = alpha dt / 2. At cycle k
the right-hand sides use the measurement of cycle k and the states of cycle k - 1; the
states are updated, and the command uses the updated p_hat. The first cycle (dt = 0) only
initialises Z and F_w. Why not Euler for the filters: along the default closed-loop run
Euler's sampling error in z - W p (6.100, zero in continuous time) is ~3e-3 rms (9e-3
peak) and does not decay, while z~ itself falls to 3e-3 .. 5e-3 rms over 15-20 s: with
Euler most of the z~ the adaptation then sees is discretisation error, and p_hat's error
in the well-excited directions of W ends ~1e-3 instead of ~1e-4. With the trapezoidal
rule z - W p stays below 3e-5 (4e-7 after 5 s). Gamma is kept exactly symmetric (the
upper triangle is updated and mirrored) and stays positive definite for gamma(t) dt < 1
(gamma <= gamma_0). Gamma^-1 and lambda_min(Gamma) come from one cyclic Jacobi
eigen-decomposition of the 5 x 5 Gamma per cycle (:func:`symmetric_eigen`, ~5 us), inside
the one compiled kernel (~10 us per cycle in all, no numpy.linalg).

Choices the thesis leaves open (parameters, documented):
  * k_0 (6.106) = 5: it must exceed ||Gamma(0)^-1|| = 1/60 for gamma(0) > 0, and by
    lemma 6.2.1 it is the ceiling of the adaptation gain Gamma^-1 (without excitation the
    forgetting lets Gamma^-1 grow to k_0 I). The desired path excites W weakly in one
    direction of p (mean W^T W over 5-20 s has eigenvalues 0.0054 .. 3.2; its weakest
    eigenvector ~ [0.66 0.51 0.55 0.05 0.05] holds almost all of p~ after a while), so k_0
    sets how fast that direction is learnt. Default runs, 20 s, k_0 = 0.05, 0.2, 1, 5, 20:
    RMS link error over 15-20 s 0.98, 0.35, 0.24, 0.20, 0.20 mrad, |p~(20 s)| 0.51, 0.45,
    0.28, 0.045, 0.001. With measurement noise (1e-4 rad, 1e-2 rad/s, 0.05 N; 40 s) the
    tracking is the same for k_0 >= 1 and the jitter of p_hat_1 over the last 5 s grows
    with k_0: std 0.0027, 0.0035, 0.0097 for k_0 = 1, 5, 20. k_0 = 5 (a gain ceiling 300
    times Gamma(0)^-1) learns p within 20-40 s with little added noise sensitivity.
  * K_e = 3.5 I (r = e' + K_e e): as the robust scheme of section 6.3.1 (thesis value);
    none is given for 6.3.2. The result hardly depends on it: K_e = 1 .. 15 changes the RMS
    link error over 15-20 s by < 5 %.
  * slow_control = false reproduces figures 6.16-6.18 ("the adaptive slow-time-scale
    control tau_s is not included", "only motor feedback control"): tau_s = 0 and the
    adaptation (6.103-6.104), part of that slow control (theorem 6.2.2), is frozen, so
    p_hat stays p_hat(0) in q_md_hat; the filters Z, W still run (z~ is reported).

Constraint force (found analysing and measuring this law; docs/thesis.md): the thesis's
reduction (6.80-6.91) drops the constraint-force terms: with z_0, z_1 of (6.80-6.81)
K_s theta = z_0 - z_1 + J^T e_lambda (printed: - J^T e_lambda) and K_s theta + J^T lambda
= z_0 - z_1 + J^T lambda_d (printed: z_0 - z_1), so the quasi-steady link model (6.91)
misses + J^T (2 lambda - lambda_d) (singular limit). Positions are unaffected (L^T J^T = 0,
Property 6.1), but the force feedback - J^T e_lambda of (6.78) acts on top of the - f_d
already inside q_md_hat, and in the quasi-steady state (motor loop J_m K_p + K_s against
the spring K_s) lambda settles at

    lambda = lambda_d (J_m K_p + K_s) / (J_m K_p + 2 K_s)   (-> lambda_d / 2 as K_s -> inf)

= 1.118 N for the 6.3.2 values (measured 1.12 N; K_p = 20: 1.032 predicted, 1.043
measured; K_p = 300: 1.333, 1.335). The force error is bounded, as the thesis claims
(remark 6.2.6), but about 0.9 N of 2 N. The law is implemented as printed.

K_s and J_m are known to this scheme (section 6.3.2: K_s = 300 I, J_m = I); they must be
those of the plant (plant parameters joint_stiffness, motor_inertia); the scheme's
registry entry sets the plant to them.

Measured (offline loop, 1 kHz, K_s = 300, J_m = 1, defaults): see
test/test_fjr_singular_perturbation.py, which prints the table.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, matrix
from cr_control.schemes.controller import ControlOutput, KernelOutput
from cr_control.schemes.flexible_joint import flexible_joint_scheme as fjs
from cr_control.schemes.flexible_joint.flexible_joint_model import (
    P_HAT_0,
    filtered_regressor_input_into,
    force_jets_into,
    mass_matrix_from_p,
    mass_regressor_into,
    regressor_into,
    regressor_jets_into,
)

N_P = 5
ESTIMATE_FIELDS = [f"p_hat_{i + 1}" for i in range(N_P)]
OWN_STATUS = ESTIMATE_FIELDS + ["gamma_inv_norm", "forgetting", "tau_s_1", "tau_s_2",
                                "z_tilde_1", "z_tilde_2", "q_md_hat_1", "q_md_hat_2",
                                "e_m_hat_1", "e_m_hat_2"]

GAINS = Layout(common=fjs.OWN, K_s=2, J_m=2, K_p=(2, 2), K_v=(2, 2), k_c=1, gamma_0=1,
               gamma_1=1, gamma_2=1, alpha=1, k_0=1, slow_control=1)
_KS, _JM, _KP, _KV, _KC, _G0, _G1, _G2, _ALPHA, _K0, _SLOW = (
    GAINS.offset(k) for k in ("K_s", "J_m", "K_p", "K_v", "k_c", "gamma_0", "gamma_1",
                              "gamma_2", "alpha", "k_0", "slow_control"))
_LEN, _N, _OFF, _LD, _KE = (fjs.COMMON.offset(k) for k in
                            ("link_length", "normal", "offset", "lambda_d", "K_e"))

#: Internal state: [started flag, p_hat (5), Gamma (5 x 5), F_w (2 x 5), Z (2), the filter
#: inputs of the last cycle: u (2 x 5) of F_w, y (2) of Z].
STATE = Layout(started=1, p_hat=N_P, Gamma=(N_P, N_P), F_w=(2, N_P), Z=2, u_last=(2, N_P),
               y_last=2)
_STARTED, _P, _GAMMA, _FW, _Z, _U, _Y = (
    STATE.offset(k) for k in ("started", "p_hat", "Gamma", "F_w", "Z", "u_last", "y_last"))

#: Jacobi sweeps at most (5 x 5 converges in ~5-6 from scratch).
JACOBI_SWEEPS = 12


@njit(cache=True, error_model="numpy")
def symmetric_eigen(A, a, V, w):
    """Eigen-decomposition A = V diag(w) V^T of the symmetric n x n ``A`` by cyclic Jacobi
    rotations (``a``: n x n work, overwritten; ``V``: eigenvectors as columns; ``w``:
    eigenvalues, unsorted). Stops when the off-diagonal part is below 1e-15 of the
    diagonal (relative) or after JACOBI_SWEEPS sweeps; returns the sweeps done."""
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            a[i, j] = A[i, j]
            V[i, j] = 1.0 if i == j else 0.0
    sweeps = 0
    for sweep in range(JACOBI_SWEEPS):
        off = 0.0
        diag = 0.0
        for i in range(n):
            diag += a[i, i] * a[i, i]
            for j in range(i + 1, n):
                off += a[i, j] * a[i, j]
        if off <= 1e-30 * diag:
            break
        sweeps = sweep + 1
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):                  # columns p, q: A J
                    akp, akq = a[k, p], a[k, q]
                    a[k, p] = c * akp - s * akq
                    a[k, q] = s * akp + c * akq
                for k in range(n):                  # rows p, q: J^T (A J)
                    apk, aqk = a[p, k], a[q, k]
                    a[p, k] = c * apk - s * aqk
                    a[q, k] = s * apk + c * aqk
                a[p, q] = 0.0
                a[q, p] = 0.0
                for k in range(n):                  # V J
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq
    for i in range(n):
        w[i] = a[i, i]
    return sweeps


@njit(cache=True, error_model="numpy")
def spd_inverse(A, out, work, V, w):
    """out = A^-1 of the s.p.d. ``A`` from its eigen-decomposition; returns
    (lambda_min(A), lambda_max(A)) so that ||A^-1|| = 1 / lambda_min."""
    n = A.shape[0]
    symmetric_eigen(A, work, V, w)
    lo, hi = w[0], w[0]
    for i in range(1, n):
        lo = min(lo, w[i])
        hi = max(hi, w[i])
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(n):
                s += V[i, k] * V[j, k] / w[k]
            out[i, j] = s
            out[j, i] = s
    return lo, hi


@njit(cache=True, error_model="numpy")
def desired_motor(g, Psi_jets, f_jets, qjet, p, out):
    """out (3 x 2): rows q_md, q_md', q_md'' of (6.62-6.64) (6.65-6.67 with p = p_hat):
    K_s^-1 (d^k Psi_d p - d^k f_d) + d^k q_ld, k = 0, 1, 2."""
    for k in range(3):
        for i in range(2):
            s = 0.0
            for j in range(N_P):
                s += Psi_jets[k, i, j] * p[j]
            out[k, i] = (s - f_jets[k, i]) / g[_KS + i] + qjet[k, i]


@njit(cache=True, error_model="numpy")
def fjr_singular_perturbation_cycle(gains, state, t, dt, q, v, force, out):
    """One cycle of (6.78) with (6.102-6.106) into ``out``; q, v = [q_l, q_m] (4), force:
    the wrench n lambda; state: STATE (updated in place)."""
    g = gains[:fjs.OWN]
    K_p = gains[_KP:_KP + 4].reshape((2, 2))
    K_v = gains[_KV:_KV + 4].reshape((2, 2))
    K_e = g[_KE:_KE + 4].reshape((2, 2))
    k_c, alpha = gains[_KC], gains[_ALPHA]
    q_l, v_l, q_m, v_m = q[0:2], v[0:2], q[2:4], v[2:4]
    p_hat = state[_P:_P + N_P]
    Gamma = state[_GAMMA:_GAMMA + N_P * N_P].reshape((N_P, N_P))
    F_w = state[_FW:_FW + 2 * N_P].reshape((2, N_P))
    Z = state[_Z:_Z + 2]

    # desired motion, its regressor and force jets (6.62-6.67)
    qjet = np.empty((5, 2))
    fjs.desired(g, t, qjet)
    Psi_jets = np.empty((3, 2, N_P))
    regressor_jets_into(qjet, Psi_jets)
    f_jets = np.empty((3, 2))
    force_jets_into(qjet, g[_LEN:_LEN + 2], g[_N:_N + 2], g[_OFF], g[_LD], f_jets)

    # measured: surface, lambda, z-filter input K_s theta + J_Phi^T lambda (6.97)
    surf = np.empty(10)
    fjs.surface(g, q_l, v_l, surf)
    J_phi = surf[1:3]
    lam = fjs.measured_lambda(g, force)
    e_lam = g[_LD] - lam
    y = np.empty(2)
    for i in range(2):
        y[i] = gains[_KS + i] * (q_m[i] - q_l[i]) + J_phi[i] * lam

    # errors (6.75-6.77)
    e, e_dot = qjet[0] - q_l, qjet[1] - v_l
    r = np.empty(2)
    qr_dot = np.empty(2)
    qr_ddot = np.empty(2)
    for i in range(2):
        ke = K_e[i, 0] * e[0] + K_e[i, 1] * e[1]
        r[i] = e_dot[i] + ke
        qr_dot[i] = qjet[1, i] + ke
        qr_ddot[i] = qjet[2, i] + K_e[i, 0] * e_dot[0] + K_e[i, 1] * e_dot[1]

    # filtered regressor W (6.99) and z (6.97): both filters by the trapezoidal rule
    u_last = state[_U:_U + 2 * N_P].reshape((2, N_P))
    y_last = state[_Y:_Y + 2]
    u = np.empty((2, N_P))
    filtered_regressor_input_into(q_l, v_l, alpha, u)
    if state[_STARTED] == 0.0:
        mass_regressor_into(q_l, v_l, F_w)
        for i in range(2):
            Z[i] = 0.0
            for j in range(N_P):
                F_w[i, j] = -alpha * F_w[i, j]
        state[_STARTED] = 1.0
    elif dt > 0.0:
        a = 0.5 * alpha * dt
        keep, take = (1.0 - a) / (1.0 + a), a / (1.0 + a)
        for i in range(2):
            Z[i] = keep * Z[i] + take * (y[i] + y_last[i])          # (6.97, 6.100)
            for j in range(N_P):
                F_w[i, j] = keep * F_w[i, j] + take * (u[i, j] + u_last[i, j])
    for i in range(2):
        y_last[i] = y[i]
        for j in range(N_P):
            u_last[i, j] = u[i, j]
    W = np.empty((2, N_P))
    mass_regressor_into(q_l, v_l, W)
    for i in range(2):
        for j in range(N_P):
            W[i, j] = alpha * W[i, j] + F_w[i, j]

    # adaptation gain: Gamma^-1, ||Gamma^-1|| = 1/lambda_min(Gamma), gamma(t) (6.106)
    Gamma_inv = np.empty((N_P, N_P))
    work = np.empty((N_P, N_P))
    V = np.empty((N_P, N_P))
    w = np.empty(N_P)
    lam_min, _ = spd_inverse(Gamma, Gamma_inv, work, V, w)
    gamma_inv_norm = 1.0 / lam_min
    forgetting = gains[_G0] * (1.0 - gamma_inv_norm / gains[_K0])

    # beta (6.79): -J_m (K_s^-1 Psi_d'' + K_v K_s^-1 Psi_d' + K_p K_s^-1 Psi_d)
    beta = np.empty((2, N_P))
    for i in range(2):
        for j in range(N_P):
            s = Psi_jets[2, i, j] / gains[_KS + i]
            for k in range(2):
                s += (K_v[i, k] * Psi_jets[1, k, j] + K_p[i, k] * Psi_jets[0, k, j]) / gains[_KS + k]
            beta[i, j] = -gains[_JM + i] * s

    slow = gains[_SLOW] != 0.0
    z_tilde = np.empty(2)
    for i in range(2):
        s = 0.0
        for j in range(N_P):
            s += W[i, j] * p_hat[j]
        z_tilde[i] = Z[i] - s                                       # z - z_hat (6.101)
    if slow and dt > 0.0:
        # Psi_s = Psi_c - beta, Psi_c = Psi(q_r'' + k_c r, q_r', q_l', q_l) (6.105)
        Psi_c = np.empty((2, N_P))
        x_dot = np.empty(2)
        for i in range(2):
            x_dot[i] = qr_ddot[i] + k_c * r[i]
        regressor_into(x_dot, qr_dot, v_l, q_l, Psi_c)
        h = np.empty(N_P)                                           # Psi_s^T r + g1 W^T z~
        for j in range(N_P):
            h[j] = (Psi_c[0, j] - beta[0, j]) * r[0] + (Psi_c[1, j] - beta[1, j]) * r[1] \
                + gains[_G1] * (W[0, j] * z_tilde[0] + W[1, j] * z_tilde[1])
        for j in range(N_P):                                        # (6.103)
            s = 0.0
            for k in range(N_P):
                s += Gamma_inv[j, k] * h[k]
            p_hat[j] += dt * s
        g2 = 2.0 * gains[_G2]
        for j in range(N_P):                                        # (6.104), symmetric
            for k in range(j, N_P):
                d = -forgetting * Gamma[j, k] + g2 * (W[0, j] * W[0, k] + W[1, j] * W[1, k])
                Gamma[j, k] += dt * d
                Gamma[k, j] = Gamma[j, k]

    # desired motor motion with the (updated) p_hat (6.65-6.67) and its errors (6.73-6.74)
    md = np.empty((3, 2))
    desired_motor(gains, Psi_jets, f_jets, qjet, p_hat, md)
    e_m, e_m_dot = md[0] - q_m, md[1] - v_m

    # slow control (6.102)
    tau_s = np.zeros(2)
    if slow:
        regressor_into(qr_ddot, qr_dot, v_l, q_l, u)
        M_hat = np.empty((2, 2))
        mass_matrix_from_p(q_l, p_hat, M_hat)
        for i in range(2):
            s = 0.0
            for j in range(N_P):
                s += u[i, j] * p_hat[j]
            tau_s[i] = s + k_c * (M_hat[i, 0] * r[0] + M_hat[i, 1] * r[1])

    # composite control (6.78), hats for the printed tildes
    tau = np.empty(2)
    for i in range(2):
        fb = md[2, i]
        for k in range(2):
            fb += K_v[i, k] * e_m_dot[k] + K_p[i, k] * e_m[k]
        tau[i] = tau_s[i] + gains[_JM + i] * fb - J_phi[i] * e_lam

    st = fjs.write_output(g, out, tau, qjet, q, v, force, surf[0])
    st[0:N_P] = p_hat
    st[5], st[6] = gamma_inv_norm, forgetting
    st[7], st[8] = tau_s[0], tau_s[1]
    st[9], st[10] = z_tilde[0], z_tilde[1]
    st[11], st[12] = md[0, 0], md[0, 1]
    st[13], st[14] = e_m[0], e_m[1]


class FJRSingularPerturbationController(fjs.FlexibleJointController):
    """Composite control (6.78) + slow adaptive control (6.102-6.106), section 6.3.2 gains."""

    scheme = "fjr_singular_perturbation"
    PARAMETERS = fjs.PARAMETERS + [
        Param("joint_stiffness", [300.0, 300.0], "Joint stiffness K_s (N m/rad), known to "
              "this scheme (6.62-6.67, 6.79, 6.97; 6.3.2: 300); must equal the plant's "
              "joint_stiffness.", "positive_vector", 2, bound=Bound.STIFFNESS),
        Param("motor_inertia", [1.0, 1.0], "Motor inertia J_m (kg m^2), known to this scheme "
              "(6.78; 6.3.2: 1.0); must equal the plant's motor_inertia.", "positive_vector", 2,
              bound=Bound.INERTIA),
        Param("K_p", matrix(2, 80.0), "Motor position gain K_p of (6.78) (6.3.2).", "spd", 2,
              bound=Bound.GAIN),
        Param("K_v", matrix(2, 80.0), "Motor velocity gain K_v of (6.78) (6.3.2).", "spd", 2,
              bound=Bound.GAIN),
        Param("k_c", 1.5, "k_c of the slow control k_c M_hat r (6.102, 6.105) (6.3.2).",
              "positive", bound=Bound.GAIN),
        fjs.k_e_parameter(3.5),
        Param("gamma_0", 1.0, "gamma_0 of the forgetting factor gamma(t) = gamma_0 (1 - "
              "||Gamma^-1|| / k_0) (6.106) (6.3.2).", "positive", bound=Bound.GAIN),
        Param("gamma_1", 7.0, "gamma_1 of the adaptation (6.103); must exceed gamma_2 "
              "(theorem 6.2.2) (6.3.2).", "positive", bound=Bound.GAIN),
        Param("gamma_2", 2.0, "gamma_2 of the gain update (6.104); must be below gamma_1 "
              "(6.3.2).", "positive", bound=Bound.GAIN),
        Param("Gamma_0", matrix(N_P, 60.0), "Initial adaptation gain matrix Gamma(0) of "
              "(6.103-6.104) (6.3.2).", "spd", N_P, read_only=True, bound=Bound.GAIN),
        Param("alpha", 5.0, "alpha of the filter w(s) = alpha / (s + alpha) (6.96) (1/s) "
              "(6.3.2).", "positive", bound=Bound.BANDWIDTH),
        Param("k_0", 5.0, "k_0 of (6.106): ceiling of the adaptation gain ||Gamma^-1|| "
              "(lemma 6.2.1); not given in the thesis: 5 chosen (module docstring); must "
              "exceed ||Gamma_0^-1||.", "positive", bound=Bound.GAIN),
        Param("p_hat_0", list(P_HAT_0), "Initial estimates p_hat(0) (6.3); true p = "
              "[0.6135 0.0045 0.30225 0.441 0.147] (docs/thesis.md).", "vector", N_P,
              read_only=True, bound=Bound.MASS),
        Param("slow_control", True, "Include the slow adaptive control tau_s (6.102) and "
              "its adaptation (6.103-6.106); false: motor feedback only, p_hat held at "
              "p_hat_0 (figures 6.16-6.18).", "bool"),
    ]
    extra_status_fields = fjs.STATUS + OWN_STATUS

    def __init__(self, values: dict):
        super().__init__(values)
        self.gains = np.zeros(GAINS.size)
        self.pack_gains()
        self.internal = STATE.pack({
            "started": 0.0, "p_hat": np.asarray(self.values["p_hat_0"], dtype=float),
            "Gamma": self.values["Gamma_0"], "F_w": 0.0, "Z": 0.0, "u_last": 0.0,
            "y_last": 0.0})
        self._output = KernelOutput(self)

    def check_values(self, values: dict) -> None:
        """Refuse gamma_1 <= gamma_2 (theorem 6.2.2) and k_0 <= ||Gamma_0^-1|| (lemma 6.2.1
        needs gamma(0) >= 0)."""
        if not values["gamma_1"] > values["gamma_2"]:
            raise ValueError(f"gamma_1 ({values['gamma_1']:g}) must exceed gamma_2 "
                             f"({values['gamma_2']:g}) (theorem 6.2.2)")
        gamma0_inv_norm = 1.0 / np.linalg.eigvalsh(values["Gamma_0"]).min()
        if not values["k_0"] > gamma0_inv_norm:
            raise ValueError(f"k_0 ({values['k_0']:g}) must exceed ||Gamma_0^-1|| = "
                             f"{gamma0_inv_norm:g} (lemma 6.2.1)")

    def pack_gains(self) -> None:
        """Pack the gains (after :meth:`check_values`)."""
        values = self.values
        self.check_values(values)
        fjs.pack_common(values, GAINS.view(self.gains, "common"))
        GAINS.pack({"common": GAINS.view(self.gains, "common").copy(),
                    "K_s": values["joint_stiffness"], "J_m": values["motor_inertia"],
                    "K_p": values["K_p"], "K_v": values["K_v"], "k_c": values["k_c"],
                    "gamma_0": values["gamma_0"], "gamma_1": values["gamma_1"],
                    "gamma_2": values["gamma_2"], "alpha": values["alpha"],
                    "k_0": values["k_0"],
                    "slow_control": 1.0 if values["slow_control"] else 0.0}, self.gains)

    def set_parameter(self, name, value) -> None:
        """Apply a validated value; a refused combination (ValueError from pack_gains)
        leaves the old value in force (the node refuses it before, by check_parameter)."""
        old = self.values[name]
        try:
            super().set_parameter(name, value)
        except ValueError:
            self.values[name] = old
            self.pack_gains()
            raise

    @property
    def estimates(self) -> np.ndarray:
        """p_hat (a copy)."""
        return STATE.view(self.internal, "p_hat").copy()

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        out = self._output.new()
        fjr_singular_perturbation_cycle(self.gains, self.internal, t, dt, q, v, force, out)
        return self._output.views(out)


@njit(cache=True, error_model="numpy")
def desired_motor_at(gains, t, p):
    """Rows q_md, q_md', q_md'' (3 x 2) of (6.62-6.64) at t for the parameters p (p_hat:
    6.65-6.67), as the cycle computes them."""
    qjet = np.empty((5, 2))
    fjs.desired(gains[:fjs.OWN], t, qjet)
    Psi_jets = np.empty((3, 2, N_P))
    regressor_jets_into(qjet, Psi_jets)
    f_jets = np.empty((3, 2))
    force_jets_into(qjet, gains[_LEN:_LEN + 2], gains[_N:_N + 2], gains[_OFF], gains[_LD],
                    f_jets)
    md = np.empty((3, 2))
    desired_motor(gains, Psi_jets, f_jets, qjet, p, md)
    return md
