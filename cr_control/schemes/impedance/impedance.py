"""Fixed impedance control (thesis section 5.2, controller 5.7; section 5.3, figs. 5.3-5.5).

    tau = J^T [M_r (r_d'' + m_m^-1 (d_m e_r' + k_m e_r + f - f_d)) + C_r r' + G_r - f]   (5.7)

with the constant impedance m_m = 1.2, d_m = 12, k_m = 60 of section 5.3, f_d = f_dm n
along the outward normal of the circular surface and the desired motion (5.21-5.22): see
:mod:`cr_control.schemes.blocks.unidirectional_impedance` for the sign convention and n. The status
also reports s = n^T e_r' + (k_m/d_m) n^T e_r, the quantity the fuzzy scheme tunes on.
One compiled call per cycle (:func:`impedance_cycle`).
"""

from __future__ import annotations

from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Param
from cr_control.schemes.blocks.unidirectional_impedance import (
    CONTACT_PARAMETERS,
    REFERENCE_PARAMETERS,
    SCHEME_GAINS_AT,
    UnidirectionalImpedanceController,
    contact_state,
    impedance_torque,
    normal_sliding,
    write_status,
)

_D, _K = SCHEME_GAINS_AT, SCHEME_GAINS_AT + 1


@njit(cache=True, error_model="numpy")
def impedance_cycle(chain, gains, t, q, v, force, out):
    """One cycle of (5.7) with the fixed d_m, k_m into ``out`` (task_space.split_output)."""
    r_d, v_d, a_d, r, r_dot, J, J_inv, jdot_v, f, n, gap, f_m, f_d = contact_state(
        chain, gains, t, q, v, force)
    e, e_dot = r_d - r, v_d - r_dot
    d_m, k_m = gains[_D], gains[_K]
    tau = impedance_torque(chain, gains, q, v, J, J_inv, jdot_v, a_d, e, e_dot, f, f_d, d_m, k_m)
    s = normal_sliding(n, e, e_dot, k_m / d_m)
    write_status(out, r_d, v_d, a_d, f_d, r, r_dot, f, e, tau, f_m, gap, n, s, d_m, k_m)


class ImpedanceController(UnidirectionalImpedanceController):
    """Fixed impedance control (5.7) with the section 5.3 impedance."""

    scheme = "impedance"
    PARAMETERS = REFERENCE_PARAMETERS + CONTACT_PARAMETERS + [
        Param("d_m", 12.0, "Desired impedance damping d_m (N s/m) (section 5.3: 12).",
              "positive"),
        Param("k_m", 60.0, "Desired impedance stiffness k_m (N/m) (section 5.3: 60).",
              "nonnegative"),
    ]
    SCHEME_GAINS = Layout(d_m=1, k_m=1)
    kernel = impedance_cycle
