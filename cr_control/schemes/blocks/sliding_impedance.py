"""What the robust (3.48) and the NN (3.76) adaptive impedance controllers share.

Both drive the sliding variable of a dynamic compensator to zero; on s = 0 the error
obeys the adaptively tuned impedance e'' + A_hat e' + B_hat e = c_hat (3.7, 3.46).

    z'    = D z + K_v e' + K_p e - K_c c_hat                      (3.40, sign: see below)
    K_v   = K_2^-1 (A_hat + K_2 D K_2^-1 - K_1)                   (3.43)
    K_p   = K_2^-1 B_hat + D K_2^-1 K_1                           (3.44)
    K_c   = K_2^-1                                                (3.45)
    s     = e' + K_1 e + K_2 z                                    (3.41)
    r_eq' = r_d' + K_1 e + K_2 z,  r_eq'' = r_d'' + K_1 e' + K_2 z'  (3.49, 3.50)
    u     = [M_r r_eq'' + C_r r_eq' + G_r]^ + K_s s + d sat(s/Delta) - f,  tau = J^T u
                                                                  (3.48, 3.76)

with A_hat, B_hat, c_hat from :class:`ImpedanceAdaptation` (3.11-3.14, with e'^T in the
A_hat law; docs/thesis.md). ``[...]^`` is the scheme's estimate of the arm's task-space
dynamics: a deliberately wrong model (3.48) or RBF networks (3.76).

Sign of D (docs/thesis.md, chapter 3). 3.40 prints
z' = -D z + ... with D "any negative definite matrix", which makes the compensator
unstable on its own (z' = +|D| z). Differentiating s (3.41) with z' = -D z + ... gives

    e'' + (A_hat + 2 K_2 D K_2^-1) e' + (B_hat + 2 K_2 D K_2^-1 K_1) e = c_hat + s' + K_2 D K_2^-1 s,

which is neither 3.42 nor, with the gains 3.43-3.45, the desired impedance 3.46: the
printed D sign does not reproduce the thesis's own algebra. With z' = +D z + ...
(D negative definite, so the compensator is stable) differentiating s gives exactly
3.42, and 3.43-3.45 give exactly 3.46: e'' + A_hat e' + B_hat e = c_hat + s' - K_2 D K_2^-1 s.
We therefore use z' = +D z + ... (:attr:`SlidingCompensator.D_SIGN` = +1). In closed loop
(robust scheme, 10 s, RMS |e| over 5-10 s): with the thesis D = -2 I both conventions
converge (14.2 mm ours, 12.0 mm printed) because 2 K_2 D K_2^-1 is small against A_hat,
B_hat; with d from bounds that hold and D = -10 I, -20 I ours gives 13.3, 14.1 mm
(insensitive to D, as theorem 3.3.1 says for any negative definite D), the printed sign
15.4 mm and divergence (|e| 457 mm at 3 s, B_hat - 80 < 0). NN scheme defaults (D = -5 I):
36.1 mm ours, 52.7 mm printed (A_hat - 10 < 0 at the start). Details and the algebraic
check: test/test_robust_schemes.py.

Boundary layer (remark 3.3.1): sgn(s) is replaced by s/Delta where |s| < Delta,
component by component (sgn(s) in 3.48 is the vector of the components' signs), i.e.
sat(s_i/Delta) = clip(s_i/Delta, -1, 1): continuous, and equal to sgn(s_i) outside.

Its width from the period and the delay. Inside the layer the switching term is d s / Delta,
and s = e' + K_1 e + K_2 z: a damping of d / Delta on each task axis. A damping loop of
apparent mass M, period T and a delay of D cycles, v_{k+1} = v_k - (c_d T / M) v_{k-D}, is
stable only for c_d T / M < c_max(D) = 2 sin(pi / (2 (2 D + 1))) (2, 1, 0.62, 0.45, 0.35 for
D = 0..4; the root locus of z^{D+1} - z^D + g crosses the unit circle there). So each
cycle the layer is widened to at least

    Delta_min = d T / (mu c_max(D) M_min),     mu = BOUNDARY_LAYER_MARGIN (0.5)

with M_min the task's smallest apparent mass (the smallest eigenvalue of Lambda at the
measured pose), T the cycle's step and D ``command_delay_cycles`` (the driver's delay the
controller is told; DEFAULT_DELAY_CYCLES where it is not): the switching term then takes at
most half of the damping the delayed loop tolerates, the rest left to K_s s and the
impedance. The widened layer is in the status (``boundary_layer``). On the robots' wiping
task it does not bind at the profiles' delay (the Panda: d = 5.1 N, M_min ~ 2.5 kg, T = 1 ms,
D = 1: Delta_min = 4 mm/s against the 50 mm/s given); it does as d grows (3.51: with the
model's acceleration error) or the delay does, where a fixed layer turned the switching
term into an unstable damping; on the thesis's arm it never binds, so those runs are as
printed.

Discretisation: z is integrated by explicit Euler with the dt of each cycle, z(0) = 0.
Every matrix is m x m on an m-axis position task (2 on the thesis's arm, 3 on a spatial one).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.linalg import matmul, matvec, min_eigenvalue_sym, spd_inverse
from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, matrix

#: The switching term's share of the damping a delayed loop tolerates (module docstring).
BOUNDARY_LAYER_MARGIN = 0.5
#: The delay (cycles) the layer is sized for where the controller is not told one: a
#: driver applies an answer in its next cycle at the earliest (libfranka, ur_robot_driver).
DEFAULT_DELAY_CYCLES = 1


def delayed_damping_bound(delay_cycles: int) -> float:
    """c_max(D) = 2 sin(pi / (2 (2 D + 1))): the largest stable c_d T / M of a damping loop
    with a delay of D cycles (module docstring)."""
    return 2.0 * math.sin(math.pi / (2.0 * (2 * max(0, int(delay_cycles)) + 1)))


def layer_rate(delay_cycles: int) -> float:
    """1 / (mu c_max(D)): Delta_min = d T layer_rate / M_min (module docstring)."""
    return 1.0 / (BOUNDARY_LAYER_MARGIN * delayed_damping_bound(delay_cycles))


def sliding_status_fields(axes: tuple[str, ...]) -> list[str]:
    """Status fields of the sliding-mode part: s and z per axis, d, then the boundary layer
    in use (Delta, widened by the period and the delay: module docstring)."""
    return [f"s_{a}" for a in axes] + [f"z_{a}" for a in axes] + ["d", "boundary_layer"]


def sliding_parameters(m: int, D: float, K: float, K_s: float,
                       boundary_layer: float) -> list[Param]:
    """Parameters of the compensator (3.40), sliding surface (3.41) and K_s, Delta (3.48)."""
    return [
        Param("D", matrix(m, D), "Compensator matrix D of z' = D z + ... (3.40), negative "
              "definite (sign convention: module docstring).", "nd", m, bound=Bound.GAIN),
        Param("K_1", matrix(m, K), "K_1 of s = e' + K_1 e + K_2 z (3.41), positive definite.",
              "spd", m, bound=Bound.GAIN),
        Param("K_2", matrix(m, K), "K_2 of s = e' + K_1 e + K_2 z (3.41), positive definite.",
              "spd", m, bound=Bound.GAIN),
        Param("K_s", matrix(m, K_s), "Sliding-surface feedback gain K_s (3.48, 3.76).", "spd", m,
              bound=Bound.GAIN),
        Param("boundary_layer", boundary_layer, "Boundary layer Delta: sgn(s_i) is replaced by "
              "s_i/Delta where |s_i| < Delta (remark 3.3.1) (m/s); widened each cycle to at "
              "least d T / (0.5 c_max(delay) M_min), so the switching term takes at most half "
              "the damping the delayed loop tolerates (status boundary_layer).", "positive",
              bound=Bound.SCALE),
    ]


def sliding_gains(m: int) -> Layout:
    """Packed sliding gains (names = parameter names; d_sign = SlidingCompensator.D_SIGN;
    layer_rate: :func:`layer_rate` of the delay)."""
    return Layout(D=(m, m), K_1=(m, m), K_2=(m, m), K_s=(m, m), boundary_layer=1, d_sign=1,
                  layer_rate=1)


@njit(cache=True, error_model="numpy")
def boundary_layer_width(delta, rate, d, dt, Lam):
    """Delta, widened to d dt rate / M_min (M_min the smallest eigenvalue of the task's
    apparent mass ``Lam``; module docstring)."""
    mass = min_eigenvalue_sym(Lam)
    if not mass > 0.0 or not dt > 0.0:
        return delta
    return max(delta, d * dt * rate / mass)


@njit(cache=True, error_model="numpy")
def boundary_layer_sign(s, delta):
    """sgn(s) with the boundary layer of remark 3.3.1, per component: clip(s/Delta, -1, 1)."""
    out = np.empty(s.shape[0])
    for i in range(s.shape[0]):
        out[i] = min(1.0, max(-1.0, s[i] / delta))
    return out


@njit(cache=True, error_model="numpy")
def compensator_update(D, K_1, K_2, d_sign, z, z_dot, dt, e, e_dot, v_d, a_d, A_hat, B_hat,
                       c_hat):
    """Advance z by dt (Euler, with the z' of the last cycle), set z' (3.40) with the gains
    3.43-3.45 for the current estimates, and return s (3.41), r_eq' (3.49), r_eq'' (3.50)."""
    z += dt * z_dot
    K_c = spd_inverse(K_2)                                     # 3.45
    D_K2inv = matmul(D, K_c)
    K_v = matmul(K_c, A_hat + matmul(K_2, D_K2inv) - K_1)      # 3.43
    K_p = matmul(K_c, B_hat) + matmul(D_K2inv, K_1)            # 3.44
    z_dot[:] = (d_sign * matvec(D, z) + matvec(K_v, e_dot) + matvec(K_p, e)
                - matvec(K_c, c_hat))
    K1_e, K2_z = matvec(K_1, e), matvec(K_2, z)
    s = e_dot + K1_e + K2_z
    return s, v_d + K1_e + K2_z, a_d + matvec(K_1, e_dot) + matvec(K_2, z_dot)


@njit(cache=True, error_model="numpy")
def sliding_views(gains, m):
    """(D, K_1, K_2, K_s, Delta, d_sign, layer_rate) of a packed sliding_gains block."""
    mm = m * m
    return (gains[:mm].reshape((m, m)), gains[mm:2 * mm].reshape((m, m)),
            gains[2 * mm:3 * mm].reshape((m, m)), gains[3 * mm:4 * mm].reshape((m, m)),
            gains[4 * mm], gains[4 * mm + 1], gains[4 * mm + 2])


class SlidingCompensator:
    """Python entry point of :func:`compensator_update` (z, z' kept here)."""

    #: z' = D_SIGN * D z + ...: +1 is the convention 3.42-3.46 are derived with (the
    #: printed 3.40 corresponds to -1; module docstring). Read when the gains are packed.
    D_SIGN = 1.0

    def __init__(self, values: dict):
        self.values = values
        m = np.asarray(values["D"]).shape[0]
        self.z = np.zeros(m)
        self.z_dot = np.zeros(m)

    def update(self, dt, e, e_dot, v_d, a_d, adaptation):
        """s, r_eq', r_eq'' after advancing by dt (see :func:`compensator_update`)."""
        v = self.values
        return compensator_update(v["D"], v["K_1"], v["K_2"], self.D_SIGN, self.z, self.z_dot,
                                  dt, e, e_dot, v_d, a_d, adaptation.A_hat, adaptation.B_hat,
                                  adaptation.c_hat)
