"""Chapter 4 plant: an end effector (m, c, k) pressing a third-order dynamic constraint
(thesis 4.1-4.6, fig. 4.1), command displacement in, constraint force out.

End effector (4.5): m delta'' + c delta' + k delta = k delta_c (the robot's own position
loop; delta_c is the command). Constraint (4.2-4.3), input delta, internal state
x = [x_1, x_2, x_3] (x_3 = x_2'), output f:

    x' = A_c x + B_c delta,   f = E x + D delta
    A_c = [[-k_o/b_s, 0, 1], [0, 0, 1], [-k_o/m_c, -(k_s+k_c)/m_c, -b_c/m_c]]
    B_c = [k_o/b_s, 0, (k_o+k_s)/m_c],  E = [-k_o, -k_s, 0],  D = k_o + k_s

The state-space model is simulated (exactly, :mod:`cr_sim.plants.lti`), not the printed
transfer-function coefficients (4.4 has typos; docs/thesis.md). Contact loss as the thesis says:
the states keep evolving and the force is reported as 0 when f would be negative.

Initial state (the thesis's "initial force 1.5 N"): at rest in equilibrium with f = f_0:
delta = delta_c = f_0 (k_c + k_s)/(k_c k_s) (0.225 m in case 1), x = [delta, f_0/k_c, 0].

On the topic contract: one prismatic joint ``delta`` along the surface normal (position
delta, velocity delta'; effort = the end effector's servo force k (delta_c - delta)); the
wrench carries f as its x component (x = the surface normal, into the constraint; f >= 0
presses); the command is a position (delta_c). Cases 1/2/3: k_o = k_s = 20/50/80.

Safe stop (the watchdog's and the reflexes' brakes). A position-commanded end
effector cannot be braked with torques; its safe stop retracts the command instead:

    delta_c = r(t) - (K_d / k) delta'

r moves from the held delta_c at ``retract_speed`` (the interface has no velocity limit of
its own) to the contact-free position and stays there: the lowest of the zero-force
equilibrium (``equilibrium(values, 0)``: delta = 0), the position where f = 0 for the
constraint's state when braking begins (delta - f_raw / (k_o + k_s)) and the held command
(never back toward the surface). The second term is the brakes' damping K_d
(this scenario's ``brake_damping``, N s/m) acting through the servo's stiffness k: the end effector's
own loop is damped at zeta ~ 0.02 and the constraint at ~0.01, so a plain hold lets the
pair ring (after the MRAC divergence trips the reflex at 5 N, held positions see the force
come back at 12-40 N within 35 s; with the damping it peaks 1.1 % above the trip value
0.15 s later - the end effector's momentum: a 20 kg end effector on a 10 N/m servo cannot
stop within a period - and the end effector comes to rest at r). At rest delta_c = r: the
position is held. "Contact-free" holds at rest: the thesis's constraint is bilateral (its
states follow delta without contact) and its compliant layer keeps ringing (tau ~ 100 s),
touching the retracted end effector with a decaying force below the force at the stop.
"""

from __future__ import annotations

import numpy as np

from cr_control.core.parameters import Bound, Param
from cr_sim.plants.base import JointLimits, Measurement, max_contact_force_parameter
from cr_sim.plants.lti import LTIPlant

NAME = "dynamic_constraint"

#: Outer-layer stiffness k_o = k_s of the thesis's cases 1, 2, 3 (N/m).
CASE_STIFFNESS = {1: 20.0, 2: 50.0, 3: 80.0}

PARAMETERS = [
    Param("end_effector_mass", 20.0, "End-effector mass m of (4.5) (kg).", "positive", read_only=True,
          bound=Bound.MASS),
    Param("end_effector_damping", 0.5, "End-effector damping c of (4.5) (N s/m).", "nonnegative",
          read_only=True, bound=Bound.DAMPING),
    Param("end_effector_stiffness", 10.0, "End-effector (position loop) stiffness k of (4.5) (N/m).",
          "positive", read_only=True, bound=Bound.STIFFNESS),
    Param("k_o", 20.0, "Outer-layer stiffness k_o (N/m); cases 1/2/3: 20/50/80.", "positive",
          read_only=True, bound=Bound.STIFFNESS),
    Param("k_s", 20.0, "Outer-layer stiffness k_s (N/m); cases 1/2/3: 20/50/80.", "positive",
          read_only=True, bound=Bound.STIFFNESS),
    Param("b_s", 1.0, "Outer-layer damping b_s (N s/m).", "positive", read_only=True, bound=Bound.DAMPING),
    Param("k_c", 10.0, "Compliant-layer stiffness k_c (N/m).", "positive", read_only=True,
          bound=Bound.STIFFNESS),
    Param("b_c", 1.0, "Compliant-layer damping b_c (N s/m).", "nonnegative", read_only=True,
          bound=Bound.DAMPING),
    Param("m_c", 50.0, "Compliant-layer mass m_c (kg).", "positive", read_only=True, bound=Bound.MASS),
    Param("initial_force", 1.5, "Force at t = 0 (N): the plant starts at rest in the "
          "equilibrium with this force (thesis: 1.5 N).", "nonnegative", read_only=True, bound=Bound.FORCE),
    Param("force_noise_std", 0.0, "Force measurement noise, std (N).", "nonnegative",
          read_only=True, bound=Bound.FORCE),
    Param("position_noise_std", 0.0, "Position (delta) measurement noise, std (m).",
          "nonnegative", read_only=True, bound=Bound.POSITION_NOISE),
    Param("noise_seed", 0, "Seed of the measurement noise.", "integer", read_only=True,
          bound=Bound.SEED),
    max_contact_force_parameter(5.0, "5 x the task's force f_d = 1 N (section 4.3; "
                                "config/backstepping_force.yaml, mrac_force.yaml), 3.3 x the "
                                "initial 1.5 N, the most the backstepping cases 1-3 reach."),
    Param("retract_speed", 0.5, "Safe stop: speed (m/s) at which the command delta_c retracts "
          "to the contact-free position (the position interface has no velocity limit of its "
          "own); ~1.5 x the fastest end-effector motion of the thesis runs (0.33 m/s).",
          "positive", read_only=True, bound=Bound.SPEED),
    Param("brake_damping", 30.0, "Safe stop: damping K_d (N s/m) the retract adds through the "
          "servo, delta_c = r(t) - (K_d / k) delta' (without it the lightly damped end effector "
          "and constraint ring: the force came back at 12-40 N after the MRAC trip at 5 N).",
          "positive", read_only=True, bound=Bound.DAMPING),
]


