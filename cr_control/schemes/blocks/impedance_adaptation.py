"""Adaptive impedance: the reference model (3.8) and the estimate laws (3.11-3.14).

The desired impedance e'' + A e' + B e = c (3.5), e = r_d - r, has unknown A, B, c.
Their estimates follow the reference model e_m'' + A_m e_m' + B_m e_m = 0 (3.8):

    varpi = P1^T xi + P2^T xi',  xi = e - e_m                            (3.14)
    c_hat = c_hat(0) - Q_c int(varpi) - Q_c* varpi                      (3.11)
    A_hat = A_hat(0) + Q_a int(varpi e'^T) + Q_a* varpi e'^T            (3.12)
    B_hat = B_hat(0) + Q_b int(varpi e^T)  + Q_b* varpi e^T             (3.13)

Shared by every impedance scheme (3.32, 3.48 with e'^T in the A_hat law as 3.12 and 3.64,
DESIGN.md; 3.76). P1, P2 are parameters with the printed defaults: they do not solve the
Lyapunov equation (3.16) for any stated Q (DESIGN.md). The reference model starts at the
measured error (e_m(0) = e(0), e_m'(0) = e'(0)), so xi(0) = 0, and is advanced by one
classical RK4 step per cycle (exact to O(dt^5) for this linear system). The integrals use
the rectangle rule with the dt of each cycle.

Compiled: :func:`impedance_update` works on the packed gains (:data:`GAINS`) and internal
state (:data:`STATE`) of :mod:`cr_control.core.packing`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.linalg import matvec, tmatvec
from cr_control.core.packing import Layout, block, block2
from cr_control.core.parameters import Param, matrix

ESTIMATE_FIELDS = [
    "A_hat_11", "A_hat_12", "A_hat_21", "A_hat_22",
    "B_hat_11", "B_hat_12", "B_hat_21", "B_hat_22",
    "c_hat_x", "c_hat_y",
    "varpi_x", "varpi_y",
]

GAINS = Layout(A_m=(2, 2), B_m=(2, 2), P1=(2, 2), P2=(2, 2), A_hat_0=(2, 2), B_hat_0=(2, 2),
               c_hat_0=2, Q_a=(2, 2), Q_b=(2, 2), Q_c=(2, 2), Q_a_star=(2, 2),
               Q_b_star=(2, 2), Q_c_star=(2, 2))
#: x_m = [e_m, e_m'] (3.8); started: 0 until the first cycle sets x_m; integrals of varpi,
#: varpi e'^T, varpi e^T (columns); A_hat, B_hat, c_hat (the ESTIMATE_FIELDS, with varpi).
STATE = Layout(x_m=4, started=1, integrals=(2, 5), A_hat=(2, 2), B_hat=(2, 2), c_hat=2,
               varpi=2)

_A_M, _B_M, _P1, _P2 = (GAINS.offset(n) for n in ("A_m", "B_m", "P1", "P2"))
_A0, _B0, _C0 = (GAINS.offset(n) for n in ("A_hat_0", "B_hat_0", "c_hat_0"))
_QA, _QB, _QC = (GAINS.offset(n) for n in ("Q_a", "Q_b", "Q_c"))
_QA_S, _QB_S, _QC_S = (GAINS.offset(n) for n in ("Q_a_star", "Q_b_star", "Q_c_star"))
_XM, _STARTED, _INT = STATE.offset("x_m"), STATE.offset("started"), STATE.offset("integrals")
_AH, _BH, _CH, _VARPI = (STATE.offset(n) for n in ("A_hat", "B_hat", "c_hat", "varpi"))
#: Where the ESTIMATE_FIELDS values lie in STATE, in order (A_hat, B_hat, c_hat, varpi).
ESTIMATES = slice(_AH, _VARPI + 2)


def impedance_parameters(A_m: float, B_m: float, P1: float, P2: float, A0: float, B0: float,
                         c0: list[float], Q: float, Q_bc_star: float,
                         Q_a_star: float | None = None) -> list[Param]:
    """Parameters of the impedance adaptation (3.8, 3.11-3.14) with given thesis defaults."""
    Q_a_star = Q if Q_a_star is None else Q_a_star
    return [
        Param("A_m", matrix(2, A_m), "Reference model damping A_m (3.8), positive definite.",
              "spd", 2),
        Param("B_m", matrix(2, B_m), "Reference model stiffness B_m (3.8), positive definite.",
              "spd", 2),
        Param("P1", matrix(2, P1), "P1 of varpi = P1^T xi + P2^T xi' (3.14).", "matrix", 2),
        Param("P2", matrix(2, P2), "P2 of varpi = P1^T xi + P2^T xi' (3.14).", "matrix", 2),
        Param("A_hat_0", matrix(2, A0), "Initial impedance estimate A_hat(0) (3.12).", "matrix",
              2, read_only=True),
        Param("B_hat_0", matrix(2, B0), "Initial impedance estimate B_hat(0) (3.13).", "matrix",
              2, read_only=True),
        Param("c_hat_0", c0, "Initial impedance estimate c_hat(0) (3.11).", "vector", 2,
              read_only=True),
        Param("Q_a", matrix(2, Q), "Integral adaptation gain of A_hat (3.12).", "spd", 2),
        Param("Q_b", matrix(2, Q), "Integral adaptation gain of B_hat (3.13).", "spd", 2),
        Param("Q_c", matrix(2, Q), "Integral adaptation gain of c_hat (3.11).", "spd", 2),
        Param("Q_a_star", matrix(2, Q_a_star), "Proportional adaptation gain Q_a* (3.12).",
              "spd", 2),
        Param("Q_b_star", matrix(2, Q_bc_star), "Proportional adaptation gain Q_b* (3.13).",
              "spd", 2),
        Param("Q_c_star", matrix(2, Q_bc_star), "Proportional adaptation gain Q_c* (3.11).",
              "spd", 2),
    ]


def initial_state(values: dict) -> np.ndarray:
    """STATE at t = 0: the initial estimates, reference model not started."""
    state = np.zeros(STATE.size)
    STATE.view(state, "A_hat")[...] = values["A_hat_0"]
    STATE.view(state, "B_hat")[...] = values["B_hat_0"]
    STATE.view(state, "c_hat")[...] = values["c_hat_0"]
    return state


@njit(cache=True, error_model="numpy")
def _reference_model_step(A_m, B_m, x, dt):
    """One classical RK4 step of x' = F x, x = [e_m, e_m'], F = [[0, I], [-B_m, -A_m]] (3.8)."""
    def f(x):
        out = np.empty(4)
        out[0], out[1] = x[2], x[3]
        out[2] = -(B_m[0, 0] * x[0] + B_m[0, 1] * x[1] + A_m[0, 0] * x[2] + A_m[0, 1] * x[3])
        out[3] = -(B_m[1, 0] * x[0] + B_m[1, 1] * x[1] + A_m[1, 0] * x[2] + A_m[1, 1] * x[3])
        return out
    k1 = f(x)
    k2 = f(x + (0.5 * dt) * k1)
    k3 = f(x + (0.5 * dt) * k2)
    k4 = f(x + dt * k3)
    return x + (dt / 6.0) * (k1 + k4 + 2.0 * (k2 + k3))


@njit(cache=True, error_model="numpy")
def impedance_update(gains, state, e, e_dot, dt):
    """Advance the reference model and the integrals by dt and set A_hat, B_hat, c_hat, varpi
    in ``state`` for the measured e, e' (3.8, 3.11-3.14)."""
    x_m = block(state, _XM, 4)
    if state[_STARTED] == 0.0:
        x_m[0], x_m[1], x_m[2], x_m[3] = e[0], e[1], e_dot[0], e_dot[1]
        state[_STARTED] = 1.0
    elif dt > 0.0:
        x_m[:] = _reference_model_step(block2(gains, _A_M), block2(gains, _B_M), x_m, dt)
    xi = e - x_m[:2]
    xi_dot = e_dot - x_m[2:]
    varpi = tmatvec(block2(gains, _P1), xi) + tmatvec(block2(gains, _P2), xi_dot)
    integrals = state[_INT:_INT + 10].reshape((2, 5))
    # products [varpi, varpi e'^T, varpi e^T]
    products = np.empty((2, 5))
    for i in range(2):
        products[i, 0] = varpi[i]
        products[i, 1], products[i, 2] = varpi[i] * e_dot[0], varpi[i] * e_dot[1]
        products[i, 3], products[i, 4] = varpi[i] * e[0], varpi[i] * e[1]
        for j in range(5):
            integrals[i, j] += products[i, j] * dt
    c_hat = block(state, _CH, 2)
    c_hat[:] = (block(gains, _C0, 2) - matvec(block2(gains, _QC), integrals[:, 0])
                - matvec(block2(gains, _QC_S), varpi))
    A_hat, B_hat = block2(state, _AH), block2(state, _BH)
    Q_a, Q_b = block2(gains, _QA), block2(gains, _QB)
    Q_a_s, Q_b_s = block2(gains, _QA_S), block2(gains, _QB_S)
    A_0, B_0 = block2(gains, _A0), block2(gains, _B0)
    for i in range(2):
        for j in range(2):
            A_hat[i, j] = A_0[i, j] + (Q_a[i, 0] * integrals[0, 1 + j] + Q_a[i, 1] * integrals[1, 1 + j]
                                       + Q_a_s[i, 0] * products[0, 1 + j]
                                       + Q_a_s[i, 1] * products[1, 1 + j])
            B_hat[i, j] = B_0[i, j] + (Q_b[i, 0] * integrals[0, 3 + j] + Q_b[i, 1] * integrals[1, 3 + j]
                                       + Q_b_s[i, 0] * products[0, 3 + j]
                                       + Q_b_s[i, 1] * products[1, 3 + j])
    state[_VARPI], state[_VARPI + 1] = varpi[0], varpi[1]


@njit(cache=True, error_model="numpy")
def impedance_acceleration(state, e, e_dot):
    """A_hat e' + B_hat e - c_hat: the adaptive-impedance part of u_0 (3.6)."""
    return (matvec(block2(state, _AH), e_dot) + matvec(block2(state, _BH), e)
            - block(state, _CH, 2))


class ImpedanceAdaptation:
    """Python view of one impedance adaptation's packed state (for status, tests, users)."""

    def __init__(self, state: np.ndarray):
        self.state = state

    @property
    def A_hat(self) -> np.ndarray:
        return STATE.view(self.state, "A_hat")

    @property
    def B_hat(self) -> np.ndarray:
        return STATE.view(self.state, "B_hat")

    @property
    def c_hat(self) -> np.ndarray:
        return STATE.view(self.state, "c_hat")

    @property
    def varpi(self) -> np.ndarray:
        return STATE.view(self.state, "varpi")
