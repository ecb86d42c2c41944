"""Small dense linear algebra for compiled kernels (no BLAS: numba's ``@`` needs SciPy, and
at 2x2 to 6x6 plain loops are faster than a BLAS call anyway)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def matvec(A, x):
    """A x."""
    rows, cols = A.shape
    out = np.zeros(rows)
    for i in range(rows):
        s = 0.0
        for j in range(cols):
            s += A[i, j] * x[j]
        out[i] = s
    return out


@njit(cache=True, error_model="numpy")
def tmatvec(A, x):
    """A^T x."""
    rows, cols = A.shape
    out = np.zeros(cols)
    for j in range(cols):
        s = 0.0
        for i in range(rows):
            s += A[i, j] * x[i]
        out[j] = s
    return out


@njit(cache=True, error_model="numpy")
def matmul(A, B):
    """A B."""
    rows, inner = A.shape
    cols = B.shape[1]
    out = np.zeros((rows, cols))
    for i in range(rows):
        for k in range(inner):
            a = A[i, k]
            for j in range(cols):
                out[i, j] += a * B[k, j]
    return out


@njit(cache=True, error_model="numpy")
def inv2(A):
    """Inverse of a 2x2 matrix."""
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    out = np.empty((2, 2))
    out[0, 0], out[0, 1] = A[1, 1] / det, -A[0, 1] / det
    out[1, 0], out[1, 1] = -A[1, 0] / det, A[0, 0] / det
    return out


@njit(cache=True, error_model="numpy")
def outer(x, y):
    """x y^T."""
    out = np.empty((x.shape[0], y.shape[0]))
    for i in range(x.shape[0]):
        for j in range(y.shape[0]):
            out[i, j] = x[i] * y[j]
    return out


@njit(cache=True, error_model="numpy")
def spectral_norm_2x2(A):
    """Largest singular value of a 2x2 matrix, closed form (an SVD costs ~10x more)."""
    a, b, c, d = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    frob2 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return np.sqrt(0.5 * (frob2 + np.sqrt(max(frob2 * frob2 - 4.0 * det * det, 0.0))))


@njit(cache=True, error_model="numpy")
def all_finite(x):
    """True if every value of the 1-D array x is finite (no overflow, no warning, no copy)."""
    for i in range(x.shape[0]):  # noqa: SIM110 - a generator in all() is slower under numba
        if not math.isfinite(x[i]):
            return False
    return True
