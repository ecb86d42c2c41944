"""How large a stiffness and a damping a sampled loop with a transport delay takes: the
discrete-time rule every gain that acts on the arm's joints is bounded by.

A gain acts through an inertia M (a joint's, or the effective inertia of the task direction
it pushes: 1 / the largest eigenvalue of that task's mobility), its torque computed from the
state of one cycle, held for a period T (the driver's zero-order hold) and applied d cycles
later (the driver's transport delay). With the torque tau = -K x - D v on a rigid inertia,
exactly discretised over each period,

    v_{k+1} = v_k + (T / M) tau_{k-d},
    x_{k+1} = x_k + T v_k + (T^2 / 2M) tau_{k-d},

and in the normalised gains k = K T^2 / M, c = D T / M the loop's characteristic polynomial
is (z-transform of the three lines)

    P(z) = z^d (z - 1)^2 + (k / 2)(z + 1) + c (z - 1).

The loop is stable when every root of P lies inside the unit circle. Pure damping (k = 0):
P = (z - 1)(z^(d+1) - z^d + c); the root z = 1 is the free position (no spring holds it, no
energy grows), the rest is the velocity loop v_{k+1} = v_k - c v_{k-d}. On the unit circle
z = e^(i w) that loop's boundary c = z^d (1 - z) needs |c| = 2 sin(w / 2) and the phase
d w + w / 2 - pi / 2 = 0, so the first crossing is at w = pi / (2 d + 1) and

    c < c_max(d) = 2 sin(pi / (2 (2 d + 1)))                       (:func:`damping_limit`)

2, 1, 0.618, 0.445, 0.347 for d = 0..4: a damping that takes more than c_max of a joint's
speed away in one period overshoots, and with delay it does so against a speed that has
already changed. Stiffness and damping together (:func:`spectral_radius` from the roots of
P, any d): a spring alone (c = 0) is never stable once sampled (at d = 0 the product of the
roots is 1 + k / 2 > 1: the held spring force adds energy every period), so a stiffness needs
a damping, and both have a largest value given the other (:func:`max_stiffness`,
:func:`damping_range`), the set of stable (k, c) shrinking as d grows.

The margin (:func:`stable_with_margin`): the gains ``margin`` times larger must still be
stable; the schemes ask it at a delay ``delay_factor`` times the one the robot's profile
declares (:mod:`cr_control.schemes.blocks.gain_bounds`). Pure math: numpy only.
"""

from __future__ import annotations

import math

import numpy as np

#: Roots within this of the unit circle count as on it (unstable): round-off of np.roots on
#: polynomials of degree up to ~20.
UNIT_CIRCLE_TOLERANCE = 1e-9


def damping_limit(delay_cycles: int) -> float:
    """c_max(d) = 2 sin(pi / (2 (2 d + 1))): the largest stable normalised damping
    D T / M of a pure damping loop delayed d cycles (module docstring)."""
    d = _cycles(delay_cycles)
    return 2.0 * math.sin(math.pi / (2.0 * (2 * d + 1)))


def pd_polynomial(k: float, c: float, delay_cycles: int) -> np.ndarray:
    """Coefficients (highest power first) of P(z) = z^d (z-1)^2 + (k/2)(z+1) + c (z-1)."""
    d = _cycles(delay_cycles)
    p = np.zeros(d + 3)
    p[0], p[1], p[2] = 1.0, -2.0, 1.0               # z^d (z - 1)^2: z^(d+2) - 2 z^(d+1) + z^d
    p[-2] += 0.5 * k + c                             # (k/2 + c) z
    p[-1] += 0.5 * k - c                             # (k/2 - c)
    return p


def loop_polynomial(k: float, c: float, delay_cycles: int) -> np.ndarray:
    """The polynomial whose roots decide the loop's stability: :func:`pd_polynomial`, or with
    k = 0 (pure damping) the velocity loop's z^(d+1) - z^d + c alone (the free position's root
    z = 1 left out)."""
    if k != 0.0:
        return pd_polynomial(k, c, delay_cycles)
    p = np.zeros(_cycles(delay_cycles) + 2)
    p[0], p[1] = 1.0, -1.0
    p[-1] += c
    return p


def spectral_radius(k: float, c: float, delay_cycles: int) -> float:
    """The largest |root| of :func:`loop_polynomial`. Non-finite or negative gains: inf; no
    gain at all: 1."""
    if not (math.isfinite(k) and math.isfinite(c)) or k < 0.0 or c < 0.0:
        return math.inf
    if k == 0.0 and c == 0.0:
        return 1.0
    return float(np.max(np.abs(np.roots(loop_polynomial(k, c, delay_cycles)))))


