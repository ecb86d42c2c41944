"""What the robust (3.48) and the NN (3.76) adaptive impedance controllers share: the
impedance adaptation (3.11-3.14), the dynamic compensator and sliding surface (3.40-3.45,
:mod:`cr_control.schemes.blocks.sliding_impedance`) and

    u = [M_r r_eq'' + C_r r_eq' + G_r]^ + K_s s + d sat(s/Delta) - f,  tau = J^T u   (3.48, 3.76)

where ``[...]^`` is the scheme's estimate of the arm's task-space dynamics: a deliberately
wrong model (3.48) or RBF networks (3.76). Packed gains after the common block: impedance
(m axes), sliding, the scheme's own; state after the reference: impedance, z, z', the
scheme's own. Status: the task-space fields, s, z, d, the boundary layer in use (widened by
the period and the delay: :mod:`cr_control.schemes.blocks.sliding_impedance`), the
estimates, the scheme's own.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

from cr_control.core.linalg import matvec, tmatvec
from cr_control.core.packing import Layout
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.blocks.references import guard_state_of
from cr_control.schemes.blocks.sliding_impedance import (
    DEFAULT_DELAY_CYCLES,
    SlidingCompensator,
    boundary_layer_sign,
    boundary_layer_width,
    compensator_update,
    layer_rate,
    sliding_gains,
    sliding_status_fields,
    sliding_views,
)
from cr_control.schemes.blocks.task_space import law_blocks, task_back, task_front
from cr_control.schemes.impedance.base import TaskSpaceController

#: One cycle of a sliding scheme before its model terms: the task frame, the measured force
#: f, the desired motion, e = r_d - r, the sliding surface s (3.41), r_eq' and r_eq''
#: (3.49-3.50), the scheme's own packed gains and state (views), the cycle's step dt.
SlidingCycle = namedtuple("SlidingCycle", ["frame", "f", "desired", "e", "s", "v_eq", "a_eq",
                                           "own_gains", "own_state", "dt"])


@njit(cache=True, error_model="numpy")
def _sizes(m):
    """(impedance gains, sliding gains, impedance state) sizes for m axes."""
    return 12 * m * m + m + 1, 4 * m * m + 3, 4 * m * m + 5 * m + 1


@njit(cache=True, error_model="numpy")
def sliding_front(chain, gains, state, targets, t, dt, q, v, force):
    """The common front, the impedance estimates and the compensator: the
    :data:`SlidingCycle`."""
    frame, f, desired = task_front(chain, gains, state, targets, t, dt, q, v, force)
    m = f.shape[0]
    law_gains, law_state = law_blocks(gains, state)
    g_imp, g_sl, s_imp = _sizes(m)
    e, e_dot = desired.r - frame.r, desired.v - frame.r_dot
    impedance_state = law_state[:s_imp]
    impedance.impedance_update(law_gains[:g_imp], impedance_state, e, e_dot, dt)
    _, _, A_hat, B_hat, c_hat, _ = impedance.state_views(impedance_state, m)
    D, K_1, K_2, _, _, d_sign, _ = sliding_views(law_gains[g_imp:g_imp + g_sl], m)
    s, v_eq, a_eq = compensator_update(D, K_1, K_2, d_sign, law_state[s_imp:s_imp + m],
                                       law_state[s_imp + m:s_imp + 2 * m], dt, e, e_dot,
                                       desired.v, desired.a, A_hat, B_hat, c_hat)
    return SlidingCycle(frame, f, desired, e, s, v_eq, a_eq, law_gains[g_imp + g_sl:],
                        law_state[s_imp + 2 * m:], dt)


@njit(cache=True, error_model="numpy")
def sliding_back(gains, state, cycle, model_terms, d, out):
    """u = model_terms + K_s s + d sat(s/Delta) - f, tau = J^T u (3.48, 3.76) for the
    :data:`SlidingCycle` ``cycle`` into ``out`` with s, z, d, the boundary layer (Delta widened
    by the period and the delay) and the estimates in the status; returns the scheme's own
    status fields (after them)."""
    frame, s = cycle.frame, cycle.s
    m, n = s.shape[0], frame.q.shape[0]
    law_gains, law_state = law_blocks(gains, state)
    g_imp, g_sl, s_imp = _sizes(m)
    _, _, _, K_s, delta, _, rate = sliding_views(law_gains[g_imp:g_imp + g_sl], m)
    _, d_s = guard.scales(guard_state_of(state, m, n), m)      # the monitor's damping scale
    delta = boundary_layer_width(delta, rate, d, cycle.dt, frame.Lam)   # period and delay
    u = model_terms + d_s * matvec(K_s, s) + d * boundary_layer_sign(s, delta) - cycle.f
    extras = task_back(gains, state, frame, tmatvec(frame.J, u), cycle.desired, cycle.f, cycle.e,
                       out)
    extras[:m] = s
    extras[m:2 * m] = law_state[s_imp:s_imp + m]
    extras[2 * m] = d
    extras[2 * m + 1] = delta
    n_est = 2 * m * m + 2 * m                   # A_hat, B_hat, c_hat, varpi: the state's tail
    extras[2 * m + 2:2 * m + 2 + n_est] = law_state[s_imp - n_est:s_imp]
    return extras[2 * m + 2 + n_est:]


class SlidingController(TaskSpaceController):
    """Shared set-up of the schemes tau = J^T (model terms + K_s s + d sat(s/Delta) - f)
    (3.48, 3.76): the impedance adaptation and the sliding compensator. Schemes give their
    parameters (:meth:`law_parameters`, with their impedance and sliding defaults) and extend
    the hooks below with their own gains, state and status fields."""

    def law_status_fields(self):
        """s, z, d (3.40-3.41, 3.51), the boundary layer in use, then the impedance estimates
        (3.11-3.14)."""
        axes = self.model.position_axes
        return sliding_status_fields(axes) + impedance.estimate_fields(axes)

    def law_gains_layout(self):
        """The impedance adaptation's and the compensator's packed gains."""
        m = self.model.m
        return Layout(impedance=impedance.gains_layout(m).size, sliding=sliding_gains(m).size)

    def law_gain_values(self):
        m = self.model.m
        return {**self.values, "impedance": impedance.gains_layout(m).pack(self.values),
                "sliding": sliding_gains(m).pack({
                    **self.values, "d_sign": SlidingCompensator.D_SIGN,
                    "layer_rate": layer_rate(self.values.get("command_delay_cycles",
                                                             DEFAULT_DELAY_CYCLES))})}

    def law_initial_state(self):
        """The impedance adaptation's state, then z and z' (3.40) at zero."""
        m = self.model.m
        return np.concatenate([impedance.initial_state(self.values, m), np.zeros(2 * m)])

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
