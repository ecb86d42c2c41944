"""Robust adaptive position/force control of a constrained flexible-joint robot with unknown
joint stiffness K_s, motor inertia J_m and link parameters (thesis section 6.2, theorem
6.2.1, with the boundary layer of remark 6.2.3 and s_z of remark 6.2.2; simulated in 6.3.1).

Plant (6.1-6.3): M(q_l) q_l'' + C q_l' + G = K_s theta + J_Phi^T lambda,
J_m q_m'' + K_s theta = tau_m, theta = q_m - q_l; n = 2 joints, m = 1 constraint, the
partition q_l^1 = theta1, q_l^2 = theta2 (section 6.3), so e^1, r^1, q_r^1 are scalars and
L = [1, L2] (6.8, corrected 6.118:
:func:`~cr_control.schemes.flexible_joint.flexible_joint_model.constraint_into`).

Step 1, the desired transmission deflection theta_d (6.13-6.42):

    e^1 = q_ld^1 - q_l^1,  e_lambda = lambda_d - lambda                             (6.13)
    r^1 = e^1' + K_e e^1,  q_r^1' = q_ld^1' + K_e e^1                                (6.14)
    sigma = L(q_l) r^1 + mu                                                          (6.15)
    nu    = L(q_l) q_r^1' + mu                                                       (6.16)
    mu'   = -K_mu mu - J_Phi^T(q_l) e_lambda                                         (6.32)
    theta_d = K_sigma sigma - K_s_inv_hat J_Phi^T lambda_d + Psi(nu', nu, q_l', q_l) p_hat  (6.29)
    p_hat'        = Gamma_p Psi^T(nu', nu, q_l', q_l) sigma                          (6.41)
    k_s_inv_hat'  = -Gamma_k phi_2,  phi_2,i = (J_Phi^T lambda_d)_i sigma_i           (6.35, 6.42)

with nu' = L' q_r^1' + L q_r^1'' + mu', q_r^1'' = q_ld^1'' + K_e e^1' (all measured: L' from
q_l', e^1' = q_ld^1' - q_l^1', mu' from the law 6.32), Psi the 2 x 10 block form of section
6.3 (Property 6.5; :func:`expanded_regressor_into`) and K_s_inv_hat = diag(k_s_inv_hat), the
adapted vector (6.21): the estimate of K_s^-1, NOT the inverse of K_s_hat (note after
6.23). p_hat estimates Lambda^-1 p = [p / k_s1; p / k_s2] (6.29-6.41: K_s Psi p_hat =
Psi p_hat_s), not p itself: for K_s = 10 I that is 0.1 p, so p_hat(0) = 0.15 p of section
6.3 starts near it; for K_s = 50 I the target is 0.02 p.

Step 2, the motor torque (6.43-6.59), remarks 6.2.2 and 6.2.3:

    z = theta_d - theta,  s_z = int_0^t sigma dt + z,  s = s_z' = sigma + z'         (6.60-6.61)
    tau_m = K_s_hat theta_d + J_m_hat q_m'' + k_tau sat(s / Delta)                   (6.58)
    k_tau = delta_K ||theta_d|| + delta_J ||q_m''||                                  (6.59, equality)

sat(x) = x for |x| <= 1, sign(x) beyond, element-wise (remark 6.2.3 replaces sgn(s) by
s / Delta "when ||s|| < Delta"; element-wise keeps each joint's sign function of 6.48).

Choices the thesis leaves open (parameters where they are values, documented):
  * k_s_inv_hat(0) = [0.125, 0.125] = 1/K_s_hat(0) diagonal (none given; the natural
    start, consistent with K_s_hat = 8 I); mu(0) = 0 (none given).
  * K_e is a scalar (n - m = 1): the (1,1) entry of the shared K_e parameter (3.5).
  * lambda is the normal force in N: Phi is scaled with the unit normal n = (1, -1)/sqrt 2
    (the thesis leaves the scale of Phi, and so the unit of lambda, open; with the raw
    normal (1, -1) lambda would be sqrt 2 times smaller). J_Phi = n^T J_tool.
  * Discretisation: explicit Euler with each cycle's dt (dt = 0 on the first cycle: no
    update, s = 0). At cycle k: mu is updated with mu' at (mu_{k-1}, measurement k); sigma,
    nu, nu' (with mu' at mu_k) and Psi follow; p_hat, k_s_inv_hat and int sigma are updated
    with the right-hand sides at (sigma_k, Psi_k) and the estimates of cycle k - 1; theta_d,
    z and the command use the updated values.
  * s = sigma + z' by remark 6.2.2: s_k = (s_z,k - s_z,k-1) / dt (the backward difference;
    with int sigma updated by dt sigma_k it equals sigma_k + (z_k - z_k-1) / dt). A later
    dt = 0 (a repeated stamp) reuses the last s.
  * q_m'' (assumption 6.3), parameter ``motor_acceleration``:
      - "measured": the plant's q_m'' sensors (plant_sensor_fields). The
        flexible_joint_surface plant evaluates them at the state with the command held
        over the last period (J_m q_m'' = tau_{k-1} - K_s theta). Not finite (not yet
        received): the filtered estimate below is used instead.
      - "filtered" (default, because the measured one drives the torque to its clip:
        below): a critically damped state-variable filter on q_m',
        x1'' + 2 w x1' + w^2 x1 = w^2 q_m' (w = ``motor_acceleration_bandwidth``), whose
        derivative state x2 = x1' estimates q_m''. It is discretised exactly (the input
        held over the period, taken at its end): with e = [x1 - u, x2],
        e_k = exp(A dt) e_{k-1}, exp(A dt) = exp(-w dt) [[1 + w dt, dt], [-w^2 dt,
        1 - w dt]], stable for every w dt; x1(0) = q_m'(0), x2(0) = 0. It runs in both
        modes (both published) so the two can be compared. w = 50 rad/s by test (case 1
        and 2, 20 s): 10 rad/s diverges for K_s = 50, 25-200 work, above ~400 the torque
        approaches the measured mode's chatter; 50 leaves a factor ~5 either way.
    What the measured q_m'' does (offline loop, 1 kHz; test/test_fjr_robust_adaptive.py):
    J_m_hat q_m'' is acceleration feedback of the motor on itself (q_m'' depends on
    tau_m through 6.2: an algebraic loop in continuous time, a one-period-old feedback
    here): it leaves the motor an effective inertia J_m - J_m_hat = 0.1 kg m^2, and with
    delta_J ||q_m''|| sat(.) the loop gain (J_m_hat + delta_J) / J_m = 4.8 exceeds 1 once
    |s| > Delta / 20. With the thesis gains the torque then alternates between the
    +-max_effort clip (100 N m) from the first cycles on, at 1 kHz and at 10 kHz alike, and
    without the clip the run diverges; the positions still converge (4-6 mrad RMS). The
    filtered q_m'' removes the loop at high frequency: torques of a few N m, errors 4-6x
    smaller. The theorem's proof treats q_m'' as an exogenous measurement; it is not.
  * Boundary layer at 1 kHz: k_tau / Delta ~ 10^3 N m s/rad acts on z' (which contains
    -q_m'), against J_m = 0.5 kg m^2: k_tau dt / (Delta J_m) ~ 2, so with Delta = 0.002
    the sampled loop settles in a limit cycle of a few N m (fast torque ~3.9 N m RMS,
    case 1, filtered); what matters is Delta / dt: at 10 kHz, or with Delta = 0.02 at
    1 kHz, the torque is smooth (0.03 N m) as section 6.3.1 describes.

Internal state (``internal``): [started, mu (2), p_hat (10), k_s_inv_hat (2), int sigma
(2), s_z of the last cycle (2), s of the last cycle (2), filter x1 (2), x2 (2)].

Cost: one compiled call per cycle (desired-motion jets to order 4, surface, the 2 x 10
regressor, a 10 x 10 adaptation gain product, the filter): ~6-7 us for the kernel on this
2-core machine, ~16 us median per Controller.step in the offline loop (~35 us while the
command is clipped every cycle, measured mode), measured in the tests (compute_time_us).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, matrix
from cr_control.schemes.controller import ControlOutput, KernelOutput
from cr_control.schemes.flexible_joint import flexible_joint_scheme as fjs
from cr_control.schemes.flexible_joint.flexible_joint_model import P_HAT_0, expanded_regressor_into

N_P = 10
MOTOR_ACCELERATION = ("measured", "filtered")

OWN_STATUS = ([f"p_hat_{i + 1}" for i in range(N_P)] + ["ks_inv_hat_1", "ks_inv_hat_2",
              "mu_1", "mu_2", "sigma_1", "sigma_2", "theta_d_1", "theta_d_2", "z_1", "z_2",
              "s_1", "s_2", "k_tau", "qddot_m_1", "qddot_m_2", "qddot_m_filtered_1",
              "qddot_m_filtered_2"])

GAINS = Layout(common=fjs.OWN, K_s_hat=(2, 2), J_m_hat=(2, 2), delta_K=1, delta_J=1,
               K_sigma=(2, 2), K_mu=(2, 2), Gamma_p=(N_P, N_P), Gamma_k=(2, 2),
               boundary_layer=1, measured=1, bandwidth=1)
_KS, _JM, _DK, _DJ, _KSIG, _KMU, _GP, _GK, _DELTA, _MEAS, _BW = (
    GAINS.offset(k) for k in ("K_s_hat", "J_m_hat", "delta_K", "delta_J", "K_sigma", "K_mu",
                              "Gamma_p", "Gamma_k", "boundary_layer", "measured", "bandwidth"))
_KE, _LD = fjs.COMMON.offset("K_e"), fjs.COMMON.offset("lambda_d")

STATE = Layout(started=1, mu=2, p_hat=N_P, ks_inv_hat=2, int_sigma=2, s_z=2, s=2,
               filter_v=2, filter_a=2)
_STARTED, _MU, _P, _KI, _IS, _SZ, _S, _FV, _FA = (
    STATE.offset(k) for k in ("started", "mu", "p_hat", "ks_inv_hat", "int_sigma", "s_z",
                              "s", "filter_v", "filter_a"))


@njit(cache=True, error_model="numpy")
def motor_acceleration_filter(x1, x2, u, w, dt):
    """One exact step of x1'' + 2 w x1' + w^2 x1 = w^2 u (u held; x2 = x1'), in place."""
    wd = w * dt
    decay = math.exp(-wd)
    for i in range(2):
        e1, e2 = x1[i] - u[i], x2[i]
        x1[i] = u[i] + decay * ((1.0 + wd) * e1 + dt * e2)
        x2[i] = decay * (-w * wd * e1 + (1.0 - wd) * e2)


@njit(cache=True, error_model="numpy")
def fjr_robust_adaptive_cycle(gains, state, t, dt, q, v, force, qddot_measured, out):
    """One cycle of theorem 6.2.1 (6.58) into ``out``; q, v = [q_l, q_m] (4), force: the
    wrench n lambda, qddot_measured: the plant's q_m'' (2); state: STATE (in place)."""
    g = gains[:fjs.OWN]
    K_sh = gains[_KS:_KS + 4].reshape((2, 2))
    J_mh = gains[_JM:_JM + 4].reshape((2, 2))
    K_sig = gains[_KSIG:_KSIG + 4].reshape((2, 2))
    K_mu = gains[_KMU:_KMU + 4].reshape((2, 2))
    Gamma_p = gains[_GP:_GP + N_P * N_P].reshape((N_P, N_P))
    Gamma_k = gains[_GK:_GK + 4].reshape((2, 2))
    k_e = g[_KE]                                   # (1,1) entry of K_e: n - m = 1
    lam_d = g[_LD]
    q_l, v_l, q_m, v_m = q[0:2], v[0:2], q[2:4], v[2:4]
    mu = state[_MU:_MU + 2]
    p_hat = state[_P:_P + N_P]
    ks_inv = state[_KI:_KI + 2]
    int_sigma = state[_IS:_IS + 2]
    s_z_prev = state[_SZ:_SZ + 2]
    s = state[_S:_S + 2]
    x1 = state[_FV:_FV + 2]
    x2 = state[_FA:_FA + 2]
    started = state[_STARTED] != 0.0
    step = started and dt > 0.0

    # desired motion, surface, force (6.13)
    qjet = np.empty((5, 2))
    fjs.desired(g, t, qjet)
    surf = np.empty(10)
    fjs.surface(g, q_l, v_l, surf)
    J, L, L_dot = surf[1:3], surf[3:5], surf[5:7]
    lam = fjs.measured_lambda(g, force)
    e_lam = lam_d - lam

    # q_m'' state-variable filter (both modes)
    if not started:
        for i in range(2):
            x1[i] = v_m[i]
            x2[i] = 0.0
    elif dt > 0.0:
        motor_acceleration_filter(x1, x2, v_m, gains[_BW], dt)

    # (6.13-6.14), scalar partition q_l^1 = theta1
    e1 = qjet[0, 0] - q_l[0]
    e1_dot = qjet[1, 0] - v_l[0]
    r1 = e1_dot + k_e * e1
    qr_dot = qjet[1, 0] + k_e * e1
    qr_ddot = qjet[2, 0] + k_e * e1_dot

    # mu (6.32), explicit Euler, then mu' at the new mu for nu'
    if step:
        d0 = -(K_mu[0, 0] * mu[0] + K_mu[0, 1] * mu[1]) - J[0] * e_lam
        d1 = -(K_mu[1, 0] * mu[0] + K_mu[1, 1] * mu[1]) - J[1] * e_lam
        mu[0] += dt * d0
        mu[1] += dt * d1
    mu_dot = np.empty(2)
    sigma = np.empty(2)
    nu = np.empty(2)
    nu_dot = np.empty(2)
    for i in range(2):
        mu_dot[i] = -(K_mu[i, 0] * mu[0] + K_mu[i, 1] * mu[1]) - J[i] * e_lam
        sigma[i] = L[i] * r1 + mu[i]                                    # (6.15)
        nu[i] = L[i] * qr_dot + mu[i]                                   # (6.16)
        nu_dot[i] = L_dot[i] * qr_dot + L[i] * qr_ddot + mu_dot[i]
    Psi = np.empty((2, N_P))
    expanded_regressor_into(nu_dot, nu, v_l, q_l, Psi)

    # adaptation (6.41), (6.42) and int sigma (6.60)
    if step:
        y = np.empty(N_P)                                               # Psi^T sigma
        for j in range(N_P):
            y[j] = Psi[0, j] * sigma[0] + Psi[1, j] * sigma[1]
        for j in range(N_P):
            acc = 0.0
            for k in range(N_P):
                acc += Gamma_p[j, k] * y[k]
            p_hat[j] += dt * acc
        phi0 = J[0] * lam_d * sigma[0]                                  # (6.35)
        phi1 = J[1] * lam_d * sigma[1]
        k0 = Gamma_k[0, 0] * phi0 + Gamma_k[0, 1] * phi1
        k1 = Gamma_k[1, 0] * phi0 + Gamma_k[1, 1] * phi1
        ks_inv[0] -= dt * k0
        ks_inv[1] -= dt * k1
        int_sigma[0] += dt * sigma[0]
        int_sigma[1] += dt * sigma[1]

    # theta_d (6.29), z, s_z (6.60) and s = s_z' (remark 6.2.2)
    theta_d = np.empty(2)
    z = np.empty(2)
    for i in range(2):
        acc = 0.0
        for j in range(N_P):
            acc += Psi[i, j] * p_hat[j]
        theta_d[i] = (K_sig[i, 0] * sigma[0] + K_sig[i, 1] * sigma[1]
                      - ks_inv[i] * J[i] * lam_d + acc)
        z[i] = theta_d[i] - (q_m[i] - q_l[i])
        s_z = int_sigma[i] + z[i]
        if step:
            s[i] = (s_z - s_z_prev[i]) / dt
        elif not started:
            s[i] = 0.0
        s_z_prev[i] = s_z
    state[_STARTED] = 1.0

    # q_m'' (assumption 6.3) and the torque (6.58-6.59), boundary layer (remark 6.2.3)
    qdd = np.empty(2)
    use_measured = gains[_MEAS] != 0.0 and math.isfinite(qddot_measured[0]) \
        and math.isfinite(qddot_measured[1])
    for i in range(2):
        qdd[i] = qddot_measured[i] if use_measured else x2[i]
    k_tau = gains[_DK] * math.hypot(theta_d[0], theta_d[1]) \
        + gains[_DJ] * math.hypot(qdd[0], qdd[1])
    delta = gains[_DELTA]
    tau = np.empty(2)
    for i in range(2):
        sat = s[i] / delta
        if sat > 1.0:
            sat = 1.0
        elif sat < -1.0:
            sat = -1.0
        tau[i] = (K_sh[i, 0] * theta_d[0] + K_sh[i, 1] * theta_d[1]
                  + J_mh[i, 0] * qdd[0] + J_mh[i, 1] * qdd[1] + k_tau * sat)

    st = fjs.write_output(g, out, tau, qjet, q, v, force, surf[0])
    st[0:N_P] = p_hat
    k = N_P
    for pair in (ks_inv, mu, sigma, theta_d, z, s):
        st[k], st[k + 1] = pair[0], pair[1]
        k += 2
    st[k] = k_tau
    st[k + 1], st[k + 2] = qdd[0], qdd[1]
    st[k + 3], st[k + 4] = x2[0], x2[1]


