"""Compliant environments the end effector presses on: unilateral spring-damper contact.

f = max(K_e delta - D_e n.r', 0) n when the tool penetrates the surface by delta > 0 (3.4),
else 0: the environment pushes along its outward normal n and never pulls.

Packed form (one float64 array, so a compiled kernel takes any surface):
    plane  (3.92):  [PLANE,  n_x, n_y, offset, K_e, D_e]   n.r + offset = 0, |n| = 1,
                    environment on the side n.r + offset < 0
    circle (5.1):   [CIRCLE, c_x, c_y, radius, K_e, D_e]   |r - c| = radius, environment
                    inside (the tool presses on it from outside)
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

PLANE = 0.0
CIRCLE = 1.0


@njit(cache=True, error_model="numpy")
def surface_contact(surface, rx, ry, vx, vy):
    """(f_x, f_y, depth, n_x, n_y): contact force on the tool at position (rx, ry) moving with
    (vx, vy), penetration depth (negative = distance when separated) and outward normal."""
    if surface[0] == PLANE:
        nx, ny = surface[1], surface[2]
        depth = -(nx * rx + ny * ry + surface[3])
    else:
        dx, dy = rx - surface[1], ry - surface[2]
        dist = math.sqrt(dx * dx + dy * dy)
        if dist > 0.0:
            nx, ny = dx / dist, dy / dist
        else:
            nx, ny = 1.0, 0.0
        depth = surface[3] - dist
    if depth <= 0.0:
        return 0.0, 0.0, depth, nx, ny
    push = surface[4] * depth - surface[5] * (nx * vx + ny * vy)
    if push < 0.0:
        push = 0.0
    return push * nx, push * ny, depth, nx, ny


def plane(normal, offset: float, stiffness: float, damping: float) -> np.ndarray:
    """Packed plane n.r + offset = 0 (normalised here); ValueError for a zero normal."""
    normal = np.asarray(normal, dtype=float)
    norm = float(np.linalg.norm(normal))
    if norm == 0.0:
        raise ValueError("surface_normal must not be zero")
    return np.array([PLANE, normal[0] / norm, normal[1] / norm, offset / norm, stiffness, damping])


def circle(centre, radius: float, stiffness: float, damping: float) -> np.ndarray:
    """Packed circle |r - centre| = radius, pressed on from outside."""
    return np.array([CIRCLE, centre[0], centre[1], radius, stiffness, damping])


def contact_force(surface: np.ndarray, r: np.ndarray, r_dot: np.ndarray) -> np.ndarray:
    """Force of ``surface`` on the tool at r moving with r' (Python entry point, for tests)."""
    fx, fy, _, _, _ = surface_contact(surface, float(r[0]), float(r[1]), float(r_dot[0]),
                                      float(r_dot[1]))
    return np.array([fx, fy])
