"""Robust NN adaptive impedance control (thesis section 3.4, controller 3.76).

Every element of the task-space dynamics (3.2) is approximated by a Gaussian RBF network
(3.66-3.75) whose weights adapt on line; no model of the arm's dynamics is used:

    u     = M_r^ r_eq'' + K_s s + d sat(s/Delta) + C_r^ r_eq' + G_r^ - f,  tau = J^T u  (3.76)
    M_r^_kj = theta_Mkj^T xi(q),  C_r^_kj = theta_Ckj^T xi(q, q'),  G_r^_k = theta_Gk^T xi(q)
    xi_i(x) = exp(-|x - mu_i|^2 / sigma^2)                                          (3.69)
    theta_Mkj' = Gamma_M xi(q) r_eq''_j s_k                                          (3.79)
    theta_Ckj' = Gamma_C xi(q, q') r_eq'_j s_k                                       (3.80)
    theta_Gk'  = Gamma_G xi(q) s_k                                                   (3.81)

Compensator, s, r_eq, boundary layer and impedance adaptation (3.82-3.85): as in
:mod:`cr_control.schemes.sliding_impedance`. All elements share one activation vector per input
(the centres are the same), so the networks are weight matrices (nodes x elements),
evaluated and updated with one matrix product each. Initial weights are zero. The weights
are integrated with the dt of each cycle (the update uses this cycle's s, then the
estimates are formed), like the impedance estimates.

Centres (remark 3.4.1): an even grid over the joint positions and velocities of the
desired motion (3.93) through the arm's inverse kinematics (branch sin(theta2) < 0, the one
the plant starts on), widened by ``rbf_q_margin`` and ``rbf_qdot_margin`` (the margin on
q also covers the start at r_e(0)); ``rbf_centres_per_dim`` per input dimension, so the
q-networks have n^2 nodes and the (q, q')-networks n^4. Fixed at start-up. With the
printed variance sigma^2 = 50, far wider than the grid, every activation is close to 1, so
n mostly scales the effective adaptation gain (about Gamma * n_nodes): n = 4 (16 and 256
nodes) keeps s inside the boundary layer after the transient with a moderate start-up
torque peak (6.2 N m; n = 5: 10 N m, n = 6: 16 N m; position errors alike) at ~0.1 ms
per cycle.

The bound d of the approximation error (3.78) is unknown; ``d`` defaults to 0.5 N, the
order of the robust scheme's d (3.51) on the same task (0.4-0.6 N with the section 3.5.2
bounds). The kinematics (J for tau = J^T u and r, r') come from the controller's arm
model; its inertial parameters are used only for the published true norms |M_r|, |C_r|,
|G_r| (``publish_true_norms``; NaN when off), never for control.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from cr_control.core.parameters import Param, ParameterError
from cr_control.schemes.adaptive_impedance import ESTIMATE_FIELDS, impedance_parameters
from cr_control.schemes.sliding_impedance import (
    SLIDING_STATUS_FIELDS,
    SlidingImpedanceController,
    sliding_parameters,
)
from cr_control.schemes.task_space import TASK_SPACE_PARAMETERS, TaskState, inverse_2x2

NN_STATUS_FIELDS = ["M_r_norm", "M_r_hat_norm", "C_r_norm", "C_r_hat_norm", "G_r_norm",
                    "G_r_hat_norm"]

NN_PARAMETERS = [
    Param("d", 0.5, "Switching gain d >= |E_M r_eq'' + E_C r_eq' + E_G| (3.78); the bound of "
          "the approximation error is unknown (N).", "nonnegative"),
    Param("Gamma_M", 8.0, "Adaptation gain Gamma_Mkj = Gamma_M I of the M_r weights (3.79).",
          "positive"),
    Param("Gamma_C", 6.0, "Adaptation gain Gamma_Ckj = Gamma_C I of the C_r weights (3.80).",
          "positive"),
    Param("Gamma_G", 10.0, "Adaptation gain Gamma_Gk = Gamma_G I of the G_r weights (3.81).",
          "positive"),
    Param("rbf_variance", 50.0, "Variance sigma^2 of the Gaussian activations (3.69).",
          "positive", read_only=True),
    Param("rbf_centres_per_dim", 4, "RBF centres per input dimension (>= 1): n^2 nodes in the "
          "q-networks, n^4 in the (q, q')-networks.", "integer", read_only=True),
    Param("rbf_q_margin", 0.3, "Centre grid: margin added to the joint-position range of the "
          "desired motion (rad).", "nonnegative", read_only=True),
    Param("rbf_qdot_margin", 0.5, "Centre grid: margin added to the joint-velocity range of "
          "the desired motion (rad/s).", "nonnegative", read_only=True),
    Param("publish_true_norms", True, "Publish |M_r|, |C_r|, |G_r| of the controller's arm "
          "model beside the estimates (for plots only; not used in control).", "bool"),
]


def _inertial_model_note(specs: list[Param]) -> list[Param]:
    """TASK_SPACE_PARAMETERS with the inertial ones marked as used for the true norms only."""
    out = []
    for p in specs:
        if p.name in ("model_link_mass", "model_link_inertia", "model_gravity"):
            p = dataclasses.replace(p, description=p.description
                                    + " Used only for the published true norms.")
        out.append(p)
    return out


def spectral_norm_2x2(A: np.ndarray) -> float:
    """Largest singular value of a 2x2 matrix, closed form (an SVD costs ~10x more)."""
    a, b, c, d = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    frob2 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return math.sqrt(0.5 * (frob2 + math.sqrt(max(frob2 * frob2 - 4.0 * det * det, 0.0))))


def desired_joint_ranges(task, samples: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of [q, q'] over one period of the desired motion (inverse kinematics,
    branch sin(theta2) < 0 as the plant's elbow_sign -1; q' = J^-1 r_d')."""
    w = task.reference.frequency
    period = 2.0 * np.pi / w if w > 0.0 else 0.0
    rows = []
    for t in np.linspace(0.0, period, samples):
        r_d, v_d, _ = task.reference(t)
        q = task.arm.inverse_kinematics(r_d, -1.0)
        rows.append(np.concatenate([q, inverse_2x2(task.arm.jacobian(q)) @ v_d]))
    rows = np.array(rows)
    return rows.min(axis=0), rows.max(axis=0)


