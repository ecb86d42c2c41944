"""Model-reference adaptive force control (thesis 4.2.2, 4.62-4.77) on the dynamic constraint
of chapter 4: delta_c = -theta_f_hat^T (P_1 phi) (4.72) with the prediction-error laws
(4.75)-(4.77) and b_3 estimated.

Reference model f_m = omega^2/(p^2 + 2 zeta omega p + omega^2) f_d (4.62); P_1 = A_m, P_2 = P_o,
P_f = P_1 P_2 (4.68); phi = [p^3..1 / P_f delta_c, p^4..1 / P_f f, -p^4..-1 / P_f f_d] (4.70).
Each signal has one 6th-order filter 1/P_f in controllable canonical form (its states are
the derivatives of the filtered signal), so P_1 phi and (1/P_1) delta_c = (P_o/P_f) delta_c
come from the same states without differentiating anything:

    eps_p = e - b3_hat (phi^T theta_f_hat + delta_c/P_1),  e = f - f_m           (4.75)
    b3_hat' = gamma_f (phi^T theta_f_hat + delta_c/P_1) eps_p                     (4.76)
    theta_f_hat' = gamma_f phi eps_p                                               (4.77)

``normalised_gradient`` (default off: the thesis's plain gradient) divides both laws by
m^2 = 1 + phi^T phi + xi^2, xi = phi^T theta_f_hat + delta_c/P_1 (the normalised gradient of
Ioannou & Sun, sec. 4.3.4; the regressor of the bilinear model is [phi; xi]):

    theta_f_hat' = gamma_f phi eps_p / m^2,   b3_hat' = gamma_f xi eps_p / m^2

Defaults (section 4.3): zeta = 0.7, omega = 0.5, P_o = p^4 + 19p^3 + 65p^2 + 77p + 30,
gamma_f = 0.8, initial estimates 0.65 x the true theta_f and 0.65 x b_3 of case 1. The
printed true theta_f is wrong in r_2..r_0 and the s_i (docs/thesis.md): the defaults use the
solution of (4.65) at the true case-1 theta (:mod:`cr_control.schemes.blocks.diophantine`).
The filters start at rest (zero) unless ``bumpless_start`` (steady state for the first
measured f, f_d and delta_c = delta(0)); the reference model starts at the first measured f.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param
from cr_control.core.topics import REFERENCE_FIELDS, STATUS_FIELDS
from cr_control.schemes.blocks import diophantine
from cr_control.schemes.controller import (
    Controller,
    ControlOutput,
    KernelOutput,
    field_at,
    split_output,
)
from cr_control.schemes.force.backstepping_force import _JOINTS, TRUE_THETA

#: True theta_f (4.69) of case 1 for the section 4.3 design (the corrected solution).
TRUE_THETA_F_CASE1 = diophantine.solve(TRUE_THETA[1], 0.7, 0.5, [1.0, 19.0, 65.0, 77.0, 30.0])["theta_f"]
THETA_F_NAMES = (["r3p", "r2p", "r1p", "r0p"] + [f"s{i}" for i in range(4, -1, -1)]
                 + [f"t{i}" for i in range(4, -1, -1)])

PARAMETERS = [
    Param("f_d", 1.0, "Desired constraint force f_d (N) (section 4.3: 1 N).", "finite", bound=Bound.FORCE),
    Param("zeta", 0.7, "Damping ratio of the reference model (4.62).", "positive", read_only=True,
          bound=Bound.SCALE),
    Param("omega", 0.5, "Natural frequency of the reference model (4.62) (rad/s).", "positive",
          read_only=True, bound=Bound.BANDWIDTH),
    Param("observer_polynomial", [19.0, 65.0, 77.0, 30.0],
          "Observer polynomial P_o = p^4 + o3 p^3 + o2 p^2 + o1 p + o0: [o3, o2, o1, o0] "
          "(Hurwitz, faster than A_m).", "vector", 4, read_only=True, bound=Bound.POLYNOMIAL),
    Param("gamma_f", 0.8, "Adaptation gain gamma_f of (4.76)-(4.77); 0 stops adaptation.",
          "nonnegative", bound=Bound.GAIN),
    Param("normalised_gradient", False, "Divide the adaptive laws (4.76)-(4.77) by "
          "m^2 = 1 + phi^T phi + xi^2 (a normalised gradient; off: the thesis's plain "
          "gradient).", "bool"),
    Param("theta_f_hat_0", [0.65 * x for x in TRUE_THETA_F_CASE1],
          "Initial theta_f_hat = [r3' r2' r1' r0' s4..s0 t4..t0] (thesis: 0.65 x the true "
          "theta_f of case 1, corrected).", "vector", 14, read_only=True, bound=Bound.POLYNOMIAL),
    Param("b3_hat_0", 0.65 * TRUE_THETA[1][0], "Initial b_3 estimate (thesis: 0.65 x b_3).",
          "finite", read_only=True, bound=Bound.POLYNOMIAL),
    Param("bumpless_start", False, "Start the filters at their steady state for the first "
          "measured force, f_d and delta_c = delta(0) instead of at zero.", "bool", read_only=True),
]

STATUS_EXTRA = ["f_m", "e", "eps_p", "b3_hat", *[f"{x}_hat" for x in THETA_F_NAMES]]

#: The internal state: the filters x / P_f of f_d, f and delta_c (6 each), the filtered
#: force f_m and its rate, theta_f_hat and b3_hat, the previous delta_c and f, the estimates'
#: rates, started (0/1).
STATE = Layout(w_d=6, w_f=6, w_r=6, f_m=2, theta_f_hat=14, b3_hat=1, u_prev=1, f_prev=1,
               theta_f_hat_dot=14, b3_hat_dot=1, started=1)
_WD, _WF, _WR, _FM, _TH, _B3, _UPREV, _FPREV, _THD, _B3D, _STARTED = (
    STATE.offset(name) for name in STATE.shapes)
STATE_SIZE = STATE.size
#: The packed gains: P_f's coefficients below the leading 1 (lowest first), A_m's
#: 2 zeta omega and omega^2, the observer polynomial, gamma_f, f_d, bumpless_start,
#: normalised_gradient.
GAINS = Layout(P_f=6, two_zeta_omega=1, omega_2=1, observer=4, gamma_f=1, f_d=1, bumpless=1,
               normalised=1)
_PF, _ZW2, _W2, _O, _GF, _FD, _BUMP, _NORM = (GAINS.offset(name) for name in GAINS.shapes)
GAINS_SIZE = GAINS.size
_F_D = field_at(REFERENCE_FIELDS, "f_d_x")
_R, _V, _F, _F_ERR, _TAU = (field_at(STATUS_FIELDS, name) for name in (
    "r_x", "v_x", "f_x", "f_err_x", "tau_1"))
_X_FM, _X_E, _X_EPS, _X_B3, _X_THETA = (STATUS_EXTRA.index(name) for name in (
    "f_m", "e", "eps_p", "b3_hat", f"{THETA_F_NAMES[0]}_hat"))


@njit(cache=True)
def _ccf_derivative(w, pf, x, out):
    for k in range(5):
        out[k] = w[k + 1]
    s = x
    for k in range(6):
        s -= pf[k] * w[k]
    out[5] = s


@njit(cache=True)
def _ccf_rk4(w, pf, x0, x1, dt, work):
    """1/P_f filter states (w, w', ..., w^(5)), input linear from x0 to x1: one RK4 step."""
    k1, k2, k3, k4, ws = work[0], work[1], work[2], work[3], work[4]
    xm = 0.5 * (x0 + x1)
    _ccf_derivative(w, pf, x0, k1)
    for i in range(6):
        ws[i] = w[i] + 0.5 * dt * k1[i]
    _ccf_derivative(ws, pf, xm, k2)
    for i in range(6):
        ws[i] = w[i] + 0.5 * dt * k2[i]
    _ccf_derivative(ws, pf, xm, k3)
    for i in range(6):
        ws[i] = w[i] + dt * k3[i]
    _ccf_derivative(ws, pf, x1, k4)
    for i in range(6):
        w[i] += dt / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])


