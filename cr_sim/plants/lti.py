"""Linear time-invariant plants stepped exactly: x' = A x + B u with u held over the period
(zero-order hold, as the plant node and the offline loop hold a command) has the exact
discrete form x+ = Phi(dt) x + Gamma(dt) u, Phi = e^{A dt}, Gamma = int_0^dt e^{A s} ds B.
Phi and Gamma are computed once per distinct dt (scaling and squaring of a Taylor series on
the augmented matrix [[A, B], [0, 0]]; no SciPy here) and one compiled call per period
applies them: no integration error at all, whatever the stiffness (ch. 4 case 3, stiff chains).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_sim.plants.base import Plant, take_command


def expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring with an 18-term Taylor series (accurate to
    rounding for the small, moderately scaled matrices of these plants)."""
    norm = np.abs(M).sum(axis=1).max()
    s = max(0, int(math.ceil(math.log2(norm))) + 1) if norm > 0.5 else 0
    X = M / (2.0 ** s)
    term = np.eye(M.shape[0])
    out = term.copy()
    for k in range(1, 19):
        term = term @ X / k
        out = out + term
    for _ in range(s):
        out = out @ out
    return out


def zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Gamma) of x' = A x + B u with u held over dt."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * dt)
    return np.ascontiguousarray(E[:n, :n]), np.ascontiguousarray(E[:n, n:])


@njit(cache=True)
def lti_step(Phi, Gam, x, held, command, work):
    """Take ``command`` as the held input if it has one finite value per input (else keep the
    last), then x <- Phi x + Gam held in place. Returns whether the command was taken."""
    accepted = take_command(held, command)
    n = x.shape[0]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += Phi[i, j] * x[j]
        for j in range(held.shape[0]):
            s += Gam[i, j] * held[j]
        work[i] = s
    x[:] = work
    return accepted


class LTIPlant(Plant):
    """A plant x' = A x + B u stepped exactly; subclasses set A, B, the state and the sensors."""

    def __init__(self, A: np.ndarray, B: np.ndarray, x0: np.ndarray, u0: np.ndarray):
        self.A = np.ascontiguousarray(A, dtype=float)
        self.B = np.ascontiguousarray(B, dtype=float)
        self._x = np.array(x0, dtype=float)
        self._held = np.array(u0, dtype=float)
        self._work = np.zeros_like(self._x)
        self._dt = None
        self._Phi = self._Gam = None
        self._t = 0.0

    @property
    def held(self) -> np.ndarray:
        """The input held now."""
        return self._held.copy()

    def step(self, command: np.ndarray, dt: float) -> None:
        if dt != self._dt:
            self._Phi, self._Gam = zoh(self.A, self.B, dt)
            self._dt = dt
        lti_step(self._Phi, self._Gam, self._x, self._held, np.asarray(command, dtype=float),
                 self._work)
        self._t += dt
