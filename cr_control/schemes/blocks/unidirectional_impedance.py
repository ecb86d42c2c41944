"""Impedance control on a unilateral surface: the building blocks of chapter 5, m axes.

Controller (5.7), shared by the fixed-impedance and the fuzzy scheme:

    tau = J^T [M_r (r_d'' + m_m^-1 (d_m e_r' + k_m e_r + f - f_d)) + C_r r' + G_r - f]

with e_r = r_d - r. Substituted into (5.4) it gives the impedance (5.6)
f_d - f = m_m e_r'' + d_m e_r' + k_m e_r. The task-space model M_r, C_r, G_r (5.4) is the
chapter 3 one (:mod:`cr_control.schemes.blocks.task_space`, any URDF arm).

Sign convention of the force. f in (5.1), (5.4) and (5.7) is the force of the environment
ON the robot (tau + J^T f), which is what this package's plants and force sensor report.
The surface pushes the tool out along its outward normal n, so f = f_m n with f_m >= 0
(5.8), and the desired force is f_d = f_dm n (5.9): f_dm = 10 N along the OUTWARD normal,
i.e. the tool presses 10 N into the surface. Projected on n, (5.6) reads
e_fm = f_dm - f_m = m_m n^T e_r'' + d_m n^T e_r' + k_m n^T e_r (5.11). A ``~/target_wrench``
replaces f_d = f_dm n by its force (and f_dm by its component along n).

The normal n. The thesis needs it at the contact point and remarks it can be estimated from
the measured force; that fails exactly when it matters (after separation f = 0). The
controller therefore knows the surface: ``surface`` "sphere" |r - c| = R (a circle on the
planar arm: section 5.3's, with n = (r - c)/|r - c| at the measured tool position, the
nearest surface point's normal) or "plane" n.(r - c) = 0 (a table: n = the plane's normal),
c = ``surface_centre`` (a point of the plane). f_m = n^T f, the measured force along that
normal: = |f| while f is a contact force along n, and it goes negative if anything pulls,
which is the "force along the normal" of figs. 5.4 and 5.7.

The desired motion (5.21-5.22) x_d = 0.8 - 0.3 sin t, y_d = -0.4 + 0.3 cos t is a
:func:`~cr_control.schemes.blocks.references.cosine_reference` r_d = offset - amplitude cos(w t
+ phase) with offset (0.8, -0.4), amplitude (0.3, -0.3), phase (-pi/2, 0), w = 1 rad/s.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Bound, Param

SPHERE, PLANE = 0.0, 1.0


def contact_parameters(m: int, thesis: bool) -> list[Param]:
    """What the controller knows of the task: desired normal force, the surface (for n) and
    the impedance inertia; section 5.3 values on the thesis's arm, a table through the base
    origin otherwise (set it to your surface)."""
    if thesis:
        surface, centre, radius, normal, f_dm = "sphere", [0.8, -0.4], 0.3, [0.0, 1.0], 10.0
    else:
        surface, centre, radius, normal, f_dm = "plane", [0.0] * m, 1.0, [0.0] * (m - 1) + [1.0], 0.0
    return [
        Param("f_dm", f_dm, "Desired contact force magnitude f_dm (N) along the outward surface "
              "normal: f_d = f_dm n (5.9; section 5.3: 10).", "nonnegative", bound=Bound.FORCE),
        Param("surface", surface, "Controller's model of the surface, for the normal n: sphere "
              "|r - c| = R (section 5.3's circle) or plane n.(r - c) = 0.", "choice",
              choices=("sphere", "plane")),
        Param("surface_centre", centre, "Surface model: the sphere's centre c, or a point of "
              "the plane (m, base frame).", "vector", m, bound=Bound.LENGTH),
        Param("surface_radius", radius, "Surface model: the sphere's radius R (m).", "positive",
              bound=Bound.LENGTH),
        Param("surface_normal", normal, "Surface model: the plane's outward normal (normalised "
              "here).", "vector", m, bound=Bound.SCALE),
        Param("m_m", 1.2, "Desired impedance inertia m_m (kg) (5.6; section 5.3: 1.2).",
              "positive", bound=Bound.MASS),
        Param("tangential_stiffness", 0.0, "Impedance stiffness k_t (N/m) across the normal, in "
              "the surface's tangent plane: stiff in the plane (friction holds a tool 3 N "
              "behind its path: 50 mm at k_m = 60 N/m), compliant along the force; 0 = k_m on "
              "every axis, as (5.6).", "nonnegative", bound=Bound.GAIN),
        Param("tangential_damping", 0.0, "Impedance damping d_t (N s/m) in the tangent plane; "
              "0 = d_m on every axis, as (5.6).", "nonnegative", bound=Bound.GAIN),
    ]


def contact_gains(m: int) -> Layout:
    """Packed contact parameters (surface as SPHERE/PLANE, the normal normalised)."""
    return Layout(f_dm=1, surface=1, surface_centre=m, surface_radius=1, surface_normal=m, m_m=1,
                  tangential_stiffness=1, tangential_damping=1)


def contact_gain_values(values: dict) -> dict:
    """The values of :func:`contact_gains` from the parameters."""
    normal = np.asarray(values["surface_normal"], dtype=float)
    norm = float(np.linalg.norm(normal))
    return {**values, "surface": PLANE if values["surface"] == "plane" else SPHERE,
            "surface_normal": normal / norm if norm > 0.0 else normal}


@njit(cache=True, error_model="numpy")
def contact_gains_size(m):
    """contact_gains(m).size, for kernels (the scheme's own gains follow)."""
    return 2 * m + 6


#: Status fields of both chapter 5 schemes after the task-space ones: measured force along
#: the normal, the gap to the controller's surface model (negative = penetration), the
#: normal, s (5.18), the impedance damping and stiffness.
def contact_status_fields(axes: tuple[str, ...]) -> list[str]:
    return ["f_m", "gap"] + [f"n_{a}" for a in axes] + ["s", "d_m", "k_m"]


@njit(cache=True, error_model="numpy")
def contact_state(contact, r, f, f_d_given, wrench_target, ramp):
    """(n, gap, f_m, f_d, f_dm): the outward normal at the tool (module docstring), the gap,
    the measured force along n, the desired force (ramp f_dm n, or ``f_d_given`` (ramped
    already) when a target wrench is in force, its normal part then being f_dm)."""
    m = r.shape[0]
    f_dm = ramp * contact[0]
    c = contact[2:2 + m]
    n = np.empty(m)
    if contact[1] == PLANE:
        n[:] = contact[3 + m:3 + 2 * m]
        gap = 0.0
        for i in range(m):
            gap += n[i] * (r[i] - c[i])
    else:
        d = r - c
        dist = math.sqrt(np.sum(d * d))
        if dist > 0.0:
            n[:] = d / dist
        else:
            n[:] = 0.0
            n[0] = 1.0
        gap = dist - contact[2 + m]
    f_m = np.sum(n * f)
    if wrench_target:
        f_d = f_d_given.copy()
        f_dm = np.sum(n * f_d)
    else:
        f_d = f_dm * n
    return n, gap, f_m, f_d, f_dm


@njit(cache=True, error_model="numpy")
def impedance_acceleration(contact, a_d, e, e_dot, f, f_d, d_m, k_m, n):
    """The task acceleration of (5.7): r_d'' + m_m^-1 (d_m e_r' + k_m e_r + f - f_d), with
    d_m, k_m along the normal n and the tangential gains (``tangential_stiffness`` k_t,
    ``tangential_damping`` d_t, where set) across it:
    d_m e' + k_m e  ->  (d_m P_n + d_t P_t) e' + (k_m P_n + k_t P_t) e,  P_n = n n^T, P_t = I - P_n."""
    m = e.shape[0]
    k_t, d_t = contact[4 + 2 * m], contact[5 + 2 * m]
    if k_t <= 0.0 and d_t <= 0.0:
        return a_d + (d_m * e_dot + k_m * e + f - f_d) / contact[3 + 2 * m]
    k_t = k_t if k_t > 0.0 else k_m
    d_t = d_t if d_t > 0.0 else d_m
    e_n, e_dot_n = np.sum(n * e), np.sum(n * e_dot)
    spring = k_t * e + (k_m - k_t) * e_n * n
    damper = d_t * e_dot + (d_m - d_t) * e_dot_n * n
    return a_d + (damper + spring + f - f_d) / contact[3 + 2 * m]


@njit(cache=True, error_model="numpy")
def normal_sliding(n, e, e_dot, lam):
    """s = n^T e_r' + lambda n^T e_r (5.18)."""
    return np.sum(n * e_dot) + lam * np.sum(n * e)


@njit(cache=True, error_model="numpy")
def write_contact_status(extras, f_m, gap, n, s, d_m, k_m):
    """Fill contact_status_fields."""
    m = n.shape[0]
    extras[0], extras[1] = f_m, gap
    extras[2:2 + m] = n
    extras[2 + m], extras[3 + m], extras[4 + m] = s, d_m, k_m
