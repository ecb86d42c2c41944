"""Chapter 2 plant: a 2-link arm constrained by an object moved by a 1-DOF manipulator
(thesis 2.1-2.4, 2.91-2.104, fig. 2.3).

One Pinocchio model holds both manipulators: the arm (joints joint1, joint2; vertical plane,
base at (a, 0)) and the prismatic x axis object_x carrying the object, whose frame sits at
(q2, b). The arm is the planar 2-link arm of the robot parameters (default
``config/two_link_arm.urdf``; any planar 2-link URDF, whose joint names the plant then
publishes, with ``link_*`` overriding its geometry and inertia; its ``base_link`` placed at
(a, 0)); the object axis is the one of ``config/moving_object.urdf`` (limits; the
``object_*`` parameters set its height and mass). The closed chain is the holonomic
constraint (2.94) of the end effector on the line x_co - y_co = 0 of the object frame,

    Phi(q) = n . (p_tool - p_object) = 0,   n = (1, -1)/sqrt(2) = n_c (2.13),

so lambda is the force on the end effector along n_c (2.11) and the object feels
-n_c lambda (2.12, A = R_o = I). Dynamics (2.14-2.16, 2.103-2.104):

    M(q) q'' + C q' + G = tau + J_Phi^T lambda,   J_Phi = [J_1^T n_c ; -n_c,x]^T
    J_Phi q'' + J_Phi' q' = -2 alpha Phi' - beta^2 Phi                       (Baumgarte)

simulated by the compiled kernels of :mod:`cr_sim.models.constrained_dynamics` (RK4, the
command held over the period, one call per period; checked in the tests against
Pinocchio's constrained forward dynamics). The contact is bilateral as in the thesis
(lambda < 0 would pull; a real contact would separate there).

Sensors: joint positions and velocities of [joint1, joint2, object_x], the held efforts,
and the contact force on the end effector n_c lambda (world frame) - the wrench topic;
lambda = n_c . force. lambda is evaluated at the new state with the held command (the
reading just before the next command).

Initial state (the thesis gives none; docs/thesis.md): at rest on the desired path of (2.106-
2.107) at t = 0 - object at x_o(0) = 0.1 (1 - sin 12), contact point at x_co(0) = y_co(0)
= -cos(2)/12, elbow branch sin(theta2) > 0 - with the initial held effort the static one
tau_0 = G(q0) - J_Phi^T lambda_0, so lambda(0) = lambda_0 = 2 N (= lambda_d) and q''(0) = 0.
Starting at rest while the desired motion moves (x_o'(0) = -0.34 m/s) makes the schemes ask
for ~20 N m in the first cycles: the plant node's default limits (URDF 20 N m, 1000 N m/s)
clip some 30-50 of them, with lambda dipping to about -10 N for a few ms.

Cost: one compiled call per period (4 RK4 stages + lambda at the new state, each a planar
chain RNEA, mass matrix, tool kinematics and a Schur-complement KKT solve).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pinocchio as pin

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.core.paths import config_file
from cr_control.models.arm_model import two_link_inverse_kinematics
from cr_sim.models.constrained_dynamics import (
    mechanism_dynamics_into,
    mechanism_rk4,
    mechanism_work_size,
    planar_mechanism,
)
from cr_sim.plants.arm_on_surface import (
    NOISE_PARAMETERS,
    arm_parameters,
    robot_parameters,
    thesis_chain,
)
from cr_sim.plants.base import ConstrainedPlant, Measurement, max_contact_force_parameter

NAME = "moving_object"
#: The URDF of chapter 2's two manipulators: the plant takes the object axis from it.
URDF_NAME = "moving_object.urdf"
OBJECT_JOINT = "object_x"
#: The object's frame: the constraint's line lies in it.
OBJECT_FRAME = "object_frame"
#: The joints with the thesis's arm (the arm's joints are its URDF's).
JOINT_NAMES = ("joint1", "joint2", OBJECT_JOINT)

#: Desired motion (2.106-2.107) at t = 0: the default initial state.
X_O0 = 0.1 * (1.0 - math.sin(12.0))
X_CO0 = -math.cos(2.0) / 12.0

PARAMETERS = [
    *robot_parameters("two_link_arm.urdf", "the 2-link arm of chapters 2, 3 and 6 (0.3 m links)"),
    *arm_parameters(length=0.3, com=0.15),
    Param("base_position", [0.2, 0.0], "Base of manipulator 1, (a, 0) (m) (2.4: a = 0.2).",
          "vector", 2, read_only=True, bound=Bound.LENGTH),
    Param("object_height", 0.5, "Height b of the object frame (m) (2.93: b = 0.5).",
          read_only=True, bound=Bound.LENGTH),
    Param("object_mass", 0.2, "Mass M2 of manipulator 2 with the object (kg) (2.4).",
          "positive", read_only=True, bound=Bound.MASS),
    Param("constraint_normal", [1.0, -1.0],
          "Normal of the line on the object, object frame: Phi = n.r_co (2.94: x_co - y_co = 0; "
          "normalised: n_c = (1, -1)/sqrt(2)).", "vector", 2, read_only=True, bound=Bound.SCALE),
    Param("baumgarte_alpha", 20.0, "Baumgarte damping alpha of the constraint error (1/s).",
          "nonnegative", read_only=True, bound=Bound.BANDWIDTH),
    Param("baumgarte_beta", 20.0, "Baumgarte stiffness beta of the constraint error (1/s).",
          "nonnegative", read_only=True, bound=Bound.BANDWIDTH),
    Param("initial_object_position", X_O0,
          "Object position x_o at t = 0, at rest (m); default: x_o(0) of (2.107).",
          read_only=True, bound=Bound.LENGTH),
    Param("initial_contact_position", X_CO0,
          "End-effector position x_co on the object's line at t = 0 (m); default: x_co(0) of "
          "(2.106).", read_only=True, bound=Bound.LENGTH),
    Param("elbow_sign", 1.0, "Inverse-kinematics branch at t = 0: sign of sin(theta2) "
          "(s2 > 0: docs/thesis.md).", read_only=True, bound=Bound.SIGN),
    Param("initial_force", 2.0, "Contact force lambda at t = 0 (N): the initial held effort is "
          "the static one G(q0) - J_Phi^T lambda_0 (default lambda_d = 2 N).", read_only=True,
          bound=Bound.FORCE),
    *NOISE_PARAMETERS,
    Param("substeps", 1, "RK4 substeps per control period.", "integer", read_only=True, bound=Bound.SUBSTEPS),
    max_contact_force_parameter(20.0, "|lambda| (either sign: the constraint is bilateral), "
                                "10 x the task's lambda_d = 2 N (2.106): the thesis runs start "
                                "with |lambda| up to ~10 N for a few ms under the node's command "
                                "limits."),
]


def _object_axis() -> tuple[pin.SE3, list[np.ndarray]]:
    """Placement and limits (effort, velocity, lower, upper) of the object axis of URDF_NAME."""
    urdf = pin.buildModelFromUrdf(str(config_file(URDF_NAME)))
    j = urdf.getJointId(OBJECT_JOINT)
    if j >= urdf.njoints or urdf.joints[j].shortname() != "JointModelPX":
        raise ParameterError(f"{URDF_NAME} has no prismatic x joint {OBJECT_JOINT}")
    iv, iq = urdf.joints[j].idx_v, urdf.joints[j].idx_q
    limits = [np.array([limit[i]]) for limit, i in (
        (urdf.effortLimit, iv), (urdf.velocityLimit, iv), (urdf.lowerPositionLimit, iq),
        (urdf.upperPositionLimit, iq))]
    return pin.SE3(urdf.jointPlacements[j]), limits


def build_moving_object_model(values: dict) -> tuple[pin.Model, int]:
    """The Pinocchio model of both manipulators with the plant's parameters: the planar 2-link
    arm of the robot parameters (joints 1 and 2, its base at ``base_position``) and the object
    axis of URDF_NAME (joint 3, at ``object_height``, carrying ``object_mass``); and the frame
    id of the arm's tip."""
    chain = thesis_chain(values, NAME)
    model = chain.model
    a = values["base_position"]
    model.jointPlacements[1].translation = np.array([a[0], a[1], 0.0])
    placement, limits = _object_axis()
    placement.translation = np.array([0.0, values["object_height"], 0.0])
    for name in (OBJECT_JOINT, OBJECT_FRAME):
        if model.existFrame(name):
            raise ParameterError(f"{NAME}: the arm's URDF has a link or joint {name!r}, a name "
                                 "of the object's axis")
    obj = model.addJoint(0, pin.JointModelPX(), placement, OBJECT_JOINT, *limits)
    model.addBodyFrame(OBJECT_FRAME, obj, pin.SE3.Identity(), model.addJointFrame(obj))
    model.inertias[obj] = pin.Inertia(values["object_mass"], np.zeros(3), np.eye(3) * 1e-3)
    return model, chain.tip


