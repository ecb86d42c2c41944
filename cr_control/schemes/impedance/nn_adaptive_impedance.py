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
desired motion (3.93), found by inverse kinematics along one period (Newton steps with the
pseudo-inverse from ``rbf_seed``, each sample from the last, so the arm's branch is kept;
on the thesis's arm the elbow branch sin(theta2) < 0 the plant starts on), widened by
``rbf_q_margin`` and ``rbf_qdot_margin`` (the margin on q also covers the start at
r_e(0)); ``rbf_centres_per_dim`` per input dimension, so the q-networks of the 2-link arm
have 4^2 nodes and the (q, q')-networks 4^4. A grid beyond ``rbf_max_nodes`` nodes (a
7-joint arm: 4^14) is replaced by as many Halton points in the same box. Fixed at
start-up. M_r^, C_r^ are m x m and G_r^ has m elements on an m-axis position task. With the
printed variance sigma^2 = 50, far wider than the grid, every activation is close to 1, so
n mostly scales the effective adaptation gain (about Gamma * n_nodes): n = 4 (16 and 256
nodes) keeps s inside the boundary layer after the transient with a moderate start-up
torque peak (6.2 N m; n = 5: 10 N m, n = 6: 16 N m; position errors alike) at ~0.1 ms
per cycle.

The bound d of the approximation error (3.78) is unknown; ``d`` defaults to 0.5 N, the
order of the robust scheme's d (3.51) on the same task (0.4-0.6 N with the section 3.5.2
bounds). The kinematics (J for tau = J^T u and r, r') come from the URDF; its inertial
parameters are used only for the published true norms |M_r|, |C_r|, |G_r|
(``publish_true_norms``; NaN when off), never for the law. On an arm with joints to spare
(the Panda, the UR5) the orientation impedance and the posture task beside the law use the
URDF's dynamically consistent projector and gravity (``null_space_model``, as an arm's own
gravity compensation would; libfranka's torque interface compensates gravity itself):
without it they hold the arm's weight with their stiffness alone (measured on the Panda's
wiping task: 21 degrees of orientation error).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.linalg import matvec, spectral_norm
from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models import spatial_chain as sc
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.blocks import rbf_network
from cr_control.schemes.blocks.references import cosine_reference
from cr_control.schemes.blocks.sliding_impedance import sliding_parameters
from cr_control.schemes.blocks.task_space import task_dynamics, task_frame, task_model
from cr_control.schemes.impedance.sliding import SlidingController, sliding_back, sliding_front

NN_STATUS_FIELDS = ["M_r_norm", "M_r_hat_norm", "C_r_norm", "C_r_hat_norm", "G_r_norm",
                    "G_r_hat_norm"]
_M_HAT, _C_HAT, _G_HAT = (NN_STATUS_FIELDS.index(f"{x}_r_hat_norm") for x in "MCG")


