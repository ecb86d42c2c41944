"""Impedance control on a curved unilateral surface: the building blocks of chapter 5.

Controller (5.7), shared by the fixed-impedance and the fuzzy scheme:

    tau = J^T [M_r (r_d'' + m_m^-1 (d_m e_r' + k_m e_r + f - f_d)) + C_r r' + G_r - f]

with e_r = r_d - r. Substituted into (5.4) it gives the impedance (5.6)
f_d - f = m_m e_r'' + d_m e_r' + k_m e_r. The task-space model M_r, C_r, G_r (5.4) is the
chapter 3 one (:mod:`cr_control.schemes.blocks.task_space`), evaluated in joint space as
J^T (M_r a + C_r r' + G_r - f) = M J^-1 (a - J' q') + C q' + G - J^T f
(:func:`~cr_control.schemes.blocks.task_space.torque_for_acceleration`, one Newton-Euler pass).

Sign convention of the force. f in (5.1), (5.4) and (5.7) is the force of the environment
ON the robot (tau + J^T f), which is what this package's plants and force sensor report.
The surface pushes the tool out along its outward normal n, so f = f_m n with f_m >= 0
(5.8), and the desired force is f_d = f_dm n (5.9): f_dm = 10 N along the OUTWARD normal,
i.e. the tool presses 10 N into the surface. Projected on n, (5.6) reads
e_fm = f_dm - f_m = m_m n^T e_r'' + d_m n^T e_r' + k_m n^T e_r (5.11).

The normal n. The thesis needs it at the contact point and remarks it can be estimated from
the measured force; that fails exactly when it matters (after separation f = 0). The
controller therefore knows the surface: a circle |r - c| = R (its own ``surface_centre``,
``surface_radius`` parameters, section 5.3 values) and takes n = (r - c)/|r - c| at the
measured tool position r (the nearest surface point's normal). f_m = n^T f, the measured
force along that normal: = |f| while f is a contact force along n, and it goes negative
if anything pulls, which is the "force along the normal" of figs. 5.4 and 5.7.

The desired motion (5.21-5.22) x_d = 0.8 - 0.3 sin t, y_d = -0.4 + 0.3 cos t is a
:func:`~cr_control.schemes.blocks.references.cosine_reference` r_d = offset - amplitude cos(w t +
phase) with offset (0.8, -0.4), amplitude (0.3, -0.3), phase (-pi/2, 0), w = 1 rad/s.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Param
from cr_control.schemes.blocks.references import CHAPTER3_REFERENCE, cosine_reference
from cr_control.schemes.blocks.task_space import (
    ARM_MODEL_PARAMETERS,
    ArmTaskSpace,
    task_state,
    torque_for_acceleration,
    write_task_space,
)
from cr_control.schemes.controller import Controller, ControlOutput, KernelOutput

_CH5_DEFAULTS = {
    "model_link_length": ([0.6, 0.6], "Controller model: link lengths (m) (section 5.3: 0.6)."),
    "model_link_com": ([0.3, 0.3], "Controller model: centre-of-mass distances (m) (mid-link)."),
    "reference_offset": ([0.8, -0.4], "r_d = offset - amplitude*cos(w t + phase): offset (m) "
                         "(5.21-5.22: the circle's centre)."),
    "reference_amplitude": ([0.3, -0.3], "r_d: amplitude per axis (m) (5.21-5.22)."),
    "reference_phase": ([-math.pi / 2, 0.0], "r_d: phase per axis (rad) (5.21: -pi/2 turns "
                        "-cos into -sin)."),
    "reference_frequency": (1.0, "r_d: angular frequency w (rad/s) (5.21-5.22: 1)."),
}


def _chapter5(specs: list[Param]) -> list[Param]:
    out = []
    for p in specs:
        if p.name in _CH5_DEFAULTS:
            default, description = _CH5_DEFAULTS[p.name]
            p = dataclasses.replace(p, default=default, description=description)
        out.append(p)
    return out


#: The arm model (0.6 m links) and the desired motion (5.21-5.22) of section 5.3.
REFERENCE_PARAMETERS = _chapter5(
    ARM_MODEL_PARAMETERS + [p for p in CHAPTER3_REFERENCE if p.name != "desired_force"])

#: What the controller knows of the task: desired normal force and the surface (for n).
CONTACT_PARAMETERS = [
    Param("f_dm", 10.0, "Desired contact force magnitude f_dm (N) along the outward surface "
          "normal: f_d = f_dm n (5.9; section 5.3: 10).", "nonnegative"),
    Param("surface_centre", [0.8, -0.4], "Controller's model of the surface |r - c| = R: "
          "centre c (m), for the normal n (section 5.3).", "vector", 2),
    Param("surface_radius", 0.3, "Controller's model of the surface: radius R (m).",
          "positive"),
    Param("m_m", 1.2, "Desired impedance inertia m_m (kg) (5.6; section 5.3: 1.2).", "positive"),
]

#: Packed form of the shared parameters (names = parameter names).
GAINS = Layout(reference_offset=2, reference_amplitude=2, reference_phase=2,
               reference_frequency=1, f_dm=1, surface_centre=2, surface_radius=1, m_m=1)
_OFF, _AMP, _PH, _W, _FDM, _C, _R, _MM = (GAINS.offset(n) for n in GAINS.shapes)

#: Status fields of both chapter 5 schemes after the task-space ones: measured force along
#: the normal, the gap to the controller's surface model (|r - c| - R; negative =
#: penetration), the normal, s (5.18), the impedance damping and stiffness in force.
STATUS_FIELDS = ["f_m", "gap", "n_x", "n_y", "s", "d_m", "k_m"]
N_EXTRA = len(STATUS_FIELDS)


@njit(cache=True, error_model="numpy")
def contact_state(chain, gains, t, q, v, force):
    """Everything (5.7) and the fuzzy rules need at time t from the measured state:
    (r_d, r_d', r_d'', r, r', J, J^-1, J' q', f, n, gap, f_m, f_d)."""
    r_d, v_d, a_d = cosine_reference(gains[_OFF:_OFF + 2], gains[_AMP:_AMP + 2],
                                     gains[_PH:_PH + 2], gains[_W], t)
    r, r_dot, J, J_inv, jdot_v = task_state(chain, q, v)
    dx, dy = r[0] - gains[_C], r[1] - gains[_C + 1]
    dist = math.sqrt(dx * dx + dy * dy)
    n = np.empty(2)
    if dist > 0.0:
        n[0], n[1] = dx / dist, dy / dist
    else:
        n[0], n[1] = 1.0, 0.0
    f = force[:2]
    f_m = n[0] * f[0] + n[1] * f[1]
    f_d = gains[_FDM] * n
    return r_d, v_d, a_d, r, r_dot, J, J_inv, jdot_v, f, n, dist - gains[_R], f_m, f_d


@njit(cache=True, error_model="numpy")
def normal_sliding(n, e, e_dot, lam):
    """s = n^T e_r' + lambda n^T e_r (5.18)."""
    return n[0] * e_dot[0] + n[1] * e_dot[1] + lam * (n[0] * e[0] + n[1] * e[1])


