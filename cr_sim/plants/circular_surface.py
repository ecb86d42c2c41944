"""Chapter 5 plant: the 2-link arm (0.6 m links) on a circular surface (thesis 5.1, 5.3, fig. 5.2).

Robot: M q'' + C q' + G = tau + J^T (f + f~) (5.1, the disturbed model of 5.3): links of
0.6 m with the centre of mass mid-link (0.3 m), m = 0.1 kg, I = 0.3 kg m^2, gravity along -y.

Environment: the disk (x - 0.8)^2 + (y + 0.4)^2 <= 0.09 (section 5.3), pressed on from
outside. Contact is unilateral (docs/thesis.md, chapter 5): when the tool is inside the circle by
delta = R - |r - c| > 0 the surface pushes it out along the outward normal
n = (r - c)/|r - c| with f = max(K_e delta - D_e n.r', 0) n, and never pulls
(:mod:`cr_sim.models.surfaces`, CIRCLE). The thesis gives no environment stiffness.
Default K_e = 2000 N/m, D_e = 10 N s/m: a compliant surface (a rubber-covered
work piece, or a stiff one behind a compliant wrist) that yields 5 mm at the desired 10 N, of
the order of the desired impedance's own stiffness scale (k_m = 60 N/m would otherwise make
the environment irrelevant) while keeping the contact mode of (5.7),
sqrt((k_m + K_e)/m_m) ~ 41 rad/s (6.6 Hz), far below the 1 kHz loop so the measured force
fed back one period late does not destabilise it. D_e is the small loss of such a material
(a damping ratio ~0.1 on the contact mode). Both are parameters.

Disturbance f~ (5.3): |f~| = 2 N from t = 2 s for 0.06 s, pulling the end effector off the
surface: by default along the outward surface normal at the end effector at the moment the
disturbance begins (``disturbance_direction`` [0, 0]), or along any fixed direction given.

Initial state (not given in the thesis): at rest at r_d(0) = (0.8, -0.1), the top of the
circle, touching with zero force. The arm's base is at the origin, so the circle spans
0.594 m to 1.194 m from it: all of it is within the 1.2 m reach, the far point only just
(|theta_2| ~ 0.2 rad there). The path never reaches theta_2 = 0 or pi, so the elbow branch
chosen at t = 0 is kept throughout; default sin(theta_2) < 0 as in ch. 3 and 6 (elbow
above the line from the base to the tool). Only the tool touches the surface: the links are
not collision-checked (on the far side of the circle the arm reaches across the disk on
either branch: the thesis's example has the same geometry).

The arm: ``config/two_link_arm_ch5.urdf`` by default, or any planar 2-link arm given by the
robot parameters (its joint names; ``link_*`` override its geometry and inertia).
"""

from __future__ import annotations

import math

import numpy as np

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_sim.models.surfaces import circle
from cr_sim.plants.arm_on_surface import (
    NOISE_PARAMETERS,
    ArmOnSurface,
    arm_parameters,
    robot_parameters,
)
from cr_sim.plants.base import max_contact_force_parameter

NAME = "circular_surface"

