"""Chapter 3 plant: the 2-link arm pressing a compliant plane (thesis 3.5, fig. 3.1).

Robot: M q'' + C q' + G = tau + J^T (f + f_dist) (3.1, 3.35). Environment: the plane
Phi(r) = n.r + offset = 0 (3.92: x - y + 0.25 = 0) with the environment on the side
Phi < 0; when the end effector penetrates it by delta = -Phi/|n| the plane pushes back
along n/|n| with f = K_e delta (3.4 with K_e = 150 I and the rest position the nearest
surface point), plus optional damping. Contact is unilateral: no pulling force.

Initial state (not given in the thesis; docs/thesis.md): at rest at r_e(0) = (-0.05, 0.2),
the surface point nearest r_d(0), touching with zero force.

The arm: ``config/two_link_arm.urdf`` by default, or any planar 2-link arm given by the robot
parameters (its joint names; ``link_*`` override its geometry and inertia).
"""

from __future__ import annotations

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_sim.models.surfaces import plane
from cr_sim.plants.arm_on_surface import (
    NOISE_PARAMETERS,
    ArmOnSurface,
    arm_parameters,
    disturbance_parameters,
    robot_parameters,
)
from cr_sim.plants.base import max_contact_force_parameter

NAME = "compliant_plane"

PARAMETERS = [
    *robot_parameters("two_link_arm.urdf", "the 2-link arm of chapter 3 (0.3 m links)"),
    *arm_parameters(length=0.3, com=0.15),
    Param("surface_normal", [1.0, -1.0],
          "n of the plane n.r + offset = 0; points out of the environment (3.92: [1, -1]).",
          "vector", 2, read_only=True, bound=Bound.SCALE),
    Param("surface_offset", 0.25, "offset of the plane n.r + offset = 0 (3.92: 0.25).",
          read_only=True, bound=Bound.LENGTH),
    Param("stiffness", 150.0, "Environment stiffness K_e along the normal (N/m) (3.5).",
          "positive", read_only=True, bound=Bound.CONTACT_STIFFNESS),
    Param("damping", 0.0, "Environment damping along the normal (N s/m); thesis: none.",
          "nonnegative", read_only=True, bound=Bound.DAMPING),
    Param("initial_position", [-0.05, 0.2],
          "End-effector position at t = 0, at rest (m); default touches the plane at zero force.",
          "vector", 2, read_only=True, bound=Bound.LENGTH),
    Param("elbow_sign", -1.0, "Inverse-kinematics branch: sign of sin(theta2) at t = 0.",
          read_only=True, bound=Bound.SIGN),
    *disturbance_parameters([0.0, 0.0], 0.0, 0.0, 0.0, "3.35"),
    *NOISE_PARAMETERS,
    Param("substeps", 1, "RK4 substeps per control period (the contact is not stiff: 1 is "
          "accurate to ~1e-9 m at 1 kHz).", "integer", read_only=True, bound=Bound.SUBSTEPS),
    max_contact_force_parameter(50.0, "~5 x the task's force: the ch. 3 contact settles at "
                                "~10.6 N (its thesis runs peak at 11.2 N)."),
]


class CompliantPlaneArm(ArmOnSurface):
    """The 2-link arm of ch. 3 in contact with a compliant plane."""

    scenario = NAME

    def __init__(self, values: dict):
        try:
            surface = plane(values["surface_normal"], values["surface_offset"],
                            values["stiffness"], values["damping"])
        except ValueError as exc:
            raise ParameterError(str(exc)) from exc
        super().__init__(values, surface, q0=[0.0, 0.0])
        try:
            q0 = self.arm.inverse_kinematics(values["initial_position"], values["elbow_sign"])
        except ValueError as exc:
            raise ParameterError(f"initial_position: {exc}") from exc
        self.reset_state(q0)