@njit(cache=True)
def _deriv(w, pf, x, k):
    """k-th derivative (k <= 6) of the filtered signal w = x / P_f."""
    if k <= 5:
        return w[k]
    s = x
    for i in range(6):
        s -= pf[i] * w[i]
    return s


@njit(cache=True)
def _am(w, pf, x, k, zw2, w2):
    """A_m applied to the k-th derivative: (p^k A_m / P_f) x = (p^k / P_o) x."""
    return _deriv(w, pf, x, k + 2) + zw2 * _deriv(w, pf, x, k + 1) + w2 * _deriv(w, pf, x, k)


@njit(cache=True)
def mrac_cycle(g, state, q, v, force, dt, work, phi, p1phi, out, extras_at):
    """One cycle of (4.72), (4.75)-(4.77) into ``out``."""
    pf = g[_PF:_PF + 6]
    zw2, w2, gf, fd = g[_ZW2], g[_W2], g[_GF], g[_FD]
    f = force[0]
    wd, wf, wr = state[_WD:_WD + 6], state[_WF:_WF + 6], state[_WR:_WR + 6]
    th, th_dot = state[_TH:_TH + 14], state[_THD:_THD + 14]
    if state[_STARTED] == 0.0:
        state[_STARTED] = 1.0
        state[_FM], state[_FM + 1] = f, 0.0
        state[_UPREV], state[_FPREV] = q[0], f
        if g[_BUMP] != 0.0:
            wd[0], wf[0], wr[0] = q[0] / pf[0], f / pf[0], fd / pf[0]
    elif dt > 0.0:
        _ccf_rk4(wd, pf, state[_UPREV], state[_UPREV], dt, work)
        _ccf_rk4(wf, pf, state[_FPREV], f, dt, work)
        _ccf_rk4(wr, pf, fd, fd, dt, work)
        # reference model: f_m'' = w2 (f_d - f_m) - zw2 f_m', RK4 with constant f_d
        x0, x1 = state[_FM], state[_FM + 1]
        a1, b1 = x1, w2 * (fd - x0) - zw2 * x1
        a2, b2 = x1 + 0.5 * dt * b1, w2 * (fd - (x0 + 0.5 * dt * a1)) - zw2 * (x1 + 0.5 * dt * b1)
        a3, b3 = x1 + 0.5 * dt * b2, w2 * (fd - (x0 + 0.5 * dt * a2)) - zw2 * (x1 + 0.5 * dt * b2)
        a4, b4 = x1 + dt * b3, w2 * (fd - (x0 + dt * a3)) - zw2 * (x1 + dt * b3)
        state[_FM] = x0 + dt / 6.0 * (a1 + 2.0 * (a2 + a3) + a4)
        state[_FM + 1] = x1 + dt / 6.0 * (b1 + 2.0 * (b2 + b3) + b4)
        for j in range(14):
            th[j] += dt * th_dot[j]
        state[_B3] += dt * state[_B3D]
    for j in range(4):                                   # p^3..1 / P_f delta_c
        phi[j] = wd[3 - j]
        p1phi[j] = _am(wd, pf, 0.0, 3 - j, zw2, w2)
    for j in range(5):                                   # p^4..1 / P_f f and -(...) f_d
        phi[4 + j] = wf[4 - j]
        p1phi[4 + j] = _am(wf, pf, f, 4 - j, zw2, w2)
        phi[9 + j] = -wr[4 - j]
        p1phi[9 + j] = -_am(wr, pf, fd, 4 - j, zw2, w2)
    delta_c = 0.0
    s = 0.0
    for j in range(14):
        delta_c -= th[j] * p1phi[j]
        s += phi[j] * th[j]
    o = g[_O:_O + 4]
    s += wd[4] + o[0] * wd[3] + o[1] * wd[2] + o[2] * wd[1] + o[3] * wd[0]   # delta_c / P_1
    e = f - state[_FM]
    eps = e - state[_B3] * s
    rate = gf
    if g[_NORM] != 0.0:                                  # m^2 = 1 + phi^T phi + xi^2
        m2 = 1.0 + s * s
        for j in range(14):
            m2 += phi[j] * phi[j]
        rate = gf / m2
    state[_B3D] = rate * s * eps
    for j in range(14):
        th_dot[j] = rate * phi[j] * eps
    state[_UPREV], state[_FPREV] = delta_c, f
    command, reference, status = split_output(out, 1)
    command[0] = delta_c
    reference[:] = 0.0
    reference[_F_D] = fd
    status[:] = 0.0
    status[_R], status[_V], status[_F] = q[0], v[0], f
    status[_F_ERR] = fd - f
    status[_TAU] = delta_c
    status[extras_at + _X_FM], status[extras_at + _X_E] = state[_FM], e
    status[extras_at + _X_EPS] = eps
    status[extras_at + _X_B3] = state[_B3]
    for j in range(14):
        status[extras_at + _X_THETA + j] = th[j]


