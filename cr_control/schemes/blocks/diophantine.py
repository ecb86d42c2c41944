"""Pole placement for the chapter-4 MRAC (4.62-4.66): the Diophantine equation (4.65)

    A_f P_r1 + b_3 P_s = P_o A_m,   P_r1 = p + r (monic, degree 1), deg P_s = 4

solved exactly as a triangular linear system in (r, s_4..s_0), then P_r = P_r1 B_f (4.64),
P_t = P_o B_m / b_3 (4.66) and theta_f = [r_3 - o_3 .. r_0 - o_0, s_4 .. s_0, t_4 .. t_0]
(4.69). Closed forms (docs/thesis.md; the printed r_2, r_1, r_0 are wrong): r = o_3 + 2 zeta omega - a_4,
r_3 = r + b_2/b_3, r_2 = (r b_2 + b_1)/b_3, r_1 = (r b_1 + b_0)/b_3, r_0 = r b_0/b_3.
Polynomials are coefficient arrays, highest power first (numpy.polymul order).
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np


def _reference_coefficients(zeta, omega) -> tuple[list, list]:
    """(A_m, B_m) of the reference model (4.62) as coefficient lists, in the arithmetic of
    the arguments (floats, or Fractions for the exact solve)."""
    return [1, 2 * zeta * omega, omega ** 2], [omega ** 2]


def reference_polynomials(zeta: float, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_m, B_m) of the reference model (4.62)."""
    A_m, B_m = _reference_coefficients(float(zeta), float(omega))
    return np.array(A_m, dtype=float), np.array(B_m, dtype=float)


def _polymul(p: list, q: list) -> list:
    """Product of two coefficient lists (highest power first)."""
    out = [0] * (len(p) + len(q) - 1)
    for i, pi in enumerate(p):
        for j, qj in enumerate(q):
            out[i + j] += pi * qj
    return out


def solve(theta, zeta: float, omega: float, observer) -> dict:
    """Controller polynomials for theta = [b3 b2 b1 b0 a4 a3 a2 a1 a0] and P_o = [1, o3..o0].

    Solved in exact rational arithmetic and rounded once: the result (the shipped
    ``theta_f_hat_0`` default among others) is the same on every machine, where a LAPACK
    solve's last bits follow the CPU's BLAS kernel.
    """
    theta = [Fraction(float(x)) for x in theta]
    P_o = [Fraction(float(x)) for x in observer]
    if len(P_o) != 5 or P_o[0] != 1:
        raise ValueError("observer polynomial must be [1, o3, o2, o1, o0]")
    b, a = theta[:4], theta[4:]
    b3 = b[0]
    A_f = [Fraction(1), *a]                              # degree 5
    B_f = [x / b3 for x in b]                            # monic, degree 3
    zeta, omega = Fraction(float(zeta)), Fraction(float(omega))
    A_m, B_m = _reference_coefficients(zeta, omega)
    rhs = _polymul(P_o, A_m)                             # degree 6, monic
    # A_f (p + r) + b3 (s4 p^4 + ... + s0) = rhs, powers 5..0. Unknowns [r, s4, .., s0]:
    # the power-5 row gives r (A_f is monic), power 4-j gives s_{4-j} (lower triangular).
    d = [rhs[k] - (A_f[k] if k < 6 else 0) for k in range(1, 7)]   # rhs - p A_f
    r = d[0]
    s = [(d[1 + j] - r * A_f[1 + j]) / b3 for j in range(5)]
    P_r1 = [Fraction(1), r]
    P_r = _polymul(P_r1, B_f)                            # monic degree 4
    P_t = [x * B_m[0] / b3 for x in P_o]
    theta_f = [x - y for x, y in zip(P_r[1:], P_o[1:], strict=True)] + s + P_t

    def arr(x):
        return np.array([float(v) for v in x])

    return {"r": float(r), "P_r1": arr(P_r1), "P_r": arr(P_r), "P_s": arr(s), "P_t": arr(P_t),
            "theta_f": arr(theta_f), "A_f": arr(A_f), "B_f": arr(B_f), "A_m": arr(A_m),
            "B_m": arr(B_m), "P_o": arr(P_o), "b3": float(b3)}


def residual(sol: dict) -> np.ndarray:
    """Coefficients of A_f P_r1 + b_3 P_s - P_o A_m (zero when (4.65) holds identically)."""
    lhs = np.polyadd(np.polymul(sol["A_f"], sol["P_r1"]), sol["b3"] * sol["P_s"])
    return np.polysub(lhs, np.polymul(sol["P_o"], sol["A_m"]))


def closed_form(theta, zeta: float, omega: float, observer) -> np.ndarray:
    """theta_f from the corrected closed forms (module docstring) and the printed s_i, t_i (in the
    arithmetic of the arguments: floats, or Fractions for the exact values)."""
    b3, b2, b1, b0, a4, a3, a2, a1, a0 = theta
    _, o3, o2, o1, o0 = observer
    o = [o0, o1, o2, o3, 1]
    a = [a0, a1, a2, a3, a4]
    w2, zw2 = omega ** 2, 2 * zeta * omega
    r = o3 + zw2 - a4
    r_ = [r * b0 / b3, (r * b1 + b0) / b3, (r * b2 + b1) / b3, r + b2 / b3]     # r_0..r_3

    def oi(i):
        return o[i] if 0 <= i <= 4 else 0

    def ai(i):
        return a[i] if 0 <= i <= 4 else 0

    s = [(w2 * oi(i) + zw2 * oi(i - 1) + oi(i - 2) - ai(i - 1) - ai(i) * r) / b3 for i in range(4)]
    s4 = (w2 + zw2 * o3 + o2 - a3 - a4 * r) / b3
    t = [w2 / b3 * oi(i) for i in range(5)]
    return np.array([r_[3] - o3, r_[2] - o2, r_[1] - o1, r_[0] - o0, s4, s[3], s[2], s[1], s[0],
                     t[4], t[3], t[2], t[1], t[0]])
