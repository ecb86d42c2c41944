"""Task-space quantities of the 2-link arm shared by the chapter 3 and 5 schemes.

Task-space model (3.2): M_r r'' + C_r r' + G_r = J^-T tau + f with
M_r = J^-T M J^-1, C_r = J^-T (M d(J^-1)/dt + C J^-1), G_r = J^-T G.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from cr_control.core.parameters import Param
from cr_control.schemes.references import CHAPTER3_REFERENCE, chapter3_reference
from cr_sim.models.arm_model import LinkParameters, TwoLinkArm

#: The controller's model of the arm (thesis values; the robust schemes use wrong ones).
ARM_MODEL_PARAMETERS = [
    Param("model_link_length", [0.3, 0.3], "Controller model: link lengths (m).",
          "positive_vector", 2, read_only=True),
    Param("model_link_com", [0.15, 0.15], "Controller model: centre-of-mass distances (m).",
          "positive_vector", 2, read_only=True),
    Param("model_link_mass", [0.1, 0.1], "Controller model: link masses (kg).",
          "positive_vector", 2, read_only=True),
    Param("model_link_inertia", [0.3, 0.3], "Controller model: link inertias (kg m^2).",
          "positive_vector", 2, read_only=True),
    Param("model_gravity", 9.8, "Controller model: gravity (m/s^2).", "nonnegative",
          read_only=True),
]

TASK_SPACE_PARAMETERS = ARM_MODEL_PARAMETERS + CHAPTER3_REFERENCE


def inverse_2x2(A: np.ndarray) -> np.ndarray:
    """Inverse of a 2x2 matrix (much cheaper than numpy's general solver at this size)."""
    a, b, c, d = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    det = a * d - b * c
    return np.array([[d, -b], [-c, a]]) / det


@dataclass
class TaskState:
    """End-effector state of one cycle: r, r', J(q), J'(q, q') q'."""

    r: np.ndarray
    r_dot: np.ndarray
    J: np.ndarray
    J_inv: np.ndarray
    jdot_v: np.ndarray


def arm_from_values(values: dict) -> TwoLinkArm:
    """The controller's arm model from its ``model_*`` parameters."""
    return TwoLinkArm(LinkParameters(
        length=list(values["model_link_length"]), com=list(values["model_link_com"]),
        mass=list(values["model_link_mass"]), inertia=list(values["model_link_inertia"]),
        gravity=values["model_gravity"],
    ))


class ArmTaskSpace:
    """The controller's model of the arm seen from the end effector, and its reference."""

    def __init__(self, values: dict):
        self.arm = arm_from_values(values)
        self.reference = chapter3_reference(values)
        self._model, self._data, self._tool = self.arm.model, self.arm.data, self.arm.tool

    def state(self, q: np.ndarray, v: np.ndarray) -> TaskState:
        """r, r' = J q', J and J' q' at (q, q')."""
        r, J, jdot_v = self.arm.kinematics(q, v)
        return TaskState(r, J @ v, J, inverse_2x2(J), jdot_v)

    def torque_for_acceleration(self, q: np.ndarray, v: np.ndarray, ts: TaskState,
                                a: np.ndarray, force: np.ndarray) -> np.ndarray:
        """tau = J^T (M_r a + C_r r' + G_r - f), evaluated in joint space as
        M J^-1 (a - J' q') + C q' + G - J^T f."""
        qdd = ts.J_inv @ (a - ts.jdot_v)
        return pin.rnea(self._model, self._data, q, v, qdd) - ts.J.T @ force

    def dynamics(self, q: np.ndarray, v: np.ndarray,
                 ts: TaskState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """M_r, C_r, G_r of (3.2) at (q, q')."""
        model, data = self._model, self._data
        M = self.arm.mass_matrix(q)
        C = pin.computeCoriolisMatrix(model, data, q, v)
        G = pin.computeGeneralizedGravity(model, data, q)
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        J_dot = pin.getFrameJacobianTimeVariation(model, data, self._tool,
                                                  pin.LOCAL_WORLD_ALIGNED)[:2, :]
        J_inv, J_inv_T = ts.J_inv, ts.J_inv.T
        J_inv_dot = -J_inv @ J_dot @ J_inv
        return J_inv_T @ M @ J_inv, J_inv_T @ (M @ J_inv_dot + C @ J_inv), J_inv_T @ G
