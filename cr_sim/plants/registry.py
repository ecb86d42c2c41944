"""Registry of the simulated plants (one module per plant/scenario)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from cr_control.core.parameters import Param, resolve
from cr_sim.plants import circular_surface, cmmsd, dynamic_constraint, joint_servo, urdf_surface
from cr_sim.plants import compliant_plane as compliant_plane_arm
from cr_sim.plants import flexible_joint_surface as flexible_joint
from cr_sim.plants import moving_object as moving_object_plant
from cr_sim.plants.base import Plant

#: scenario name -> (parameters, factory taking the converted parameter values)
SCENARIOS: dict[str, tuple[list[Param], Callable[[dict], Plant]]] = {
    compliant_plane_arm.NAME: (compliant_plane_arm.PARAMETERS, compliant_plane_arm.CompliantPlaneArm),
    circular_surface.NAME: (circular_surface.PARAMETERS, circular_surface.CircularSurfaceArm),
    moving_object_plant.NAME: (moving_object_plant.PARAMETERS, moving_object_plant.MovingObjectPlant),
    dynamic_constraint.NAME: (dynamic_constraint.PARAMETERS, dynamic_constraint.DynamicConstraint),
    cmmsd.NAME: (cmmsd.PARAMETERS, cmmsd.CMMSD),
    flexible_joint.NAME: (flexible_joint.PARAMETERS, flexible_joint.FlexibleJointSurface),
    urdf_surface.NAME: (urdf_surface.PARAMETERS, urdf_surface.URDFSurface),
    joint_servo.NAME: (joint_servo.PARAMETERS, joint_servo.JointServoSurface),
}


def make_plant(scenario: str, overrides: dict[str, Any] | None = None) -> Plant:
    """A plant of ``scenario`` with the thesis defaults and ``overrides`` (ROS-style values)."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; known: {sorted(SCENARIOS)}")
    params, factory = SCENARIOS[scenario]
    return factory(resolve(params, overrides))
