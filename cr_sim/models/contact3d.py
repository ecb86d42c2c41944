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