def nn_parameters(n: int, seed: list[float], null_space_model: bool) -> list[Param]:
    """The network's parameters (section 3.5.3 values); ``seed`` is rbf_seed's default."""
    return [
        Param("d", 0.5, "Switching gain d >= |E_M r_eq'' + E_C r_eq' + E_G| (3.78); the bound of "
              "the approximation error is unknown (N).", "nonnegative", bound=Bound.FORCE),
        Param("Gamma_M", 8.0, "Adaptation gain Gamma_Mkj = Gamma_M I of the M_r weights (3.79).",
              "positive", bound=Bound.GAIN),
        Param("Gamma_C", 6.0, "Adaptation gain Gamma_Ckj = Gamma_C I of the C_r weights (3.80).",
              "positive", bound=Bound.GAIN),
        Param("Gamma_G", 10.0, "Adaptation gain Gamma_Gk = Gamma_G I of the G_r weights (3.81).",
              "positive", bound=Bound.GAIN),
        Param("rbf_variance", 50.0, "Variance sigma^2 of the Gaussian activations (3.69).",
              "positive", read_only=True, bound=Bound.GAIN),
        Param("rbf_centres_per_dim", 4, "RBF centres per input dimension (>= 1): per_dim^n nodes "
              "in the q-networks, per_dim^2n in the (q, q')-networks, up to rbf_max_nodes.",
              "integer", read_only=True, bound=Bound.RBF_CENTRES),
        Param("rbf_max_nodes", 256, "Largest network (>= 1): a bigger grid is replaced by this "
              "many Halton points over the same box.", "integer", read_only=True,
              bound=Bound.RBF_NODES),
        Param("rbf_q_margin", 0.3, "Centre grid: margin added to the joint-position range of the "
              "desired motion (rad).", "nonnegative", read_only=True, bound=Bound.JOINT),
        Param("rbf_qdot_margin", 0.5, "Centre grid: margin added to the joint-velocity range of "
              "the desired motion (rad/s).", "nonnegative", read_only=True,
              bound=Bound.JOINT_RATE),
        Param("rbf_seed", seed, "Joint configuration the inverse kinematics of the desired "
              f"motion starts from ({n} values; it chooses the arm's branch); empty = posture, "
              "else the URDF's neutral clipped into the limits.", "vector", read_only=True,
              bound=Bound.JOINT),
        Param("publish_true_norms", True, "Publish |M_r|, |C_r|, |G_r| of the URDF's model beside "
              "the estimates (for plots only; not used in control).", "bool"),
        Param("nn_warm_start", False, "Start the M_r and G_r networks at the URDF model's M_r, "
              "G_r at rbf_seed (each weight vector the minimum-norm one giving them there) "
              "instead of at zero as section 3.5.3 does; the law (3.76) and the weight laws "
              "(3.79-3.81) are unchanged. On an arm of a few kilograms a zero M_r^ makes the "
              "law's first second a bouncing transient on the table.", "bool", read_only=True),
        Param("null_space_model", null_space_model, "The orientation and posture tasks beside "
              "the law (arms with joints to spare) use the URDF's dynamics: a dynamically "
              "consistent projector and gravity, as an arm's own gravity compensation would; "
              "false = kinematic projector and no gravity. The law (3.76) never uses a model.",
              "bool", read_only=True),
    ]


#: rbf_seed on the thesis's arm: on its elbow branch sin(theta2) < 0, near r_d(0).
THESIS_SEED = [3.0, -2.2]


