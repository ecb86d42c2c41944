"""Desired motions and forces of the thesis scenarios, with exact derivatives."""

from __future__ import annotations

import math

import numpy as np

from cr_control.core.parameters import Param


class CosineTrajectory:
    """r_d(t) = offset - amplitude * cos(w t), per axis (3.93: x_d = -0.1 cos 2t,
    y_d = 0.35 - 0.1 cos 2t), with exact first and second derivatives."""

    def __init__(self, offset: np.ndarray, amplitude: np.ndarray, frequency: float):
        self.offset = np.asarray(offset, dtype=float)
        self.amplitude = np.asarray(amplitude, dtype=float)
        self.frequency = float(frequency)

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r_d, r_d', r_d'') at time t."""
        w = self.frequency
        c, s = math.cos(w * t), math.sin(w * t)
        return (self.offset - self.amplitude * c, self.amplitude * (w * s),
                self.amplitude * (w * w * c))


#: Parameters of the chapter 3 desired motion (3.93) and force.
CHAPTER3_REFERENCE = [
    Param("reference_offset", [0.0, 0.35], "r_d = offset - amplitude*cos(w t): offset (m).",
          "vector", 2),
    Param("reference_amplitude", [0.1, 0.1], "r_d: amplitude per axis (m).", "vector", 2),
    Param("reference_frequency", 2.0, "r_d: angular frequency w (rad/s).", "nonnegative"),
    Param("desired_force", [5.0, -5.0], "Desired contact force f_d on the robot (N) (3.5).",
          "vector", 2),
]


def chapter3_reference(values: dict) -> CosineTrajectory:
    """The desired motion of section 3.5 from converted parameter values."""
    return CosineTrajectory(values["reference_offset"], values["reference_amplitude"],
                            values["reference_frequency"])
