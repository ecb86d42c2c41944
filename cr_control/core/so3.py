"""Rotations for compiled kernels: quaternions [w, x, y, z], rotation matrices, the SO(3)
logarithm and exponential (no ROS, no SciPy).

The orientation error of a Cartesian orientation impedance is the rotation vector

    e_o = log(R_d R^T)          (world frame; |e_o| <= pi)

that turns the measured orientation R into the desired R_d; it is computed from the
quaternion of R_d R^T taken with w >= 0 (the short way round), as 2 atan2(|v|, w) v/|v|,
which stays accurate near 0 and near pi (an arccos of the trace does not).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def quaternion_from_matrix(R):
    """Unit quaternion [w, x, y, z] of a rotation matrix (Shepperd's method: the largest of
    w, x, y, z is computed from a square root, the others from it), with w >= 0."""
    t = R[0, 0] + R[1, 1] + R[2, 2]
    qw = np.empty(4)
    if t >= R[0, 0] and t >= R[1, 1] and t >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + t)
        qw[0] = 0.25 * s
        qw[1], qw[2], qw[3] = (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] >= R[1, 1] and R[0, 0] >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        qw[0], qw[1] = (R[2, 1] - R[1, 2]) / s, 0.25 * s
        qw[2], qw[3] = (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        qw[0], qw[2] = (R[0, 2] - R[2, 0]) / s, 0.25 * s
        qw[1], qw[3] = (R[0, 1] + R[1, 0]) / s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        qw[0], qw[3] = (R[1, 0] - R[0, 1]) / s, 0.25 * s
        qw[1], qw[2] = (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s
    if qw[0] < 0.0:
        qw *= -1.0
    return qw


@njit(cache=True, error_model="numpy")
def matrix_from_quaternion(qw):
    """Rotation matrix of a quaternion [w, x, y, z] (normalised here)."""
    n = math.sqrt(qw[0] * qw[0] + qw[1] * qw[1] + qw[2] * qw[2] + qw[3] * qw[3])
    w, x, y, z = qw[0] / n, qw[1] / n, qw[2] / n, qw[3] / n
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return R


@njit(cache=True, error_model="numpy")
def rotation_vector(qw):
    """log of a unit quaternion as a rotation vector (angle * axis, |angle| <= pi)."""
    w, x, y, z = qw[0], qw[1], qw[2], qw[3]
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    out = np.empty(3)
    k = 2.0 * math.atan2(s, w) / s if s > 1e-300 else 2.0 / max(w, 1e-300)
    out[0], out[1], out[2] = k * x, k * y, k * z
    return out


@njit(cache=True, error_model="numpy")
def quaternion_exp(w_vec):
    """Unit quaternion of the rotation vector ``w_vec`` (exp map)."""
    angle = math.sqrt(w_vec[0] ** 2 + w_vec[1] ** 2 + w_vec[2] ** 2)
    out = np.empty(4)
    out[0] = math.cos(0.5 * angle)
    k = math.sin(0.5 * angle) / angle if angle > 1e-12 else 0.5 - angle * angle / 48.0
    out[1], out[2], out[3] = k * w_vec[0], k * w_vec[1], k * w_vec[2]
    return out


@njit(cache=True, error_model="numpy")
def quaternion_multiply(a, b):
    """Hamilton product a b (apply b, then a)."""
    out = np.empty(4)
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]
    return out


@njit(cache=True, error_model="numpy")
def quaternion_conjugate(a):
    """The inverse rotation of a unit quaternion."""
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = a[0], -a[1], -a[2], -a[3]
    return out


@njit(cache=True, error_model="numpy")
def orientation_error(q_desired, R):
    """e_o = log(R_d R^T) (world frame) for the desired quaternion and the measured matrix."""
    return rotation_vector(quaternion_multiply(q_desired, quaternion_conjugate(quaternion_from_matrix(R))))