@njit(cache=True, error_model="numpy")
def impedance_torque(chain, gains, q, v, J, J_inv, jdot_v, a_d, e, e_dot, f, f_d, d_m, k_m):
    """tau of (5.7) with damping d_m and stiffness k_m (m_m from the shared gains)."""
    u = a_d + (d_m * e_dot + k_m * e + f - f_d) / gains[_MM]
    return torque_for_acceleration(chain, q, v, J, J_inv, jdot_v, u, f)


@njit(cache=True, error_model="numpy")
def write_status(out, r_d, v_d, a_d, f_d, r, r_dot, f, e, tau, f_m, gap, n, s, d_m, k_m):
    """Fill the cycle's output vector (task-space part, then STATUS_FIELDS at the end)."""
    status = write_task_space(out, r_d, v_d, a_d, f_d, r, r_dot, f, e, tau)
    k = status.shape[0] - N_EXTRA
    status[k], status[k + 1], status[k + 2], status[k + 3] = f_m, gap, n[0], n[1]
    status[k + 4], status[k + 5], status[k + 6] = s, d_m, k_m


class UnidirectionalImpedanceController(Controller):
    """Common part of the chapter 5 schemes: packed gains (the shared block, then the
    scheme's ``SCHEME_GAINS``), the arm model and one kernel call per cycle.

    Subclasses set ``scheme``, ``PARAMETERS`` (REFERENCE_PARAMETERS + CONTACT_PARAMETERS +
    their own), ``SCHEME_GAINS`` and ``kernel(chain, gains, t, q, v, force, out)``. The laws
    have no evolving state (d_m of the fuzzy scheme is a static map of the measured state).
    """

    extra_status_fields = STATUS_FIELDS
    SCHEME_GAINS = Layout()
    kernel = None

    def __init__(self, values: dict):
        super().__init__(values)
        self.task = ArmTaskSpace(self.values)
        self.layout = Layout(shared=GAINS.size, scheme=self.SCHEME_GAINS.size)
        self.gains = np.zeros(self.layout.size)
        self.pack_gains()
        self._output = KernelOutput(self)
        self._kernel = type(self).kernel

    def pack_gains(self) -> None:
        """Copy the current parameter values into the packed gains the kernel reads."""
        GAINS.pack(self.values, self.layout.view(self.gains, "shared"))
        self.SCHEME_GAINS.pack(self.values, self.layout.view(self.gains, "scheme"))

    def compute(self, t, dt, q, v, force) -> ControlOutput:
        out = self._output.new()
        self._kernel(self.task.chain, self.gains, t, q, v, force, out)
        return self._output.views(out)


#: Where a scheme's own gains start in the packed vector; where f_dm sits in it.
SCHEME_GAINS_AT = GAINS.size
F_DM_AT = _FDM
