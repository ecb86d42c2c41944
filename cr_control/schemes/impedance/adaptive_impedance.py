"""Adaptive impedance control (thesis section 3.2, controller 3.32, laws 3.11-3.14).

    tau = J^T [M_r (r_d'' + A_hat e' + B_hat e - c_hat) + C_r r' + G_r - f]   (3.32)

with A_hat, B_hat, c_hat from the reference model (3.8) and the laws (3.11-3.14) in
:mod:`cr_control.schemes.blocks.impedance_adaptation`, e = r_d - r, and the task-space model
(3.2) of any URDF arm (:mod:`cr_control.schemes.blocks.task_space`; on the thesis's 2-link arm
J^-T and J^-1 are the thesis's). One compiled call per cycle (:func:`adaptive_impedance_cycle`).
"""

from __future__ import annotations

from numba import njit

from cr_control.core.linalg import tmatvec
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.blocks.references import guard_state_of
from cr_control.schemes.blocks.task_space import law_blocks, model_force, task_back, task_front
from cr_control.schemes.impedance.base import TaskSpaceController


@njit(cache=True, error_model="numpy")
def adaptive_impedance_cycle(chain, gains, state, targets, t, dt, q, v, force, out):
    """One cycle of (3.32) into ``out`` (see task_space.task_back)."""
    frame, f, desired = task_front(chain, gains, state, targets, t, dt, q, v, force)
    law_gains, law_state = law_blocks(gains, state)
    m = f.shape[0]
    e, e_dot = desired.r - frame.r, desired.v - frame.r_dot
    impedance.impedance_update(law_gains, law_state, e, e_dot, dt)
    k_s, d_s = guard.scales(guard_state_of(state, m, q.shape[0]), m)
    u0 = desired.a + impedance.impedance_acceleration(law_state, k_s * e, d_s * e_dot)
    tau = tmatvec(frame.J, model_force(chain, frame, u0, frame.r_dot) - f)
    extras = task_back(gains, state, frame, tau, desired, f, e, out)
    extras[:] = law_state[law_state.shape[0] - extras.shape[0]:]   # the estimates: the tail


class AdaptiveImpedanceController(TaskSpaceController):
    """Adaptive impedance control (3.32) with the section 3.5.1 gains."""

    scheme = "adaptive_impedance"
    kernel = adaptive_impedance_cycle

    @classmethod
    def reference_defaults(cls) -> dict:
        """The desired motion of section 3.5 (3.93) and the desired force."""
        return dict(offset=[0.0, 0.35], amplitude=[0.1, 0.1], phase=[0.0, 0.0], frequency=2.0,
                    relative=False, desired_force=[5.0, -5.0], what="3.93")

    @classmethod
    def law_parameters(cls, model, thesis):
        return impedance.impedance_parameters(model.m, A_m=20.0, B_m=400.0, P1=1.25, P2=6.56,
                                              A0=45.0, B0=30.0, c0=[1.0] * model.m, Q=5.0,
                                              Q_bc_star=1.5,
                                              c_max=0.0 if thesis else impedance.C_HAT_MAX)

    def law_status_fields(self):
        return impedance.estimate_fields(self.model.position_axes)

    def law_gains_layout(self):
        return impedance.gains_layout(self.model.m)

    def law_initial_state(self):
        return impedance.initial_state(self.values, self.model.m)

    def __init__(self, values: dict):
        super().__init__(values)
        self.adaptation = impedance.ImpedanceAdaptation(
            self.internal[self.reference_state.size:], self.model.m)
