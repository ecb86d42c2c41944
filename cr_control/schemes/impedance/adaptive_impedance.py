"""Adaptive impedance control (thesis section 3.2, controller 3.32, laws 3.11-3.14).

    tau = J^T [M_r (r_d'' + A_hat e' + B_hat e - c_hat) + C_r r' + G_r - f]   (3.32)

with A_hat, B_hat, c_hat from the reference model (3.8) and the laws (3.11-3.14) in
:mod:`cr_control.schemes.blocks.impedance_adaptation`, e = r_d - r, and the task-space model
(3.2) evaluated in joint space (:func:`~cr_control.schemes.blocks.task_space.torque_for_acceleration`).
One compiled call per cycle (:func:`adaptive_impedance_cycle`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.schemes.blocks import impedance_adaptation as impedance
from cr_control.schemes.blocks.impedance_adaptation import (
    ESTIMATE_FIELDS,
    ImpedanceAdaptation,
    impedance_acceleration,
    impedance_parameters,
    impedance_update,
)
from cr_control.schemes.blocks.references import REFERENCE, packed_reference
from cr_control.schemes.blocks.task_space import (
    TASK_SPACE_PARAMETERS,
    ArmTaskSpace,
    task_state,
    torque_for_acceleration,
    write_task_space,
)
from cr_control.schemes.controller import Controller, ControlOutput, KernelOutput

#: The scheme's packed gains: the reference block, then the impedance adaptation's.
_R = REFERENCE.size
_I = _R + impedance.GAINS.size
_EST = impedance.ESTIMATES


@njit(cache=True, error_model="numpy")
def adaptive_impedance_cycle(chain, gains, state, t, dt, q, v, force, out, extras_at):
    """One cycle of (3.32) into ``out`` (task_space.split_output)."""
    r_d, v_d, a_d, f_d = packed_reference(gains[:_R], t)
    f = force[:2]
    r, r_dot, J, J_inv, jdot_v = task_state(chain, q, v)
    e, e_dot = r_d - r, v_d - r_dot
    impedance_update(gains[_R:_I], state, e, e_dot, dt)
    u0 = a_d + impedance_acceleration(state, e, e_dot)
    tau = torque_for_acceleration(chain, q, v, J, J_inv, jdot_v, u0, f)
    status = write_task_space(out, r_d, v_d, a_d, f_d, r, r_dot, f, e, tau)
    status[extras_at:] = state[_EST]


class AdaptiveImpedanceController(Controller):
    """Adaptive impedance control (3.32) with the section 3.5.1 gains."""

    scheme = "adaptive_impedance"
    PARAMETERS = TASK_SPACE_PARAMETERS + impedance_parameters(
        A_m=20.0, B_m=400.0, P1=1.25, P2=6.56, A0=45.0, B0=30.0, c0=[1.0, 1.0],
        Q=5.0, Q_bc_star=1.5)
    extra_status_fields = ESTIMATE_FIELDS
    GAINS = Layout(reference=_R, impedance=impedance.GAINS.size)

    def __init__(self, values: dict):
        super().__init__(values)
        self.task = ArmTaskSpace(self.values)
        self.gains = np.zeros(self.GAINS.size)
        self.pack_gains()
        self.internal = impedance.initial_state(self.values)
        self.adaptation = ImpedanceAdaptation(self.internal)
        self._output = KernelOutput(self)
        self._extras_at = self._output.extras_at

    def pack_gains(self) -> None:
        """Copy the current parameter values into the packed gains the kernel reads."""
        REFERENCE.pack(self.values, self.GAINS.view(self.gains, "reference"))
        impedance.GAINS.pack(self.values, self.GAINS.view(self.gains, "impedance"))

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        out = self._output.new()
        adaptive_impedance_cycle(self.task.chain, self.gains, self.internal, t, dt, q, v, force,
                                 out, self._extras_at)
        return self._output.views(out)
