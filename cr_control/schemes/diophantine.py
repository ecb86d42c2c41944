"""Pole placement for the chapter-4 MRAC (4.62-4.66): the Diophantine equation (4.65)

    A_f P_r1 + b_3 P_s = P_o A_m,   P_r1 = p + r (monic, degree 1), deg P_s = 4

solved as a linear system in (r, s_4..s_0), then P_r = P_r1 B_f (4.64), P_t = P_o B_m / b_3
(4.66) and theta_f = [r_3 - o_3 .. r_0 - o_0, s_4 .. s_0, t_4 .. t_0] (4.69). Closed forms
(DESIGN.md; the printed r_2, r_1, r_0 are wrong): r = o_3 + 2 zeta omega - a_4,
r_3 = r + b_2/b_3, r_2 = (r b_2 + b_1)/b_3, r_1 = (r b_1 + b_0)/b_3, r_0 = r b_0/b_3.
Polynomials are coefficient arrays, highest power first (numpy.polymul order).
"""

from __future__ import annotations

import numpy as np


def reference_polynomials(zeta: float, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_m, B_m) of the reference model (4.62)."""
    return np.array([1.0, 2.0 * zeta * omega, omega ** 2]), np.array([omega ** 2])


def solve(theta, zeta: float, omega: float, observer) -> dict:
    """Controller polynomials for theta = [b3 b2 b1 b0 a4 a3 a2 a1 a0] and P_o = [1, o3..o0]."""
    theta = np.asarray(theta, dtype=float)
    b, a = theta[:4], theta[4:]
    b3 = b[0]
    A_f = np.concatenate([[1.0], a])                     # degree 5
    B_f = b / b3                                         # monic, degree 3
    P_o = np.asarray(observer, dtype=float)
    if P_o.shape != (5,) or P_o[0] != 1.0:
        raise ValueError("observer polynomial must be [1, o3, o2, o1, o0]")
    A_m, B_m = reference_polynomials(zeta, omega)
    rhs = np.polymul(P_o, A_m)                           # degree 6, monic
    # A_f (p + r) + b3 (s4 p^4 + ... + s0) = rhs: unknowns x = [r, s4, s3, s2, s1, s0]
    M = np.zeros((7, 6))
    M[1:, 0] = A_f                                       # r A_f: powers 5..0 -> rows 1..6
    for j in range(5):
        M[2 + j, 1 + j] = b3                             # s_{4-j} p^{4-j} -> row 6-(4-j)
    known = np.polymul(A_f, [1.0, 0.0])                  # p A_f
    x = np.linalg.solve(M[1:], (rhs - known)[1:])
    r, s = x[0], x[1:]
    P_r1 = np.array([1.0, r])
    P_r = np.polymul(P_r1, B_f)                          # monic degree 4
    P_s = s
    P_t = P_o * B_m[0] / b3
    theta_f = np.concatenate([P_r[1:] - P_o[1:], P_s, P_t])
    return {"r": r, "P_r1": P_r1, "P_r": P_r, "P_s": P_s, "P_t": P_t, "theta_f": theta_f,
            "A_f": A_f, "B_f": B_f, "A_m": A_m, "B_m": B_m, "P_o": P_o, "b3": b3}


def residual(sol: dict) -> np.ndarray:
    """Coefficients of A_f P_r1 + b_3 P_s - P_o A_m (zero when (4.65) holds identically)."""
    lhs = np.polyadd(np.polymul(sol["A_f"], sol["P_r1"]), sol["b3"] * sol["P_s"])
    return np.polysub(lhs, np.polymul(sol["P_o"], sol["A_m"]))


def closed_form(theta, zeta: float, omega: float, observer) -> np.ndarray:
    """theta_f from the corrected closed forms (DESIGN.md) and the printed s_i, t_i."""
    b3, b2, b1, b0, a4, a3, a2, a1, a0 = np.asarray(theta, dtype=float)
    _, o3, o2, o1, o0 = observer
    o = [o0, o1, o2, o3, 1.0]
    a = [a0, a1, a2, a3, a4]
    w2, zw2 = omega ** 2, 2.0 * zeta * omega
    r = o3 + zw2 - a4
    r_ = [r * b0 / b3, (r * b1 + b0) / b3, (r * b2 + b1) / b3, r + b2 / b3]     # r_0..r_3

    def oi(i):
        return o[i] if 0 <= i <= 4 else 0.0

    def ai(i):
        return a[i] if 0 <= i <= 4 else 0.0

    s = [(w2 * oi(i) + zw2 * oi(i - 1) + oi(i - 2) - ai(i - 1) - ai(i) * r) / b3 for i in range(4)]
    s4 = (w2 + zw2 * o3 + o2 - a3 - a4 * r) / b3
    t = [w2 / b3 * oi(i) for i in range(5)]
    return np.array([r_[3] - o3, r_[2] - o2, r_[1] - o1, r_[0] - o0, s4, s[3], s[2], s[1], s[0],
                     t[4], t[3], t[2], t[1], t[0]])
