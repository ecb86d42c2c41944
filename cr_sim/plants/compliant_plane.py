"""Chapter 3 plant: the 2-link arm pressing a compliant plane (thesis 3.5, fig. 3.1).

Robot: M q'' + C q' + G = tau + J^T (f + f_dist) (3.1, 3.35). Environment: the plane
Phi(r) = n.r + offset = 0 (3.92: x - y + 0.25 = 0) with the environment on the side
Phi < 0; when the end effector penetrates it by delta = -Phi/|n| the plane pushes back
along n/|n| with f = K_e delta (3.4 with K_e = 150 I and the rest position the nearest
surface point), plus optional damping. Contact is unilateral: no pulling force.

Initial state (not given in the thesis, DESIGN.md): at rest at r_e(0) = (-0.05, 0.2),
the surface point nearest r_d(0), touching with zero force.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from cr_control.core.parameters import Param, ParameterError
from cr_sim.integrators import integrate
from cr_sim.models.arm_model import LinkParameters, TwoLinkArm
from cr_sim.plants.base import Measurement, Plant

NAME = "compliant_plane"

PARAMETERS = [
    Param("link_length", [0.3, 0.3], "Link lengths (m).", "positive_vector", 2, read_only=True),
    Param("link_com", [0.15, 0.15], "Centre-of-mass distance from each joint (m).",
          "positive_vector", 2, read_only=True),
    Param("link_mass", [0.1, 0.1], "Link masses (kg).", "positive_vector", 2, read_only=True),
    Param("link_inertia", [0.3, 0.3], "Link inertias about the centre of mass (kg m^2).",
          "positive_vector", 2, read_only=True),
    Param("gravity", 9.8, "Gravitational acceleration along -y (m/s^2).", "nonnegative",
          read_only=True),
    Param("surface_normal", [1.0, -1.0],
          "n of the plane n.r + offset = 0; points out of the environment (3.92: [1, -1]).",
          "vector", 2, read_only=True),
    Param("surface_offset", 0.25, "offset of the plane n.r + offset = 0 (3.92: 0.25).",
          read_only=True),
    Param("stiffness", 150.0, "Environment stiffness K_e along the normal (N/m) (3.5).",
          "positive", read_only=True),
    Param("damping", 0.0, "Environment damping along the normal (N s/m); thesis: none.",
          "nonnegative", read_only=True),
    Param("initial_position", [-0.05, 0.2],
          "End-effector position at t = 0, at rest (m); default touches the plane at zero force.",
          "vector", 2, read_only=True),
    Param("elbow_sign", -1.0, "Inverse-kinematics branch: sign of sin(theta2) at t = 0.",
          read_only=True),
    Param("disturbance_amplitude", [0.0, 0.0],
          "External disturbance force f_dist on the end effector (N) (3.35); 0 = none.",
          "vector", 2, read_only=True),
    Param("disturbance_frequency", 0.0,
          "f_dist = amplitude*sin(w t) with this w (rad/s); 0 = constant force.",
          "nonnegative", read_only=True),
    Param("disturbance_start", 0.0, "Time the disturbance starts (s).", "nonnegative",
          read_only=True),
    Param("disturbance_duration", 0.0, "How long it lasts (s); 0 = to the end.", "nonnegative",
          read_only=True),
    Param("position_noise_std", 0.0, "Joint position measurement noise, std (rad).",
          "nonnegative", read_only=True),
    Param("velocity_noise_std", 0.0, "Joint velocity measurement noise, std (rad/s).",
          "nonnegative", read_only=True),
    Param("force_noise_std", 0.0, "Force measurement noise, std (N).", "nonnegative",
          read_only=True),
    Param("noise_seed", 0, "Seed of the measurement noise.", "integer", read_only=True),
    Param("substeps", 1, "RK4 substeps per control period (the contact is not stiff: 1 is "
          "accurate to ~1e-9 m at 1 kHz).", "integer", read_only=True),
]


class CompliantPlane:
    """Unilateral compliant plane n.r + offset = 0, environment on the side n.r + offset < 0."""

    def __init__(self, normal: np.ndarray, offset: float, stiffness: float, damping: float):
        norm = float(np.linalg.norm(normal))
        if norm == 0.0:
            raise ParameterError("surface_normal must not be zero")
        self.normal = np.asarray(normal, dtype=float) / norm
        self.offset = offset / norm
        self._n = (float(self.normal[0]), float(self.normal[1]))
        self.stiffness = stiffness
        self.damping = damping

    def force(self, r: np.ndarray, r_dot: np.ndarray) -> np.ndarray:
        """Contact force on the end effector (3.4), never pulling."""
        n0, n1 = self._n
        depth = -(n0 * r[0] + n1 * r[1] + self.offset)
        if depth <= 0.0:
            return np.zeros(2)
        push = self.stiffness * depth - self.damping * (n0 * r_dot[0] + n1 * r_dot[1])
        return max(push, 0.0) * self.normal


class CompliantPlaneArm(Plant):
    """The 2-link arm of ch. 3 in contact with a compliant plane."""

    joint_names = TwoLinkArm.joint_names
    command_interface = "effort"

    def __init__(self, values: dict):
        if values["substeps"] < 1:
            raise ParameterError("substeps must be >= 1")
        self.arm = TwoLinkArm(LinkParameters(
            length=list(values["link_length"]), com=list(values["link_com"]),
            mass=list(values["link_mass"]), inertia=list(values["link_inertia"]),
            gravity=values["gravity"],
        ))
        self.plane = CompliantPlane(values["surface_normal"], values["surface_offset"],
                                    values["stiffness"], values["damping"])
        self.substeps = values["substeps"]
        self._dist = (values["disturbance_amplitude"], values["disturbance_frequency"],
                      values["disturbance_start"], values["disturbance_duration"])
        self._disturbed = bool(np.any(values["disturbance_amplitude"] != 0.0))
        self._noise = (values["position_noise_std"], values["velocity_noise_std"],
                       values["force_noise_std"])
        self._rng = np.random.default_rng(values["noise_seed"])
        try:
            q0 = self.arm.inverse_kinematics(values["initial_position"], values["elbow_sign"])
        except ValueError as exc:
            raise ParameterError(f"initial_position: {exc}") from exc
        self._x = np.concatenate([q0, np.zeros(2)])
        self._t = 0.0
        self._effort = np.zeros(2)
        self._model, self._data, self._tool = self.arm.model, self.arm.data, self.arm.tool

    @property
    def time(self) -> float:
        return self._t

    @property
    def state(self) -> np.ndarray:
        """[q1, q2, q1', q2'] (true, noise-free)."""
        return self._x.copy()

    def disturbance(self, t: float) -> np.ndarray:
        """External disturbance force f_dist(t) on the end effector (3.35)."""
        amplitude, omega, start, duration = self._dist
        if t < start or (duration > 0.0 and t >= start + duration):
            return np.zeros(2)
        return amplitude * math.sin(omega * (t - start)) if omega > 0.0 else amplitude

    def _tool_state(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        J = pin.computeFrameJacobian(self._model, self._data, q, self._tool,
                                     pin.LOCAL_WORLD_ALIGNED)[:2, :]
        r = self._data.oMf[self._tool].translation[:2]
        return r, J, J @ v

    def contact_force(self, x: np.ndarray | None = None) -> np.ndarray:
        """Force of the plane on the end effector at state x (default: now)."""
        x = self._x if x is None else x
        r, _, r_dot = self._tool_state(x[:2], x[2:])
        return self.plane.force(r, r_dot)

    def _derivative(self, t: float, x: np.ndarray) -> np.ndarray:
        q, v = x[:2], x[2:]
        r, J, r_dot = self._tool_state(q, v)
        f = self.plane.force(r, r_dot)
        if self._disturbed:
            f = f + self.disturbance(t)
        x_dot = np.empty(4)
        x_dot[:2] = v
        x_dot[2:] = pin.aba(self._model, self._data, q, v, self._effort + J.T @ f)
        return x_dot

    def step(self, command: np.ndarray, dt: float) -> None:
        """Advance by dt with joint torques ``command`` held (a refused command keeps the last)."""
        if self.accept(command):
            self._effort = np.array(command, dtype=float)
        self._x = integrate(self._derivative, self._t, self._x, dt, self.substeps)
        self._t += dt

    def measurement(self) -> Measurement:
        q, v = self._x[:2].copy(), self._x[2:].copy()
        force = self.contact_force()
        q_std, v_std, f_std = self._noise
        if q_std or v_std or f_std:
            q += q_std * self._rng.standard_normal(2)
            v += v_std * self._rng.standard_normal(2)
            force = force + f_std * self._rng.standard_normal(2)
        return Measurement(self._t, q, v, self._effort.copy(), np.array([force[0], force[1], 0.0]))
