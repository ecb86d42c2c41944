"""Fuzzy tuning of the impedance damping d_m: memberships (5.13-5.17) and rule set 2 (5.18-5.20).

Inputs: s = n^T e_r' + lambda n^T e_r (5.18) and the normal force error e_fm = f_dm - f_m,
compared with e_fmin = f_dm - f_max and e_fmax = f_dm - f_min (5.12; the thesis prints
e_fmax = f_d; f_dm - f_min is taken so that e_fm < e_fmax means f_m > f_min).

Rule set 2 (section 5.2):
    s positive, e_fm - e_fmax positive  (f_m below f_min, tool moving in)   -> d_m small
    s positive, e_fm - e_fmin negative  (f_m above f_max, tool moving in)   -> d_m big
    s negative, e_fm - e_fmax positive  (f_m below f_min, tool moving out)  -> d_m big
    s negative, e_fm - e_fmin negative  (f_m above f_max, tool moving out)  -> d_m small
    e_fm - e_fmin positive and e_fm - e_fmax negative (f_min < f_m < f_max)  -> d_m medium

Singleton fuzzifier, product inference and centre-average defuzzifier give (5.20):
d_m = w_1 d_s + w_2 d_b + w_3 d_med. Only the centres d_s, d_med, d_b of the output sets
(5.15-5.17) enter the centre-average defuzzifier, so their widths k_s, k_med, k_b have no
effect on d_m and are not parameters. The input memberships are the sigmoids (5.13-5.14)
with slopes k_p, k_n (per unit of their argument: m/s for s, N for the force errors).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, error_model="numpy", inline="always")
def sigmoid(z):
    """1 / (1 + e^-z) without overflow for any finite z."""
    if z >= 0.0:
        return 1.0 / (1.0 + math.exp(-z))
    ez = math.exp(z)
    return ez / (1.0 + ez)


@njit(cache=True, error_model="numpy", inline="always")
def mu_positive(x, k_p):
    """(5.13) mu_positive(x) = 1 / (1 + e^(-k_p x))."""
    return sigmoid(k_p * x)


@njit(cache=True, error_model="numpy", inline="always")
def mu_negative(x, k_n):
    """(5.14) mu_negative(x) = 1 / (1 + e^(k_n x))."""
    return sigmoid(-k_n * x)


@njit(cache=True, error_model="numpy")
def rule_set_2_weights(s, e_fm, e_fmin, e_fmax, k_p, k_n):
    """(w_1, w_2, w_3) of (5.20): the normalised firing strengths of small, big and medium."""
    ps, ns = mu_positive(s, k_p), mu_negative(s, k_n)
    a, b = e_fm - e_fmax, e_fm - e_fmin
    pa, na = mu_positive(a, k_p), mu_negative(a, k_n)
    pb, nb = mu_positive(b, k_p), mu_negative(b, k_n)
    small = ps * pa + ns * nb
    big = ps * nb + ns * pa
    medium = pb * na
    w = (ps + ns) * (pa + nb) + medium        # = small + big + medium
    if not w > 0.0:                           # every membership underflowed: stay medium
        return 0.0, 0.0, 1.0
    return small / w, big / w, medium / w


@njit(cache=True, error_model="numpy")
def rule_set_2_damping(s, e_fm, e_fmin, e_fmax, k_p, k_n, d_s, d_med, d_b):
    """Crisp d_m of (5.20): w_1 d_s + w_2 d_b + w_3 d_med."""
    w1, w2, w3 = rule_set_2_weights(s, e_fm, e_fmin, e_fmax, k_p, k_n)
    return w1 * d_s + w2 * d_b + w3 * d_med