def matrices(values: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C) of the whole plant, state X = [delta, delta', x_1, x_2, x_3], input delta_c,
    output f = C X (before the contact clip)."""
    m, c, k = values["end_effector_mass"], values["end_effector_damping"], values["end_effector_stiffness"]
    ko, ks, bs = values["k_o"], values["k_s"], values["b_s"]
    kc, bc, mc = values["k_c"], values["b_c"], values["m_c"]
    A = np.zeros((5, 5))
    A[0, 1] = 1.0
    A[1, 0], A[1, 1] = -k / m, -c / m
    A[2:, 2:] = [[-ko / bs, 0.0, 1.0], [0.0, 0.0, 1.0], [-ko / mc, -(ks + kc) / mc, -bc / mc]]
    A[2:, 0] = [ko / bs, 0.0, (ko + ks) / mc]
    B = np.zeros((5, 1))
    B[1, 0] = k / m
    C = np.array([ko + ks, 0.0, -ko, -ks, 0.0])
    return A, B, C


def equilibrium(values: dict, force: float) -> np.ndarray:
    """The state at rest with contact force ``force`` (delta_c = delta)."""
    ks, kc = values["k_s"], values["k_c"]
    delta = force * (kc + ks) / (kc * ks)
    return np.array([delta, 0.0, delta, force / kc, 0.0])


def true_theta(values: dict) -> np.ndarray:
    """theta = [b_3 b_2 b_1 b_0 a_4 a_3 a_2 a_1 a_0] of (4.6) from the state-space model
    (the transfer function C (sI - A)^-1 B, computed from the matrices, not from 4.4)."""
    A, B, C = matrices(values)
    den = np.real(np.poly(A))                                  # s^5 + a_4 s^4 + ...
    # numerator: C adj(sI - A) B = det(sI - A + B C) - det(sI - A)
    num = np.real(np.poly(A - B @ C[None, :])) - den
    return np.concatenate([num[2:], den[1:]])


class DynamicConstraint(LTIPlant):
    """The end effector on the dynamic constraint (4.2-4.5), delta_c in, f out."""

    command_interface = "position"
    joint_names = ("delta",)

    def __init__(self, values: dict):
        self.values = dict(values)
        A, B, self.C = matrices(values)
        x0 = equilibrium(values, values["initial_force"])
        super().__init__(A, B, x0, [x0[0]])
        self._noise = (values["position_noise_std"], values["force_noise_std"])
        self._rng = np.random.default_rng(values["noise_seed"])
        self._k = values["end_effector_stiffness"]
        self.max_contact_force = float(values["max_contact_force"])
        self.retract_speed = float(values["retract_speed"])
        #: K_d (N s/m) of the safe stop's damping through the servo (module docstring).
        self.brake_damping = float(values["brake_damping"])
        self._c_list = [float(c) for c in self.C]

    def raw_force(self) -> float:
        """f = E x + D delta, negative when the contact would pull (not clipped)."""
        return float(self.C @ self._x)

    def joint_limits(self) -> JointLimits:
        return JointLimits.unlimited(1)

    def contact_force_magnitude(self) -> float:
        """f (N), true: the raw force clipped at 0 as the thesis reports it (no noise)."""
        f = sum(c * x for c, x in zip(self._c_list, self._x.tolist(), strict=True))
        return f if f > 0.0 else 0.0

    def true_velocity(self) -> list[float]:
        return [float(self._x[1])]

    def contact_free_position(self) -> np.ndarray:
        """Where the safe stop retracts delta_c to (module docstring): the lowest of the
        zero-force equilibrium, the position where f = 0 now and the held command."""
        rest = float(equilibrium(self.values, 0.0)[0])
        free_now = float(self._x[0]) - self.raw_force() / self._c_list[0]
        return np.array([min(rest, free_now, float(self._held[0]))])

    def safe_stop_command(self) -> np.ndarray:
        """The retract (base class) plus the brakes' damping through the servo:
        delta_c = r(t) - (K_d / k) delta' (module docstring)."""
        command = super().safe_stop_command()
        command[0] -= self.brake_damping / self._k * float(self._x[1])
        return command

    def describe_safe_stop(self) -> str:
        return (super().describe_safe_stop() + f", damped by {self.brake_damping:g} N s/m "
                "through the servo")

    def measurement(self) -> Measurement:
        x = self._x
        f = max(float(self.C @ x), 0.0)
        q = np.array([x[0]])
        if any(self._noise):
            q[0] += self._noise[0] * self._rng.standard_normal()
            f += self._noise[1] * self._rng.standard_normal()
        effort = np.array([self._k * (self._held[0] - x[0])])
        return Measurement(self._t, q, np.array([x[1]]), effort, np.array([f, 0.0, 0.0]))
