"""Compiled rigid-body kinematics and dynamics of a serial chain in 3-D (any URDF arm).

The 3-D counterpart of :mod:`cr_control.models.planar_chain`: a serial chain of revolute,
continuous and prismatic joints, packed once from the Pinocchio model that
:func:`cr_control.models.urdf.load_chain` builds (rooted at the base frame), and compiled
(numba, cached on disk) so the 1 kHz loop pays one Python-level call for the tip's pose,
Jacobian and bias acceleration, the mass matrix and C q' + G together. The tests check every
quantity against Pinocchio to 1e-10.

Notation (R. Featherstone, *Rigid Body Dynamics Algorithms*, Springer 2008, with spatial
vectors in base coordinates, so no transform between bodies is ever needed). Joint i's frame
has rotation R_i and origin p_i in the base frame:
    R_i = R_{i-1} R^pl_i E_i(q_i),   p_i = p_{i-1} + R_{i-1} p^pl_i (+ z_i q_i if prismatic),
with (R^pl_i, p^pl_i) the placement of joint i in joint i-1, E_i the rotation by q_i about the
unit axis a_i (Rodrigues; identity if prismatic) and z_i = R_{i-1} R^pl_i a_i the axis in the
base frame. A motion vector is [w; v_O] (angular velocity; velocity of the body point at the
base origin), a force [n_O; f]; the joint's motion subspace is S_i = [z_i; p_i x z_i]
(revolute) or [0; z_i] (prismatic). Body i (mass m, centre of mass c, rotational inertia
I_c about c, all in the base frame) has the spatial inertia
    I_i [w; v] = [Ibar w + h x v; m v - h x w],   h = m c,   Ibar = I_c + m (|c|^2 1 - c c^T),
and these three parts add up for a composite body.

    RNEA (Featherstone ch. 5):   V_i = V_{i-1} + S_i q'_i,   A_0 = [0; -g],
        A_i = A_{i-1} + S_i q''_i + V_i x (S_i q'_i),   F_i = I_i A_i + V_i x* (I_i V_i),
        tau_i = S_i^T sum_{k >= i} F_k               (tau = M q'' + C q' + G)
    CRBA (Featherstone ch. 6):   M_ij = S_i^T (sum_{k >= j} I_k) S_j   for i <= j
    tip (p, R fixed in body n):  J_i = [S_i,v + S_i,w x p; S_i,w]   (Pinocchio's
        LOCAL_WORLD_ALIGNED frame Jacobian: linear velocity of the tip point, angular velocity)
        J' q' = [a_O + al x p + w x (v_O + w x p); al] with [al; a_O] = A_n at q'' = 0, g = 0
        (the tip's classical acceleration), and d/dt J_i from S_i' = V_i x S_i:
        J'_i = [S'_i,v + S'_i,w x p + S_i,w x p'; S'_i,w]
    C(q, v) x (Christoffel form) by polarisation of c(w) = C(q, w) w = RNEA(q, w, 0, g = 0):
        C(q, v) x = (c(v + x) - c(v) - c(x)) / 2
Here x is the cross product; V x M = [w x w'; w x v' + v x w'], V x* F = [w x n + v x f; w x f].
Continuous joints are driven by their angle (Pinocchio's configuration holds cos, sin).

Pinocchio's conventions, as the tests establish: ``getFrameJacobianTimeVariation(...,
LOCAL_WORLD_ALIGNED)`` after ``computeJointJacobiansTimeVariation`` is d/dt of the
LOCAL_WORLD_ALIGNED frame Jacobian (it agrees with :func:`jacobian_dot` and with central
finite differences of J, including the S_i,w x p' term), and ``computeCoriolisMatrix`` is the
Christoffel C, whose product with any x the polarisation above reproduces.

The packed parameter vector ``chain`` (float64) is laid out as
    header [n, g_x, g_y, g_z]                        (gravity in the base frame)
    per joint i = 1..n (PER_JOINT = 26 values):
        [kind (0 revolute or continuous, 1 prismatic), a_i (3, unit, joint frame),
         R^pl_i (9, row-major), p^pl_i (3)           (joint i in joint i-1, base for i = 1),
         m_i, com_i (3, joint frame), I_c,i (6: xx, xy, xz, yy, yz, zz, joint frame)]
    tip [R (9, row-major), p (3)]                   (tip frame in joint n's frame)

Kernels (all take ``chain`` first; q, v, a, x are joint vectors of length n):
    tip_kinematics(chain, q, v) -> (p, R, J, J' q')     tip pose in the base frame, J (6 x n)
    jacobian_dot(chain, q, v) -> J'                      d/dt J along q' = v
    rnea(chain, q, v, a, gravity_on) -> tau              M a + C v (+ G)
    mass_matrix(chain, q) -> M                           CRBA, symmetric
    coriolis_product(chain, q, v, x) -> C(q, v) x        Christoffel form
    tip_dynamics_into(chain, q, v, work)                 hot path, allocation-free: p, R, J, J' q',
        M and h = C v + G in one geometry pass, read through output_views(work, n)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from numba import njit

from cr_control.models.urdf import ChainModel

HEADER = 4        # n, g_x, g_y, g_z
PER_JOINT = 26    # offsets below
KIND, AXIS, ROT, POS, MASS, COM, INERTIA = 0, 1, 4, 13, 16, 17, 20
TIP = 12          # R (9), p (3)
REVOLUTE_KIND, PRISMATIC_KIND = 0.0, 1.0

#: Per-joint geometry row (GEO_WIDTH values) computed once per configuration: R_i (0:9),
#: p_i (9:12), S_i (12:18), and the spatial inertia m (18), h = m c (19:22), Ibar (22:28).
GEO_WIDTH = 28
#: Per-joint motion row: V_i (0:6), A_i (6:12), body force F_i (12:18).
MOTION_WIDTH = 18
#: (row, column) of the six stored entries of a symmetric 3x3 matrix.
SYM_ROW, SYM_COL = (0, 0, 0, 1, 1, 2), (0, 1, 2, 1, 2, 2)

_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}
_ALIGNED = {f"JointModel{prefix}{axis}": (kind, _AXES[axis]) for axis in "XYZ"
            for prefix, kind in (("R", REVOLUTE_KIND), ("RUB", REVOLUTE_KIND), ("P", PRISMATIC_KIND))}
_UNALIGNED = {"JointModelRevoluteUnaligned": REVOLUTE_KIND,
              "JointModelRevoluteUnboundedUnaligned": REVOLUTE_KIND,
              "JointModelPrismaticUnaligned": PRISMATIC_KIND}


# -- building blocks -----------------------------------------------------------------------------
@njit(cache=True, error_model="numpy")
def rotate_about_axis_into(src, dst, ax, ay, az, angle):
    """dst[0:9] = src[0:9] Rot(a, angle): a row-major 3x3 rotation times the rotation by
    ``angle`` (rad) about the unit axis a = (ax, ay, az), by Rodrigues' formula
    Rot = c I + s [a]x + (1 - c) a a^T. ``dst`` may be ``src``."""
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    e00, e01, e02 = c + t * ax * ax, t * ax * ay - s * az, t * ax * az + s * ay
    e10, e11, e12 = t * ax * ay + s * az, c + t * ay * ay, t * ay * az - s * ax
    e20, e21, e22 = t * ax * az - s * ay, t * ay * az + s * ax, c + t * az * az
    for r in range(3):
        a0, a1, a2 = src[3 * r], src[3 * r + 1], src[3 * r + 2]
        dst[3 * r] = a0 * e00 + a1 * e10 + a2 * e20
        dst[3 * r + 1] = a0 * e01 + a1 * e11 + a2 * e21
        dst[3 * r + 2] = a0 * e02 + a1 * e12 + a2 * e22


@njit(cache=True, error_model="numpy")
def _compose(Ra, pa, Rb, pb, R, p):
    """R = Ra Rb, p = pa + Ra pb (rotations flat, row-major; R, p must not alias Ra, pa)."""
    for r in range(3):
        a0, a1, a2 = Ra[3 * r], Ra[3 * r + 1], Ra[3 * r + 2]
        for c in range(3):
            R[3 * r + c] = a0 * Rb[c] + a1 * Rb[3 + c] + a2 * Rb[6 + c]
        p[r] = pa[r] + a0 * pb[0] + a1 * pb[1] + a2 * pb[2]


@njit(cache=True, error_model="numpy")
def _apply_inertia(inertia, wx, wy, wz, vx, vy, vz):
    """I [w; v] = [Ibar w + h x v; m v - h x w] for ``inertia`` = [m, h (3), Ibar (6)]."""
    m, hx, hy, hz = inertia[0], inertia[1], inertia[2], inertia[3]
    nx = inertia[4] * wx + inertia[5] * wy + inertia[6] * wz + hy * vz - hz * vy
    ny = inertia[5] * wx + inertia[7] * wy + inertia[8] * wz + hz * vx - hx * vz
    nz = inertia[6] * wx + inertia[8] * wy + inertia[9] * wz + hx * vy - hy * vx
    return nx, ny, nz, m * vx - hy * wz + hz * wy, m * vy - hz * wx + hx * wz, m * vz - hx * wy + hy * wx


@njit(cache=True, error_model="numpy")
def _world_inertia(chain, k, row):
    """Spatial inertia of body i (record at ``k``) in base coordinates into row[18:28], from
    its pose R_i = row[0:9], p_i = row[9:12]: m, h = m c, Ibar = R I_c R^T + m (|c|^2 1 - c c^T)."""
    m = chain[k + MASS]
    c = (row[9] + row[0] * chain[k + COM] + row[1] * chain[k + COM + 1] + row[2] * chain[k + COM + 2],
         row[10] + row[3] * chain[k + COM] + row[4] * chain[k + COM + 1] + row[5] * chain[k + COM + 2],
         row[11] + row[6] * chain[k + COM] + row[7] * chain[k + COM + 1] + row[8] * chain[k + COM + 2])
    i = k + INERTIA
    full = (chain[i], chain[i + 1], chain[i + 2], chain[i + 1], chain[i + 3], chain[i + 4],
            chain[i + 2], chain[i + 4], chain[i + 5])
    cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
    row[18] = m
    for r in range(3):
        row[19 + r] = m * c[r]
    for e in range(6):
        a, b = SYM_ROW[e], SYM_COL[e]
        s = 0.0
        for u in range(3):
            t = 0.0
            for w in range(3):
                t += full[3 * u + w] * row[3 * b + w]
            s += row[3 * a + u] * t
        row[22 + e] = s + m * ((cc if a == b else 0.0) - c[a] * c[b])


@njit(cache=True, error_model="numpy")
def geometry_into(chain, q, geo, pose):
    """The forward geometry pass: every joint's row of ``geo`` (n x GEO_WIDTH: R_i, p_i, S_i,
    spatial inertia in base coordinates) and the tip's pose = [p (3), R (9, row-major)]."""
    n = int(chain[0])
    for i in range(n):
        k = HEADER + PER_JOINT * i
        row = geo[i]
        if i == 0:
            row[0:9] = chain[k + ROT:k + ROT + 9]
            row[9:12] = chain[k + POS:k + POS + 3]
        else:
            _compose(geo[i - 1, 0:9], geo[i - 1, 9:12], chain[k + ROT:k + ROT + 9],
                     chain[k + POS:k + POS + 3], row[0:9], row[9:12])
        ax, ay, az = chain[k + AXIS], chain[k + AXIS + 1], chain[k + AXIS + 2]
        zx = row[0] * ax + row[1] * ay + row[2] * az
        zy = row[3] * ax + row[4] * ay + row[5] * az
        zz = row[6] * ax + row[7] * ay + row[8] * az
        if chain[k + KIND] == PRISMATIC_KIND:
            row[9] += zx * q[i]
            row[10] += zy * q[i]
            row[11] += zz * q[i]
            row[12] = row[13] = row[14] = 0.0
            row[15], row[16], row[17] = zx, zy, zz
        else:
            rotate_about_axis_into(row, row, ax, ay, az, q[i])
            px, py, pz = row[9], row[10], row[11]
            row[12], row[13], row[14] = zx, zy, zz
            row[15], row[16], row[17] = py * zz - pz * zy, pz * zx - px * zz, px * zy - py * zx
        _world_inertia(chain, k, row)
    t = HEADER + PER_JOINT * n
    _compose(geo[n - 1, 0:9], geo[n - 1, 9:12], chain[t:t + 9], chain[t + 9:t + 12], pose[3:12], pose[0:3])


