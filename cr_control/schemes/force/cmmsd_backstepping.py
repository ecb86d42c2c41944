"""Adaptive output-feedback backstepping position control of a chain of N mass-spring-dampers
(thesis appendix C, C.11-C.56, control C.50): regulate q_1 to 0 with the force u on the last
mass, measuring q_1 only, for any N.

The plant q_1/u is of order n = 2N and relative degree rho = 2N (no zeros), theta =
[d_2N, a_{2N,2N-1} .. a_{2N,0}] (C.5-C.6). The design is the generic one of
:mod:`cr_control.schemes.blocks.backstepping` (Sizes(2N, 2N)) with c_1 = zeta + 1/2, c_i = zeta and
nonlinear damping d_i = 1/4 for 2 <= i < 2N and d_2N = 0 as printed in (C.39), (C.47), (C.50).

Only q_1 is read: :meth:`CMMSDBacksteppingController.compute` passes q[0] to the kernel and
nothing else (the joint state carries every mass for the recording); the command is [0, .., 0, u].

The thesis gives no numbers; defaults (documented choices): zeta = 1, gamma = 0.01,
Gamma = 0.01 I, A0's poles all at -1 (lambda = coefficients of (s + 1)^2N), no nonlinear
damping, initial estimates 0.65 x the theta of a nominal uniform chain (m = 1, b = 0.5,
k = 4: the plant's defaults, like chapter 4's 0.65 x theta), filters at rest. N = number of
joint names. With the printed 1/4 nonlinear damping, theta_hat(0) = 0 or Gamma = I the
alpha_i of N >= 2 peak (they are polynomials of high degree) and the loop diverged from
q_1(0) = 0.1 m.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.core.topics import REFERENCE_FIELDS, STATUS_FIELDS
from cr_control.schemes.blocks import backstepping as bs
from cr_control.schemes.controller import (
    Controller,
    ControlOutput,
    KernelOutput,
    field_at,
    split_output,
)

_R_D, _R, _E = (field_at(REFERENCE_FIELDS, "r_d_x"), field_at(STATUS_FIELDS, "r_x"),
                field_at(STATUS_FIELDS, "e_x"))

_JOINTS = Param("joint_names", ["q1", "q2"], "The chain's joints q1..qN in order (N = their "
                "number); only q1 is read, the force goes to the last.", "string_list",
                read_only=True)

PARAMETERS = [
    Param("zeta", 1.0, "Backstepping gain zeta_i (all steps; C.39, C.47, C.50).", "positive",
          bound=Bound.SCALE),
    Param("nonlinear_damping", 0.0, "Nonlinear damping d_i of steps 2..2N-1 (C.47 prints 1/4; "
          "0 by default: the gamma_i^2 terms raise the degree of the alpha_i and made N = 2 "
          "peak and diverge from q_1(0) = 0.1 m).", "nonnegative", bound=Bound.GAIN),
    Param("gamma", 0.01, "Adaptation gain of d_hat, the estimate of 1/d_2N (C.40).",
          "nonnegative", bound=Bound.GAIN),
    Param("Gamma", 0.01, "Adaptation gain Gamma = this x I (C.56).", "nonnegative", bound=Bound.GAIN),
    Param("observer_pole", 1.0, "A0 = A - lambda e_1^T has all its 2N poles at -this (C.13).",
          "positive", read_only=True, bound=Bound.BANDWIDTH),
    Param("nominal_mass", 1.0, "Nominal m_i (kg) of the controller's nominal chain.", "positive",
          read_only=True, bound=Bound.MASS),
    Param("nominal_damping", 0.5, "Nominal b_i (N s/m) of the nominal chain.", "nonnegative",
          read_only=True, bound=Bound.DAMPING),
    Param("nominal_stiffness", 4.0, "Nominal k_i (N/m) of the nominal chain.", "positive",
          read_only=True, bound=Bound.STIFFNESS),
    Param("initial_estimate_scale", 0.65, "Without theta_hat_0: theta_hat(0) and d_hat(0) are "
          "this x the nominal chain's theta and 1/d_2N (as chapter 4 starts at 0.65 x).",
          "finite", read_only=True, bound=Bound.SCALE),
    Param("theta_hat_0", [], "Initial theta_hat = [d_2N, a_{2N,2N-1} .. a_{2N,0}] (2N+1 "
          "values); empty = initial_estimate_scale x the nominal chain's.", "vector",
          read_only=True, bound=Bound.POLYNOMIAL),
    Param("d_hat_0", 0.0, "Initial estimate of 1/d_2N; 0 = initial_estimate_scale x the "
          "nominal chain's.", "finite", read_only=True, bound=Bound.POLYNOMIAL),
    Param("q_d", 0.0, "Set point of q_1 (m) (appendix C: 0).", "finite", bound=Bound.LENGTH),
]


@njit(cache=True)
def cmmsd_cycle(op, a, b, value, outputs, n, p, inp, vals, work, state, res, q1, q_d, dt, out,
                extras_at, n_joints):
    bs.backstepping_cycle(op, a, b, value, outputs, n, n, p, inp, vals, work, state, q1, q_d, dt,
                          res)
    command, reference, status = split_output(out, n_joints)
    command[:] = 0.0
    command[n_joints - 1] = res[0]
    reference[:] = 0.0
    reference[_R_D] = q_d
    status[:] = 0.0
    status[_R] = q1
    status[_E] = q_d - q1
    status[extras_at] = res[0]
    status[extras_at + 1] = state[2 * n + p]            # d_hat
    s = 0.0
    for j in range(p):
        s += state[2 * n + j] ** 2
    status[extras_at + 2] = np.sqrt(s)
    status[extras_at + 3] = res[2 + p]                  # z_1


def nominal_theta(n_masses: int, mass: float, damping: float, stiffness: float) -> np.ndarray:
    """theta = [d_2N, a_{2N,2N-1} .. a_{2N,0}] (C.5) of a uniform chain (the controller's
    nominal model: q_1/u of C.1 with every m_i, b_i, k_i equal)."""
    n = n_masses
    A = np.zeros((2 * n, 2 * n))
    for i in range(n):
        A[2 * i, 2 * i + 1] = 1.0
        r = 2 * i + 1
        A[r, r] = -damping / mass
        for j in (i - 1, i + 1):
            if 0 <= j < n:
                A[r, 2 * i] -= stiffness / mass
                A[r, 2 * j] += stiffness / mass
    den = np.real(np.poly(A))
    d_2n = stiffness ** (n - 1) / mass ** n          # C.5: d_2N = k_1..k_{N-1} / (m_1..m_N)
    return np.concatenate([[d_2n], den[1:]])


class CMMSDBacksteppingController(Controller):
    """Adaptive output-feedback backstepping (C.50) for the N-mass chain."""

    scheme = "cmmsd_backstepping"
    PARAMETERS = PARAMETERS
    extra_status_fields = ["u", "d_hat", "theta_hat_norm", "z_1"]

    JOINT_NAMES_PARAMETER = _JOINTS

    def __init__(self, values: dict):
        super().__init__(values)
        n = 2 * self.n_joints
        self.sizes = bs.Sizes(n, n)
        v = self.values
        nominal = nominal_theta(self.n_joints, v["nominal_mass"], v["nominal_damping"],
                                v["nominal_stiffness"])
        theta0 = np.asarray(v["theta_hat_0"], dtype=float)
        if theta0.size == 0:
            theta0 = v["initial_estimate_scale"] * nominal
        if theta0.size != self.sizes.p:
            raise ParameterError(f"theta_hat_0 needs {self.sizes.p} values, got {theta0.size}")
        d0 = v["d_hat_0"] or v["initial_estimate_scale"] / nominal[0]
        self.design = bs.Backstepping(self.sizes)
        self.pack_gains()
        self.internal = bs.initial_state(self.sizes, theta0, d0)
        self._output = KernelOutput(self)
        self._extras_at = self._output.extras_at

    def pack_gains(self) -> None:
        v, s = self.values, self.sizes
        c = np.full(s.rho, v["zeta"])
        c[0] += 0.5
        d = np.full(s.rho, v["nonlinear_damping"])
        d[0] = d[-1] = 0.0
        lam = bs.observer_coefficients(np.full(s.n, -v["observer_pole"]))
        self.design.set_gains(c, d, lam, np.full(s.p, v["Gamma"]), v["gamma"])

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        q1 = float(q[0])                  # the only measurement the scheme reads (appendix C)
        out = self._output.new()
        d, t_, s = self.design, self.design.tape, self.sizes
        cmmsd_cycle(t_.op, t_.a, t_.b, t_.value, t_.outputs, s.n, s.p, d.inp, d.vals, d.work,
                    self.internal, d.res, q1, self.values["q_d"], dt, out, self._extras_at,
                    self.n_joints)
        return self._output.views(out)
