"""Model-based adaptive position/force control of a robot constrained by a moving object
(thesis section 2.3.1, controller 2.27, adaptation law 2.35).

    tau = Psi_r P_hat - J^{1T} n_c (lambda_d + k_lambda int e_lambda) + L^-T K r^1      (2.27)
    P_hat' = Gamma Psi_r^T L r^1                                                         (2.35)

with Psi_r = Psi(q^1, q^1', q_r^1', q_r^1''), e^1 = q_d^1 - q^1, r^1 = e^1' + K_e e^1,
q_r^1' = q_d^1' + K_e e^1 (2.22-2.26), e_lambda = lambda_d - lambda, lambda = n_c . f (the
wrench carries n_c lambda). Regressor with the Psi_11 correction and "L^-T" the right
inverse L (L^T L)^-1 of L^T (docs/thesis.md): :mod:`cr_control.schemes.closed_chain.moving_object_model`.
(2.35) is printed as P~' = ...; the proof (2.39) needs P_hat' = -P~' = Gamma Psi_r^T L r^1.

Section 2.4 gains: K_e = 20 I, K = 15 I, k_lambda = 15, Gamma = 15 I_7,
P_hat(0) = [0.2 0.01 0.4 0.4 0.1 0.2 0.2]. Commands: [tau_1 (2 joints), tau_2 (object
axis)]. The estimates and the force integral are integrated by explicit Euler with each
cycle's dt (updated first, then the command uses them). One compiled call per cycle.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, matrix
from cr_control.schemes.closed_chain import moving_object_model as mo
from cr_control.schemes.controller import ControlOutput, KernelOutput

ESTIMATE_FIELDS = [f"P_hat_{i + 1}" for i in range(7)]

GAINS = Layout(common=mo.COMMON.size, Gamma=(7, 7))
_GAMMA = GAINS.offset("Gamma")
_NC = mo.COMMON.size
_EXTRAS = mo.EXTRAS_AT


@njit(cache=True)
def moving_object_adaptive_cycle(gains, state, t, dt, q, v, force, out):
    """One cycle of (2.27) with (2.35) into ``out``; state = [int e_lambda, P_hat (7)]."""
    g = gains[:_NC]
    (qd, qd_dot, q1, v1, e, r1, qr_dot, qr_ddot, L, _, jtn, X, lam, lam_cmd,
     motion) = mo.control_front(g, state[0:1], t, dt, q, v, force)
    P_hat = state[1:8]
    Psi = mo.regressor(g, q1, v1, qr_dot, qr_ddot)
    if dt > 0.0:
        Lr = np.empty(3)
        for i in range(3):
            Lr[i] = L[i, 0] * r1[0] + L[i, 1] * r1[1]
        y = np.zeros(7)                                   # Psi_r^T L r^1
        for k in range(7):
            for i in range(3):
                y[k] += Psi[i, k] * Lr[i]
        Gamma = gains[_GAMMA:_GAMMA + 49].reshape((7, 7))
        for k in range(7):
            s = 0.0
            for j in range(7):
                s += Gamma[k, j] * y[j]
            P_hat[k] += dt * s                            # (2.35)
    fb = mo.feedback(g, X, r1, np.zeros(2))
    tau = np.empty(3)
    for i in range(3):
        s = 0.0
        for k in range(7):
            s += Psi[i, k] * P_hat[k]
        tau[i] = s - jtn[i] * lam_cmd + fb[i]            # (2.27)
    st = mo.write_output(g, out, tau, qd, qd_dot, q, v, force, e, r1, lam, state[0], motion)
    st[_EXTRAS:_EXTRAS + 7] = P_hat


class MovingObjectAdaptiveController(mo.MovingObjectController):
    """Model-based adaptive control (2.27, 2.35) with the section 2.4 gains."""

    scheme = "moving_object_adaptive"
    PARAMETERS = mo.scheme_parameters([
        Param("Gamma", matrix(7, 15.0), "Adaptation gain Gamma of (2.35).", "spd", 7, bound=Bound.GAIN),
        Param("P_hat_0", [0.2, 0.01, 0.4, 0.4, 0.1, 0.2, 0.2],
              "Initial estimates P_hat(0) (2.4); true P = [0.6135 0.0045 0.30225 0.441 0.147 "
              "0.06 0.06] (docs/thesis.md).", "vector", 7, read_only=True, bound=Bound.MASS),
    ])
    extra_status_fields = mo.STATUS + ESTIMATE_FIELDS

    def __init__(self, values: dict):
        super().__init__(values)
        self.gains = np.zeros(GAINS.size)
        self.pack_gains()
        self.internal = np.concatenate([[0.0], np.asarray(self.values["P_hat_0"], dtype=float)])
        self._output = KernelOutput(self)

    def pack_gains(self) -> None:
        mo.pack_common(self.values, GAINS.view(self.gains, "common"))
        GAINS.view(self.gains, "Gamma")[...] = self.values["Gamma"]

    @property
    def estimates(self) -> np.ndarray:
        """P_hat (a copy)."""
        return self.internal[1:8].copy()

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        out = self._output.new()
        moving_object_adaptive_cycle(self.gains, self.internal, t, dt, q, v, force, out)
        return self._output.views(out)
