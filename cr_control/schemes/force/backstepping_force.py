"""Adaptive output-feedback force control with backstepping (thesis 4.2.1: K-filters
4.13-4.22, tuning functions and stabilizing function 4.30-4.55, control 4.56, laws 4.40 and
4.55) on the dynamic constraint of chapter 4 (n = 5, rho = 2): the command displacement
delta_c drives the constraint force f to f_d, only f is used.

The design is the generic one of :mod:`cr_control.schemes.blocks.backstepping` (Sizes(5, 2)) with
c = [h_1, h_2] and no nonlinear damping; it keeps the d alpha_1/d v terms that the printed
(4.47) leaves out (see there). Defaults are section 4.3's: h_1 = h_2 = 2, gamma = 0.01,
Gamma = diag(45, 60, 60, 60, 45, 45, 45, 45, 10), lambda = [12 5 15 2 4], initial estimates
0.65 x the printed nominal theta = [20 200.3 8 40 20.04 21.52 27.01 0.9 8] and 0.65 x
d = 0.05. The printed nominal theta matches the true one only in b and a_4 (docs/thesis.md);
``INITIAL_ESTIMATES`` has both choices (printed nominal, 0.65 x the true theta of each case).
Case 4 (no adaptation) is gamma = 0, Gamma = 0 (config/backstepping_force_case4.yaml).

The K-filters start at rest (zero; the thesis does not say) unless ``bumpless_start``: then
at their steady state for the first measured f and a held delta_c = delta(0), which is what
a plant at rest in equilibrium implies (y_hat(0) = y(0) when theta_hat is right).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.parameters import Bound, Param
from cr_control.core.topics import REFERENCE_FIELDS, STATUS_FIELDS
from cr_control.schemes.blocks import backstepping as bs
from cr_control.schemes.controller import (
    Controller,
    ControlOutput,
    KernelOutput,
    field_at,
    split_output,
)

SIZES = bs.Sizes(5, 2)
N, RHO, P = SIZES.n, SIZES.rho, SIZES.p
#: The internal state's and a cycle's results' blocks (:func:`backstepping.state_layout`,
#: :func:`backstepping.result_layout`).
STATE, RESULT = bs.state_layout(SIZES), bs.result_layout(SIZES)

#: The nominal theta printed in section 4.3 (matches the true one only in b and a_4).
PRINTED_NOMINAL_THETA = [20.0, 200.3, 8.0, 40.0, 20.04, 21.52, 27.01, 0.9, 8.0]
#: True theta of cases 1-3 (from the state-space model (4.2-4.3, 4.5); docs/thesis.md).
TRUE_THETA = {
    1: [20.0, 200.4, 8.0, 40.0, 20.045, 2.4005, 22.045, 1.0, 6.0],
    2: [50.0, 1251.0, 35.0, 250.0, 50.045, 4.9505, 85.09, 3.1, 30.0],
    3: [80.0, 3201.6, 80.0, 640.0, 80.045, 7.5005, 184.135, 6.1, 72.0],
}
#: Initial (theta_hat, d_hat): thesis = 0.65 x printed nominal and 0.65 x 0.05; "true_case<k>"
#: = 0.65 x the true theta and 0.65 x 1/b_3 of case k.
INITIAL_ESTIMATES = {
    "printed_nominal": ([0.65 * x for x in PRINTED_NOMINAL_THETA], 0.65 * 0.05),
    **{f"true_case{k}": ([0.65 * x for x in th], 0.65 / th[0]) for k, th in TRUE_THETA.items()},
}

THETA_NAMES = ["b3", "b2", "b1", "b0", "a4", "a3", "a2", "a1", "a0"]

_JOINTS = Param("joint_names", ["delta"], "Joints commanded, in command order (one prismatic "
                "joint along the surface normal).", "string_list", read_only=True)

PARAMETERS = [
    Param("f_d", 1.0, "Desired constraint force f_d (N) (section 4.3: 1 N).", "finite", bound=Bound.FORCE),
    Param("h", [2.0, 2.0], "Backstepping gains h_1, h_2 (4.34, 4.56; the proof wants > 1).",
          "positive_vector", 2, bound=Bound.GAIN),
    Param("gamma", 0.01, "Adaptation gain of d_hat, the estimate of 1/b_3 (4.40); 0 stops it.",
          "nonnegative", bound=Bound.GAIN),
    Param("Gamma", [45.0, 60.0, 60.0, 60.0, 45.0, 45.0, 45.0, 45.0, 10.0],
          "Diagonal of the adaptation gain Gamma of theta_hat (4.55); 0 stops it.",
          "nonnegative_vector", P, bound=Bound.GAIN),
    Param("lambda", [12.0, 5.0, 15.0, 2.0, 4.0], "K-filter gain lambda: A0 = A - lambda e_1^T "
          "must be Hurwitz (4.16-4.17).", "vector", N, read_only=True, bound=Bound.POLYNOMIAL),
    Param("theta_hat_0", INITIAL_ESTIMATES["printed_nominal"][0],
          "Initial theta_hat = [b3 b2 b1 b0 a4 a3 a2 a1 a0] (thesis: 0.65 x the printed "
          "nominal theta; 0.65 x the true one is the other documented choice).", "vector", P,
          read_only=True, bound=Bound.POLYNOMIAL),
    Param("d_hat_0", INITIAL_ESTIMATES["printed_nominal"][1],
          "Initial estimate of 1/b_3 (thesis: 0.65 x 0.05).", "finite", read_only=True,
          bound=Bound.POLYNOMIAL),
    Param("bumpless_start", False, "Start the K-filters at their steady state for the first "
          "measured force and delta_c = delta(0) instead of at zero.", "bool", read_only=True),
]

STATUS_EXTRA = ["z_1", "z_2", *[f"{x}_hat" for x in THETA_NAMES], "d_hat", "gamma_2"]


# where force_cycle reads and writes (numba takes these module constants as literals)
_THETA, _D_HAT, _U_PREV = (STATE.offset(name) for name in ("theta_hat", "rho_hat", "u_prev"))
_U, _Z, _GAMMA_2 = RESULT.offset("u"), RESULT.offset("z"), RESULT.offset("gamma_2")
_F_D = field_at(REFERENCE_FIELDS, "f_d_x")
_R, _V, _F, _F_ERR, _TAU = (field_at(STATUS_FIELDS, name) for name in (
    "r_x", "v_x", "f_x", "f_err_x", "tau_1"))
_X_Z, _X_THETA, _X_D_HAT, _X_GAMMA_2 = (STATUS_EXTRA.index(name) for name in (
    "z_1", "b3_hat", "d_hat", "gamma_2"))


def check_hurwitz(lam) -> None:
    if not np.all(np.real(np.linalg.eigvals(bs.a0_matrix(lam))) < 0):
        from cr_control.core.parameters import ParameterError

        raise ParameterError(f"lambda = {list(lam)} does not make A0 Hurwitz")


def steady_filters(lam, y: float, u: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(eta, lam_f) at rest for constant y and u: A0 eta = e_n y, A0 lam_f = -e_n u."""
    A0 = bs.a0_matrix(lam)
    e_n = np.eye(n)[n - 1]
    return np.linalg.solve(A0, e_n * y), np.linalg.solve(A0, -e_n * u)


