"""Neural-network adaptive position/force control of a robot constrained by a moving object
(thesis section 2.3.2, controller 2.74, laws 2.79-2.81). Model free: no regressor and no
dynamics model; every element of M^1 (3x2), C^1 (3x2) and G^1 (3) of the reduced model
(2.20) is a Gaussian RBF network (2.63-2.73) whose weights adapt on line:

    tau = M^_nn q_r'' + C^_nn q_r' + G^_nn - J^{1T} n_c (lambda_d + k_lambda int e_lambda)
          + L^-T (K r^1 + K_s sat(r^1 / Delta))                                       (2.74)
    M^_kj = theta_kj^T xi(q^1),  C^_kj = alpha_kj^T zeta(q^1, q^1'),  G^_k = beta_k^T eta(q^1)
    theta_kj' = Gamma xi(q^1) q_r,j'' (L r^1)_k                                       (2.79)
    alpha_kj' = Q zeta(z) q_r,j' (L r^1)_k                                            (2.80)
    beta_k'   = U eta(q^1) (L r^1)_k                                                  (2.81)

The GL-matrix products of (2.68-2.73) are element-wise inner products; since all elements
of a network family share their centres, each family is one weight matrix (nodes x
elements) and one activation vector (:mod:`cr_control.schemes.blocks.rbf_network`). sgn(r^1) is
replaced by a boundary layer sat(r^1/Delta) (remark 2.3.6), Delta = 0.01 (2.4).

Section 2.4 values: 120 nodes per network, sigma^2 = 40, Gamma = 0.1, Q = 0.2, U = 5.0,
K_e = 20 I, K = 15 I, k_lambda = 15. Centres: even grids (crossing points) over the ranges
the thesis states, q^1 in [-1.2, 1.7] rad and q^1' in [-1, 1] rad/s: 12 x 10 = 120 nodes for
the q^1 networks (M, G) and 5 x 4 x 3 x 2 = 120 for the (q^1, q^1') networks (C) - the
thesis does not say how 120 nodes split over the axes. The branch s2 > 0 keeps q_d^1 inside
the q range (theta1 in [0.97, 1.57], theta2 in [0.40, 1.56]); q_d^1' slightly leaves
[-1, 1] (theta1' in [-1.19, 1.22], theta2' in [-1.09, 1.07] rad/s; test_chapter2).
K_s is not given: 0.5 (N m), a documented choice. Initial weights zero.

The kinematics (L, J^1, n_c) need the link lengths, the base and the line - geometry, not
dynamics. The true norms |M^1|, |C^1|, |G^1| published beside the estimates (figs. 2.10-
2.12) come from the closed form with ``true_parameters`` and are never used for control
(``publish_true_norms``). Norms: spectral for M^1 and C^1 (3x2), Euclidean for G^1.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.schemes.blocks import rbf_network
from cr_control.schemes.closed_chain import moving_object_model as mo
from cr_control.schemes.controller import ControlOutput, KernelOutput

NORM_FIELDS = ["M1_norm", "M1_hat_norm", "C1_norm", "C1_hat_norm", "G1_norm", "G1_hat_norm"]

GAINS = Layout(common=mo.COMMON.size, K_s=1, boundary_layer=1, Gamma=1, Q=1, U=1,
               inv_variance=1, true_norms=1, true_parameters=7)
_NC = mo.COMMON.size
_EXTRAS = mo.EXTRAS_AT
_KS, _DELTA, _GAMMA, _Q, _U, _IV, _TN, _TP = (
    GAINS.offset(k) for k in ("K_s", "boundary_layer", "Gamma", "Q", "U", "inv_variance",
                              "true_norms", "true_parameters"))


@njit(cache=True)
def moving_object_nn_cycle(gains, state, centres_q, centres_z, t, dt, q, v, force, out):
    """One cycle of (2.74) with (2.79-2.81) into ``out``; state = [int e_lambda, theta
    (n_q x 6), alpha (n_z x 6), beta (n_q x 3)], elements row-major (k, j)."""
    g = gains[:_NC]
    (qd, qd_dot, q1, v1, e, r1, qr_dot, qr_ddot, L, _, jtn, X, lam, lam_cmd,
     motion) = mo.control_front(g, state[0:1], t, dt, q, v, force)
    n_q, n_z = centres_q.shape[0], centres_z.shape[0]
    w = state[1:]
    theta = w[:6 * n_q].reshape((n_q, 6))
    alpha = w[6 * n_q:6 * (n_q + n_z)].reshape((n_z, 6))
    beta = w[6 * (n_q + n_z):6 * (n_q + n_z) + 3 * n_q].reshape((n_q, 3))
    z = np.empty(4)
    z[:2], z[2:] = q1, v1
    inv_variance = gains[_IV]
    xi = rbf_network.activations(centres_q, inv_variance, q1)
    zeta = rbf_network.activations(centres_z, inv_variance, z)
    Lr = np.empty(3)
    for i in range(3):
        Lr[i] = L[i, 0] * r1[0] + L[i, 1] * r1[1]
    if dt > 0.0:
        y_m = np.empty(6)
        y_c = np.empty(6)
        for k in range(3):
            for j in range(2):
                y_m[2 * k + j] = qr_ddot[j] * Lr[k]
                y_c[2 * k + j] = qr_dot[j] * Lr[k]
        rbf_network.adapt(theta, xi, gains[_GAMMA] * dt, y_m)    # (2.79)
        rbf_network.adapt(alpha, zeta, gains[_Q] * dt, y_c)      # (2.80)
        rbf_network.adapt(beta, xi, gains[_U] * dt, Lr)          # (2.81)
    M_hat = rbf_network.output(xi, theta).reshape((3, 2))
    C_hat = rbf_network.output(zeta, alpha).reshape((3, 2))
    G_hat = rbf_network.output(xi, beta)
    delta = gains[_DELTA]
    sat = np.empty(2)
    for i in range(2):
        sat[i] = gains[_KS] * min(1.0, max(-1.0, r1[i] / delta))
    fb = mo.feedback(g, X, r1, sat)
    tau = np.empty(3)
    for i in range(3):
        tau[i] = (M_hat[i, 0] * qr_ddot[0] + M_hat[i, 1] * qr_ddot[1]
                  + C_hat[i, 0] * qr_dot[0] + C_hat[i, 1] * qr_dot[1] + G_hat[i]
                  - jtn[i] * lam_cmd + fb[i])                        # (2.74)
    st = mo.write_output(g, out, tau, qd, qd_dot, q, v, force, e, r1, lam, state[0], motion)
    k = _EXTRAS
    if gains[_TN] > 0.0:
        M1, C1, G1 = mo.reduced_dynamics(g, gains[_TP:_TP + 7], q1, v1)
        st[k], st[k + 2] = mo.norm_3x2(M1), mo.norm_3x2(C1)
        st[k + 4] = math.sqrt(G1[0] ** 2 + G1[1] ** 2 + G1[2] ** 2)
    else:
        st[k] = st[k + 2] = st[k + 4] = np.nan
    st[k + 1], st[k + 3] = mo.norm_3x2(M_hat), mo.norm_3x2(C_hat)
    st[k + 5] = math.sqrt(G_hat[0] ** 2 + G_hat[1] ** 2 + G_hat[2] ** 2)


def grid(low, high, counts) -> np.ndarray:
    """Crossing points of an even grid over the box [low, high], counts[i] per axis (rows)."""
    axes = [np.linspace(lo, hi, int(n)) if int(n) > 1 else np.array([(lo + hi) / 2.0])
            for lo, hi, n in zip(low, high, counts, strict=True)]
    return np.ascontiguousarray(
        np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(low)))


class MovingObjectNNController(mo.MovingObjectController):
    """RBF-network adaptive control (2.74, 2.79-2.81) with the section 2.4 values."""

    scheme = "moving_object_nn"
    PARAMETERS = mo.scheme_parameters([
        Param("K_s", 0.5, "K_s of the robust term L^-T K_s sat(r^1/Delta) (2.74); not given in "
              "the thesis (N m).", "nonnegative", bound=Bound.GAIN),
        Param("boundary_layer", 0.01, "Boundary layer Delta replacing sgn(r^1) (remark 2.3.6).",
              "positive", bound=Bound.SCALE),
        Param("Gamma", 0.1, "Gamma_kij of the M^1 weights (2.79).", "positive", bound=Bound.GAIN),
        Param("Q", 0.2, "Q_kij of the C^1 weights (2.80).", "positive", bound=Bound.GAIN),
        Param("U", 5.0, "U_kij of the G^1 weights (2.81).", "positive", bound=Bound.GAIN),
        Param("rbf_variance", 40.0, "sigma^2 of the Gaussian activations (2.63).", "positive",
              read_only=True, bound=Bound.GAIN),
        Param("rbf_q_range", [-1.2, 1.7], "Centre grid: range of each joint angle (rad) (2.4).",
              "vector", 2, read_only=True, bound=Bound.JOINT),
        Param("rbf_qdot_range", [-1.0, 1.0], "Centre grid: range of each joint rate (rad/s) "
              "(2.4).", "vector", 2, read_only=True, bound=Bound.JOINT_RATE),
        Param("rbf_grid_q", [12.0, 10.0], "Centres per axis (theta1, theta2) of the M^1 and G^1 "
              "networks (12 x 10 = 120 nodes).", "positive_vector", 2, read_only=True,
              bound=Bound.RBF_CENTRES),
        Param("rbf_grid_z", [5.0, 4.0, 3.0, 2.0], "Centres per axis (theta1, theta2, theta1', "
              "theta2') of the C^1 networks (5 x 4 x 3 x 2 = 120 nodes).", "positive_vector", 4,
              read_only=True, bound=Bound.RBF_CENTRES),
        Param("publish_true_norms", True, "Publish |M^1|, |C^1|, |G^1| from true_parameters "
              "beside the estimates (plots only; never used for control).", "bool"),
        Param("true_parameters", list(mo.TRUE_P), "P used only for the published true norms.",
              "vector", 7, bound=Bound.MASS),
    ])
    extra_status_fields = mo.STATUS + NORM_FIELDS

    def __init__(self, values: dict):
        super().__init__(values)
        vals = self.values
        counts_q, counts_z = vals["rbf_grid_q"], vals["rbf_grid_z"]
        if any(c != int(c) for c in [*counts_q, *counts_z]):
            raise ParameterError("rbf_grid_q and rbf_grid_z must be whole numbers")
        q_lo, q_hi = vals["rbf_q_range"]
        v_lo, v_hi = vals["rbf_qdot_range"]
        if not (q_lo <= q_hi and v_lo <= v_hi):
            raise ParameterError("rbf ranges must be [low, high]")
        self.centres_q = grid([q_lo, q_lo], [q_hi, q_hi], counts_q)
        self.centres_z = grid([q_lo, q_lo, v_lo, v_lo], [q_hi, q_hi, v_hi, v_hi], counts_z)
        n_q, n_z = len(self.centres_q), len(self.centres_z)
        self.gains = np.zeros(GAINS.size)
        self.pack_gains()
        self.internal = np.zeros(1 + 6 * n_q + 6 * n_z + 3 * n_q)
        self._output = KernelOutput(self)

    def pack_gains(self) -> None:
        v = self.values
        mo.pack_common(v, GAINS.view(self.gains, "common"))
        GAINS.pack({"common": GAINS.view(self.gains, "common").copy(), "K_s": v["K_s"],
                    "boundary_layer": v["boundary_layer"], "Gamma": v["Gamma"], "Q": v["Q"],
                    "U": v["U"], "inv_variance": 1.0 / v["rbf_variance"],
                    "true_norms": 1.0 if v["publish_true_norms"] else 0.0,
                    "true_parameters": v["true_parameters"]}, self.gains)

    def weights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of theta (n_q x 6), alpha (n_z x 6), beta (n_q x 3)."""
        n_q, n_z = len(self.centres_q), len(self.centres_z)
        w = self.internal[1:]
        return (w[:6 * n_q].reshape(n_q, 6).copy(),
                w[6 * n_q:6 * (n_q + n_z)].reshape(n_z, 6).copy(),
                w[6 * (n_q + n_z):].reshape(n_q, 3).copy())

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        out = self._output.new()
        moving_object_nn_cycle(self.gains, self.internal, self.centres_q, self.centres_z, t, dt,
                               q, v, force, out)
        return self._output.views(out)
