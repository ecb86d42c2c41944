"""Desired motions and forces of the thesis scenarios, with exact derivatives."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cr_control.core.packing import Layout
from cr_control.core.parameters import Param


@njit(cache=True, error_model="numpy")
def cosine_reference(offset, amplitude, phase, w, t):
    """(r_d, r_d', r_d'') of r_d(t) = offset - amplitude * cos(w t + phase), per axis, exact
    derivatives (3.93: x_d = -0.1 cos 2t, y_d = 0.35 - 0.1 cos 2t; 5.21-5.22 with phases)."""
    n = offset.shape[0]
    r, v, a = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        c, s = math.cos(w * t + phase[i]), math.sin(w * t + phase[i])
        r[i] = offset[i] - amplitude[i] * c
        v[i] = amplitude[i] * w * s
        a[i] = amplitude[i] * w * w * c
    return r, v, a


class CosineTrajectory:
    """Python entry point of :func:`cosine_reference` with fixed offset, amplitude, phase, w."""

    def __init__(self, offset, amplitude, frequency: float, phase=(0.0, 0.0)):
        self.offset = np.asarray(offset, dtype=float)
        self.amplitude = np.asarray(amplitude, dtype=float)
        self.phase = np.asarray(phase, dtype=float)
        self.frequency = float(frequency)

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r_d, r_d', r_d'') at time t."""
        return cosine_reference(self.offset, self.amplitude, self.phase, self.frequency, t)


#: Parameters of the chapter 3 desired motion (3.93) and force.
CHAPTER3_REFERENCE = [
    Param("reference_offset", [0.0, 0.35],
          "r_d = offset - amplitude*cos(w t + phase): offset (m).", "vector", 2),
    Param("reference_amplitude", [0.1, 0.1], "r_d: amplitude per axis (m).", "vector", 2),
    Param("reference_phase", [0.0, 0.0], "r_d: phase per axis (rad).", "vector", 2),
    Param("reference_frequency", 2.0, "r_d: angular frequency w (rad/s).", "nonnegative"),
    Param("desired_force", [5.0, -5.0], "Desired contact force f_d on the robot (N) (3.5).",
          "vector", 2),
]

#: Packed form of the reference parameters for the kernels (names = parameter names).
REFERENCE = Layout(reference_offset=2, reference_amplitude=2, reference_phase=2,
                   reference_frequency=1, desired_force=2)
_OFFSET, _AMPLITUDE, _PHASE, _W, _F_D = (
    REFERENCE.offset(n) for n in ("reference_offset", "reference_amplitude", "reference_phase",
                                  "reference_frequency", "desired_force"))


@njit(cache=True, error_model="numpy")
def packed_reference(gains, t):
    """(r_d, r_d', r_d'', f_d) from a packed REFERENCE block at time t."""
    r, v, a = cosine_reference(gains[_OFFSET:_OFFSET + 2], gains[_AMPLITUDE:_AMPLITUDE + 2],
                               gains[_PHASE:_PHASE + 2], gains[_W], t)
    return r, v, a, gains[_F_D:_F_D + 2]


def chapter3_reference(values: dict) -> CosineTrajectory:
    """The desired motion of section 3.5 from converted parameter values."""
    return CosineTrajectory(values["reference_offset"], values["reference_amplitude"],
                            values["reference_frequency"], values["reference_phase"])
