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
A_hat law, DESIGN.md). ``[...]^`` is the scheme's estimate of the arm's task-space
dynamics: a deliberately wrong model (3.48) or RBF networks (3.76).

Sign of D (DESIGN.md: "check the sign convention of D in 3.40"). 3.40 prints
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

Discretisation: z is integrated by explicit Euler with the dt of each cycle, z(0) = 0.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.linalg import inv2, matmul, matvec, tmatvec
from cr_control.core.packing import Layout, block, block2
from cr_control.core.parameters import Param, matrix
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.blocks.impedance_adaptation import ImpedanceAdaptation, impedance_update
from cr_control.schemes.blocks.references import REFERENCE, packed_reference
from cr_control.schemes.blocks.task_space import (
    ArmTaskSpace,
    task_state,
    write_task_space,
)
from cr_control.schemes.controller import Controller, KernelOutput

#: Status fields of the sliding-mode part, before the scheme's own and ESTIMATE_FIELDS.
SLIDING_STATUS_FIELDS = ["s_x", "s_y", "z_x", "z_y", "d"]


def sliding_parameters(D: float, K: float, K_s: float, boundary_layer: float) -> list[Param]:
    """Parameters of the compensator (3.40), sliding surface (3.41) and K_s, Delta (3.48)."""
    return [
        Param("D", matrix(2, D), "Compensator matrix D of z' = D z + ... (3.40), negative "
              "definite (sign convention: module docstring).", "nd", 2),
        Param("K_1", matrix(2, K), "K_1 of s = e' + K_1 e + K_2 z (3.41), positive definite.",
              "spd", 2),
        Param("K_2", matrix(2, K), "K_2 of s = e' + K_1 e + K_2 z (3.41), positive definite.",
              "spd", 2),
        Param("K_s", matrix(2, K_s), "Sliding-surface feedback gain K_s (3.48, 3.76).", "spd", 2),
        Param("boundary_layer", boundary_layer, "Boundary layer Delta: sgn(s_i) is replaced by "
              "s_i/Delta where |s_i| < Delta (remark 3.3.1) (m/s).", "positive"),
    ]


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
    K_c = inv2(K_2)                                            # 3.45
    D_K2inv = matmul(D, K_c)
    K_v = matmul(K_c, A_hat + matmul(K_2, D_K2inv) - K_1)      # 3.43
    K_p = matmul(K_c, B_hat) + matmul(D_K2inv, K_1)            # 3.44
    z_dot[:] = (d_sign * matvec(D, z) + matvec(K_v, e_dot) + matvec(K_p, e)
                - matvec(K_c, c_hat))
    K1_e, K2_z = matvec(K_1, e), matvec(K_2, z)
    s = e_dot + K1_e + K2_z
    return s, v_d + K1_e + K2_z, a_d + matvec(K_1, e_dot) + matvec(K_2, z_dot)


class SlidingCompensator:
    """Python entry point of :func:`compensator_update` (z, z' kept here)."""

    #: z' = D_SIGN * D z + ...: +1 is the convention 3.42-3.46 are derived with (the
    #: printed 3.40 corresponds to -1; module docstring). Read when the gains are packed.
    D_SIGN = 1.0

    def __init__(self, values: dict):
        self.values = values
        self.z = np.zeros(2)
        self.z_dot = np.zeros(2)

    def update(self, dt, e, e_dot, v_d, a_d, adaptation):
        """s, r_eq', r_eq'' after advancing by dt (see :func:`compensator_update`)."""
        v = self.values
        return compensator_update(v["D"], v["K_1"], v["K_2"], self.D_SIGN, self.z, self.z_dot,
                                  dt, e, e_dot, v_d, a_d, adaptation.A_hat, adaptation.B_hat,
                                  adaptation.c_hat)


#: Packed gains of the sliding part (names = parameter names; d_sign = D_SIGN).
SLIDING_GAINS = Layout(D=(2, 2), K_1=(2, 2), K_2=(2, 2), K_s=(2, 2), boundary_layer=1, d_sign=1)
#: Internal state of the compensator.
SLIDING_STATE = Layout(z=2, z_dot=2)
_D, _K1, _K2, _KS = (SLIDING_GAINS.offset(n) for n in ("D", "K_1", "K_2", "K_s"))
_DELTA, _DSIGN = SLIDING_GAINS.offset("boundary_layer"), SLIDING_GAINS.offset("d_sign")

#: Every sliding scheme's packed gains start with these blocks, its state with these.
_R = REFERENCE.size
_I = _R + impedance.GAINS.size
_S = _I + SLIDING_GAINS.size
_IS = impedance.STATE.size
_SS = _IS + SLIDING_STATE.size
_EST = impedance.ESTIMATES
_A_HAT, _B_HAT, _C_HAT = (impedance.STATE.offset(n) for n in ("A_hat", "B_hat", "c_hat"))
_N_EST = len(impedance.ESTIMATE_FIELDS)


