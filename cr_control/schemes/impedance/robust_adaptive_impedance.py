"""Robust adaptive impedance control (thesis section 3.3, controller 3.48).

    tau = J^T [M_r^ r_eq'' + K_s s + d sat(s/Delta) + C_r^ r_eq' + G_r^ - f]      (3.48)
    d   = dM |r_eq''| + dC |r_eq'| + dG + df      (3.51, with equality, every cycle)

M_r^, C_r^, G_r^ are the task-space dynamics (3.2) of the controller's model of the arm,
which is deliberately wrong (section 3.5.2): link inertias 0.2 kg m^2 and masses 0.05 kg
instead of 0.3 and 0.1, i.e. ``model_inertia_scale`` 2/3 and ``model_mass_scale`` 0.5 of the
URDF's (on any URDF arm the same scales apply to every link). Compensator z (3.40,
3.43-3.45), s (3.41), r_eq (3.49-3.50), the boundary layer (remark 3.3.1) and the D sign convention are in
:mod:`cr_control.schemes.blocks.sliding_impedance`; the impedance estimates follow 3.61-3.65 with
e'^T in the A_hat law (3.48 prints e^T; docs/thesis.md) through
:mod:`cr_control.schemes.blocks.impedance_adaptation`.

The printed bounds dM = 0.1, dC = 0.1 (3.36-3.37) do not bound the real model errors of
this example (|M_r - M_r^| is several kg in the workspace); they are used as printed and
K_s s carries the rest, as in the thesis's simulation.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.blocks.sliding_impedance import sliding_parameters
from cr_control.schemes.blocks.task_space import model_force
from cr_control.schemes.impedance.sliding import SlidingController, sliding_back, sliding_front

UNCERTAINTY_PARAMETERS = [
    Param("delta_M", 0.1, "Bound dM of |M_r - M_r^| (3.36), used in d (3.51).", "nonnegative",
          bound=Bound.MASS),
    Param("delta_C", 0.1, "Bound dC of |C_r - C_r^| (3.37), used in d (3.51).", "nonnegative",
          bound=Bound.GAIN),
    Param("delta_G", 0.05, "Bound dG of |G_r - G_r^| (3.38), used in d (3.51) (N).",
          "nonnegative", bound=Bound.FORCE),
    Param("delta_f", 0.1, "Bound df of the disturbance force |f~| (3.39), used in d (3.51) (N).",
          "nonnegative", bound=Bound.FORCE),
]


@njit(cache=True, error_model="numpy")
def robust_adaptive_impedance_cycle(chain, gains, state, targets, t, dt, q, v, force, out):
    """One cycle of (3.48) into ``out``."""
    cycle = sliding_front(chain, gains, state, targets, t, dt, q, v, force)
    own, v_eq, a_eq = cycle.own_gains, cycle.v_eq, cycle.a_eq
    delta_M, delta_C, delta_G, delta_f = own[0], own[1], own[2], own[3]
    d = (delta_M * math.sqrt(np.sum(a_eq * a_eq)) + delta_C * math.sqrt(np.sum(v_eq * v_eq))
         + delta_G + delta_f)                                                      # 3.51
    model_terms = model_force(chain, cycle.frame, a_eq, v_eq)
    sliding_back(gains, state, cycle, model_terms, d, out)


class RobustAdaptiveImpedanceController(SlidingController):
    """Robust adaptive impedance control (3.48) with the section 3.5.2 gains."""

    scheme = "robust_adaptive_impedance"
    kernel = robust_adaptive_impedance_cycle
    ROBOT_DEFAULTS = {
        "model_mass_scale": (0.5, "The controller's model: every link mass times this; section "
                             "3.5.2 estimates 0.05 kg for the true 0.1 kg."),
        "model_inertia_scale": (0.2 / 0.3, "The controller's model: every rotational inertia "
                                "times this; section 3.5.2 estimates 0.2 kg m^2 for the true 0.3."),
    }

    @classmethod
    def reference_defaults(cls) -> dict:
        """The desired motion of section 3.5 (3.93) and the desired force."""
        return dict(offset=[0.0, 0.35], amplitude=[0.1, 0.1], phase=[0.0, 0.0], frequency=2.0,
                    relative=False, desired_force=[5.0, -5.0], what="3.93")

    @classmethod
    def law_parameters(cls, model, thesis):
        m = model.m
        return (sliding_parameters(m, D=-2.0, K=2.0, K_s=4.0, boundary_layer=0.05)
                + UNCERTAINTY_PARAMETERS
                + impedance.impedance_parameters(m, A_m=20.0, B_m=400.0, P1=1.25, P2=6.56,
                                                 A0=45.0, B0=30.0, c0=[1.0] * m, Q=5.0,
                                                 Q_bc_star=1.5,
                                                 c_max=0.0 if thesis else impedance.C_HAT_MAX))

    def law_gains_layout(self) -> Layout:
        """The sliding schemes' gains, then the bounds of (3.51)."""
        return super().law_gains_layout().extended(delta_M=1, delta_C=1, delta_G=1, delta_f=1)
