"""Task-space quantities of the 2-link arm shared by the chapter 3 and 5 schemes.

Task-space model (3.2): M_r r'' + C_r r' + G_r = J^-T tau + f with
M_r = J^-T M J^-1, C_r = J^-T (M d(J^-1)/dt + C J^-1), G_r = J^-T G.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from cr_control.core.linalg import inv2, matmul, matvec, tmatvec
from cr_control.core.parameters import Param
from cr_control.models.arm_model import LinkParameters, TwoLinkArm
from cr_control.models.planar_chain import (
    PlanarChain,
    coriolis_matrix,
    mass_matrix,
    rnea,
    tool_jacobian_dot,
    tool_kinematics,
)
from cr_control.schemes.blocks.references import CHAPTER3_REFERENCE, chapter3_reference

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
    """End-effector state of one cycle: r, r', J(q), J(q)^-1, J'(q, q') q'."""

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


# -- compiled kernels (numba): the chain is the packed PlanarChain of the controller's model --
@njit(cache=True, error_model="numpy")
def task_state(chain, q, v):
    """(r, r' = J q', J, J^-1, J' q') at (q, q')."""
    r, J, jdot_v = tool_kinematics(chain, q, v)
    return r, matvec(J, v), J, inv2(J), jdot_v


@njit(cache=True, error_model="numpy")
def torque_for_acceleration(chain, q, v, J, J_inv, jdot_v, a, f):
    """tau = J^T (M_r a + C_r r' + G_r - f), evaluated in joint space as
    M J^-1 (a - J' q') + C q' + G - J^T f (one recursive Newton-Euler pass)."""
    qdd = matvec(J_inv, a - jdot_v)
    return rnea(chain, q, v, qdd, True) - tmatvec(J, f)


@njit(cache=True, error_model="numpy")
def task_dynamics(chain, q, v, J_inv):
    """M_r, C_r, G_r of (3.2) at (q, q'): J^-T M J^-1, J^-T (M d(J^-1)/dt + C J^-1), J^-T G,
    with d(J^-1)/dt = -J^-1 J' J^-1 and C in Christoffel form."""
    M = mass_matrix(chain, q)
    C = coriolis_matrix(chain, q, v)
    zero = np.zeros(q.shape[0])
    G = rnea(chain, q, zero, zero, True)
    J_inv_T = J_inv.T.copy()
    J_inv_dot = -matmul(matmul(J_inv, tool_jacobian_dot(chain, q, v)), J_inv)
    M_r = matmul(matmul(J_inv_T, M), J_inv)
    C_r = matmul(J_inv_T, matmul(M, J_inv_dot) + matmul(C, J_inv))
    return M_r, C_r, matvec(J_inv_T, G)


class ArmTaskSpace:
    """The controller's model of the arm seen from the end effector, and its reference.

    ``chain`` (packed, for the kernels) comes from the Pinocchio model of the URDF with the
    ``model_*`` parameters; the methods are Python entry points to the kernels.
    """

    def __init__(self, values: dict):
        self.arm = arm_from_values(values)
        self.chain = PlanarChain.from_model(self.arm.model, "tool0").chain
        self.reference = chapter3_reference(values)

    def state(self, q: np.ndarray, v: np.ndarray) -> TaskState:
        """r, r' = J q', J, J^-1 and J' q' at (q, q')."""
        return TaskState(*task_state(self.chain, q, v))

    def torque_for_acceleration(self, q: np.ndarray, v: np.ndarray, ts: TaskState,
                                a: np.ndarray, force: np.ndarray) -> np.ndarray:
        """tau = J^T (M_r a + C_r r' + G_r - f)."""
        return torque_for_acceleration(self.chain, q, v, ts.J, ts.J_inv, ts.jdot_v, a, force)

    def dynamics(self, q: np.ndarray, v: np.ndarray,
                 ts: TaskState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """M_r, C_r, G_r of (3.2) at (q, q')."""
        return task_dynamics(self.chain, q, v, ts.J_inv)


#: Where a cycle kernel writes its results in the one output vector the scheme allocates per
#: cycle (boxing three returned arrays costs ~100 interpreter loop iterations, slicing one
#: vector ~10): [command (n) | reference values (8) | status values].
N_REFERENCE = 8


@njit(cache=True, error_model="numpy")
def split_output(out, n):
    """(command, reference, status) views of a cycle's output vector."""
    return out[:n], out[n:n + N_REFERENCE], out[n + N_REFERENCE:]


@njit(cache=True, error_model="numpy")
def write_task_space(out, r_d, v_d, a_d, f_d, r, r_dot, f, e, tau):
    """Fill the output vector: command tau, reference (topics.REFERENCE_FIELDS after stamp)
    and the task-space part of the status (topics.STATUS_FIELDS after stamp); the rest of
    the status (timing, held, the scheme's fields) is zeroed for the caller to fill."""
    n = tau.shape[0]
    command, reference, status = split_output(out, n)
    command[:] = tau
    reference[0:2], reference[2:4], reference[4:6], reference[6:8] = r_d, v_d, a_d, f_d
    status[:] = 0.0
    for i in range(2):
        status[i], status[2 + i], status[4 + i] = r[i], r_dot[i], f[i]
        status[6 + i], status[8 + i] = e[i], f_d[i] - f[i]
    for i in range(n):
        status[10 + i] = tau[i]
    return status
