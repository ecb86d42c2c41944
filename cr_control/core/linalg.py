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
def cholesky_into(A, L):
    """Lower Cholesky factor L of a symmetric positive-definite A (L L^T = A); A may be L.
    Returns False (L unusable) if A is not numerically positive definite."""
    n = A.shape[0]
    for i in range(n):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 0.0:
                    return False
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
        for j in range(i + 1, n):
            L[i, j] = 0.0
    return True


@njit(cache=True, error_model="numpy")
def cholesky_solve_into(L, b, x):
    """x with L L^T x = b (forward then back substitution); x may be b."""
    n = b.shape[0]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True, error_model="numpy")
def cholesky_solve_matrix(L, B):
    """X with L L^T X = B, column by column (B is n x k)."""
    X = B.copy()
    for j in range(B.shape[1]):
        column = X[:, j].copy()
        cholesky_solve_into(L, column, column)
        X[:, j] = column
    return X


@njit(cache=True, error_model="numpy")
def spd_inverse(A):
    """Inverse of a symmetric positive-definite matrix by Cholesky (small sizes); NaN if A
    is not positive definite."""
    n = A.shape[0]
    L = np.empty((n, n))
    out = np.full((n, n), np.nan)
    if cholesky_into(A, L):
        out = cholesky_solve_matrix(L, np.eye(n))
    return out


@njit(cache=True, error_model="numpy")
def min_eigenvalue_sym(A):
    """Smallest eigenvalue of a small symmetric matrix: cyclic Jacobi rotations until the
    off-diagonal part is below 1e-14 of the norm (at most 20 sweeps; exact for n = 1)."""
    n = A.shape[0]
    B = A.copy()
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale += B[i, j] * B[i, j]
    for _ in range(20):
        off = 0.0
        for i in range(n):
            for j in range(i + 1, n):
                off += B[i, j] * B[i, j]
        if off <= 1e-28 * scale:
            break
        for p in range(n - 1):
            for r in range(p + 1, n):
                if B[p, r] == 0.0:
                    continue
                theta = (B[r, r] - B[p, p]) / (2.0 * B[p, r])
                t = math.copysign(1.0, theta) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):
                    bkp, bkr = B[k, p], B[k, r]
                    B[k, p], B[k, r] = c * bkp - s * bkr, s * bkp + c * bkr
                for k in range(n):
                    bpk, brk = B[p, k], B[r, k]
                    B[p, k], B[r, k] = c * bpk - s * brk, s * bpk + c * brk
    smallest = B[0, 0]
    for i in range(1, n):
        smallest = min(smallest, B[i, i])
    return smallest


@njit(cache=True, error_model="numpy")
def spectral_norm(A):
    """Largest singular value of a small matrix: sqrt of the largest eigenvalue of A^T A."""
    return math.sqrt(max(0.0, -min_eigenvalue_sym(-matmul(A.T.copy(), A))))


@njit(cache=True, error_model="numpy")
def all_finite(x):
    """True if every value of the 1-D array x is finite (no overflow, no warning, no copy)."""
    for i in range(x.shape[0]):  # noqa: SIM110 - a generator in all() is slower under numba
        if not math.isfinite(x[i]):
            return False
    return True