@njit(cache=True, error_model="numpy")
def motion_into(chain, geo, v, a, gravity_on, motion):
    """RNEA forward pass: V_i, A_i (A_0 = [0; -g] if ``gravity_on``) and the body forces
    F_i = I_i A_i + V_i x* (I_i V_i) into ``motion`` (n x MOTION_WIDTH)."""
    n = int(chain[0])
    wx = wy = wz = vx = vy = vz = dwx = dwy = dwz = 0.0
    dvx, dvy, dvz = (-chain[1], -chain[2], -chain[3]) if gravity_on else (0.0, 0.0, 0.0)
    for i in range(n):
        S, out = geo[i, 12:18], motion[i]
        s0, s1, s2, s3, s4, s5 = S[0] * v[i], S[1] * v[i], S[2] * v[i], S[3] * v[i], S[4] * v[i], S[5] * v[i]
        wx, wy, wz, vx, vy, vz = wx + s0, wy + s1, wz + s2, vx + s3, vy + s4, vz + s5
        dwx += S[0] * a[i] + wy * s2 - wz * s1
        dwy += S[1] * a[i] + wz * s0 - wx * s2
        dwz += S[2] * a[i] + wx * s1 - wy * s0
        dvx += S[3] * a[i] + wy * s5 - wz * s4 + vy * s2 - vz * s1
        dvy += S[4] * a[i] + wz * s3 - wx * s5 + vz * s0 - vx * s2
        dvz += S[5] * a[i] + wx * s4 - wy * s3 + vx * s1 - vy * s0
        inertia = geo[i, 18:28]
        nx, ny, nz, fx, fy, fz = _apply_inertia(inertia, dwx, dwy, dwz, dvx, dvy, dvz)
        kx, ky, kz, lx, ly, lz = _apply_inertia(inertia, wx, wy, wz, vx, vy, vz)
        out[0], out[1], out[2], out[3], out[4], out[5] = wx, wy, wz, vx, vy, vz
        out[6], out[7], out[8], out[9], out[10], out[11] = dwx, dwy, dwz, dvx, dvy, dvz
        out[12] = nx + wy * kz - wz * ky + vy * lz - vz * ly
        out[13] = ny + wz * kx - wx * kz + vz * lx - vx * lz
        out[14] = nz + wx * ky - wy * kx + vx * ly - vy * lx
        out[15] = fx + wy * lz - wz * ly
        out[16] = fy + wz * lx - wx * lz
        out[17] = fz + wx * ly - wy * lx