class MovingObjectPlant(ConstrainedPlant):
    """The closed chain of fig. 2.3: arm + prismatic object axis + contact constraint.
    State x = [q, q'] (joints 1, 2 and the object's axis)."""

    command_interface = "effort"

    def __init__(self, values: dict):
        if values["substeps"] < 1:
            raise ParameterError("substeps must be >= 1")
        normal = np.asarray(values["constraint_normal"], dtype=float)
        if not math.hypot(*normal) > 0.0 or normal[1] == 0.0:
            raise ParameterError("constraint_normal must be non-zero with a non-zero y component")
        self.model, self._tool = build_moving_object_model(values)
        self.data = self.model.createData()
        self.arm = SimpleNamespace(model=self.model, gravity=self.gravity)
        self.joint_names = tuple(self.model.names[1:])
        self.normal = normal / math.hypot(*normal)        # n_c (world = object frame, R_o = I)
        self.mech = planar_mechanism(self.model, values["tip_link"], OBJECT_FRAME,
                                     np.array([*self.normal, 0.0]), 0.0,
                                     values["baumgarte_alpha"], values["baumgarte_beta"])
        self.substeps = int(values["substeps"])
        self.max_contact_force = float(values["max_contact_force"])
        self._noise = (values["position_noise_std"], values["velocity_noise_std"],
                       values["force_noise_std"])
        self._noisy = any(self._noise)
        self._rng = np.random.default_rng(values["noise_seed"])
        self._work = np.empty(mechanism_work_size(self.mech))
        self._lam = np.zeros(1)
        self._phi = np.zeros(2)
        self._t = 0.0
        # initial state on the desired path, at rest, pressing with initial_force
        b = values["object_height"]
        x_o, x_co = values["initial_object_position"], values["initial_contact_position"]
        y_co = -self.normal[0] * x_co / self.normal[1]          # on the line n . r_co = 0
        try:
            arm_q = two_link_inverse_kinematics(values["link_length"], values["base_position"],
                                           (x_o + x_co, b + y_co), values["elbow_sign"])
        except ValueError as exc:
            raise ParameterError(f"initial state: {exc}") from exc
        q0 = np.array([*arm_q, x_o])
        self._effort = self.static_command(q0, values["initial_force"])
        self.reset_state(q0)

    # -- model queries (Pinocchio; not on the hot path) ----------------------------------
    def gravity(self, q: np.ndarray) -> np.ndarray:
        """G(q) of the three joints."""
        return pin.computeGeneralizedGravity(self.model, self.data, np.asarray(q, dtype=float))

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q) of the three joints (the arm's two and the object's axis), symmetric: what the
        brakes scale by."""
        M = pin.crba(self.model, self.data, np.asarray(q, dtype=float))
        return np.triu(M) + np.triu(M, 1).T

    def constraint_jacobian(self, q: np.ndarray) -> np.ndarray:
        """J_Phi(q) (3,): Phi' = J_Phi q'."""
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        J = pin.getFrameJacobian(self.model, self.data, self._tool, pin.LOCAL_WORLD_ALIGNED)[:2]
        out = self.normal @ J
        out[2] = -self.normal[0]
        return out

    def static_command(self, q: np.ndarray, force: float) -> np.ndarray:
        """tau holding the plant at rest at q with lambda = force: G(q) - J_Phi^T lambda."""
        return self.gravity(q) - self.constraint_jacobian(q) * force

    # -- state -----------------------------------------------------------------------------
    def reset_state(self, q0, v0=None) -> None:
        """Put the plant at q0 (at rest unless v0 is given), time unchanged; lambda and Phi
        are evaluated with the held effort."""
        self._x = np.concatenate([np.asarray(q0, dtype=float),
                                  np.zeros(3) if v0 is None else np.asarray(v0, dtype=float)])
        self._evaluate()

    def _evaluate(self) -> None:
        acc = np.empty(3)
        self._phi[:] = mechanism_dynamics_into(self.mech, self._x[:3], self._x[3:], self._effort,
                                               self._work, acc, self._lam)

    def sensors(self) -> list[float]:
        return [float(self._lam[0]), float(self._phi[0]), float(self._phi[1])]

    def contact_force_magnitude(self) -> float:
        """|lambda| (N), true."""
        return abs(float(self._lam[0]))

    def true_velocity(self) -> list[float]:
        """q' without the measurement noise."""
        return self._x[3:].tolist()

    def step(self, command: np.ndarray, dt: float) -> None:
        """Advance by dt with the efforts ``command`` held (a refused command keeps the last)."""
        if command.shape == (3,) and math.isfinite(command[0] + command[1] + command[2]):
            self._effort[:] = command
        self._phi[:] = mechanism_rk4(self.mech, self._x, self._effort, dt, self.substeps,
                                     self._work, self._lam)
        self._t += dt

    def measurement(self) -> Measurement:
        x = self._x
        q, v = x[:3].copy(), x[3:].copy()
        lam = self._lam[0]
        force = np.array([self.normal[0] * lam, self.normal[1] * lam, 0.0])
        if self._noisy:
            q_std, v_std, f_std = self._noise
            q += q_std * self._rng.standard_normal(3)
            v += v_std * self._rng.standard_normal(3)
            force[:2] += f_std * self._rng.standard_normal(2)
        return Measurement(self._t, q, v, self._effort.copy(), force)