class FJRRobustAdaptiveController(fjs.FlexibleJointController):
    """Robust adaptive control (theorem 6.2.1, 6.58) with the section 6.3.1 gains."""

    scheme = "fjr_robust_adaptive"
    PARAMETERS = fjs.PARAMETERS + [
        fjs.k_e_parameter(3.5),
        Param("K_s_hat", matrix(2, 8.0), "Joint stiffness estimate K_s_hat in tau_m = "
              "K_s_hat theta_d + ... (6.58) (N m/rad) (6.3.1: 8).", "spd", 2, bound=Bound.STIFFNESS),
        Param("J_m_hat", matrix(2, 0.4), "Motor inertia estimate J_m_hat in (6.58) (kg m^2) "
              "(6.3.1: 0.4).", "spd", 2, bound=Bound.INERTIA),
        Param("delta_K", 4.0, "delta_K >= ||K_s - K_s_hat|| (assumption 6.2) in k_tau = "
              "delta_K ||theta_d|| + delta_J ||q_m''|| (6.59) (6.3.1: 4).", "nonnegative",
              bound=Bound.STIFFNESS),
        Param("delta_J", 2.0, "delta_J >= ||J_m - J_m_hat|| (assumption 6.2) in k_tau (6.59) "
              "(6.3.1: 2).", "nonnegative", bound=Bound.INERTIA),
        Param("K_sigma", matrix(2, 1.0), "K_sigma of theta_d (6.29) (6.3.1: 1).", "spd", 2, bound=Bound.GAIN),
        Param("K_mu", matrix(2, 1.5), "K_mu of mu' = -K_mu mu - J_Phi^T e_lambda (6.32) "
              "(6.3.1: 1.5).", "spd", 2, bound=Bound.GAIN),
        Param("Gamma_p", matrix(N_P, 0.08), "Adaptation gain Gamma_p of p_hat' = Gamma_p "
              "Psi^T sigma (6.41), 10 x 10 (0.08 I_10: the thesis prints 2 x 2; docs/thesis.md).",
              "spd", N_P, bound=Bound.GAIN),
        Param("Gamma_k", matrix(2, 0.08), "Adaptation gain Gamma_k of k_s_inv_hat' = "
              "-Gamma_k phi_2 (6.42) (6.3.1: 0.08).", "spd", 2, bound=Bound.GAIN),
        Param("boundary_layer", 0.002, "Boundary layer Delta: sgn(s) of (6.58) replaced by "
              "s / Delta for |s| < Delta, element-wise (remark 6.2.3) (6.3.1: 0.002).",
              "positive", bound=Bound.SCALE),
        Param("p_hat_0", list(P_HAT_0) * 2, "Initial estimates p_hat(0) of the 10-parameter "
              "block form (section 6.3: [0.092 0.0007 0.045 0.066 0.022] twice); p_hat "
              "estimates [p / k_s1; p / k_s2], true p = [0.6135 0.0045 0.30225 0.441 0.147] "
              "(docs/thesis.md).", "vector", N_P, read_only=True, bound=Bound.MASS),
        Param("ks_inv_hat_0", [0.125, 0.125], "Initial estimates k_s_inv_hat(0) of K_s^-1 "
              "(6.21) (rad/(N m)); the thesis gives none: 1 / K_s_hat = 0.125.", "vector", 2,
              read_only=True, bound=100.0),     # a joint softer than 0.01 N m/rad is none
        Param("motor_acceleration", "filtered", "Source of q_m'' in (6.58-6.59) (assumption "
              "6.3): 'filtered' (a critically damped state-variable filter on q_m'; default) or "
              "'measured' (the plant's joint1/2_motor_acceleration sensors, the filter "
              "estimate while none has arrived; with the thesis gains its torque sits at the "
              "+-max_effort clip, see the docstring).", "choice", choices=MOTOR_ACCELERATION),
        Param("motor_acceleration_bandwidth", 50.0, "Bandwidth w (rad/s) of the q_m'' filter "
              "w^2 s / (s + w)^2 on q_m' (runs in both modes, published as "
              "qddot_m_filtered_*).", "positive", bound=Bound.BANDWIDTH),
    ]
    extra_status_fields = fjs.STATUS + OWN_STATUS
    plant_sensor_fields = ("joint1_motor_acceleration", "joint2_motor_acceleration")

    def __init__(self, values: dict):
        super().__init__(values)
        self.gains = np.zeros(GAINS.size)
        self.pack_gains()
        self.internal = STATE.pack({
            "started": 0.0, "mu": 0.0,
            "p_hat": np.asarray(self.values["p_hat_0"], dtype=float),
            "ks_inv_hat": np.asarray(self.values["ks_inv_hat_0"], dtype=float),
            "int_sigma": 0.0, "s_z": 0.0, "s": 0.0, "filter_v": 0.0, "filter_a": 0.0})
        self._output = KernelOutput(self)

    def pack_gains(self) -> None:
        values = self.values
        common = np.zeros(fjs.OWN)
        fjs.pack_common(values, common)
        GAINS.pack({
            "common": common, "K_s_hat": values["K_s_hat"], "J_m_hat": values["J_m_hat"],
            "delta_K": values["delta_K"], "delta_J": values["delta_J"],
            "K_sigma": values["K_sigma"], "K_mu": values["K_mu"],
            "Gamma_p": values["Gamma_p"], "Gamma_k": values["Gamma_k"],
            "boundary_layer": values["boundary_layer"],
            "measured": 1.0 if values["motor_acceleration"] == "measured" else 0.0,
            "bandwidth": values["motor_acceleration_bandwidth"]}, self.gains)

    @property
    def estimates(self) -> np.ndarray:
        """[p_hat (10), k_s_inv_hat (2)] (a copy)."""
        return np.concatenate([STATE.view(self.internal, "p_hat"),
                               STATE.view(self.internal, "ks_inv_hat")])

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        out = self._output.new()
        fjr_robust_adaptive_cycle(self.gains, self.internal, t, dt, q, v, force,
                                  self.plant_sensors, out)
        return self._output.views(out)