@njit(cache=True, error_model="numpy")
def joint_forces_into(geo, motion, tau):
    """RNEA backward pass: tau_i = S_i^T sum_{k >= i} F_k."""
    n0 = n1 = n2 = f0 = f1 = f2 = 0.0
    for i in range(tau.shape[0] - 1, -1, -1):
        F, S = motion[i, 12:18], geo[i, 12:18]
        n0, n1, n2, f0, f1, f2 = n0 + F[0], n1 + F[1], n2 + F[2], f0 + F[3], f1 + F[4], f2 + F[5]
        tau[i] = S[0] * n0 + S[1] * n1 + S[2] * n2 + S[3] * f0 + S[4] * f1 + S[5] * f2


@njit(cache=True, error_model="numpy")
def tip_into(chain, geo, motion, gravity_on, pose, J, jdot_v):
    """The tip's Jacobian J (6 x n) and classical acceleration at q'' = 0, J' q' (6), from the
    geometry and a forward pass at q'' = 0 (run with or without gravity, as ``gravity_on``)."""
    n = int(chain[0])
    px, py, pz = pose[0], pose[1], pose[2]
    for i in range(n):
        S = geo[i, 12:18]
        J[0, i] = S[3] + S[1] * pz - S[2] * py
        J[1, i] = S[4] + S[2] * px - S[0] * pz
        J[2, i] = S[5] + S[0] * py - S[1] * px
        J[3, i], J[4, i], J[5, i] = S[0], S[1], S[2]
    last = motion[n - 1]
    wx, wy, wz = last[0], last[1], last[2]
    dwx, dwy, dwz = last[6], last[7], last[8]
    ux = last[3] + wy * pz - wz * py  # tip point velocity
    uy = last[4] + wz * px - wx * pz
    uz = last[5] + wx * py - wy * px
    gx, gy, gz = (chain[1], chain[2], chain[3]) if gravity_on else (0.0, 0.0, 0.0)
    jdot_v[0] = last[9] + gx + dwy * pz - dwz * py + wy * uz - wz * uy
    jdot_v[1] = last[10] + gy + dwz * px - dwx * pz + wz * ux - wx * uz
    jdot_v[2] = last[11] + gz + dwx * py - dwy * px + wx * uy - wy * ux
    jdot_v[3], jdot_v[4], jdot_v[5] = dwx, dwy, dwz


