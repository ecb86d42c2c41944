"""Adaptive impedance control (thesis section 3.2, controller 3.32, laws 3.11-3.14).

The desired impedance e'' + A e' + B e = c (3.5), e = r_d - r, has unknown A, B, c.
Their estimates follow the reference model e_m'' + A_m e_m' + B_m e_m = 0 (3.8):

    varpi = P1^T xi + P2^T xi',  xi = e - e_m                            (3.14)
    c_hat = c_hat(0) - Q_c int(varpi) - Q_c* varpi                      (3.11)
    A_hat = A_hat(0) + Q_a int(varpi e'^T) + Q_a* varpi e'^T            (3.12)
    B_hat = B_hat(0) + Q_b int(varpi e^T)  + Q_b* varpi e^T             (3.13)
    tau   = J^T [M_r (r_d'' + A_hat e' + B_hat e - c_hat) + C_r r' + G_r - f]  (3.32)

P1, P2 are parameters with the printed defaults: they do not solve the Lyapunov
equation (3.16) for any stated Q (DESIGN.md). The reference model starts at the
measured error (e_m(0) = e(0), e_m'(0) = e'(0)), so xi(0) = 0.
"""

from __future__ import annotations

import numpy as np

from cr_control.core.parameters import Param, matrix
from cr_control.schemes.controller import Controller, ControlOutput
from cr_control.schemes.task_space import TASK_SPACE_PARAMETERS, ArmTaskSpace

ESTIMATE_FIELDS = [
    "A_hat_11", "A_hat_12", "A_hat_21", "A_hat_22",
    "B_hat_11", "B_hat_12", "B_hat_21", "B_hat_22",
    "c_hat_x", "c_hat_y",
    "varpi_x", "varpi_y",
]


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


_ONE = np.ones(1)


class ImpedanceAdaptation:
    """Reference model (3.8) and the adaptive impedance laws (3.11-3.14)."""

    def __init__(self, values: dict):
        self.values = values
        # Columns: int(varpi), int(varpi e'^T), int(varpi e^T).
        self.integrals = np.zeros((2, 5))
        self.x_m: np.ndarray | None = None
        self.varpi = np.zeros(2)
        self.A_hat = values["A_hat_0"].copy()
        self.B_hat = values["B_hat_0"].copy()
        self.c_hat = values["c_hat_0"].copy()
        self._transition_key: tuple | None = None
        self._transition = np.eye(4)

    def _reference_model_transition(self, dt: float) -> np.ndarray:
        """RK4 step matrix of x_m' = F x_m, x_m = [e_m, e_m'], F = [[0, I], [-B_m, -A_m]] (3.8).

        For a linear system one RK4 step is x <- (I + hF + (hF)^2/2 + (hF)^3/6 + (hF)^4/24) x;
        cached while dt and the gains stay the same.
        """
        A_m, B_m = self.values["A_m"], self.values["B_m"]
        key = (dt, id(A_m), id(B_m))
        if key != self._transition_key:
            hF = np.block([[np.zeros((2, 2)), np.eye(2)], [-B_m, -A_m]]) * dt
            T = np.eye(4)
            for k in (4, 3, 2, 1):
                T = np.eye(4) + hF @ T / k
            self._transition, self._transition_key = T, key
        return self._transition

    def update(self, e: np.ndarray, e_dot: np.ndarray, dt: float) -> None:
        """Advance by dt and compute A_hat, B_hat, c_hat for the measured e, e'."""
        v = self.values
        if self.x_m is None:
            self.x_m = np.concatenate([e, e_dot])
        elif dt > 0.0:
            self.x_m = self._reference_model_transition(dt) @ self.x_m
        varpi = v["P1"].T @ (e - self.x_m[:2]) + v["P2"].T @ (e_dot - self.x_m[2:])
        products = np.outer(varpi, np.concatenate([_ONE, e_dot, e]))  # [varpi, varpi e'^T, varpi e^T]
        self.integrals += products * dt
        integ, self.varpi = self.integrals, varpi
        self.c_hat = v["c_hat_0"] - v["Q_c"] @ integ[:, 0] - v["Q_c_star"] @ varpi
        self.A_hat = v["A_hat_0"] + v["Q_a"] @ integ[:, 1:3] + v["Q_a_star"] @ products[:, 1:3]
        self.B_hat = v["B_hat_0"] + v["Q_b"] @ integ[:, 3:5] + v["Q_b_star"] @ products[:, 3:5]

    def impedance_acceleration(self, e: np.ndarray, e_dot: np.ndarray) -> np.ndarray:
        """A_hat e' + B_hat e - c_hat: the adaptive-impedance part of u_0 (3.6)."""
        return self.A_hat @ e_dot + self.B_hat @ e - self.c_hat

    def estimates(self) -> np.ndarray:
        """Values of ESTIMATE_FIELDS."""
        return np.concatenate([self.A_hat.ravel(), self.B_hat.ravel(), self.c_hat, self.varpi])


_TIMING_PLACEHOLDER = np.zeros(2)


def task_space_status(ts, force: np.ndarray, e: np.ndarray, f_err: np.ndarray,
                      tau: np.ndarray, *extra: np.ndarray) -> np.ndarray:
    """Status values after ``stamp``: topics.STATUS_FIELDS (timing filled by Controller.step),
    then the scheme's extra fields."""
    return np.concatenate([ts.r, ts.r_dot, force[:2], e, f_err, tau, _TIMING_PLACEHOLDER, *extra])


class AdaptiveImpedanceController(Controller):
    """Adaptive impedance control (3.32) with the section 3.5.1 gains."""

    scheme = "adaptive_impedance"
    PARAMETERS = TASK_SPACE_PARAMETERS + impedance_parameters(
        A_m=20.0, B_m=400.0, P1=1.25, P2=6.56, A0=45.0, B0=30.0, c0=[1.0, 1.0],
        Q=5.0, Q_bc_star=1.5)
    extra_status_fields = ESTIMATE_FIELDS

    def __init__(self, values: dict):
        super().__init__(values)
        self.task = ArmTaskSpace(values)
        self.adaptation = ImpedanceAdaptation(self.values)

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        f = force[:2]
        r_d, v_d, a_d = self.task.reference(t)
        f_d = self.values["desired_force"]
        ts = self.task.state(q, v)
        e, e_dot = r_d - ts.r, v_d - ts.r_dot
        self.adaptation.update(e, e_dot, dt)
        u0 = a_d + self.adaptation.impedance_acceleration(e, e_dot)
        tau = self.task.torque_for_acceleration(q, v, ts, u0, f)
        status = task_space_status(ts, f, e, f_d - f, tau, self.adaptation.estimates())
        return ControlOutput(tau, np.concatenate([r_d, v_d, a_d, f_d]), status)
