"""Fuzzy unidirectional force control (thesis section 5.2: 5.7 with 5.18-5.20; figs. 5.6-5.9).

The impedance controller (5.7) with k_m = lambda d_m and d_m tuned every cycle by fuzzy rule
set 2 (:mod:`cr_control.schemes.blocks.fuzzy`):

    s    = n^T e_r' + lambda n^T e_r                                           (5.18)
    e_fm = f_dm - f_m,  e_fmin = f_dm - f_max,  e_fmax = f_dm - f_min           (5.11-5.12)
    d_m  = w_1 d_s + w_2 d_b + w_3 d_med,  k_m = lambda d_m                     (5.20)
    tau  = J^T [M_r (r_d'' + m_m^-1 (d_m e_r' + k_m e_r + f - f_d)) + C_r r' + G_r - f]  (5.7)

Section 5.3 values as defaults: m_m = 1.2, d_s = 5, d_med = 15, d_b = 25, lambda = 5,
k_p = k_n = 1, f_dm = 10 N, f_max = 12 N, f_min = 1 N. e_fmax = f_dm - f_min (the thesis
prints e_fmax = f_d; docs/thesis.md). The rules are written for f_min < f_dm < f_max and
d_s < d_med < d_b; other values are accepted and give what (5.20) gives. d_m is a static
map of the measured state: the law has no internal state. One compiled call per cycle
(:func:`fuzzy_unidirectional_cycle`).
"""

from __future__ import annotations

from numba import njit

from cr_control.core.parameters import Bound, Param
from cr_control.schemes.blocks.fuzzy import rule_set_2_damping
from cr_control.schemes.blocks.unidirectional_impedance import normal_sliding
from cr_control.schemes.impedance.unidirectional import (
    UnidirectionalController,
    unidirectional_back,
    unidirectional_front,
)

FUZZY_PARAMETERS = [
    Param("lambda", 5.0, "lambda of s = n^T e_r' + lambda n^T e_r (5.18) and k_m = lambda d_m "
          "(1/s) (section 5.3: 5).", "positive", bound=Bound.GAIN),
    Param("k_p", 1.0, "Slope k_p of mu_positive(x) = 1/(1 + exp(-k_p x)) (5.13), per unit of x "
          "(m/s for s, N for force errors) (section 5.3: 1).", "positive", bound=Bound.GAIN),
    Param("k_n", 1.0, "Slope k_n of mu_negative(x) = 1/(1 + exp(k_n x)) (5.14) (section 5.3: 1).",
          "positive", bound=Bound.GAIN),
    Param("d_s", 5.0, "Centre d_s of the output set 'small' (5.16) (N s/m) (section 5.3: 5).",
          "positive", bound=Bound.GAIN),
    Param("d_med", 15.0, "Centre d_med of the output set 'medium' (5.17) (N s/m) "
          "(section 5.3: 15).", "positive", bound=Bound.GAIN),
    Param("d_b", 25.0, "Centre d_b of the output set 'big' (5.15) (N s/m) (section 5.3: 25).",
          "positive", bound=Bound.GAIN),
    Param("f_max", 12.0, "Largest contact force allowed f_max (N): e_fmin = f_dm - f_max (5.12) "
          "(section 5.3: 12).", "nonnegative", bound=Bound.FORCE),
    Param("f_min", 1.0, "Smallest contact force wanted f_min (N): e_fmax = f_dm - f_min (5.12, "
          "docs/thesis.md) (section 5.3: 1).", "nonnegative", bound=Bound.FORCE),
]


@njit(cache=True, error_model="numpy")
def fuzzy_unidirectional_cycle(chain, gains, state, targets, t, dt, q, v, force, out):
    """One cycle of (5.7) with d_m from (5.20) and k_m = lambda d_m into ``out``."""
    cycle = unidirectional_front(chain, gains, state, targets, t, dt, q, v, force)
    own, f_dm = cycle.own, cycle.f_dm
    lam, k_p, k_n, d_s, d_med, d_b, f_max, f_min = (own[0], own[1], own[2], own[3], own[4],
                                                    own[5], own[6], own[7])
    s = normal_sliding(cycle.n, cycle.e, cycle.e_dot, lam)
    d_m = rule_set_2_damping(s, f_dm - cycle.f_m, f_dm - f_max, f_dm - f_min, k_p, k_n, d_s,
                             d_med, d_b)
    unidirectional_back(chain, gains, state, cycle, d_m, lam * d_m, lam, out)


class FuzzyUnidirectionalController(UnidirectionalController):
    """Fuzzy unidirectional force control (5.7 + 5.20) with the section 5.3 values."""

    scheme = "fuzzy_unidirectional"
    kernel = fuzzy_unidirectional_cycle
    @classmethod
    def law_parameters(cls, model, thesis):
        return super().law_parameters(model, thesis) + FUZZY_PARAMETERS

    def law_gains_layout(self):
        """The contact's gains, then rule set 2's (in FUZZY_PARAMETERS' order)."""
        return super().law_gains_layout().extended(**dict.fromkeys(
            (p.name for p in FUZZY_PARAMETERS), 1))