@njit(cache=True, error_model="numpy")
def mass_matrix_into(geo, composite, M):
    """CRBA: M_ij = M_ji = S_i^T Ic_j S_j (i <= j), Ic_j = sum_{k >= j} I_k accumulated in
    ``composite`` (10 floats: m, h, Ibar)."""
    composite[:] = 0.0
    for j in range(M.shape[0] - 1, -1, -1):
        for e in range(10):
            composite[e] += geo[j, 18 + e]
        S = geo[j, 12:18]
        n0, n1, n2, f0, f1, f2 = _apply_inertia(composite, S[0], S[1], S[2], S[3], S[4], S[5])
        for i in range(j + 1):
            Si = geo[i, 12:18]
            M[i, j] = M[j, i] = Si[0] * n0 + Si[1] * n1 + Si[2] * n2 + Si[3] * f0 + Si[4] * f1 + Si[5] * f2


@njit(cache=True, error_model="numpy")
def _layout(n):
    """Offsets into ``work``: the outputs pose [p, R] (0:12), J (6 n), J' q' (6), M (n^2), h (n),
    then scratch: geometry, motion, composite inertia (10), a zero vector (n); and the size."""
    jacobian = 12
    bias = jacobian + 6 * n
    mass = bias + 6
    h = mass + n * n
    geo = h + n
    motion = geo + GEO_WIDTH * n
    composite = motion + MOTION_WIDTH * n
    zero = composite + 10
    return jacobian, bias, mass, h, geo, motion, composite, zero, zero + n


