"""Truncated Taylor-series ("jet") arithmetic: exact higher time derivatives of closed forms.

A jet of order K is a float64 array ``a`` of length K + 1 holding the **normalised Taylor
coefficients** of a smooth function f at a time t:

    a[k] = f^(k)(t) / k!,   k = 0..K

so f(t + h) = sum_k a[k] h^k + O(h^(K+1)). Products, quotients and the elementary functions
then follow from Cauchy-product recurrences (Griewank & Walther, "Evaluating Derivatives",
ch. 13) that are exact up to rounding: no finite differences, no step size. Use
:func:`jet_from_derivatives` / :func:`jet_to_derivatives` to convert from / to plain
derivatives [f, f', f'', ...] (the chapter 6 references need q_ld up to its 4th
derivative and the desired regressor up to its 2nd, "analytically or by exact
differentiation, not by noisy finite differences").

Every operation is compiled (numba, cached), writes into caller-provided arrays and takes
its order from the length of ``out`` (all operands at least that long); no allocation.
Aliasing: ``out`` may be the same array as an operand for add/sub/scale/shift/mul, and as
the numerator ``a`` of :func:`jet_div` and the argument of :func:`jet_sqrt`; the outputs of
sin_cos, atan2, acos and derivative must not alias their inputs (the recurrences reread
earlier input coefficients).

Recurrences (k >= 1; D[m] = (m+1) theta[m+1] are the coefficients of theta'):
    mul    c[k] = sum_{j=0..k} a[j] b[k-j]
    div    c[k] = (a[k] - sum_{j=1..k} b[j] c[k-j]) / b[0]
    sqrt   s[k] = (a[k] - sum_{j=1..k-1} s[j] s[k-j]) / (2 s[0])
    sin/cos  k s[k] = sum_{j=1..k} j a[j] c[k-j],   k c[k] = -sum_{j=1..k} j a[j] s[k-j]
    atan2  theta' (x^2 + y^2) = x y' - y x'
    acos   theta' sin(theta) = -a',  (sin theta)' = a theta'   (theta = acos a in [0, pi])
"""

from __future__ import annotations

import math

from numba import njit


# -- conversion --------------------------------------------------------------------------
@njit(cache=True, error_model="numpy")
def jet_from_derivatives(d, out):
    """out[k] = d[k] / k! for k < len(out): plain derivatives [f, f', f'', ...] to a jet."""
    fact = 1.0
    for k in range(out.shape[0]):
        if k > 0:
            fact *= k
        out[k] = d[k] / fact


@njit(cache=True, error_model="numpy")
def jet_to_derivatives(a, out):
    """out[k] = k! a[k] for k < len(out): a jet to plain derivatives [f, f', f'', ...]."""
    fact = 1.0
    for k in range(out.shape[0]):
        if k > 0:
            fact *= k
        out[k] = a[k] * fact


@njit(cache=True, error_model="numpy")
def jet_variable(t, out):
    """The jet of the independent variable itself at t: [t, 1, 0, ...]."""
    out[:] = 0.0
    out[0] = t
    if out.shape[0] > 1:
        out[1] = 1.0


@njit(cache=True, error_model="numpy")
def jet_constant(value, out):
    """The jet of a constant: [value, 0, 0, ...]."""
    out[:] = 0.0
    out[0] = value


@njit(cache=True, error_model="numpy")
def jet_derivative(a, out):
    """The jet of f' from the jet of f: out[k] = (k+1) a[k+1]; needs len(a) > len(out)."""
    for k in range(out.shape[0]):
        out[k] = (k + 1) * a[k + 1]


# -- linear operations ---------------------------------------------------------------------
@njit(cache=True, error_model="numpy")
def jet_add(a, b, out):
    """a + b."""
    for k in range(out.shape[0]):
        out[k] = a[k] + b[k]


@njit(cache=True, error_model="numpy")
def jet_sub(a, b, out):
    """a - b."""
    for k in range(out.shape[0]):
        out[k] = a[k] - b[k]


@njit(cache=True, error_model="numpy")
def jet_scale(a, s, out):
    """s a for a scalar s."""
    for k in range(out.shape[0]):
        out[k] = s * a[k]


@njit(cache=True, error_model="numpy")
def jet_shift(a, c, out):
    """a + c for a scalar c (only the value coefficient changes)."""
    for k in range(out.shape[0]):
        out[k] = a[k]
    out[0] += c


