"""The braking law of this project: a controller's braking command and the simulated robot's
safe stop both brake with it.

    tau_b = G_b(q) - M(q) (2 w_b q' + w_b^2 (q - q_b))

a joint-space PD scaled by the mass matrix M(q) (:func:`brake_torque`): with the gravity
torque G_b held (zero where the robot adds gravity itself), every joint is a critically
damped second-order system of natural frequency w_b, whatever its inertia, held near q_b.

Why scaled by M(q): a brake torque is a command, held for one period dt until the next. A
damping fixed in N m s/rad, tau = -K_d q', takes K_d dt / M_jj of a joint's speed away per
period, and beyond 2 it reverses the speed by more than it had: at K_d = 30 N m s/rad and
1 ms the Panda's wrist (M_77 ~ 0.005 kg m^2) gets 5.7, and its brake command alternated
+-12 N m every cycle at +-1.2 rad/s. With the mass matrix the step is w_b dt on every joint:
the held-torque loop of each joint (a double integrator under a zero-order hold) has two
real poles in (0, 1) for w_b dt <= 0.5 (at w_b dt = 1 one reaches -1: a command alternating
every cycle), so the simulated robot's safe stop asks w_b dt <= :data:`MAX_BRAKE_STEP`.

Where to hold: the position where braking began makes each joint overshoot it and swing
back (critically damped from a speed v it comes back at up to 0.135 v). Holding instead
:func:`stop_position`, q_b = q + q'/w_b, the law's solution from (q, q') is
q'(t) = q' e^{-w_b t}: every joint's speed falls monotonically to rest, v/w_b beyond where
braking began, and stays there (a stop in the manner of IEC 60204-1's stop category 1:
a controlled deceleration, then held).
"""

from __future__ import annotations

import numpy as np

#: The largest brake step w_b dt a simulated robot's safe stop accepts (module docstring:
#: real poles in (0, 1) up to 0.5; half of it for the coupling and friction M(q) leaves out).
MAX_BRAKE_STEP = 0.25


def brake_torque(M: np.ndarray, gravity: np.ndarray | None, q: np.ndarray, v: np.ndarray,
                 hold: np.ndarray, frequency: float) -> np.ndarray:
    """tau_b = G_b - M (2 w_b q' + w_b^2 (q - q_b)) (module docstring); ``gravity`` None: G_b = 0."""
    w = frequency
    tau = -M @ (2.0 * w * v + w * w * (q - hold))
    return tau if gravity is None else tau + gravity


def stop_position(q: np.ndarray, v: np.ndarray, frequency: float) -> np.ndarray:
    """q_b = q + q'/w_b: where each joint braked by :func:`brake_torque` from (q, q') comes
    to rest with its speed falling as e^{-w_b t} (module docstring)."""
    return np.asarray(q, dtype=float) + np.asarray(v, dtype=float) / frequency
