"""Robust adaptive impedance control (thesis section 3.3, controller 3.48).

    tau = J^T [M_r^ r_eq'' + K_s s + d sat(s/Delta) + C_r^ r_eq' + G_r^ - f]      (3.48)
    d   = dM |r_eq''| + dC |r_eq'| + dG + df      (3.51, with equality, every cycle)

M_r^, C_r^, G_r^ are the task-space dynamics (3.2) of the controller's model of the arm,
which is deliberately wrong (section 3.5.2): link inertias 0.2 kg m^2 and masses 0.05 kg
instead of 0.3 and 0.1. Compensator z (3.40, 3.43-3.45), s (3.41), r_eq (3.49-3.50), the
boundary layer (remark 3.3.1) and the D sign convention are in
:mod:`cr_control.schemes.blocks.sliding_impedance`; the impedance estimates follow 3.61-3.65 with
e'^T in the A_hat law (3.48 prints e^T; DESIGN.md) through :class:`ImpedanceAdaptation`.

The printed bounds dM = 0.1, dC = 0.1 (3.36-3.37) do not bound the real model errors of
this example (|M_r - M_r^| is several kg in the workspace); they are used as printed and
K_s s carries the rest, as in the thesis's simulation.
"""

from __future__ import annotations

import dataclasses
import math

from numba import njit

from cr_control.core.linalg import matvec
from cr_control.core.packing import Layout
from cr_control.core.parameters import Param
from cr_control.schemes.blocks.impedance_adaptation import ESTIMATE_FIELDS, impedance_parameters
from cr_control.schemes.blocks.sliding_impedance import (
    SCHEME_GAINS_AT,
    SLIDING_STATUS_FIELDS,
    SlidingImpedanceController,
    sliding_back,
    sliding_front,
    sliding_parameters,
)
from cr_control.schemes.blocks.task_space import TASK_SPACE_PARAMETERS, task_dynamics
from cr_control.schemes.controller import ControlOutput

#: The controller's (wrong) estimate of the links' inertial parameters (section 3.5.2).
_WRONG_MODEL = {
    "model_link_inertia": ([0.2, 0.2], "Controller model: link inertias (kg m^2); section "
                           "3.5.2 estimate (true 0.3)."),
    "model_link_mass": ([0.05, 0.05], "Controller model: link masses (kg); section 3.5.2 "
                        "estimate (true 0.1)."),
}


def _with_wrong_model(specs: list[Param]) -> list[Param]:
    out = []
    for p in specs:
        if p.name in _WRONG_MODEL:
            default, description = _WRONG_MODEL[p.name]
            p = dataclasses.replace(p, default=default, description=description)
        out.append(p)
    return out


UNCERTAINTY_PARAMETERS = [
    Param("delta_M", 0.1, "Bound dM of |M_r - M_r^| (3.36), used in d (3.51).", "nonnegative"),
    Param("delta_C", 0.1, "Bound dC of |C_r - C_r^| (3.37), used in d (3.51).", "nonnegative"),
    Param("delta_G", 0.05, "Bound dG of |G_r - G_r^| (3.38), used in d (3.51) (N).",
          "nonnegative"),
    Param("delta_f", 0.1, "Bound df of the disturbance force |f~| (3.39), used in d (3.51) (N).",
          "nonnegative"),
]


ROBUST_GAINS = Layout(delta_M=1, delta_C=1, delta_G=1, delta_f=1)


@njit(cache=True, error_model="numpy")
def robust_adaptive_impedance_cycle(chain, gains, state, t, dt, q, v, force, out, extras_at):
    """One cycle of (3.48) into ``out`` (task_space.split_output)."""
    (r_d, v_d, a_d, f_d, r, r_dot, J, J_inv, e, e_dot, s, v_eq, a_eq) = sliding_front(
        chain, gains, state, t, dt, q, v)
    delta_M, delta_C, delta_G, delta_f = (gains[SCHEME_GAINS_AT], gains[SCHEME_GAINS_AT + 1],
                                          gains[SCHEME_GAINS_AT + 2], gains[SCHEME_GAINS_AT + 3])
    d = (delta_M * math.hypot(a_eq[0], a_eq[1]) + delta_C * math.hypot(v_eq[0], v_eq[1])
         + delta_G + delta_f)                                                      # 3.51
    M_r, C_r, G_r = task_dynamics(chain, q, v, J_inv)
    model_terms = matvec(M_r, a_eq) + matvec(C_r, v_eq) + G_r
    sliding_back(gains, state, force, model_terms, d, r_d, v_d, a_d, f_d, r, r_dot, J, e, s,
                 out, extras_at)


class RobustAdaptiveImpedanceController(SlidingImpedanceController):
    """Robust adaptive impedance control (3.48) with the section 3.5.2 gains."""

    scheme = "robust_adaptive_impedance"
    PARAMETERS = (_with_wrong_model(TASK_SPACE_PARAMETERS)
                  + sliding_parameters(D=-2.0, K=2.0, K_s=4.0, boundary_layer=0.05)
                  + UNCERTAINTY_PARAMETERS
                  + impedance_parameters(A_m=20.0, B_m=400.0, P1=1.25, P2=6.56, A0=45.0,
                                         B0=30.0, c0=[1.0, 1.0], Q=5.0, Q_bc_star=1.5))
    extra_status_fields = SLIDING_STATUS_FIELDS + ESTIMATE_FIELDS
    SCHEME_GAINS = ROBUST_GAINS

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        out = self._output.new()
        robust_adaptive_impedance_cycle(self.task.chain, self.gains, self.internal, t, dt, q, v,
                                        force, out, self._extras_at)
        return self._output.views(out)