def stable(k: float, c: float, delay_cycles: int) -> bool:
    """Whether the loop of normalised stiffness k and damping c delayed d cycles is stable
    (pure damping: its velocity loop; no gain at all: nothing to be unstable): every root of
    its polynomial inside |z| < 1 - UNIT_CIRCLE_TOLERANCE, by :func:`schur_stable` (the same
    verdict as :func:`spectral_radius`'s roots, without finding them: ~6x faster, and the
    bounds' bisections call it thousands of times per controller)."""
    if k == 0.0 and c == 0.0:
        return True
    if not (math.isfinite(k) and math.isfinite(c)) or k < 0.0 or c < 0.0:
        return False
    return schur_stable(loop_polynomial(k, c, delay_cycles).tolist(),
                        1.0 - UNIT_CIRCLE_TOLERANCE)


def schur_stable(coefficients: list[float], radius: float = 1.0) -> bool:
    """Whether every root of the real polynomial (coefficients highest power first) lies in
    |z| < ``radius``: the Schur-Cohn test on q(z) = p(radius z). With q = a_0 z^n + ... + a_n
    and its reciprocal q* (the coefficients reversed), k = a_n / a_0 must satisfy |k| < 1,
    and then (q - k q*) / z, of degree n - 1, must pass the same test (Schur 1917, Cohn
    1922; e.g. Jury, "Theory and Application of the z-Transform Method", 1964)."""
    n = len(coefficients) - 1
    a = [float(x) * radius ** (n - i) for i, x in enumerate(coefficients)]
    while len(a) > 1:
        if a[0] == 0.0:
            return False
        k = a[-1] / a[0]
        if not abs(k) < 1.0:
            return False
        a = [a[i] - k * a[-1 - i] for i in range(len(a) - 1)]
    return True


def stable_with_margin(k: float, c: float, delay_cycles: int, margin: float = 1.0) -> bool:
    """Whether the gains and the gains ``margin`` times larger are stable (a gain margin)."""
    return stable(k, c, delay_cycles) and stable(margin * k, margin * c, delay_cycles)


def max_stiffness(c: float, delay_cycles: int, margin: float = 1.0) -> float:
    """The largest normalised stiffness k stable with ``margin`` beside the damping c
    (0 if none is: no damping, or a damping beyond the pure loop's limit)."""
    if not stable_with_margin(0.0, c, delay_cycles, margin) or c == 0.0:
        return 0.0
    return _largest(lambda k: stable_with_margin(k, c, delay_cycles, margin), 4.0)


def damping_range(k: float, delay_cycles: int, margin: float = 1.0) -> tuple[float, float]:
    """(smallest, largest) normalised damping c stable with ``margin`` beside the stiffness
    k; (nan, nan) if none is. With k = 0: (0, c_max(d) / margin)."""
    limit = damping_limit(delay_cycles) / margin
    if k == 0.0:
        return 0.0, limit
    grid = np.linspace(0.0, limit, 201)[1:]
    ok = [c for c in grid if stable_with_margin(k, float(c), delay_cycles, margin)]
    if not ok:
        return math.nan, math.nan
    step = grid[1] - grid[0]
    low = _bisect(lambda c: stable_with_margin(k, c, delay_cycles, margin),
                  max(ok[0] - step, 0.0), ok[0], want_low=True)
    high = _bisect(lambda c: stable_with_margin(k, c, delay_cycles, margin),
                   ok[-1], min(ok[-1] + step, limit), want_low=False)
    return low, high


def _largest(is_stable, start: float) -> float:
    """The largest x > 0 with is_stable(x), the stable x forming an interval (0, x_max)."""
    high = start
    while is_stable(high):
        high *= 2.0
        if high > 1e6:
            return high
    low = 0.0
    return _bisect(is_stable, low, high, want_low=False)


def _bisect(is_stable, low: float, high: float, want_low: bool, steps: int = 60) -> float:
    """The stable/unstable boundary between ``low`` and ``high``: want_low: the smallest stable
    value (low unstable, high stable), else the largest (low stable, high unstable)."""
    for _ in range(steps):
        mid = 0.5 * (low + high)
        if is_stable(mid) != want_low:
            low = mid
        else:
            high = mid
    return high if want_low else low


def _cycles(delay_cycles: int) -> int:
    d = int(delay_cycles)
    if d < 0 or d != delay_cycles:
        raise ValueError(f"a delay of {delay_cycles} cycles: a whole number >= 0")
    return d
