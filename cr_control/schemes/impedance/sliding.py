"""What the robust (3.48) and the NN (3.76) adaptive impedance controllers share: the
impedance adaptation (3.11-3.14), the dynamic compensator and sliding surface (3.40-3.45,
:mod:`cr_control.schemes.blocks.sliding_impedance`) and

    u = [M_r r_eq'' + C_r r_eq' + G_r]^ + K_s s + d sat(s/Delta) - f,  tau = J^T u   (3.48, 3.76)

where ``[...]^`` is the scheme's estimate of the arm's task-space dynamics: a deliberately
wrong model (3.48) or RBF networks (3.76). Packed gains after the common block: impedance
(m axes), sliding, the scheme's own; state after the reference: impedance, z, z', the
scheme's own. Status: the task-space fields, s, z, d, the scheme's own, the estimates.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.linalg import matvec, tmatvec
from cr_control.core.packing import Layout
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.blocks.references import guard_state_of
from cr_control.schemes.blocks.sliding_impedance import (
    SlidingCompensator,
    boundary_layer_sign,
    compensator_update,
    sliding_gains,
    sliding_status_fields,
    sliding_views,
)
from cr_control.schemes.blocks.task_space import law_blocks, task_back, task_front
from cr_control.schemes.impedance.base import TaskSpaceController


@njit(cache=True, error_model="numpy")
def _sizes(m):
    """(impedance gains, sliding gains, impedance state) sizes for m axes."""
    return 12 * m * m + m + 1, 4 * m * m + 2, 4 * m * m + 5 * m + 1


@njit(cache=True, error_model="numpy")
def sliding_front(chain, gains, state, targets, t, dt, q, v, force):
    """The common front, the impedance estimates and the compensator: (frame, f, r_d, r_d',
    r_d'', f_d, q_d, w_d, posture, e, s, r_eq', r_eq'', the scheme's own gains and state)."""
    frame, f, r_d, v_d, a_d, f_d, quat_d, w_d, posture, _ = task_front(
        chain, gains, state, targets, t, dt, q, v, force)
    m = r_d.shape[0]
    law_gains, law_state = law_blocks(gains, state)
    g_imp, g_sl, s_imp = _sizes(m)
    e, e_dot = r_d - frame.r, v_d - frame.r_dot
    impedance_state = law_state[:s_imp]
    impedance.impedance_update(law_gains[:g_imp], impedance_state, e, e_dot, dt)
    _, _, A_hat, B_hat, c_hat, _ = impedance.state_views(impedance_state, m)
    D, K_1, K_2, _, _, d_sign = sliding_views(law_gains[g_imp:g_imp + g_sl], m)
    s, v_eq, a_eq = compensator_update(D, K_1, K_2, d_sign, law_state[s_imp:s_imp + m],
                                       law_state[s_imp + m:s_imp + 2 * m], dt, e, e_dot, v_d,
                                       a_d, A_hat, B_hat, c_hat)
    return (frame, f, r_d, v_d, a_d, f_d, quat_d, w_d, posture, e, s, v_eq, a_eq,
            law_gains[g_imp + g_sl:], law_state[s_imp + 2 * m:])


@njit(cache=True, error_model="numpy")
def sliding_back(gains, state, frame, model_terms, d, f, r_d, v_d, a_d, f_d, quat_d, w_d,
                 posture, e, s, out):
    """u = model_terms + K_s s + d sat(s/Delta) - f, tau = J^T u (3.48, 3.76) into ``out``
    with s, z, d and the estimates in the status; returns the scheme's own status fields."""
    m, n = r_d.shape[0], frame.q.shape[0]
    law_gains, law_state = law_blocks(gains, state)
    g_imp, g_sl, s_imp = _sizes(m)
    _, _, _, K_s, delta, _ = sliding_views(law_gains[g_imp:g_imp + g_sl], m)
    _, d_s = guard.scales(guard_state_of(state, m, n), m)      # the monitor's damping scale
    u = model_terms + d_s * matvec(K_s, s) + d * boundary_layer_sign(s, delta) - f
    extras = task_back(gains, state, frame, tmatvec(frame.J, u), quat_d, w_d, posture, r_d, v_d, a_d,
                       f_d, f, e, out)
    extras[:m] = s
    extras[m:2 * m] = law_state[s_imp:s_imp + m]
    extras[2 * m] = d
    n_est = 2 * m * m + 2 * m
    extras[extras.shape[0] - n_est:] = law_state[s_imp - n_est:s_imp]
    return extras[2 * m + 1:extras.shape[0] - n_est]


class SlidingController(TaskSpaceController):
    """Shared set-up of the schemes tau = J^T (model terms + K_s s + d sat(s/Delta) - f)
    (3.48, 3.76): subclasses give their impedance and sliding defaults
    (:meth:`law_parameters`), their own gains (``own_gains_layout``, ``own_gain_values``),
    state (``own_initial_state``) and status fields (``OWN_STATUS``)."""

    def law_status_fields(self):
        axes = self.model.position_axes
        return (sliding_status_fields(axes) + self.own_status_fields()
                + impedance.estimate_fields(axes))

    def own_status_fields(self) -> list[str]:
        return []

    def own_gains_layout(self) -> Layout:
        return Layout()

    def own_gain_values(self) -> dict:
        return self.values

    def own_initial_state(self) -> np.ndarray:
        return np.zeros(0)

    def law_gains_layout(self):
        m = self.model.m
        return Layout(impedance=impedance.gains_layout(m).size, sliding=sliding_gains(m).size,
                      own=self.own_gains_layout().size)

    def pack_law_gains(self, out: np.ndarray) -> None:
        m, law = self.model.m, self.law_gains
        impedance.gains_layout(m).pack(self.values, law.view(out, "impedance"))
        sliding_gains(m).pack({**self.values, "d_sign": SlidingCompensator.D_SIGN},
                              law.view(out, "sliding"))
        self.own_gains_layout().pack(self.own_gain_values(), law.view(out, "own"))

    def law_initial_state(self):
        m = self.model.m
        return np.concatenate([impedance.initial_state(self.values, m), np.zeros(2 * m),
                               self.own_initial_state()])

    def __init__(self, values: dict):
        super().__init__(values)
        m = self.model.m
        at = self.reference_state.size
        self.adaptation = impedance.ImpedanceAdaptation(self.internal[at:], m)
        self._z_at = at + impedance.state_layout(m).size

    @property
    def z(self) -> np.ndarray:
        """The compensator state z (3.40)."""
        return self.internal[self._z_at:self._z_at + self.model.m]
