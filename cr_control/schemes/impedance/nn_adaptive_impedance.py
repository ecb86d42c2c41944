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
:mod:`cr_control.schemes.blocks.sliding_impedance`. All elements share one activation vector per input
(the centres are the same), so the networks are weight matrices (nodes x elements),
evaluated and updated with one matrix product each. Initial weights are zero. The weights
are integrated with the dt of each cycle (the update uses this cycle's s, then the
estimates are formed), like the impedance estimates. The control kernel receives the arm's
kinematics only (a chain with zero masses, inertias and gravity), so it cannot use a
dynamics model.

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
from numba import njit

from cr_control.core.linalg import matvec, spectral_norm_2x2
from cr_control.core.packing import Layout
from cr_control.core.parameters import Param, ParameterError
from cr_control.models.planar_chain import kinematics_only
from cr_control.schemes.blocks import rbf_network
from cr_control.schemes.blocks.impedance_adaptation import ESTIMATE_FIELDS, impedance_parameters
from cr_control.schemes.blocks.sliding_impedance import (
    SCHEME_GAINS_AT,
    SCHEME_STATE_AT,
    SLIDING_STATUS_FIELDS,
    SlidingImpedanceController,
    sliding_back,
    sliding_front,
    sliding_parameters,
)
from cr_control.schemes.blocks.task_space import TASK_SPACE_PARAMETERS, ArmTaskSpace, inverse_2x2
from cr_control.schemes.controller import ControlOutput

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

_N_SLIDING = len(SLIDING_STATUS_FIELDS)
NN_GAINS = Layout(d=1, Gamma_M=1, Gamma_C=1, Gamma_G=1, inv_variance=1)


def _inertial_model_note(specs: list[Param]) -> list[Param]:
    """TASK_SPACE_PARAMETERS with the inertial ones marked as used for the true norms only."""
    out = []
    for p in specs:
        if p.name in ("model_link_mass", "model_link_inertia", "model_gravity"):
            p = dataclasses.replace(p, description=p.description
                                    + " Used only for the published true norms.")
        out.append(p)
    return out


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


@njit(cache=True, error_model="numpy")
def nn_adaptive_impedance_cycle(kinematic_chain, gains, state, centres_q, centres_qv, t, dt,
                                q, v, force, out, extras_at):
    """One cycle of (3.76) with the weight laws (3.79-3.81) into ``out``."""
    (r_d, v_d, a_d, f_d, r, r_dot, J, _, e, e_dot, s, v_eq, a_eq) = sliding_front(
        kinematic_chain, gains, state, t, dt, q, v)
    own = gains[SCHEME_GAINS_AT:]
    d, Gamma_M, Gamma_C, Gamma_G, inv_variance = own[0], own[1], own[2], own[3], own[4]
    n_q, n_qv = centres_q.shape[0], centres_qv.shape[0]
    weights = state[SCHEME_STATE_AT:]
    theta_M = weights[:4 * n_q].reshape((n_q, 4))   # columns: M_r 11, 12, 21, 22
    theta_C = weights[4 * n_q:4 * (n_q + n_qv)].reshape((n_qv, 4))
    theta_G = weights[4 * (n_q + n_qv):].reshape((n_q, 2))
    qv = np.empty(4)
    qv[:2], qv[2:] = q, v
    xi_q = rbf_network.activations(centres_q, inv_variance, q)
    xi_qv = rbf_network.activations(centres_qv, inv_variance, qv)
    if dt > 0.0:
        rbf_network.adapt(theta_M, xi_q, Gamma_M * dt, np.outer(s, a_eq).ravel())   # 3.79
        rbf_network.adapt(theta_C, xi_qv, Gamma_C * dt, np.outer(s, v_eq).ravel())  # 3.80
        rbf_network.adapt(theta_G, xi_q, Gamma_G * dt, s)                            # 3.81
    M_hat = rbf_network.output(xi_q, theta_M).reshape((2, 2))
    C_hat = rbf_network.output(xi_qv, theta_C).reshape((2, 2))
    G_hat = rbf_network.output(xi_q, theta_G)
    model_terms = matvec(M_hat, a_eq) + matvec(C_hat, v_eq) + G_hat
    status = sliding_back(gains, state, force, model_terms, d, r_d, v_d, a_d, f_d, r, r_dot, J,
                          e, s, out, extras_at)
    k = extras_at + _N_SLIDING
    status[k:k + 6] = np.nan   # the true norms: filled by the node's Python side if wanted
    status[k + 1] = spectral_norm_2x2(M_hat)
    status[k + 3] = spectral_norm_2x2(C_hat)
    status[k + 5] = math.hypot(G_hat[0], G_hat[1])


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
    SCHEME_GAINS = NN_GAINS

    def __init__(self, values: dict):
        per_dim = values["rbf_centres_per_dim"]
        if per_dim < 1:
            raise ParameterError(f"rbf_centres_per_dim must be >= 1, got {per_dim}")
        low, high = desired_joint_ranges(ArmTaskSpace(values))
        margin = np.array([values["rbf_q_margin"]] * 2 + [values["rbf_qdot_margin"]] * 2)
        low, high = low - margin, high + margin
        self.centres_q = rbf_network.grid_centres(low[:2], high[:2], per_dim)
        self.centres_qv = rbf_network.grid_centres(low, high, per_dim)
        n_q, n_qv = len(self.centres_q), len(self.centres_qv)
        # Initial weights are zero: M_r, C_r (4 elements each), G_r (2).
        super().__init__(values, scheme_state=np.zeros(4 * n_q + 4 * n_qv + 2 * n_q))
        self.kinematic_chain = kinematics_only(self.task.chain)
        self._norms_at = self._extras_at + len(SLIDING_STATUS_FIELDS)

    def scheme_gain_values(self) -> dict:
        return {**self.values, "inv_variance": 1.0 / self.values["rbf_variance"]}

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        vector = self._output.new()
        nn_adaptive_impedance_cycle(self.kinematic_chain, self.gains, self.internal,
                                    self.centres_q, self.centres_qv, t, dt, q, v, force, vector,
                                    self._extras_at)
        out = self._output.views(vector)
        if self.values["publish_true_norms"]:
            M_r, C_r, G_r = self.task.dynamics(q, v, self.task.state(q, v))
            k = self._norms_at
            out.status[k], out.status[k + 2] = spectral_norm_2x2(M_r), spectral_norm_2x2(C_r)
            out.status[k + 4] = math.hypot(G_r[0], G_r[1])
        return out