@njit(cache=True, error_model="numpy")
def work_length(n):
    """Length of the ``work`` vector :func:`tip_dynamics_into` needs (for kernels)."""
    return _layout(n)[-1]


def work_size(n: int) -> int:
    """Length of the ``work`` vector :func:`tip_dynamics_into` needs for an n-joint chain."""
    return int(work_length(n))


@njit(cache=True, error_model="numpy")
def output_views(work, n):
    """Views (p, R, J, J' q', M, h) into ``work`` where :func:`tip_dynamics_into` writes them."""
    jacobian, bias, mass, h, geo = _layout(n)[:5]
    return (work[0:3], work[3:12].reshape((3, 3)), work[jacobian:bias].reshape((6, n)),
            work[bias:mass], work[mass:h].reshape((n, n)), work[h:geo])


@njit(cache=True, error_model="numpy")
def tip_dynamics_into(chain, q, v, work):
    """Hot path, allocation-free: at (q, q' = v), the tip's p, R, J, J' q', the mass matrix M
    and h = C(q, q') q' + G(q), written into ``work`` (length work_size(n); read them through
    output_views(work, n)). One geometry pass, one RNEA at q'' = 0 with gravity (its last
    body's acceleration minus gravity's gives J' q'), one CRBA."""
    n = int(chain[0])
    jacobian, bias, mass, h, geo, motion, composite, zero, end = _layout(n)
    pose = work[0:12]
    geometry_rows = work[geo:motion].reshape((n, GEO_WIDTH))
    motion_rows = work[motion:composite].reshape((n, MOTION_WIDTH))
    geometry_into(chain, q, geometry_rows, pose)
    work[zero:end] = 0.0
    motion_into(chain, geometry_rows, v, work[zero:end], True, motion_rows)
    joint_forces_into(geometry_rows, motion_rows, work[h:geo])
    tip_into(chain, geometry_rows, motion_rows, True, pose, work[jacobian:bias].reshape((6, n)),
             work[bias:mass])
    mass_matrix_into(geometry_rows, work[composite:zero], work[mass:h].reshape((n, n)))


