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

import numpy as np
from numba import njit

from cr_control.core.linalg import tmatvec
from cr_control.core.packing import Layout
from cr_control.schemes.blocks import contact_guard as guard
from cr_control.schemes.blocks import unidirectional_impedance as contact
from cr_control.schemes.blocks.references import TARGETS, guard_gains_of, guard_state_of
from cr_control.schemes.blocks.task_space import common_blocks, model_force, task_back, task_front
from cr_control.schemes.impedance.base import TaskSpaceController

_WRENCH_SEQ = TARGETS.offset("wrench_seq")


@njit(cache=True, error_model="numpy")
def unidirectional_front(chain, gains, state, targets, t, dt, q, v, force):
    """The common front, then the contact state: (frame, f, r_d, v_d, a_d, quat_d, w_d,
    posture, n, gap, f_m, f_d, f_dm, e, e', the contact gains, the scheme's own gains)."""
    frame, f, r_d, v_d, a_d, f_d_ref, quat_d, w_d, posture, ramp = task_front(
        chain, gains, state, targets, t, dt, q, v, force)
    m, n_q = r_d.shape[0], q.shape[0]
    common, law_at = common_blocks(gains)
    law = gains[law_at:]
    size = contact.contact_gains_size(m)
    gains_contact = law[:size]
    n, gap, f_m, f_d, f_dm = contact.contact_state(
        gains_contact, frame.r, f, f_d_ref, targets[_WRENCH_SEQ] != 0.0,
        guard.contact_ramp(guard_gains_of(common.reference, m, n_q),
                           guard_state_of(state, m, n_q), ramp, gains_contact[0]))
    if f_dm < 0.0:          # a target pulling on the unilateral surface (module docstring)
        f_d = f_d - f_dm * n
        f_dm = 0.0
    return (frame, f, r_d, v_d, a_d, quat_d, w_d, posture, n, gap, f_m, f_d, f_dm,
            r_d - frame.r, v_d - frame.r_dot, gains_contact, law[size:])


@njit(cache=True, error_model="numpy")
def unidirectional_back(chain, gains, state, frame, f, r_d, v_d, a_d, quat_d, w_d, posture, n,
                        gap, f_m, f_d, e, e_dot, gains_contact, d_m, k_m, lam, out):
    """tau of (5.7) with d_m, k_m (scaled by the contact-stability monitor); the output
    vector and the contact status (s with lambda)."""
    k_s, d_s = guard.scales(guard_state_of(state, e.shape[0], frame.q.shape[0]), e.shape[0])
    d_m, k_m = d_s * d_m, k_s * k_m
    u = contact.impedance_acceleration(gains_contact, a_d, e, e_dot, f, f_d, d_m, k_m, n)
    tau = tmatvec(frame.J, model_force(chain, frame, u, frame.r_dot) - f)
    extras = task_back(gains, state, frame, tau, quat_d, w_d, posture, r_d, v_d, a_d, f_d, f, e, out)
    s = contact.normal_sliding(n, e, e_dot, lam)
    contact.write_contact_status(extras, f_m, gap, n, s, d_m, k_m)


class UnidirectionalController(TaskSpaceController):
    """The chapter 5 schemes on any URDF arm; subclasses add their own gains (``OWN``:
    parameter name -> packed size 1) and kernel."""

    HAS_DESIRED_FORCE = False
    ROBOT_DEFAULTS = {"urdf_file": ("two_link_arm_ch5.urdf", "URDF file: a path, a file of "
                                    "cr_control's config directory, or package://PKG/path. "
                                    "Default: the chapter 5 arm (0.6 m links, section 5.3).")}
    OWN: tuple[str, ...] = ()

    @classmethod
    def reference_defaults(cls) -> dict:
        """The desired motion of section 5.3 (5.21-5.22) on the circle."""
        return dict(offset=[0.8, -0.4], amplitude=[0.3, -0.3], phase=[-math.pi / 2, 0.0],
                    frequency=1.0, relative=False, desired_force=None, what="5.21-5.22")

    @classmethod
    def law_parameters(cls, model, thesis):
        return contact.contact_parameters(model.m, thesis) + cls.own_parameters()

    @classmethod
    def own_parameters(cls):
        return []

    def law_status_fields(self):
        return contact.contact_status_fields(self.model.position_axes)

    def law_gains_layout(self):
        m = self.model.m
        return Layout(**contact.contact_gains(m).shapes, **dict.fromkeys(self.OWN, 1))

    def law_gain_values(self):
        return contact.contact_gain_values(self.values)

    def default_approach_direction(self):
        """Against the plane's outward normal (a sphere: none; give approach_direction)."""
        if self.values["surface"] != "plane":
            return np.zeros(self.model.m)
        return -np.asarray(contact.contact_gain_values(self.values)["surface_normal"], dtype=float)
