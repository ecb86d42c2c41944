"""Fixed-step integrators for the plants."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Derivative = Callable[[float, np.ndarray], np.ndarray]


def rk4_step(f: Derivative, t: float, x: np.ndarray, dt: float) -> np.ndarray:
    """One classical fourth-order Runge-Kutta step of x' = f(t, x)."""
    half = 0.5 * dt
    k1 = f(t, x)
    k2 = f(t + half, x + half * k1)
    k3 = f(t + half, x + half * k2)
    k4 = f(t + dt, x + dt * k3)
    return x + (dt / 6.0) * (k1 + k4 + 2.0 * (k2 + k3))


def integrate(f: Derivative, t: float, x: np.ndarray, dt: float, substeps: int) -> np.ndarray:
    """Advance x' = f(t, x) by ``dt`` with ``substeps`` RK4 steps (input held constant)."""
    h = dt / substeps
    for i in range(substeps):
        x = rk4_step(f, t + i * h, x, h)
    return x
