"""Unilateral compliant contact of a point (the tool tip) with a plane or a sphere, in 3-D.

Geometry (base frame), with the outward unit normal n at the tip position r:

    plane:   depth = -n . (r - p)          (p a point of the plane; environment n.(r - p) < 0)
    sphere:  depth = R - |r - c|,  n = (r - c)/|r - c|     (environment inside the ball)
    none:    depth = -inf (never in contact)

Force on the tip moving with r' (v_n = n . r', v_t = r' - v_n n):

    f_n = max(K_e depth - D_e v_n, 0)                            when depth > 0, else 0
    f_t = -mu f_n v_t / sqrt(|v_t|^2 + eps^2) - c_v v_t           while f_n > 0, else 0
    f   = f_n n + f_t

The normal force never pulls (a tip leaving faster than the pad recovers feels nothing) and
there is no friction without a normal force. The Coulomb term is regularised over ``eps``
(m/s): it reaches 71 % of mu f_n at |v_t| = eps and is smooth, so RK4 can integrate it.

Packed form (one float64 array, so the compiled kernels take any surface)::

    [kind, a_x, a_y, a_z, n_x, n_y, n_z, R, K_e, D_e, mu, c_v, eps]

with kind PLANE (a = p, n unit), SPHERE (a = c, R the radius) or NONE.

Wrist sensor (:func:`wrist_wrench_into`): what a force/torque sensor between the arm and a
rigid tool reads when the tool touches the surface (the equations are in
:mod:`cr_sim.plants.urdf_surface`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

NONE = 0.0
PLANE = 1.0
SPHERE = 2.0
#: Floats of a packed surface.
SURFACE_SIZE = 13


@njit(cache=True, error_model="numpy")
def contact_into(surface, r, v, f):
    """Write the contact force on a tip at ``r`` moving with ``v`` into ``f`` (3); return the
    penetration depth (m; negative = distance when separated, -inf without a surface)."""
    kind = surface[0]
    if kind == NONE:
        f[0] = f[1] = f[2] = 0.0
        return -math.inf
    if kind == PLANE:
        nx, ny, nz = surface[4], surface[5], surface[6]
        depth = -(nx * (r[0] - surface[1]) + ny * (r[1] - surface[2]) + nz * (r[2] - surface[3]))
    else:
        dx, dy, dz = r[0] - surface[1], r[1] - surface[2], r[2] - surface[3]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dist > 0.0:
            nx, ny, nz = dx / dist, dy / dist, dz / dist
        else:
            nx, ny, nz = 0.0, 0.0, 1.0
        depth = surface[7] - dist
    f[0] = f[1] = f[2] = 0.0
    if depth <= 0.0:
        return depth
    vn = nx * v[0] + ny * v[1] + nz * v[2]
    fn = surface[8] * depth - surface[9] * vn
    if fn <= 0.0:
        return depth
    tx, ty, tz = v[0] - vn * nx, v[1] - vn * ny, v[2] - vn * nz
    mu, cv, eps = surface[10], surface[11], surface[12]
    coulomb = mu * fn / math.sqrt(tx * tx + ty * ty + tz * tz + eps * eps)
    c = coulomb + cv
    f[0] = fn * nx - c * tx
    f[1] = fn * ny - c * ty
    f[2] = fn * nz - c * tz
    return depth


def packed(kind: float, anchor=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), radius: float = 0.0,
           stiffness: float = 0.0, damping: float = 0.0, coulomb: float = 0.0,
           viscous: float = 0.0, epsilon: float = 1e-3) -> np.ndarray:
    """A packed surface (``normal`` is normalised here; ValueError if it is zero)."""
    normal = np.asarray(normal, dtype=float)
    norm = float(np.linalg.norm(normal))
    if not norm > 0.0:
        raise ValueError("surface_normal must not be zero")
    return np.array([kind, *np.asarray(anchor, dtype=float), *(normal / norm), radius,
                     stiffness, damping, coulomb, viscous, epsilon], dtype=float)


def contact_force(surface: np.ndarray, r, v) -> tuple[np.ndarray, float]:
    """(force on the tip (3), depth) at r moving with v (Python entry point, for tests)."""
    f = np.zeros(3)
    depth = contact_into(surface, np.asarray(r, dtype=float), np.asarray(v, dtype=float), f)
    return f, float(depth)


def moved_away(surface: np.ndarray, r, distance: float) -> np.ndarray:
    """A copy of the packed ``surface`` moved ``distance`` (m) away from the point ``r`` along
    its outward normal there: a plane's point by -distance n, a sphere's centre by
    -distance (r - c)/|r - c| (+z if r is the centre); no surface stays as it is."""
    moved = np.array(surface, dtype=float)
    if moved[0] == PLANE:
        moved[1:4] -= distance * moved[4:7]
    elif moved[0] == SPHERE:
        d = np.asarray(r, dtype=float) - moved[1:4]
        dist = float(np.linalg.norm(d))
        moved[1:4] -= distance * (d / dist if dist > 0.0 else np.array([0.0, 0.0, 1.0]))
    return moved


#: Floats of a packed tool for :func:`wrist_wrench_into`:
#: [m, c (3), I_c (9, row-major), p (3), g (3), bias (6)].
TOOL_SIZE = 25


def packed_tool(mass: float, com, inertia: np.ndarray, point, gravity, bias) -> np.ndarray:
    """A packed tool: mass (kg), centre of mass c and contact point p in the sensor frame
    (m), inertia I_c about c in the sensor frame's axes (3 x 3), gravity g in the world frame
    (m/s^2), the sensor's bias (6: N, N m, sensor frame)."""
    packed = np.concatenate([[mass], np.ravel(com), np.ravel(inertia), np.ravel(point),
                             np.ravel(gravity), np.ravel(bias)]).astype(float)
    if packed.shape != (TOOL_SIZE,):
        raise ValueError(f"a packed tool has {TOOL_SIZE} values, got {packed.size}")
    return packed