# -- allocating entry points (tests, set-up, Python) ------------------------------------------
@njit(cache=True, error_model="numpy")
def _geometry(chain, q):
    n = int(chain[0])
    geo, pose = np.empty((n, GEO_WIDTH)), np.empty(12)
    geometry_into(chain, q, geo, pose)
    return geo, pose


@njit(cache=True, error_model="numpy")
def tip_kinematics(chain, q, v):
    """The tip's position p (3) and rotation R (3 x 3) in the base frame, its Jacobian J
    (6 x n, LOCAL_WORLD_ALIGNED: linear rows first) and J'(q, q') q' (6)."""
    n = int(chain[0])
    geo, pose = _geometry(chain, q)
    motion = np.empty((n, MOTION_WIDTH))
    motion_into(chain, geo, v, np.zeros(n), False, motion)
    J, jdot_v = np.empty((6, n)), np.empty(6)
    tip_into(chain, geo, motion, False, pose, J, jdot_v)
    return pose[0:3], pose[3:12].reshape((3, 3)), J, jdot_v


@njit(cache=True, error_model="numpy")
def jacobian_dot(chain, q, v):
    """J'(q, q') = d/dt J along q' = v (6 x n): column i from S'_i = V_i x S_i,
    [S'_i,v + S'_i,w x p + S_i,w x p'; S'_i,w], so that J' v is the tip's J' q'."""
    n = int(chain[0])
    geo, pose = _geometry(chain, q)
    motion = np.empty((n, MOTION_WIDTH))
    motion_into(chain, geo, v, np.zeros(n), False, motion)
    px, py, pz = pose[0], pose[1], pose[2]
    last = motion[n - 1]
    ux = last[3] + last[1] * pz - last[2] * py  # tip point velocity p'
    uy = last[4] + last[2] * px - last[0] * pz
    uz = last[5] + last[0] * py - last[1] * px
    J_dot = np.empty((6, n))
    for i in range(n):
        S, V = geo[i, 12:18], motion[i]
        ax = V[1] * S[2] - V[2] * S[1]   # S'_w = w_i x S_w
        ay = V[2] * S[0] - V[0] * S[2]
        az = V[0] * S[1] - V[1] * S[0]
        bx = V[1] * S[5] - V[2] * S[4] + V[4] * S[2] - V[5] * S[1]   # S'_v = w_i x S_v + v_i x S_w
        by = V[2] * S[3] - V[0] * S[5] + V[5] * S[0] - V[3] * S[2]
        bz = V[0] * S[4] - V[1] * S[3] + V[3] * S[1] - V[4] * S[0]
        J_dot[0, i] = bx + ay * pz - az * py + S[1] * uz - S[2] * uy
        J_dot[1, i] = by + az * px - ax * pz + S[2] * ux - S[0] * uz
        J_dot[2, i] = bz + ax * py - ay * px + S[0] * uy - S[1] * ux
        J_dot[3, i], J_dot[4, i], J_dot[5, i] = ax, ay, az
    return J_dot


@njit(cache=True, error_model="numpy")
def rnea(chain, q, v, a, gravity_on):
    """tau = M(q) a + C(q, v) v (+ G(q) if ``gravity_on``): recursive Newton-Euler."""
    n = int(chain[0])
    geo = _geometry(chain, q)[0]
    motion, tau = np.empty((n, MOTION_WIDTH)), np.empty(n)
    motion_into(chain, geo, v, a, gravity_on, motion)
    joint_forces_into(geo, motion, tau)
    return tau


@njit(cache=True, error_model="numpy")
def mass_matrix(chain, q):
    """M(q) by the composite rigid body algorithm, symmetric."""
    n = int(chain[0])
    M = np.empty((n, n))
    mass_matrix_into(_geometry(chain, q)[0], np.empty(10), M)
    return M