def joint_path(model, values: dict, samples: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """[q, q'] along one period of the desired motion (rows): inverse kinematics by Newton
    steps q += J^+ (r_d - r(q)) to 1e-12 m, each sample from the last (module docstring),
    and q' = J^+ r_d'."""
    chain, rows, n = model.chain, model.task[3:3 + model.m].astype(int), model.n
    seed = np.asarray(values["rbf_seed"], dtype=float)
    if seed.size == 0:
        seed = np.asarray(values["posture"], dtype=float)
    if seed.size == 0:
        lim = model.chain_model.limits
        seed = np.clip(np.zeros(n), lim.lower, lim.upper)
    if seed.size != n:
        raise ParameterError(f"rbf_seed needs {n} values, got {seed.size}")
    zero = np.zeros(n)
    offset = np.array(values["reference_offset"], dtype=float)
    if values["reference_relative"]:
        offset += sc.tip_kinematics(chain, seed, zero)[0][rows]
    w = values["reference_frequency"]
    times = np.linspace(0.0, 2.0 * np.pi / w, samples) if w > 0.0 else np.zeros(1)
    q, out = seed.copy(), []
    for t in times:
        r_d, v_d, _ = cosine_reference(offset, values["reference_amplitude"],
                                       values["reference_phase"], w, t)
        for _ in range(100):
            p, _, J6, _ = sc.tip_kinematics(chain, q, zero)
            step = np.linalg.lstsq(J6[rows], r_d - p[rows], rcond=None)[0]
            q = q + step
            if np.abs(step).max() < 1e-13:
                break
        J = sc.tip_kinematics(chain, q, zero)[2][rows]
        out.append(np.concatenate([q, np.linalg.lstsq(J, v_d, rcond=None)[0]]))
    path = np.array(out)
    return path[:, :n], path[:, n:]


@njit(cache=True, error_model="numpy")
def nn_adaptive_impedance_cycle(chain, gains, state, targets, centres_q, centres_qv, t, dt, q,
                                v, force, out):
    """One cycle of (3.76) with the weight laws (3.79-3.81) into ``out``."""
    cycle = sliding_front(chain, gains, state, targets, t, dt, q, v, force)
    own, weights = cycle.own_gains, cycle.own_state
    s, v_eq, a_eq = cycle.s, cycle.v_eq, cycle.a_eq
    d, Gamma_M, Gamma_C, Gamma_G, inv_variance = own[0], own[1], own[2], own[3], own[4]
    m, n = s.shape[0], q.shape[0]
    mm = m * m
    n_q, n_qv = centres_q.shape[0], centres_qv.shape[0]
    theta_M = weights[:mm * n_q].reshape((n_q, mm))          # columns: M_r row-major
    theta_C = weights[mm * n_q:mm * (n_q + n_qv)].reshape((n_qv, mm))
    theta_G = weights[mm * (n_q + n_qv):].reshape((n_q, m))
    qv = np.empty(2 * n)
    qv[:n], qv[n:] = q, v
    xi_q = rbf_network.activations(centres_q, inv_variance, q)
    xi_qv = rbf_network.activations(centres_qv, inv_variance, qv)
    if dt > 0.0:
        rbf_network.adapt(theta_M, xi_q, Gamma_M * dt, np.outer(s, a_eq).ravel())   # 3.79
        rbf_network.adapt(theta_C, xi_qv, Gamma_C * dt, np.outer(s, v_eq).ravel())  # 3.80
        rbf_network.adapt(theta_G, xi_q, Gamma_G * dt, s)                            # 3.81
    M_hat = rbf_network.output(xi_q, theta_M).reshape((m, m))
    C_hat = rbf_network.output(xi_qv, theta_C).reshape((m, m))
    G_hat = rbf_network.output(xi_q, theta_G)
    model_terms = matvec(M_hat, a_eq) + matvec(C_hat, v_eq) + G_hat
    own_status = sliding_back(gains, state, cycle, model_terms, d, out)
    own_status[:] = np.nan   # the true norms: filled on the Python side if wanted
    own_status[_M_HAT] = spectral_norm(M_hat)
    own_status[_C_HAT] = spectral_norm(C_hat)
    own_status[_G_HAT] = math.sqrt(np.sum(G_hat * G_hat))


@njit(cache=True, error_model="numpy")
def true_norms(chain, task, singularity_mass, q, v):
    """|M_r|, |C_r|, |G_r| of a model-based chain at (q, q') (for the status)."""
    M_r, C_r, G_r = task_dynamics(chain, task_frame(chain, task, singularity_mass, q, v))
    return spectral_norm(M_r), spectral_norm(C_r), math.sqrt(np.sum(G_r * G_r))


class NNAdaptiveImpedanceController(SlidingController):
    """Robust NN adaptive impedance control (3.76) with the section 3.5.3 gains."""

    scheme = "nn_adaptive_impedance"
    MODEL_FREE = True

    @classmethod
    def model_free(cls, values: dict) -> bool:
        return not values["null_space_model"]

    @classmethod
    def reference_defaults(cls) -> dict:
        """The desired motion of section 3.5 (3.93) and the desired force."""
        return dict(offset=[0.0, 0.35], amplitude=[0.1, 0.1], phase=[0.0, 0.0], frequency=2.0,
                    relative=False, desired_force=[5.0, -5.0], what="3.93")

    @classmethod
    def law_parameters(cls, model, thesis):
        m = model.m
        return (sliding_parameters(m, D=-5.0, K=5.0, K_s=36.0, boundary_layer=0.05)
                + nn_parameters(model.n, THESIS_SEED if thesis else [], not thesis)
                + impedance.impedance_parameters(m, A_m=20.0, B_m=40.0, P1=0.625, P2=6.5,
                                                 A0=1.0, B0=110.0, c0=[-4.0, 4.0] if thesis
                                                 else [0.0] * m, Q=4.0, Q_bc_star=8.0,
                                                 Q_a_star=4.0,
                                                 c_max=0.0 if thesis else impedance.C_HAT_MAX))

    def law_status_fields(self) -> list[str]:
        """The sliding schemes' fields, then the norms of the true and estimated dynamics."""
        return super().law_status_fields() + list(NN_STATUS_FIELDS)

    def law_gains_layout(self) -> Layout:
        """The sliding schemes' gains, then d and the network's (3.76, 3.79-3.81)."""
        return super().law_gains_layout().extended(d=1, Gamma_M=1, Gamma_C=1, Gamma_G=1,
                                                   inv_variance=1)

    def law_gain_values(self) -> dict:
        return {**super().law_gain_values(), "inv_variance": 1.0 / self.values["rbf_variance"]}

    def law_initial_state(self) -> np.ndarray:
        """The sliding schemes' state, then the weights [theta_M, theta_C, theta_G]: zero
        (section 3.5.3), or with ``nn_warm_start`` theta_M and theta_G such that
        M_r^(q_0) = M_r(q_0) and G_r^(q_0) = G_r(q_0) of the URDF model at q_0 = rbf_seed:
        theta_i = xi_i(q_0) y / |xi(q_0)|^2 for each output y (the minimum-norm weights)."""
        m, n_q, n_qv = self.model.m, len(self.centres_q), len(self.centres_qv)
        theta_M, theta_C, theta_G = np.zeros((n_q, m * m)), np.zeros(n_qv * m * m), np.zeros((n_q, m))
        if self.values["nn_warm_start"]:
            q0, zero = self._warm_q0, np.zeros(self.model.n)
            true = task_model(self.values, model_free=False)
            M_r, _, G_r = task_dynamics(true.chain, task_frame(
                true.chain, true.task, self.values["singularity_mass"], q0, zero))
            xi = rbf_network.activations(self.centres_q, 1.0 / self.values["rbf_variance"], q0)
            share = xi / float(xi @ xi)
            theta_M, theta_G = np.outer(share, M_r.ravel()), np.outer(share, G_r)
        return np.concatenate([super().law_initial_state(), theta_M.ravel(), theta_C,
                               theta_G.ravel()])

    def __init__(self, values: dict):
        for name in ("rbf_centres_per_dim", "rbf_max_nodes"):
            if values[name] < 1:
                raise ParameterError(f"{name} must be >= 1, got {values[name]}")
        model = task_model(values, model_free=True)     # kinematics only
        q_path, qdot_path = joint_path(model, values)
        n = model.n
        margin = np.array([values["rbf_q_margin"]] * n + [values["rbf_qdot_margin"]] * n)
        low = np.concatenate([q_path.min(axis=0), qdot_path.min(axis=0)]) - margin
        high = np.concatenate([q_path.max(axis=0), qdot_path.max(axis=0)]) + margin
        per_dim, max_nodes = values["rbf_centres_per_dim"], values["rbf_max_nodes"]
        self.centres_q = rbf_network.centres(low[:n], high[:n], per_dim, max_nodes)
        self.centres_qv = rbf_network.centres(low, high, per_dim, max_nodes)
        self._warm_q0 = q_path[0]          # rbf_seed moved onto the desired motion's start
        super().__init__(values)
        self.true_model = task_model(self.values, model_free=False)
        self._norms_at = self.status_fields.index("M_r_norm") - 1

    def cycle(self, t, dt, q, v, force, vector):
        nn_adaptive_impedance_cycle(self.model.chain, self.gains, self.internal, self.targets,
                                    self.centres_q, self.centres_qv, t, dt, q, v, force, vector)
        out = self._output.views(vector)
        if self.values["publish_true_norms"]:
            k = self._norms_at
            out.status[k], out.status[k + 2], out.status[k + 4] = true_norms(
                self.true_model.chain, self.true_model.task, self.values["singularity_mass"], q, v)
        return out