class MRACForceController(Controller):
    """MRAC force control (4.72, 4.76-4.77), delta_c commanded."""

    scheme = "mrac_force"
    command_interface = "position"
    PARAMETERS = PARAMETERS
    extra_status_fields = STATUS_EXTRA

    JOINT_NAMES_PARAMETER = _JOINTS

    def __init__(self, values: dict):
        super().__init__(values)
        self.gains = np.zeros(GAINS_SIZE)
        self.pack_gains()
        self.internal = np.zeros(STATE_SIZE)
        self.internal[_TH:_TH + 14] = self.values["theta_f_hat_0"]
        self.internal[_B3] = self.values["b3_hat_0"]
        self._work = np.zeros((5, 6))
        self._phi, self._p1phi = np.zeros(14), np.zeros(14)
        self._output = KernelOutput(self)
        self._extras_at = self._output.extras_at

    def pack_gains(self) -> None:
        v = self.values
        A_m, _ = diophantine.reference_polynomials(v["zeta"], v["omega"])
        P_f = np.polymul(A_m, np.concatenate([[1.0], v["observer_polynomial"]]))
        g = self.gains
        g[_PF:_PF + 6] = P_f[::-1][:6]
        g[_ZW2], g[_W2] = A_m[1], A_m[2]
        g[_O:_O + 4] = v["observer_polynomial"]
        g[_GF], g[_FD], g[_BUMP] = v["gamma_f"], v["f_d"], float(v["bumpless_start"])
        g[_NORM] = float(v["normalised_gradient"])

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        out = self._output.new()
        mrac_cycle(self.gains, self.internal, q, v, force, dt, self._work, self._phi,
                   self._p1phi, out, self._extras_at)
        return self._output.views(out)