def grid_centres(low: np.ndarray, high: np.ndarray, per_dim: int) -> np.ndarray:
    """Centres evenly spread over the box [low, high], per_dim per dimension (rows)."""
    axes = [np.linspace(lo, hi, per_dim) if per_dim > 1 else np.array([(lo + hi) / 2])
            for lo, hi in zip(low, high, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(low))


class GaussianLayer:
    """Activations xi_i(x) = exp(-|x - mu_i|^2 / sigma^2) (3.69) of fixed centres mu_i."""

    def __init__(self, centres: np.ndarray, variance: float):
        self.centres = np.ascontiguousarray(centres)
        self.inv_variance = 1.0 / variance

    def __call__(self, x: np.ndarray) -> np.ndarray:
        diff = self.centres - x
        return np.exp(-self.inv_variance * np.einsum("ij,ij->i", diff, diff))


class NNAdaptiveImpedanceController(SlidingImpedanceController):
    """Robust NN adaptive impedance control (3.76) with the section 3.5.3 gains."""

    scheme = "nn_adaptive_impedance"
    PARAMETERS = (_inertial_model_note(TASK_SPACE_PARAMETERS)
                  + sliding_parameters(D=-5.0, K=5.0, K_s=36.0, boundary_layer=0.05)
                  + NN_PARAMETERS
                  + impedance_parameters(A_m=20.0, B_m=40.0, P1=0.625, P2=6.5, A0=1.0,
                                         B0=110.0, c0=[-4.0, 4.0], Q=4.0, Q_bc_star=8.0,
                                         Q_a_star=4.0))
    extra_status_fields = SLIDING_STATUS_FIELDS + NN_STATUS_FIELDS + ESTIMATE_FIELDS

    def __init__(self, values: dict):
        super().__init__(values)
        per_dim = self.values["rbf_centres_per_dim"]
        if per_dim < 1:
            raise ParameterError(f"rbf_centres_per_dim must be >= 1, got {per_dim}")
        low, high = desired_joint_ranges(self.task)
        margin = np.array([self.values["rbf_q_margin"]] * 2 + [self.values["rbf_qdot_margin"]] * 2)
        low, high = low - margin, high + margin
        variance = self.values["rbf_variance"]
        self.xi_q = GaussianLayer(grid_centres(low[:2], high[:2], per_dim), variance)
        self.xi_qv = GaussianLayer(grid_centres(low, high, per_dim), variance)
        n_q, n_qv = len(self.xi_q.centres), len(self.xi_qv.centres)
        # Columns: row-major elements (11, 12, 21, 22) of M_r, C_r; (1, 2) of G_r.
        self.theta_M = np.zeros((n_q, 4))
        self.theta_C = np.zeros((n_qv, 4))
        self.theta_G = np.zeros((n_q, 2))
        self.M_hat = np.zeros((2, 2))
        self.C_hat = np.zeros((2, 2))
        self.G_hat = np.zeros(2)
        self._qv = np.empty(4)

    def model_terms(self, dt: float, q: np.ndarray, v: np.ndarray, ts: TaskState,
                    s: np.ndarray, v_eq: np.ndarray, a_eq: np.ndarray) -> np.ndarray:
        """Adapt the weights (3.79-3.81) by dt, then M_r^ r_eq'' + C_r^ r_eq' + G_r^ (3.73-3.75)."""
        values = self.values
        self._qv[:2], self._qv[2:] = q, v
        xi_q, xi_qv = self.xi_q(q), self.xi_qv(self._qv)
        if dt > 0.0:
            self.theta_M += np.outer(xi_q, (values["Gamma_M"] * dt) * np.outer(s, a_eq).ravel())
            self.theta_C += np.outer(xi_qv, (values["Gamma_C"] * dt) * np.outer(s, v_eq).ravel())
            self.theta_G += np.outer(xi_q, (values["Gamma_G"] * dt) * s)
        self.M_hat = (xi_q @ self.theta_M).reshape(2, 2)
        self.C_hat = (xi_qv @ self.theta_C).reshape(2, 2)
        self.G_hat = xi_q @ self.theta_G
        return self.M_hat @ a_eq + self.C_hat @ v_eq + self.G_hat

    def switching_gain(self, v_eq: np.ndarray, a_eq: np.ndarray) -> float:
        """The constant d of 3.76 (3.78)."""
        return self.values["d"]

    def scheme_status(self, q: np.ndarray, v: np.ndarray, ts: TaskState) -> np.ndarray:
        """|M_r|, |M_r^|, |C_r|, |C_r^| (largest singular values), |G_r|, |G_r^| (Euclidean)."""
        if self.values["publish_true_norms"]:
            M_r, C_r, G_r = self.task.dynamics(q, v, ts)
            true = (spectral_norm_2x2(M_r), spectral_norm_2x2(C_r), math.hypot(*G_r))
        else:
            true = (np.nan, np.nan, np.nan)
        return np.array([true[0], spectral_norm_2x2(self.M_hat), true[1],
                         spectral_norm_2x2(self.C_hat), true[2], math.hypot(*self.G_hat)])