@njit(cache=True, error_model="numpy")
def wrist_wrench_into(R, v, a, f, tool, out):
    """The wrench the tool exerts on the arm at the sensor origin, sensor frame, into ``out``
    (6: force, torque) plus the bias:

        F = R^T f + m (R^T g - a_c)
        T = p x R^T f + c x m (R^T g - a_c) - (I_c alpha + omega x I_c omega)
        a_c = a_o + omega x v_o + alpha x c + omega x (omega x c)

    R: the sensor frame's rotation (world <- sensor); v = (v_o, omega), a = (a_o, alpha): its
    spatial velocity and acceleration in its own frame (Pinocchio's LOCAL); f: the contact
    force on the tip, world frame; ``tool``: :func:`packed_tool`."""
    m = tool[0]
    cx, cy, cz = tool[1], tool[2], tool[3]
    px, py, pz = tool[13], tool[14], tool[15]
    # contact force and gravity in the sensor frame: R^T f, R^T g
    fx = R[0, 0] * f[0] + R[1, 0] * f[1] + R[2, 0] * f[2]
    fy = R[0, 1] * f[0] + R[1, 1] * f[1] + R[2, 1] * f[2]
    fz = R[0, 2] * f[0] + R[1, 2] * f[1] + R[2, 2] * f[2]
    g0, g1, g2 = tool[16], tool[17], tool[18]
    gx = R[0, 0] * g0 + R[1, 0] * g1 + R[2, 0] * g2
    gy = R[0, 1] * g0 + R[1, 1] * g1 + R[2, 1] * g2
    gz = R[0, 2] * g0 + R[1, 2] * g1 + R[2, 2] * g2
    vx, vy, vz, wx, wy, wz = v[0], v[1], v[2], v[3], v[4], v[5]
    ax, ay, az, bx, by, bz = a[0], a[1], a[2], a[3], a[4], a[5]
    # omega x c, then a_c = a_o + omega x v_o + alpha x c + omega x (omega x c)
    ux, uy, uz = wy * cz - wz * cy, wz * cx - wx * cz, wx * cy - wy * cx
    acx = ax + (wy * vz - wz * vy) + (by * cz - bz * cy) + (wy * uz - wz * uy)
    acy = ay + (wz * vx - wx * vz) + (bz * cx - bx * cz) + (wz * ux - wx * uz)
    acz = az + (wx * vy - wy * vx) + (bx * cy - by * cx) + (wx * uy - wy * ux)
    # the tool's weight less its inertial force, acting at c
    hx, hy, hz = m * (gx - acx), m * (gy - acy), m * (gz - acz)
    # I_c alpha + omega x I_c omega
    Iw0 = tool[4] * wx + tool[5] * wy + tool[6] * wz
    Iw1 = tool[7] * wx + tool[8] * wy + tool[9] * wz
    Iw2 = tool[10] * wx + tool[11] * wy + tool[12] * wz
    Ia0 = tool[4] * bx + tool[5] * by + tool[6] * bz + (wy * Iw2 - wz * Iw1)
    Ia1 = tool[7] * bx + tool[8] * by + tool[9] * bz + (wz * Iw0 - wx * Iw2)
    Ia2 = tool[10] * bx + tool[11] * by + tool[12] * bz + (wx * Iw1 - wy * Iw0)
    out[0] = fx + hx + tool[19]
    out[1] = fy + hy + tool[20]
    out[2] = fz + hz + tool[21]
    out[3] = (py * fz - pz * fy) + (cy * hz - cz * hy) - Ia0 + tool[22]
    out[4] = (pz * fx - px * fz) + (cz * hx - cx * hz) - Ia1 + tool[23]
    out[5] = (px * fy - py * fx) + (cx * hy - cy * hx) - Ia2 + tool[24]
