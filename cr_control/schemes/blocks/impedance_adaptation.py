"""Adaptive impedance: the reference model (3.8) and the estimate laws (3.11-3.14), m axes.

The desired impedance e'' + A e' + B e = c (3.5), e = r_d - r, has unknown A, B, c.
Their estimates follow the reference model e_m'' + A_m e_m' + B_m e_m = 0 (3.8):

    varpi = P1^T xi + P2^T xi',  xi = e - e_m                            (3.14)
    c_hat = c_hat(0) - Q_c int(varpi) - Q_c* varpi                      (3.11)
    A_hat = A_hat(0) + Q_a int(varpi e'^T) + Q_a* varpi e'^T            (3.12)
    B_hat = B_hat(0) + Q_b int(varpi e^T)  + Q_b* varpi e^T             (3.13)

Shared by every impedance scheme (3.32, 3.48 with e'^T in the A_hat law as 3.12 and 3.64,
docs/thesis.md; 3.76). P1, P2 are parameters with the printed defaults: they do not solve the
Lyapunov equation (3.16) for any stated Q (docs/thesis.md). The reference model starts at the
measured error (e_m(0) = e(0), e_m'(0) = e'(0)), so xi(0) = 0, and is advanced by one
classical RK4 step per cycle (exact to O(dt^5) for this linear system). The integrals use
the rectangle rule with the dt of each cycle.

Bounded c_hat (``c_hat_max``). The thesis bounds the true c = M_m^-1 (f_d + K_e (r_d -
r_e)) (3.5) by the boundedness of f_d, r_e and r_d (section 3.2, after 3.33), but (3.11)
bounds nothing: an error the law cannot remove (the tool held by an obstacle short of r_d,
the force admittance at its limit) integrates into c_hat without end, and M_r c_hat is
pressed against whatever holds the tool. With ``c_hat_max`` > 0 the integral part
c_I = c_hat(0) - Q_c int(varpi) is kept in the box |c_I,i| <= c_hat_max by projection: after
each step a component that left the box is put back on its face and int(varpi) is set to
match (int = Q_c^-1 (c_hat(0) - c_I), Q_c being positive definite). This is the parameter
projection of robust adaptive control (Ioannou and Sun, "Robust Adaptive Control",
Prentice Hall 1996, section 4.4 and chapter 8; Krstic, Kanellakopoulos and Kokotovic,
"Nonlinear and Adaptive Control Design", Wiley 1995, appendix E): clipping moves c_I
towards every point of the box (for a diagonal Q_c, as every default, also in the
Q_c^-1-weighted distance of the c term of (3.17)), so for a box that holds the c the task
needs the projection never makes that term grow, and the estimate is bounded whatever
happens. Inside the box nothing changes, bit for bit; 0 (the default on the thesis's arm)
= no box: (3.11) as printed. A_hat and B_hat are left as printed:
their integrands varpi e'^T and varpi e^T vanish with e' and grow only with e^2 while the
tool is held (at 1 cm, 6e-4 s^-2 per second with the section 3.5.1 gains).

The task has m position axes (2 on the thesis's planar arm, 3 on a spatial arm): every
matrix is m x m. Compiled: :func:`impedance_update` works on the packed gains
(:func:`gains_layout`: the twelve m x m matrices, then c_hat(0) and c_hat_max) and internal
state (:func:`state_layout`), whose offsets it computes from m.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.linalg import cholesky_into, cholesky_solve_into, matvec, tmatvec
from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, matrix

#: c_hat_max on any arm but the thesis's (m/s^2): above the 2.6 the robots' wiping task reaches
#: (the NN scheme; the others 0.5), ~25 N of M_r c_hat on the Panda (M_r 4.9 kg along the
#: table's normal at home) and ~18 N on the UR5 (3.5 kg).
C_HAT_MAX = 5.0

#: The m x m matrices of the packed gains, in order (c_hat_0 and c_hat_max follow them).
MATRICES = ("A_m", "B_m", "P1", "P2", "A_hat_0", "B_hat_0", "Q_a", "Q_b", "Q_c", "Q_a_star",
            "Q_b_star", "Q_c_star")


def gains_layout(m: int) -> Layout:
    """Packed impedance gains for m axes (names = parameter names)."""
    return Layout(**dict.fromkeys(MATRICES, (m, m)), c_hat_0=m, c_hat_max=1)


def state_layout(m: int) -> Layout:
    """x_m = [e_m, e_m'] (3.8); started: 0 until the first cycle sets x_m; integrals of
    varpi, varpi e'^T, varpi e^T (columns); A_hat, B_hat, c_hat, varpi."""
    return Layout(x_m=2 * m, started=1, integrals=(m, 1 + 2 * m), A_hat=(m, m), B_hat=(m, m),
                  c_hat=m, varpi=m)


def estimate_fields(axes: tuple[str, ...]) -> list[str]:
    """Status names of A_hat, B_hat (row-major, 1-based), c_hat and varpi per axis."""
    m = len(axes)
    pairs = [f"{i + 1}{j + 1}" for i in range(m) for j in range(m)]
    return ([f"A_hat_{p}" for p in pairs] + [f"B_hat_{p}" for p in pairs]
            + [f"c_hat_{a}" for a in axes] + [f"varpi_{a}" for a in axes])


def estimates_slice(m: int) -> slice:
    """Where the estimate_fields values (A_hat, B_hat, c_hat, varpi) lie in the state."""
    layout = state_layout(m)
    return slice(layout.offset("A_hat"), layout.size)


def impedance_parameters(m: int, A_m: float, B_m: float, P1: float, P2: float, A0: float,
                         B0: float, c0: list[float], Q: float, Q_bc_star: float,
                         Q_a_star: float | None = None, c_max: float = 0.0) -> list[Param]:
    """Parameters of the impedance adaptation (3.8, 3.11-3.14) on m axes, thesis defaults
    given by their diagonals; ``c_max`` the default of c_hat_max (0: none, the thesis)."""
    Q_a_star = Q if Q_a_star is None else Q_a_star
    return [
        Param("A_m", matrix(m, A_m), "Reference model damping A_m (3.8), positive definite.",
              "spd", m, bound=Bound.GAIN),
        Param("B_m", matrix(m, B_m), "Reference model stiffness B_m (3.8), positive definite.",
              "spd", m, bound=Bound.GAIN),
        Param("P1", matrix(m, P1), "P1 of varpi = P1^T xi + P2^T xi' (3.14).", "matrix", m, bound=Bound.GAIN),
        Param("P2", matrix(m, P2), "P2 of varpi = P1^T xi + P2^T xi' (3.14).", "matrix", m, bound=Bound.GAIN),
        Param("A_hat_0", matrix(m, A0), "Initial impedance estimate A_hat(0) (3.12).", "matrix",
              m, read_only=True, bound=Bound.GAIN),
        Param("B_hat_0", matrix(m, B0), "Initial impedance estimate B_hat(0) (3.13).", "matrix",
              m, read_only=True, bound=Bound.GAIN),
        Param("c_hat_0", c0, "Initial impedance estimate c_hat(0) (3.11).", "vector", m,
              read_only=True, bound=Bound.GAIN),
        Param("c_hat_max", c_max, "Box of c_hat's integral part c_hat(0) - Q_c int(varpi) "
              "(3.11), per axis (m/s^2): kept in it by projection, so an error the law cannot "
              "remove (the tool held short of r_d) does not wind c_hat up; M_r c_hat_max is the "
              "most it then adds to the force. 0 = no box (3.11 as printed, the thesis's runs); "
              f"{C_HAT_MAX:g} on any other arm (the robots' wiping task reaches 2.6 at most).",
              "nonnegative", bound=Bound.GAIN),
        Param("Q_a", matrix(m, Q), "Integral adaptation gain of A_hat (3.12).", "spd", m, bound=Bound.GAIN),
        Param("Q_b", matrix(m, Q), "Integral adaptation gain of B_hat (3.13).", "spd", m, bound=Bound.GAIN),
        Param("Q_c", matrix(m, Q), "Integral adaptation gain of c_hat (3.11).", "spd", m, bound=Bound.GAIN),
        Param("Q_a_star", matrix(m, Q_a_star), "Proportional adaptation gain Q_a* (3.12).",
              "spd", m, bound=Bound.GAIN),
        Param("Q_b_star", matrix(m, Q_bc_star), "Proportional adaptation gain Q_b* (3.13).",
              "spd", m, bound=Bound.GAIN),
        Param("Q_c_star", matrix(m, Q_bc_star), "Proportional adaptation gain Q_c* (3.11).",
              "spd", m, bound=Bound.GAIN),
    ]


def initial_state(values: dict, m: int) -> np.ndarray:
    """The state at t = 0: the initial estimates, reference model not started."""
    layout = state_layout(m)
    state = np.zeros(layout.size)
    layout.view(state, "A_hat")[...] = values["A_hat_0"]
    layout.view(state, "B_hat")[...] = values["B_hat_0"]
    layout.view(state, "c_hat")[...] = values["c_hat_0"]
    return state


@njit(cache=True, error_model="numpy", inline="always")
def _mat(vector, k, m):
    """The k-th m x m matrix of a packed gains vector (a view)."""
    return vector[k * m * m:(k + 1) * m * m].reshape((m, m))


@njit(cache=True, error_model="numpy")
def _reference_model_step(A_m, B_m, x, dt):
    """One classical RK4 step of x' = F x, x = [e_m, e_m'], F = [[0, I], [-B_m, -A_m]] (3.8)."""
    m = A_m.shape[0]

    def f(x):
        out = np.empty(2 * m)
        for i in range(m):
            out[i] = x[m + i]
            s = 0.0
            for j in range(m):
                s += B_m[i, j] * x[j]
            for j in range(m):
                s += A_m[i, j] * x[m + j]
            out[m + i] = -s
        return out
    k1 = f(x)
    k2 = f(x + (0.5 * dt) * k1)
    k3 = f(x + (0.5 * dt) * k2)
    k4 = f(x + dt * k3)
    return x + (dt / 6.0) * (k1 + k4 + 2.0 * (k2 + k3))


@njit(cache=True, error_model="numpy")
def state_views(state, m):
    """(x_m, integrals, A_hat, B_hat, c_hat, varpi) views of a packed impedance state."""
    mm = m * m
    s_int = 2 * m + 1
    s_a = s_int + m * (1 + 2 * m)
    return (state[:2 * m], state[s_int:s_a].reshape((m, 1 + 2 * m)),
            state[s_a:s_a + mm].reshape((m, m)), state[s_a + mm:s_a + 2 * mm].reshape((m, m)),
            state[s_a + 2 * mm:s_a + 2 * mm + m], state[s_a + 2 * mm + m:s_a + 2 * mm + 2 * m])


@njit(cache=True, error_model="numpy")
def _project_c(Q_c, c_0, c_max, c_integral, integrals):
    """Put c_I = c_hat(0) - Q_c int(varpi) back into the box |c_I,i| <= c_max and int(varpi)
    (column 0 of ``integrals``) to match: int = Q_c^-1 (c_hat(0) - c_I) (module docstring)."""
    m = c_0.shape[0]
    for i in range(m):
        c_integral[i] = min(max(c_integral[i], -c_max), c_max)
    L = np.empty((m, m))
    if not cholesky_into(Q_c, L):
        return
    solution = np.empty(m)
    cholesky_solve_into(L, c_0 - c_integral, solution)
    integrals[:, 0] = solution


@njit(cache=True, error_model="numpy")
def impedance_update(gains, state, e, e_dot, dt):
    """Advance the reference model and the integrals by dt and set A_hat, B_hat, c_hat, varpi
    in ``state`` for the measured e, e' (3.8, 3.11-3.14)."""
    m = e.shape[0]
    x_m, integrals, A_hat, B_hat, c_hat, varpi = state_views(state, m)
    if state[2 * m] == 0.0:
        x_m[:m], x_m[m:] = e, e_dot
        state[2 * m] = 1.0
    elif dt > 0.0:
        x_m[:] = _reference_model_step(_mat(gains, 0, m), _mat(gains, 1, m), x_m, dt)
    xi = e - x_m[:m]
    xi_dot = e_dot - x_m[m:]
    varpi[:] = tmatvec(_mat(gains, 2, m), xi) + tmatvec(_mat(gains, 3, m), xi_dot)
    # products [varpi, varpi e'^T, varpi e^T]
    products = np.empty((m, 1 + 2 * m))
    for i in range(m):
        products[i, 0] = varpi[i]
        for j in range(m):
            products[i, 1 + j] = varpi[i] * e_dot[j]
            products[i, 1 + m + j] = varpi[i] * e[j]
        for j in range(1 + 2 * m):
            integrals[i, j] += products[i, j] * dt
    c_0, Q_c = gains[12 * m * m:12 * m * m + m], _mat(gains, 8, m)
    c_integral = c_0 - matvec(Q_c, integrals[:, 0])
    c_max = gains[12 * m * m + m]
    if c_max > 0.0 and np.max(np.abs(c_integral)) > c_max:
        _project_c(Q_c, c_0, c_max, c_integral, integrals)
    c_hat[:] = c_integral - matvec(_mat(gains, 11, m), varpi)
    A_0, B_0 = _mat(gains, 4, m), _mat(gains, 5, m)
    Q_a, Q_b, Q_a_s, Q_b_s = _mat(gains, 6, m), _mat(gains, 7, m), _mat(gains, 9, m), _mat(gains, 10, m)
    for i in range(m):
        for j in range(m):
            a = A_0[i, j]
            b = B_0[i, j]
            for k in range(m):
                a += Q_a[i, k] * integrals[k, 1 + j]
                b += Q_b[i, k] * integrals[k, 1 + m + j]
            for k in range(m):
                a += Q_a_s[i, k] * products[k, 1 + j]
                b += Q_b_s[i, k] * products[k, 1 + m + j]
            A_hat[i, j], B_hat[i, j] = a, b


@njit(cache=True, error_model="numpy")
def impedance_acceleration(state, e, e_dot):
    """A_hat e' + B_hat e - c_hat: the adaptive-impedance part of u_0 (3.6)."""
    _, _, A_hat, B_hat, c_hat, _ = state_views(state, e.shape[0])
    return matvec(A_hat, e_dot) + matvec(B_hat, e) - c_hat


class ImpedanceAdaptation:
    """Python view of one impedance adaptation's packed state (for status, tests, users)."""

    def __init__(self, state: np.ndarray, m: int):
        self.state = state
        self.layout = state_layout(m)

    @property
    def A_hat(self) -> np.ndarray:
        return self.layout.view(self.state, "A_hat")

    @property
    def B_hat(self) -> np.ndarray:
        return self.layout.view(self.state, "B_hat")

    @property
    def c_hat(self) -> np.ndarray:
        return self.layout.view(self.state, "c_hat")

    @property
    def varpi(self) -> np.ndarray:
        return self.layout.view(self.state, "varpi")