@njit(cache=True, error_model="numpy")
def coriolis_product(chain, q, v, x):
    """C(q, v) x, C in Christoffel form: (c(v + x) - c(v) - c(x)) / 2 with c(w) the RNEA at
    (q, w, q'' = 0) without gravity (a quadratic form in w with symmetric Christoffel symbols)."""
    n = int(chain[0])
    geo = _geometry(chain, q)[0]
    motion, zero, c = np.empty((n, MOTION_WIDTH)), np.zeros(n), np.empty(n)
    out = np.empty(n)
    motion_into(chain, geo, v + x, zero, False, motion)
    joint_forces_into(geo, motion, out)
    for w, sign in ((v, -1.0), (x, -1.0)):
        motion_into(chain, geo, w, zero, False, motion)
        joint_forces_into(geo, motion, c)
        for i in range(n):
            out[i] += sign * c[i]
    for i in range(n):
        out[i] *= 0.5
    return out


def kinematics_only(chain: np.ndarray) -> np.ndarray:
    """A copy of ``chain`` with zero gravity, masses and inertias: geometry only, for laws
    that must not use a dynamics model (its RNEA is identically zero)."""
    out = chain.copy()
    out[1:HEADER] = 0.0
    for i in range(int(chain[0])):
        k = HEADER + PER_JOINT * i
        out[k + MASS] = 0.0
        out[k + INERTIA:k + INERTIA + 6] = 0.0
    return out


def scale_inertias(chain: np.ndarray, mass_scale: float, inertia_scale: float) -> None:
    """Scale every joint's mass and rotational inertia about its centre of mass in place (a
    deliberately wrong model of the arm; the centres of mass stay)."""
    for i in range(int(chain[0])):
        k = HEADER + PER_JOINT * i
        chain[k + MASS] *= mass_scale
        chain[k + INERTIA:k + INERTIA + 6] *= inertia_scale


# -- packing -------------------------------------------------------------------------------------
def _joint_kind_and_axis(model: pin.Model, j: int) -> tuple[float, np.ndarray]:
    joint = model.joints[j]
    name = joint.shortname()
    if name in _ALIGNED:
        kind, axis = _ALIGNED[name]
        return kind, np.array(axis)
    if name in _UNALIGNED:
        axis = np.asarray(joint.extract().axis, dtype=float)
        return _UNALIGNED[name], axis / np.linalg.norm(axis)
    raise ValueError(f"joint {model.names[j]!r} is a {name}: a chain may have revolute, continuous "
                     "and prismatic joints only")


@dataclass(frozen=True)
class SpatialChain:
    """A serial chain read from a Pinocchio model; ``chain`` is its packed form (module docstring)."""

    chain: np.ndarray
    joint_names: tuple[str, ...]

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.joint_names)

    @classmethod
    def from_chain(cls, chain: ChainModel) -> SpatialChain:
        """Pack the chain :func:`cr_control.models.urdf.load_chain` built."""
        return cls.from_model(chain.model, chain.tip)

    @classmethod
    def from_model(cls, model: pin.Model, tip: int) -> SpatialChain:
        """Pack ``model`` (joints 1..n a serial chain base -> tip of revolute, continuous and
        prismatic joints, frame ``tip`` fixed to joint n); ValueError if it is not such a chain."""
        n = model.njoints - 1
        if n < 1:
            raise ValueError("the model has no joint")
        values = [float(n), *model.gravity.linear]
        for j in range(1, n + 1):
            if model.parents[j] != j - 1:
                raise ValueError(f"joint {model.names[j]!r} does not follow joint {j - 1}: "
                                 "not a serial chain")
            kind, axis = _joint_kind_and_axis(model, j)
            placement, inertia = model.jointPlacements[j], model.inertias[j]
            I_c = inertia.inertia
            values += [kind, *axis, *placement.rotation.reshape(9), *placement.translation,
                       inertia.mass, *inertia.lever,
                       I_c[0, 0], I_c[0, 1], I_c[0, 2], I_c[1, 1], I_c[1, 2], I_c[2, 2]]
        frame = model.frames[tip]
        if frame.parentJoint != n:
            raise ValueError(f"tip frame {frame.name!r} is not fixed to the last joint")
        values += [*frame.placement.rotation.reshape(9), *frame.placement.translation]
        return cls(np.array(values, dtype=float), tuple(model.names[1:]))
