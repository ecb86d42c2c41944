"""Appendix C plant: a chain of n mass-spring-dampers (CMMSD, fig. C.1, C.1-C.2).

    m_1 q_1'' = -b_1 q_1' - k_1 q_1 + k_1 q_2
    m_i q_i'' = -b_i q_i' - (k_{i-1} + k_i) q_i + k_{i-1} q_{i-1} + k_i q_{i+1}
    m_n q_n'' = -b_n q_n' - k_{n-1} q_n + k_{n-1} q_{n-1} + u

n - 1 springs join neighbouring masses, every mass has viscous damping b_i to the ground and
no spring to the ground (as printed: the chain has a rigid-body mode, x_1/u has a pole at 0).
State x = [q_1, q_1', ..., q_n, q_n'] (C.2), stepped exactly (:mod:`cr_sim.plants.lti`).

The thesis gives no numbers. Defaults (documented choices): n = 2, every m_i = 1 kg,
b_i = 0.5 N s/m, k_i = 4 N/m, every mass displaced by q_i(0) = 0.1 m at rest (springs
unstretched). Vectors of one value apply to every mass (spring).

On the topic contract: joints q1..qn (prismatic, every mass is in /joint_states for the
recording; only q_1 is the thesis's measurement, and the scheme reads q_1 only). Commands are
efforts, one per mass; C.1 has a force on the last mass only, which is what the scheme sends
(the others are zero; they are applied if a user sends them).

No contact: the chain touches nothing, so its wrench is always zero (the springs' forces are
internal, u is the actuator's). The force reflex (``max_contact_force``) acts on that
measured wrench like every plant's, i.e. never; the joints have no URDF velocity limits, so
neither does the joint velocity reflex. The watchdog's safe stop still brakes the masses.
"""

from __future__ import annotations

import numpy as np

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_sim.plants.base import JointLimits, Measurement, max_contact_force_parameter
from cr_sim.plants.lti import LTIPlant

NAME = "cmmsd"

PARAMETERS = [
    # 20: each mass adds two steps to the backstepping design (appendix C) and two orders to
    # the model polynomial, whose coefficients grow combinatorially.
    Param("masses", 2, "Number of masses n.", "integer", read_only=True, bound=20),
    Param("mass", [1.0], "Masses m_1..m_n (kg); one value = every mass.", "positive_vector",
          read_only=True, bound=Bound.MASS),
    Param("damping", [0.5], "Viscous damping b_1..b_n of each mass to the ground (N s/m); one "
          "value = every mass.", "nonnegative_vector", read_only=True, bound=Bound.DAMPING),
    Param("stiffness", [4.0], "Spring constants k_1..k_{n-1} between neighbours (N/m); one "
          "value = every spring.", "positive_vector", read_only=True, bound=Bound.STIFFNESS),
    Param("initial_position", [0.1], "Displacements q_1(0)..q_n(0) from equilibrium, at rest "
          "(m); one value = every mass.", "vector", read_only=True, bound=Bound.LENGTH),
    Param("position_noise_std", 0.0, "Position measurement noise, std (m).", "nonnegative",
          read_only=True, bound=Bound.POSITION_NOISE),
    Param("noise_seed", 0, "Seed of the measurement noise.", "integer", read_only=True,
          bound=Bound.SEED),
    max_contact_force_parameter(10.0, "the chain has no contact and no task force (appendix "
                                "C): it acts on the measured wrench, always 0, so it never "
                                "trips; 10 N is a placeholder."),
]


def _per(values: dict, name: str, size: int) -> np.ndarray:
    v = np.asarray(values[name], dtype=float)
    if v.size == 1:
        return np.full(size, float(v[0]))
    if v.size != size:
        raise ParameterError(f"{name} needs 1 or {size} values, got {v.size}")
    return v


def matrices(values: dict) -> tuple[np.ndarray, np.ndarray]:
    """(A_x, B) of (C.2) with one input column per mass (the thesis's b_x is the last)."""
    n = values["masses"]
    if n < 1:
        raise ParameterError(f"masses must be >= 1, got {n}")
    m, b = _per(values, "mass", n), _per(values, "damping", n)
    k = _per(values, "stiffness", n - 1) if n > 1 else np.zeros(0)
    A = np.zeros((2 * n, 2 * n))
    B = np.zeros((2 * n, n))
    for i in range(n):
        A[2 * i, 2 * i + 1] = 1.0
        r = 2 * i + 1
        A[r, r] = -b[i] / m[i]
        if i > 0:
            A[r, 2 * i] -= k[i - 1] / m[i]
            A[r, 2 * (i - 1)] += k[i - 1] / m[i]
        if i < n - 1:
            A[r, 2 * i] -= k[i] / m[i]
            A[r, 2 * (i + 1)] += k[i] / m[i]
        B[r, i] = 1.0 / m[i]
    return A, B


def true_theta(values: dict) -> np.ndarray:
    """theta = [d_2n, a_{2n,2n-1}, ..., a_{2n,0}] of (C.5)-(C.6) from the matrices."""
    A, B = matrices(values)
    n2 = A.shape[0]
    den = np.real(np.poly(A))
    C = np.zeros(n2)
    C[0] = 1.0
    num = np.real(np.poly(A - B[:, -1:] @ C[None, :])) - den
    return np.concatenate([[num[-1]], den[1:]])


class CMMSD(LTIPlant):
    """The chain (C.1), a force per mass in, every mass's position and velocity out."""

    command_interface = "effort"

    def __init__(self, values: dict):
        n = values["masses"]
        A, B = matrices(values)
        q0 = _per(values, "initial_position", n)
        x0 = np.zeros(2 * n)
        x0[0::2] = q0
        self.joint_names = tuple(f"q{i + 1}" for i in range(n))
        super().__init__(A, B, x0, np.zeros(n))
        self._n = n
        self._mass = _per(values, "mass", n)
        self.max_contact_force = float(values["max_contact_force"])
        self._noise = values["position_noise_std"]
        self._rng = np.random.default_rng(values["noise_seed"])

    def joint_limits(self) -> JointLimits:
        return JointLimits.unlimited(self._n)

    def mass_matrix(self, q: np.ndarray | None = None) -> np.ndarray:
        """M = diag(m_1, ..., m_n) (kg), whatever the positions: what the brakes scale by."""
        return np.diag(self._mass)

    def contact_force_magnitude(self) -> float:
        """The measured wrench's force, always 0 (no contact; no draw from the noise)."""
        return 0.0

    def true_velocity(self) -> list[float]:
        return self._x[1::2].tolist()

    def measurement(self) -> Measurement:
        q = self._x[0::2].copy()
        if self._noise:
            q += self._noise * self._rng.standard_normal(self._n)
        return Measurement(self._t, q, self._x[1::2].copy(), self._held.copy(), np.zeros(3))