@njit(cache=True, error_model="numpy")
def sliding_front(chain, gains, state, t, dt, q, v):
    """The part of (3.48, 3.76) before the model terms: reference, task state, impedance
    estimates, compensator. Returns (r_d, v_d, a_d, f_d, r, r', J, e, e', s, r_eq', r_eq'')."""
    r_d, v_d, a_d, f_d = packed_reference(gains[:_R], t)
    r, r_dot, J, J_inv, _ = task_state(chain, q, v)
    e, e_dot = r_d - r, v_d - r_dot
    impedance_state = state[:_IS]
    impedance_update(gains[_R:_I], impedance_state, e, e_dot, dt)
    sliding = gains[_I:_S]
    s, v_eq, a_eq = compensator_update(
        block2(sliding, _D), block2(sliding, _K1), block2(sliding, _K2), sliding[_DSIGN],
        state[_IS:_IS + 2], state[_IS + 2:_SS], dt, e, e_dot, v_d, a_d,
        block2(impedance_state, _A_HAT), block2(impedance_state, _B_HAT),
        block(impedance_state, _C_HAT, 2))
    return r_d, v_d, a_d, f_d, r, r_dot, J, J_inv, e, e_dot, s, v_eq, a_eq


@njit(cache=True, error_model="numpy")
def sliding_back(gains, state, force, model_terms, d, r_d, v_d, a_d, f_d, r, r_dot, J, e, s,
                 out, extras_at):
    """u = model_terms + K_s s + d sat(s/Delta) - f, tau = J^T u (3.48, 3.76) into ``out``
    with the sliding fields and the estimates of the status filled; returns the status."""
    sliding = gains[_I:_S]
    f = force[:2]
    u = (model_terms + matvec(block2(sliding, _KS), s)
         + d * boundary_layer_sign(s, sliding[_DELTA]) - f)
    tau = tmatvec(J, u)
    status = write_task_space(out, r_d, v_d, a_d, f_d, r, r_dot, f, e, tau)
    status[extras_at:extras_at + 2] = s
    status[extras_at + 2:extras_at + 4] = state[_IS:_IS + 2]
    status[extras_at + 4] = d
    status[status.shape[0] - _N_EST:] = state[_EST]
    return status


def sliding_gains_layout(scheme_gains: Layout) -> Layout:
    """A sliding scheme's packed gains: reference, impedance, sliding, then its own block."""
    return Layout(reference=_R, impedance=impedance.GAINS.size, sliding=SLIDING_GAINS.size,
                  scheme=scheme_gains.size)


class SlidingImpedanceController(Controller):
    """Shared set-up of the schemes tau = J^T (model terms + K_s s + d sat(s/Delta) - f)
    (3.48, 3.76): packed gains (reference, impedance, sliding, the scheme's ``SCHEME_GAINS``)
    and internal state (impedance, compensator, the scheme's ``scheme_state_size`` values).
    Status fields: topics.STATUS_FIELDS, SLIDING_STATUS_FIELDS, the scheme's own, then
    ESTIMATE_FIELDS."""

    SCHEME_GAINS = Layout()

    def __init__(self, values: dict, scheme_state: np.ndarray | None = None):
        super().__init__(values)
        self.task = ArmTaskSpace(self.values)
        self.GAINS = sliding_gains_layout(self.SCHEME_GAINS)
        self.gains = np.zeros(self.GAINS.size)
        self.pack_gains()
        extra = np.zeros(0) if scheme_state is None else scheme_state
        self.internal = np.concatenate([impedance.initial_state(self.values),
                                        np.zeros(SLIDING_STATE.size), extra])
        self.adaptation = ImpedanceAdaptation(self.internal[:_IS])
        self._output = KernelOutput(self)
        self._extras_at = self._output.extras_at

    @property
    def z(self) -> np.ndarray:
        """The compensator state z (3.40)."""
        return self.internal[_IS:_IS + 2]

    def pack_gains(self) -> None:
        """Copy the current parameter values into the packed gains the kernels read."""
        REFERENCE.pack(self.values, self.GAINS.view(self.gains, "reference"))
        impedance.GAINS.pack(self.values, self.GAINS.view(self.gains, "impedance"))
        SLIDING_GAINS.pack({**self.values, "d_sign": SlidingCompensator.D_SIGN},
                           self.GAINS.view(self.gains, "sliding"))
        self.SCHEME_GAINS.pack(self.scheme_gain_values(), self.GAINS.view(self.gains, "scheme"))

    def scheme_gain_values(self) -> dict:
        """Values of the scheme's own packed gains (default: its parameters by name)."""
        return self.values


#: Where a sliding scheme's own gains and state begin in its packed vectors.
SCHEME_GAINS_AT = _S
SCHEME_STATE_AT = _SS