PARAMETERS = [
    *robot_parameters("two_link_arm_ch5.urdf", "the 2-link arm of chapter 5 (0.6 m links)"),
    *arm_parameters(length=0.6, com=0.3),
    Param("surface_centre", [0.8, -0.4], "Centre c of the circular surface |r - c| = R (m) "
          "(section 5.3: (x - 0.8)^2 + (y + 0.4)^2 = 0.09).", "vector", 2, read_only=True,
          bound=Bound.LENGTH),
    Param("surface_radius", 0.3, "Radius R of the circular surface (m) (section 5.3: 0.3).",
          "positive", read_only=True, bound=Bound.LENGTH),
    Param("stiffness", 2000.0, "Environment stiffness K_e along the normal (N/m); the thesis "
          "gives none: a compliant surface yielding 5 mm at the desired 10 N.", "positive",
          read_only=True, bound=Bound.CONTACT_STIFFNESS),
    Param("damping", 10.0, "Environment damping D_e along the normal (N s/m); only pushes "
          "(unilateral).", "nonnegative", read_only=True, bound=Bound.DAMPING),
    Param("initial_position", [0.8, -0.1],
          "End-effector position at t = 0, at rest (m); default r_d(0), on the surface at "
          "zero force.", "vector", 2, read_only=True, bound=Bound.LENGTH),
    Param("elbow_sign", -1.0, "Inverse-kinematics branch: sign of sin(theta2) at t = 0 (-1: "
          "elbow up, clear of the disk).", read_only=True, bound=Bound.SIGN),
    Param("disturbance_magnitude", 2.0, "|f~| of the disturbance force on the end effector "
          "(N) (5.3: 2 N); 0 = none.", "nonnegative", read_only=True, bound=Bound.FORCE),
    Param("disturbance_direction", [0.0, 0.0], "Direction of f~ (normalised here); [0, 0] = "
          "the outward surface normal at the end effector when f~ begins (pulls it off).",
          "vector", 2, read_only=True, bound=Bound.SCALE),
    Param("disturbance_start", 2.0, "Time f~ begins (s) (5.3: 2 s).", "nonnegative",
          read_only=True, bound=Bound.TIME),
    Param("disturbance_duration", 0.06, "How long f~ lasts (s) (5.3: 0.06 s).", "nonnegative",
          read_only=True, bound=Bound.TIME),
    *NOISE_PARAMETERS,
    Param("substeps", 1, "RK4 substeps per control period (contact mode ~41 rad/s: 1 is "
          "plenty at 1 kHz).", "integer", read_only=True, bound=Bound.SUBSTEPS),
    max_contact_force_parameter(50.0, "5 x the task's force f_dm = 10 N (5.3; the thesis "
                                "runs peak at 15.2 N on the first impact)."),
]


class CircularSurfaceArm(ArmOnSurface):
    """The 2-link arm of ch. 5 on the circular surface, with the push-off disturbance."""

    scenario = NAME

    def __init__(self, values: dict):
        if values["surface_radius"] <= 0.0:
            raise ParameterError("surface_radius must be > 0")
        surface = circle(values["surface_centre"], values["surface_radius"], values["stiffness"],
                         values["damping"])
        base = dict(values, disturbance_amplitude=[0.0, 0.0], disturbance_frequency=0.0)
        super().__init__(base, surface, q0=[0.0, 0.0])
        try:
            q0 = self.arm.inverse_kinematics(values["initial_position"], values["elbow_sign"])
        except ValueError as exc:
            raise ParameterError(f"initial_position: {exc}") from exc
        self.reset_state(q0)
        self._magnitude = float(values["disturbance_magnitude"])
        direction = np.asarray(values["disturbance_direction"], dtype=float)
        norm = float(np.hypot(*direction))
        #: The fixed direction of f~, or None: the outward normal when f~ begins.
        self.disturbance_direction = direction / norm if norm > 0.0 else None
        self._armed = self._magnitude > 0.0
        if self._armed and self.disturbance_direction is not None:
            self._set_disturbance(self.disturbance_direction)
            self._armed = False
        self._start = float(values["disturbance_start"])

    def _set_disturbance(self, direction) -> None:
        self.disturbance_packed[0] = self._magnitude * direction[0]
        self.disturbance_packed[1] = self._magnitude * direction[1]

    def outward_normal(self) -> np.ndarray:
        """The surface's outward normal at the end effector's current position."""
        c = self.surface
        dx, dy = self.sensors[3] - c[1], self.sensors[4] - c[2]
        dist = math.hypot(dx, dy)
        return np.array([dx / dist, dy / dist]) if dist > 0.0 else np.array([1.0, 0.0])

    def disturbance_force(self) -> np.ndarray:
        """The disturbance vector f~ while it acts (its direction fixed once it begins)."""
        return self.disturbance_packed[:2].copy()

    def step(self, command: np.ndarray, dt: float) -> None:
        # The normal-direction disturbance takes the outward normal at the end effector at the
        # last state before it begins (one float comparison per cycle until then).
        if self._armed and self._t + dt > self._start:
            self._set_disturbance(self.outward_normal())
            self._armed = False
        super().step(command, dt)