@njit(cache=True, error_model="numpy")
def jet_axpy(s, a, b, out):
    """s a + b for a scalar s."""
    for k in range(out.shape[0]):
        out[k] = s * a[k] + b[k]


# -- nonlinear operations ------------------------------------------------------------------
@njit(cache=True, error_model="numpy")
def jet_mul(a, b, out):
    """a b (Cauchy product; computed from the top coefficient down so out may alias a or b)."""
    for k in range(out.shape[0] - 1, -1, -1):
        s = 0.0
        for j in range(k + 1):
            s += a[j] * b[k - j]
        out[k] = s


@njit(cache=True, error_model="numpy")
def jet_div(a, b, out):
    """a / b (out may alias a, not b)."""
    b0 = b[0]
    for k in range(out.shape[0]):
        s = a[k]
        for j in range(1, k + 1):
            s -= b[j] * out[k - j]
        out[k] = s / b0


@njit(cache=True, error_model="numpy")
def jet_sqrt(a, out):
    """sqrt(a) (principal root; a[0] > 0 for finite derivatives; out may alias a)."""
    s0 = math.sqrt(a[0])
    out[0] = s0
    for k in range(1, out.shape[0]):
        s = a[k]
        for j in range(1, k):
            s -= out[j] * out[k - j]
        out[k] = s / (2.0 * s0)


@njit(cache=True, error_model="numpy")
def jet_sin_cos(a, s, c):
    """s = sin(a), c = cos(a) by their joint recurrence (s, c distinct from a)."""
    s[0] = math.sin(a[0])
    c[0] = math.cos(a[0])
    for k in range(1, s.shape[0]):
        ss = 0.0
        cc = 0.0
        for j in range(1, k + 1):
            ss += j * a[j] * c[k - j]
            cc -= j * a[j] * s[k - j]
        s[k] = ss / k
        c[k] = cc / k


@njit(cache=True, error_model="numpy")
def jet_atan2(y, x, out):
    """atan2(y, x) from theta' (x^2 + y^2) = x y' - y x' (out distinct from x and y).

    The value is math.atan2 (in (-pi, pi]); the derivatives are those of the continuous
    angle, so they stay exact across the branch cut at x < 0, y = 0.
    """
    out[0] = math.atan2(y[0], x[0])
    r0 = x[0] * x[0] + y[0] * y[0]
    for m in range(out.shape[0] - 1):
        # numerator coefficient n[m] of x y' - y x'
        s = 0.0
        for j in range(m + 1):
            s += (m - j + 1) * (x[j] * y[m - j + 1] - y[j] * x[m - j + 1])
        # minus sum_{j=1..m} r[j] D[m-j], r = x^2 + y^2, D[i] = (i+1) out[i+1]
        for j in range(1, m + 1):
            rj = 0.0
            for i in range(j + 1):
                rj += x[i] * x[j - i] + y[i] * y[j - i]
            s -= rj * (m - j + 1) * out[m - j + 1]
        out[m + 1] = s / (r0 * (m + 1))


@njit(cache=True, error_model="numpy")
def jet_acos(a, out, sin_out):
    """theta = acos(a) in [0, pi] into out and sin(theta) = sqrt(1 - a^2) >= 0 into sin_out.

    theta' = -a' / sin(theta), (sin theta)' = a theta'. Derivatives are infinite at
    a[0] = +-1 (where acos is not differentiable); NaN for |a[0]| > 1.
    """
    out[0] = math.acos(a[0]) if abs(a[0]) <= 1.0 else math.nan
    s0 = math.sqrt(1.0 - a[0] * a[0]) if abs(a[0]) <= 1.0 else math.nan
    sin_out[0] = s0
    for m in range(out.shape[0] - 1):
        # D[m] s[0] = -(m+1) a[m+1] - sum_{j=0..m-1} D[j] s[m-j]
        d = -(m + 1) * a[m + 1]
        for j in range(m):
            d -= (j + 1) * out[j + 1] * sin_out[m - j]
        d /= s0
        out[m + 1] = d / (m + 1)
        # (m+1) s[m+1] = sum_{j=0..m} a[m-j] D[j]
        t = 0.0
        for j in range(m + 1):
            t += a[m - j] * (j + 1) * out[j + 1]
        sin_out[m + 1] = t / (m + 1)