@njit(cache=True)
def force_cycle(op, a, b, value, outputs, inp, vals, work, state, res, q, v, force, f_d, dt, out,
                extras_at):
    """One cycle of (4.56) into ``out`` (command delta_c, reference, status)."""
    f = force[0]
    bs.backstepping_cycle(op, a, b, value, outputs, N, RHO, P, inp, vals, work, state, f, f_d,
                          dt, res)
    command, reference, status = split_output(out, 1)
    command[0] = res[_U]
    reference[:] = 0.0
    reference[_F_D] = f_d
    status[:] = 0.0
    status[_R], status[_V], status[_F] = q[0], v[0], f
    status[_F_ERR] = f_d - f
    status[_TAU] = res[_U]
    for j in range(RHO):
        status[extras_at + _X_Z + j] = res[_Z + j]
    for j in range(P):
        status[extras_at + _X_THETA + j] = state[_THETA + j]
    status[extras_at + _X_D_HAT] = state[_D_HAT]
    status[extras_at + _X_GAMMA_2] = res[_GAMMA_2]


class BacksteppingForceController(Controller):
    """Adaptive output-feedback backstepping force control (4.56), delta_c commanded."""

    scheme = "backstepping_force"
    command_interface = "position"
    PARAMETERS = PARAMETERS
    extra_status_fields = STATUS_EXTRA

    JOINT_NAMES_PARAMETER = _JOINTS

    def __init__(self, values: dict):
        super().__init__(values)
        check_hurwitz(self.values["lambda"])
        self.design = bs.Backstepping(SIZES)
        self.pack_gains()
        self.internal = bs.initial_state(SIZES, self.values["theta_hat_0"], self.values["d_hat_0"])
        self._started = False
        self._output = KernelOutput(self)
        self._extras_at = self._output.extras_at

    def pack_gains(self) -> None:
        v = self.values
        self.design.set_gains(v["h"], [0.0, 0.0], v["lambda"], v["Gamma"], v["gamma"])

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        if not self._started:
            self._started = True
            if self.values["bumpless_start"]:
                eta, lam = steady_filters(self.values["lambda"], float(force[0]), float(q[0]), N)
                STATE.view(self.internal, "eta")[:], STATE.view(self.internal, "lam")[:] = eta, lam
                self.internal[_U_PREV] = q[0]                  # delta_c held = delta
        out = self._output.new()
        d, t_ = self.design, self.design.tape
        force_cycle(t_.op, t_.a, t_.b, t_.value, t_.outputs, d.inp, d.vals, d.work, self.internal,
                    d.res, q, v, force, self.values["f_d"], dt, out, self._extras_at)
        return self._output.views(out)
