"""What the chapter 5 schemes share: the controller (5.7) on a known unilateral surface
(:mod:`cr_control.schemes.blocks.unidirectional_impedance`), with the damping d_m and the
stiffness k_m chosen per cycle by the scheme (fixed, 5.7; fuzzy, 5.20).

A ``~/target_wrench`` whose part along the outward normal is negative asks the surface to
pull the tool: a unilateral surface cannot (f = f_m n, f_m >= 0, 5.8; f_d = f_dm n with
f_dm >= 0, 5.9), and (5.6) would turn it into a motion away from the surface of
|f_dm| / k_m (0.83 m for -50 N at k_m = 60 N/m) and an impact on the way back (measured on
the Panda's wiping task: after -50 N for 1 s the tool was still off the table 3 s after
+10 N was asked again; with less normal damping, -10 N for 2 s then +10 N hit the table
with 19.5 N). That part is taken as zero:
f_d <- f_d - min(f_dm, 0) n, the tool stays on the surface at zero normal force; to leave
the surface, send a target pose."""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

from cr_control.core.linalg import tmatvec
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.blocks import unidirectional_impedance as contact
from cr_control.schemes.blocks.references import (
    TARGETS,
    DesiredMotion,
    guard_gains_of,
    guard_state_of,
)
from cr_control.schemes.blocks.task_space import common_blocks, model_force, task_back, task_front
from cr_control.schemes.impedance.base import TaskSpaceController

_WRENCH_SEQ = TARGETS.offset("wrench_seq")

#: One cycle of a chapter 5 law before its d_m and k_m: the task frame, the measured force f,
#: the desired motion (its force f_d = f_dm n, or the target wrench's without a pull), the
#: outward normal n at the tool, the gap, f_m = n^T f, f_dm, e_r = r_d - r and e_r', the
#: packed contact gains (:func:`contact_gains`) and the scheme's own.
ContactCycle = namedtuple("ContactCycle", ["frame", "f", "desired", "n", "gap", "f_m", "f_dm",
                                           "e", "e_dot", "contact", "own"])


@njit(cache=True, error_model="numpy")
def unidirectional_front(chain, gains, state, targets, t, dt, q, v, force):
    """The common front, then the contact state: the :data:`ContactCycle`."""
    frame, f, desired = task_front(chain, gains, state, targets, t, dt, q, v, force)
    m, n_q = f.shape[0], q.shape[0]
    common, law_at = common_blocks(gains)
    law = gains[law_at:]
    size = contact.contact_gains_size(m)
    gains_contact = law[:size]
    n, gap, f_m, f_d, f_dm = contact.contact_state(
        gains_contact, frame.r, f, desired.f, targets[_WRENCH_SEQ] != 0.0,
        guard.contact_ramp(guard_gains_of(common.reference, m, n_q),
                           guard_state_of(state, m, n_q), desired.ramp, gains_contact[0]))
    if f_dm < 0.0:          # a target pulling on the unilateral surface (module docstring)
        f_d = f_d - f_dm * n
        f_dm = 0.0
    desired = DesiredMotion(desired.r, desired.v, desired.a, f_d, desired.quat, desired.w,
                            desired.posture, desired.ramp)
    return ContactCycle(frame, f, desired, n, gap, f_m, f_dm, desired.r - frame.r,
                        desired.v - frame.r_dot, gains_contact, law[size:])


@njit(cache=True, error_model="numpy")
def unidirectional_back(chain, gains, state, cycle, d_m, k_m, lam, out):
    """tau of (5.7) for the :data:`ContactCycle` ``cycle`` with d_m, k_m (scaled by the
    contact-stability monitor) into ``out``, with the contact status (s with lambda)."""
    c, m = cycle, cycle.e.shape[0]
    k_s, d_s = guard.scales(guard_state_of(state, m, c.frame.q.shape[0]), m)
    d_m, k_m = d_s * d_m, k_s * k_m
    u = contact.impedance_acceleration(c.contact, c.desired.a, c.e, c.e_dot, c.f, c.desired.f,
                                       d_m, k_m, c.n)
    tau = tmatvec(c.frame.J, model_force(chain, c.frame, u, c.frame.r_dot) - c.f)
    extras = task_back(gains, state, c.frame, tau, c.desired, c.f, c.e, out)
    s = contact.normal_sliding(c.n, c.e, c.e_dot, lam)
    contact.write_contact_status(extras, c.f_m, c.gap, c.n, s, d_m, k_m)


class UnidirectionalController(TaskSpaceController):
    """The chapter 5 schemes on any URDF arm: the contact's parameters, gains and status
    fields; schemes extend the hooks with their own parameters and gains, and give the
    kernel."""

    HAS_DESIRED_FORCE = False
    ROBOT_DEFAULTS = {"urdf_file": ("two_link_arm_ch5.urdf", "URDF file: a path, a file of "
                                    "cr_control's config directory, or package://PKG/path. "
                                    "Default: the chapter 5 arm (0.6 m links, section 5.3).")}
    @classmethod
    def reference_defaults(cls) -> dict:
        """The desired motion of section 5.3 (5.21-5.22) on the circle."""
        return dict(offset=[0.8, -0.4], amplitude=[0.3, -0.3], phase=[-math.pi / 2, 0.0],
                    frequency=1.0, relative=False, desired_force=None, what="5.21-5.22")

    @classmethod
    def law_parameters(cls, model, thesis):
        return contact.contact_parameters(model.m, thesis)

    def law_status_fields(self):
        return contact.contact_status_fields(self.model.position_axes)

    def law_gains_layout(self):
        return contact.contact_gains(self.model.m)

    def law_gain_values(self):
        return contact.contact_gain_values(self.values)

    def default_approach_direction(self):
        """Against the plane's outward normal (a sphere: none; give approach_direction)."""
        if self.values["surface"] != "plane":
            return np.zeros(self.model.m)
        return -np.asarray(contact.contact_gain_values(self.values)["surface_normal"], dtype=float)
