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

from abc import abstractmethod

import numpy as np

from cr_control.core.parameters import Param, matrix
from cr_control.schemes.adaptive_impedance import ImpedanceAdaptation, task_space_status
from cr_control.schemes.controller import Controller, ControlOutput
from cr_control.schemes.task_space import ArmTaskSpace, TaskState, inverse_2x2

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


def boundary_layer_sign(s: np.ndarray, delta: float) -> np.ndarray:
    """sgn(s) with the boundary layer of remark 3.3.1, per component: clip(s/Delta, -1, 1)."""
    return np.clip(s / delta, -1.0, 1.0)


class SlidingCompensator:
    """Dynamic compensator (3.40) with the gains (3.43-3.45), s (3.41) and r_eq (3.49-3.50)."""

    #: z' = D_SIGN * D z + ...: +1 is the convention 3.42-3.46 are derived with (the
    #: printed 3.40 corresponds to -1; module docstring).
    D_SIGN = 1.0

    def __init__(self, values: dict):
        self.values = values
        self.z = np.zeros(2)
        self.z_dot = np.zeros(2)

    def gains(self, A_hat: np.ndarray,
              B_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """K_v, K_p, K_c of 3.43-3.45 for the current impedance estimates."""
        v = self.values
        D, K_1 = v["D"], v["K_1"]
        K_c = inverse_2x2(v["K_2"])
        D_K2inv = D @ K_c
        K_v = K_c @ (A_hat + v["K_2"] @ D_K2inv - K_1)
        K_p = K_c @ B_hat + D_K2inv @ K_1
        return K_v, K_p, K_c

    def update(self, dt: float, e: np.ndarray, e_dot: np.ndarray, v_d: np.ndarray,
               a_d: np.ndarray,
               adaptation: ImpedanceAdaptation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance z by dt (Euler) and return s (3.41), r_eq' (3.49) and r_eq'' (3.50)."""
        v = self.values
        self.z = self.z + dt * self.z_dot
        K_v, K_p, K_c = self.gains(adaptation.A_hat, adaptation.B_hat)
        self.z_dot = (self.D_SIGN * (v["D"] @ self.z) + K_v @ e_dot + K_p @ e
                      - K_c @ adaptation.c_hat)
        K1_e = v["K_1"] @ e
        K2_z = v["K_2"] @ self.z
        s = e_dot + K1_e + K2_z
        return s, v_d + K1_e + K2_z, a_d + v["K_1"] @ e_dot + v["K_2"] @ self.z_dot


class SlidingImpedanceController(Controller):
    """tau = J^T (model_terms + K_s s + d sat(s/Delta) - f) (3.48, 3.76).

    Subclasses give the estimate of M_r r_eq'' + C_r r_eq' + G_r (:meth:`model_terms`),
    the switching gain d (:meth:`switching_gain`) and their extra status values.
    Status fields: topics.STATUS_FIELDS, SLIDING_STATUS_FIELDS, ``scheme_status_fields``,
    then ESTIMATE_FIELDS.
    """

    def __init__(self, values: dict):
        super().__init__(values)
        self.task = ArmTaskSpace(self.values)
        self.adaptation = ImpedanceAdaptation(self.values)
        self.compensator = SlidingCompensator(self.values)

    @abstractmethod
    def model_terms(self, dt: float, q: np.ndarray, v: np.ndarray, ts: TaskState,
                    s: np.ndarray, v_eq: np.ndarray, a_eq: np.ndarray) -> np.ndarray:
        """The scheme's estimate of M_r r_eq'' + C_r r_eq' + G_r (may adapt, by dt)."""

    @abstractmethod
    def switching_gain(self, v_eq: np.ndarray, a_eq: np.ndarray) -> float:
        """d of d sgn(s)."""

    def scheme_status(self, q: np.ndarray, v: np.ndarray, ts: TaskState) -> np.ndarray:
        """Values of the scheme's own status fields (between d and the estimates)."""
        return np.zeros(0)

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        values = self.values
        f = force[:2]
        r_d, v_d, a_d = self.task.reference(t)
        f_d = values["desired_force"]
        ts = self.task.state(q, v)
        e, e_dot = r_d - ts.r, v_d - ts.r_dot
        self.adaptation.update(e, e_dot, dt)
        s, v_eq, a_eq = self.compensator.update(dt, e, e_dot, v_d, a_d, self.adaptation)
        d = self.switching_gain(v_eq, a_eq)
        u = (self.model_terms(dt, q, v, ts, s, v_eq, a_eq) + values["K_s"] @ s
             + d * boundary_layer_sign(s, values["boundary_layer"]) - f)
        tau = ts.J.T @ u
        status = task_space_status(ts, f, e, f_d - f, tau, s, self.compensator.z, np.array([d]),
                                   self.scheme_status(q, v, ts), self.adaptation.estimates())
        return ControlOutput(tau, np.concatenate([r_d, v_d, a_d, f_d]), status)
