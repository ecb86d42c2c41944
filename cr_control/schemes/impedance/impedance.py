"""Fixed impedance control (thesis section 5.2, controller 5.7; section 5.3, figs. 5.3-5.5).

    tau = J^T [M_r (r_d'' + m_m^-1 (d_m e_r' + k_m e_r + f - f_d)) + C_r r' + G_r - f]   (5.7)

with the constant impedance m_m = 1.2, d_m = 12, k_m = 60 of section 5.3, f_d = f_dm n
along the outward normal of the surface and the desired motion (5.21-5.22): see
:mod:`cr_control.schemes.blocks.unidirectional_impedance` for the sign convention and n. The
status also reports s = n^T e_r' + (k_m/d_m) n^T e_r, the quantity the fuzzy scheme tunes
on. One compiled call per cycle (:func:`impedance_cycle`).
"""

from __future__ import annotations

from numba import njit

from cr_control.core.parameters import Bound, Param
from cr_control.schemes.impedance.unidirectional import (
    UnidirectionalController,
    unidirectional_back,
    unidirectional_front,
)


@njit(cache=True, error_model="numpy")
def impedance_cycle(chain, gains, state, targets, t, dt, q, v, force, out):
    """One cycle of (5.7) with the fixed d_m, k_m into ``out``."""
    cycle = unidirectional_front(chain, gains, state, targets, t, dt, q, v, force)
    d_m, k_m = cycle.own[0], cycle.own[1]
    unidirectional_back(chain, gains, state, cycle, d_m, k_m, k_m / d_m, out)


class ImpedanceController(UnidirectionalController):
    """Fixed impedance control (5.7) with the section 5.3 impedance."""

    scheme = "impedance"
    kernel = impedance_cycle
    @classmethod
    def law_parameters(cls, model, thesis):
        return super().law_parameters(model, thesis) + [
            Param("d_m", 12.0, "Desired impedance damping d_m (N s/m) (section 5.3: 12).",
                  "positive", bound=Bound.GAIN),
            Param("k_m", 60.0, "Desired impedance stiffness k_m (N/m) (section 5.3: 60).",
                  "nonnegative", bound=Bound.GAIN),
        ]

    def law_gains_layout(self):
        """The contact's gains, then d_m and k_m."""
        return super().law_gains_layout().extended(d_m=1, k_m=1)
