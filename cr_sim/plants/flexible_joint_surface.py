"""Chapter 6 plant: a 2-link flexible-joint arm whose end effector slides on a rigid surface
(thesis 6.1-6.5, section 6.3).

The links are the 2-link arm of chapter 3 (``config/two_link_arm.urdf`` through Pinocchio,
link length 0.3 m, centre of mass 0.15 m, m = 0.1 kg, I = 0.3 kg m^2, g = 9.8 along -y,
vertical plane; or any planar 2-link arm given by the robot parameters, ``link_*``
overriding its geometry and inertia, whose joints J then name the links and the motors
J_motor); each joint is an elastic transmission of stiffness K_s driven by a motor
of inertia J_m (the reduced model of Spong, [93]):

    M(q_l) q_l'' + C(q_l, q_l') q_l' + G(q_l) = K_s theta + J_Phi(q_l)^T lambda   (6.1, 6.5)
    J_m q_m'' + K_s theta = tau_m                                                  (6.2)
    theta = q_m - q_l                                                              (6.3)

with the holonomic frictionless constraint (6.4) of the end effector on the rigid line
x - y + 0.35 = 0 (docs/thesis.md: the printed x - y + 0.25 = 0 does not contain the desired
path). The thesis leaves the scaling of Phi (and so the unit of lambda) implicit; here

    Phi(q_l) = n . p_tool(q_l) + 0.35/sqrt(2),   n = (1, -1)/sqrt(2)

(generally n = n_raw/|n_raw| and offset/|n_raw| for ``surface_normal`` n_raw and
``surface_offset`` c, the surface n_raw . p + c = 0), so Phi is the signed distance (m) of
the end effector from the surface, J_Phi = n^T J_tool and lambda is the normal contact force
in newtons: the surface pushes the end effector with n lambda, lambda > 0 when the arm
presses on it (the base side is Phi > 0). The contact is bilateral as in the thesis
(lambda < 0 would pull). The links are integrated with Baumgarte's stabilisation

    J_Phi q_l'' + J_Phi' q_l' = -2 alpha Phi' - beta^2 Phi      (alpha = beta = 20 /s)

by the compiled kernels of :mod:`cr_sim.models.constrained_dynamics` (planar chain, the
plane fixed to the world; checked in the tests against Pinocchio's KKT solve), and the
motors alongside: one compiled call per control period does ``substeps`` classical RK4
steps over the 8-state x = [q_l, q_l', q_m, q_m'] with tau_m held (each stage: q_l'' and
lambda from the KKT solve with the joint torque K_s theta, q_m'' from (6.2)), then
evaluates lambda, Phi, Phi' and q_m'' at the new state with the held command. Nothing is
allocated per step. A command that is not two finite motor torques is ignored (the last
good one is held). One ``step`` costs about 10 us (1 RK4 step, 2 cores, numba); RK4 at
1 kHz with ``substeps`` = 1 keeps |Phi| below 1e-9 m even for the stiff case K_s = 300,
J_m = 1 of section 6.3.2 (the transmission modes are ~30 rad/s, h omega ~ 0.03).

Sensors (assumption 6.3: q_l, q_m, q_l', q_m', q_m'' and lambda measurable): joint states
of [joint1, joint2, joint1_motor, joint2_motor] (links, then motors), efforts [K_s theta
(the link-side torque a joint torque sensor would read), tau_m held], the contact force
n lambda in the world frame (wrench topic); ``sensors()`` gives lambda, Phi, Phi' and the
motor accelerations q_m'' (evaluated at the new state with the held command). Only the two
motor torques are commanded (``command_joint_names``).

Initial state (section 6.3, corrected as in docs/thesis.md): at rest, theta1(0) = 2.85 and theta2(0) solved
exactly onto the surface on the branch of the given theta2's sign (-2.1202: the printed
-1.77 lies on neither line), so Phi(0) = 0 to round-off; lambda(0) = 2 N; the motors at the
static equilibrium K_s (q_m0 - q_l0) = G(q_l0) - J_Phi^T lambda_0, and the held command
(``held``, what the plant node holds before the first command) is that static torque
tau_m0 = G(q_l0) - J_Phi^T lambda_0 = [0.00186, 0.70863] N m (G = [-0.31282, 0.10956],
J_Phi = [-0.15734, -0.29954] m), so with it the plant stays at rest pressing with 2 N;
q_l0 = [2.85, -2.120208], q_m0 = q_l0 + K_s^-1 tau_m0 = [2.850186, -2.049345] rad for
K_s = 10 (tool at (-0.06374, 0.28626) m).

The thesis gives no motor torque limit: ``motor_effort_limit`` (100 N m, far above the
static torques of < 1 N m; a parameter) bounds the commands in the plant node.

Joint names: the URDF's link joints J1, J2 (joint1, joint2 on the thesis's arm), the motors
J1_motor, J2_motor and their sensors J1_motor_acceleration, J2_motor_acceleration.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from numba import njit

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.brake import brake_torque
from cr_sim.models.constrained_dynamics import (
    mechanism_dynamics_into,
    mechanism_work_size,
    planar_mechanism,
)
from cr_sim.plants.arm_on_surface import (
    NOISE_PARAMETERS,
    arm_parameters,
    robot_parameters,
    thesis_chain,
)
from cr_sim.plants.base import (
    ConstrainedPlant,
    JointLimits,
    Measurement,
    max_contact_force_parameter,
    take_command,
)

NAME = "flexible_joint_surface"
#: The frame the plant adds at the origin of the base frame (= the model's world frame), to
#: which the surface is fixed (a trailing "_" added while the URDF has a frame of the name).
SURFACE_FRAME = "surface"


def motor_joints(link_joints) -> tuple[str, ...]:
    """Names of the motors behind the link joints ``link_joints``."""
    return tuple(f"{name}_motor" for name in link_joints)


def sensor_names(link_joints) -> tuple[str, ...]:
    """Values of ``sensors()`` with the link joints ``link_joints``."""
    return ("lambda", "phi", "phi_dot", *(f"{m}_acceleration" for m in motor_joints(link_joints)))


#: The joints and sensors with the thesis's arm.
LINK_JOINTS = ("joint1", "joint2")
MOTOR_JOINTS = motor_joints(LINK_JOINTS)
SENSORS = sensor_names(LINK_JOINTS)

PARAMETERS = [
    *robot_parameters("two_link_arm.urdf", "the 2-link arm of chapters 3 and 6 (0.3 m links)"),
    *arm_parameters(length=0.3, com=0.15),
    Param("joint_stiffness", [10.0, 10.0],
          "Joint stiffness K_s per joint (N m/rad) (6.1-6.3; 6.3.1 case 1: 10, case 2: 50; "
          "6.3.2: 300).", "positive_vector", 2, read_only=True, bound=Bound.STIFFNESS),
    Param("motor_inertia", [0.5, 0.5],
          "Motor inertia J_m per joint (kg m^2) (6.2; 6.3.1: 0.5, 6.3.2: 1.0).",
          "positive_vector", 2, read_only=True, bound=Bound.INERTIA),
    Param("surface_normal", [1.0, -1.0],
          "Normal n_raw of the rigid surface n_raw . p + offset = 0 (world; Phi uses it "
          "normalised, so lambda is the normal force in N and lambda > 0 presses).",
          "vector", 2, read_only=True, bound=Bound.SCALE),
    Param("surface_offset", 0.35,
          "Offset c of the rigid surface n_raw . p + c = 0 (m * |n_raw|) (docs/thesis.md: "
          "x - y + 0.35 = 0, not the printed 0.25).", read_only=True, bound=Bound.LENGTH),
    Param("baumgarte_alpha", 20.0, "Baumgarte damping alpha of the constraint error (1/s).",
          "nonnegative", read_only=True, bound=Bound.BANDWIDTH),
    Param("baumgarte_beta", 20.0, "Baumgarte stiffness beta of the constraint error (1/s).",
          "nonnegative", read_only=True, bound=Bound.BANDWIDTH),
    Param("initial_link_position", [2.85, -2.1202],
          "Link angles q_l at t = 0, at rest (rad): theta1 is kept, theta2 is solved onto the "
          "surface on the branch of its sign (docs/thesis.md: [2.85, -2.1202]; the printed -1.77 "
          "is off the surface).", "vector", 2, read_only=True, bound=Bound.JOINT),
    Param("initial_force", 2.0, "Contact force lambda at t = 0 (N): motors and held torque "
          "start at the static equilibrium G(q_l0) - J_Phi^T lambda_0 (6.3: 2 N).",
          read_only=True, bound=Bound.FORCE),
    Param("motor_effort_limit", 100.0, "Motor torque limit (N m) for the command limits (the "
          "thesis gives none).", "positive", read_only=True, bound=Bound.EFFORT),
    *NOISE_PARAMETERS,
    Param("substeps", 1, "RK4 substeps per control period.", "integer", read_only=True, bound=Bound.SUBSTEPS),
    max_contact_force_parameter(20.0, "|lambda| (either sign: the constraint is bilateral), "
                                "10 x the task's lambda(0) = lambda_d = 2 N (6.3; the thesis "
                                "runs peak at 3.3 N, robust adaptive, and 8.2 N, singular "
                                "perturbation)."),
]


@njit(cache=True, error_model="numpy")
def flexible_joint_derivative(mech, flex, x, tau_m, work, tau_l, out, lam):
    """out = x' of x = [q_l, q_l', q_m, q_m'] (4n) with motor torques ``tau_m``: q_l'' and
    lambda (into ``lam``) from the constrained link dynamics with the joint torque
    tau_l = K_s (q_m - q_l), q_m'' = J_m^-1 (tau_m - tau_l); flex = [k_s (n), j_m (n)].
    ``work``: mechanism_work_size(mech) floats, ``tau_l``: n. Returns (Phi, Phi')."""
    n = x.shape[0] // 4
    for j in range(n):
        tau_l[j] = flex[j] * (x[2 * n + j] - x[j])
        out[j] = x[n + j]
        out[2 * n + j] = x[3 * n + j]
        out[3 * n + j] = (tau_m[j] - tau_l[j]) / flex[n + j]
    return mechanism_dynamics_into(mech, x[:n], x[n:2 * n], tau_l, work, out[n:2 * n], lam)


def buffer_size(n: int) -> int:
    """Floats of the RK4 buffers of :func:`flexible_joint_step` (n links)."""
    return 5 * 4 * n + n + 1


@njit(cache=True, error_model="numpy")
def flexible_joint_step(mech, flex, x, tau_m, command, dt, substeps, work, buf, sensors):
    """Take ``command`` as the held motor torque ``tau_m`` if it has one finite value per
    motor (else keep the last), advance x = [q_l, q_l', q_m, q_m'] in place by ``dt``
    (``substeps`` classical RK4 steps, tau_m held) and write [lambda, Phi, Phi', q_m'']
    at the new state with the held command into ``sensors``. ``work``:
    mechanism_work_size(mech) floats, ``buf``: buffer_size(n). Returns whether the command
    was taken."""
    accepted = take_command(tau_m, command)
    m = x.shape[0]
    n = m // 4
    k1, k2, k3 = buf[:m], buf[m:2 * m], buf[2 * m:3 * m]
    k4, xs = buf[3 * m:4 * m], buf[4 * m:5 * m]
    tau_l = buf[5 * m:5 * m + n]
    lam = buf[5 * m + n:5 * m + n + 1]
    h = dt / substeps
    for _ in range(substeps):
        flexible_joint_derivative(mech, flex, x, tau_m, work, tau_l, k1, lam)
        for j in range(m):
            xs[j] = x[j] + 0.5 * h * k1[j]
        flexible_joint_derivative(mech, flex, xs, tau_m, work, tau_l, k2, lam)
        for j in range(m):
            xs[j] = x[j] + 0.5 * h * k2[j]
        flexible_joint_derivative(mech, flex, xs, tau_m, work, tau_l, k3, lam)
        for j in range(m):
            xs[j] = x[j] + h * k3[j]
        flexible_joint_derivative(mech, flex, xs, tau_m, work, tau_l, k4, lam)
        for j in range(m):
            x[j] = x[j] + (h / 6.0) * (k1[j] + k4[j] + 2.0 * (k2[j] + k3[j]))
    phi, phi_dot = flexible_joint_derivative(mech, flex, x, tau_m, work, tau_l, k1, lam)
    sensors[0] = lam[0]
    sensors[1] = phi
    sensors[2] = phi_dot
    for j in range(n):
        sensors[3 + j] = k1[3 * n + j]
    return accepted


def surface_angle(length, normal: np.ndarray, offset: float, theta1: float,
                  theta2: float) -> float:
    """theta2 putting the tool of the 2-link arm (base at the origin) with joint 1 at
    ``theta1`` on the line n . p + offset = 0 (n unit), on the branch of theta2's sign
    (closest to theta2 if both solutions are); ValueError if there is none."""
    d1, d2 = length
    # n . p = d1 n.(c1, s1) + d2 cos(theta1 + theta2 - psi),  psi = atan2(n_y, n_x)
    a = d1 * (normal[0] * math.cos(theta1) + normal[1] * math.sin(theta1)) + offset
    c = -a / d2
    if not -1.0 <= c <= 1.0:
        raise ValueError(f"theta1 = {theta1} puts no point of the tool on the surface")
    psi = math.atan2(normal[1], normal[0])
    sign = math.copysign(1.0, theta2)
    roots = []
    for s in (1.0, -1.0):
        t2 = math.remainder(psi + s * math.acos(c) - theta1, 2.0 * math.pi)
        if math.copysign(1.0, t2) == sign:
            roots.append(t2)
    if not roots:
        raise ValueError(f"theta1 = {theta1} puts no point of the tool on the surface with "
                         f"theta2 of the sign of {theta2}")
    return min(roots, key=lambda t2: abs(t2 - theta2))


class FlexibleJointSurface(ConstrainedPlant):
    """The constrained flexible-joint arm of chapter 6: links on a rigid surface, motors
    behind elastic joints; the commands are the two motor torques. State
    x = [q_l, q_l', q_m, q_m'] (8)."""

    command_interface = "effort"
    joint_names = (*LINK_JOINTS, *MOTOR_JOINTS)
    command_joint_names = MOTOR_JOINTS
    sensor_fields = SENSORS

    def __init__(self, values: dict):
        if values["substeps"] < 1:
            raise ParameterError("substeps must be >= 1")
        ks = np.asarray(values["joint_stiffness"], dtype=float)
        jm = np.asarray(values["motor_inertia"], dtype=float)
        if ks.shape != (2,) or not np.all(ks > 0.0) or not np.all(np.isfinite(ks)):
            raise ParameterError(f"joint_stiffness must be two positive numbers, got {list(ks)}")
        if jm.shape != (2,) or not np.all(jm > 0.0) or not np.all(np.isfinite(jm)):
            raise ParameterError(f"motor_inertia must be two positive numbers, got {list(jm)}")
        raw = np.asarray(values["surface_normal"], dtype=float)
        norm = math.hypot(*raw)
        if not (math.isfinite(norm) and norm > 0.0):
            raise ParameterError(f"surface_normal must be non-zero, got {list(raw)}")
        if not values["motor_effort_limit"] > 0.0:
            raise ParameterError("motor_effort_limit must be > 0")
        chain = thesis_chain(values, NAME)
        self.model = chain.model
        surface_frame = SURFACE_FRAME
        while self.model.existFrame(surface_frame):
            surface_frame += "_"
        self.model.addFrame(pin.Frame(surface_frame, 0, 0, pin.SE3.Identity(),
                                      pin.FrameType.OP_FRAME))
        self.data = self.model.createData()
        self._tool = chain.tip
        self.link_joint_names = chain.joint_names
        self.command_joint_names = motor_joints(chain.joint_names)
        self.joint_names = (*chain.joint_names, *self.command_joint_names)
        self.sensor_fields = sensor_names(chain.joint_names)
        self.normal = raw / norm                                  # n (unit, world)
        self.offset = float(values["surface_offset"]) / norm      # Phi = n . p + offset
        self.stiffness, self.motor_inertia = ks.copy(), jm.copy()
        self.effort_limit = float(values["motor_effort_limit"])
        # Phi = n . p_tool - offset_mech in constrained_dynamics' convention
        self.mech = planar_mechanism(self.model, values["tip_link"], surface_frame,
                                     np.array([*self.normal, 0.0]), -self.offset,
                                     values["baumgarte_alpha"], values["baumgarte_beta"])
        self.flex = np.concatenate([ks, jm])
        self.substeps = int(values["substeps"])
        self.max_contact_force = float(values["max_contact_force"])
        self._noise = (values["position_noise_std"], values["velocity_noise_std"],
                       values["force_noise_std"])
        self._noisy = any(self._noise)
        self._rng = np.random.default_rng(values["noise_seed"])
        self._work = np.empty(mechanism_work_size(self.mech))
        self._buf = np.empty(buffer_size(2))
        self._sensors = np.zeros(len(SENSORS))
        self._none = np.empty(0)
        self._t = 0.0
        # initial state: at rest on the surface, pressing with initial_force (static motors)
        theta1, theta2 = (float(v) for v in values["initial_link_position"])
        try:
            theta2 = surface_angle(values["link_length"], self.normal, self.offset, theta1, theta2)
        except ValueError as exc:
            raise ParameterError(f"initial_link_position: {exc}") from exc
        q_l0 = np.array([theta1, theta2])
        self._held = self.static_command(q_l0, float(values["initial_force"]))
        self.reset_state(np.concatenate([q_l0, q_l0 + self._held / ks]))

    # -- model queries (Pinocchio; not on the hot path) ----------------------------------
    def gravity(self, q_l: np.ndarray) -> np.ndarray:
        """G(q_l): gravity torque of the links."""
        return pin.computeGeneralizedGravity(self.model, self.data,
                                             np.asarray(q_l, dtype=float)[:2]).copy()

    def tool_position(self, q_l: np.ndarray) -> np.ndarray:
        """End-effector position p_tool(q_l) (2)."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q_l, dtype=float)[:2])
        return self.data.oMf[self._tool].translation[:2].copy()

    def constraint(self, q_l: np.ndarray) -> float:
        """Phi(q_l) = n . p_tool + offset (m)."""
        return float(self.normal @ self.tool_position(q_l) + self.offset)

    def constraint_jacobian(self, q_l: np.ndarray) -> np.ndarray:
        """J_Phi(q_l) = n^T J_tool (2,): Phi' = J_Phi q_l'."""
        J = pin.computeFrameJacobian(self.model, self.data, np.asarray(q_l, dtype=float)[:2],
                                     self._tool, pin.LOCAL_WORLD_ALIGNED)
        return self.normal @ J[:2]

    def static_command(self, q_l: np.ndarray, force: float) -> np.ndarray:
        """Motor torque holding the plant at rest at q_l with lambda = force:
        tau_m = K_s theta = G(q_l) - J_Phi^T lambda."""
        return self.gravity(q_l) - self.constraint_jacobian(q_l) * force

    # -- state -----------------------------------------------------------------------------
    def reset_state(self, q0, v0=None) -> None:
        """Put the plant at positions q0 = [q_l, q_m] (4; at rest unless velocities v0 =
        [q_l', q_m'] are given), time and held command unchanged; the sensors are evaluated
        with the held command."""
        q0 = np.asarray(q0, dtype=float)
        v0 = np.zeros(4) if v0 is None else np.asarray(v0, dtype=float)
        self._x = np.concatenate([q0[:2], v0[:2], q0[2:], v0[2:]])
        # a zero-length step: evaluates the sensors (and loads the compiled kernel)
        flexible_joint_step(self.mech, self.flex, self._x, self._held, self._none, 0.0, 1,
                            self._work, self._buf, self._sensors)

    @property
    def held(self) -> np.ndarray:
        """The motor torques tau_m held now."""
        return self._held.copy()

    def sensors(self) -> list[float]:
        return [float(v) for v in self._sensors]

    def contact_force_magnitude(self) -> float:
        """|lambda| (N), true."""
        return abs(float(self._sensors[0]))

    def true_velocity(self) -> list[float]:
        """[q_l', q_m'] (joint_names order) without the measurement noise."""
        x = self._x
        return [float(x[2]), float(x[3]), float(x[6]), float(x[7])]

    @property
    def motor_acceleration(self) -> np.ndarray:
        """q_m'' now, with the held command (6.2)."""
        return self._sensors[3:5].copy()

    def step(self, command: np.ndarray, dt: float) -> None:
        """Advance by dt with the motor torques ``command`` held (a refused command keeps the
        last)."""
        command = np.asarray(command, dtype=np.float64)
        if command.ndim != 1:
            command = self._none
        flexible_joint_step(self.mech, self.flex, self._x, self._held, command, dt,
                            self.substeps, self._work, self._buf, self._sensors)
        self._t += dt

    def measurement(self) -> Measurement:
        x = self._x
        q = np.array([x[0], x[1], x[4], x[5]])
        v = np.array([x[2], x[3], x[6], x[7]])
        effort = np.concatenate([self.stiffness * (q[2:] - q[:2]), self._held])
        lam = self._sensors[0]
        force = np.array([self.normal[0] * lam, self.normal[1] * lam, 0.0])
        if self._noisy:
            q_std, v_std, f_std = self._noise
            q += q_std * self._rng.standard_normal(4)
            v += v_std * self._rng.standard_normal(4)
            force[:2] += f_std * self._rng.standard_normal(2)
        return Measurement(self._t, q, v, effort, force)

    # -- limits and brakes -------------------------------------------------------------------
    def joint_limits(self) -> JointLimits:
        """The two motors: torque within ``motor_effort_limit``, nothing else limited."""
        limits = JointLimits.unlimited(2)
        limits.effort = np.full(2, self.effort_limit)
        return limits

    def velocity_limits(self) -> list[tuple[int, float]]:
        """The links' URDF velocity limits (the motors have none): the joint velocity reflex
        watches q_l'."""
        model = self.model
        out = []
        for i, name in enumerate(self.link_joint_names):
            limit = float(model.velocityLimit[model.joints[model.getJointId(name)].idx_v])
            if 0.0 < limit < math.inf:
                out.append((i, limit))
        return out

    def describe_safe_stop(self) -> str:
        w = self.brake_frequency
        return (f"motor brakes: spring torque compensated, motors braked at w_b = {w:g} rad/s, "
                f"scaled by their inertia (speeds falling as e^(-{w:g} t)), and held where they "
                "come to rest")

    def brake_inertia(self, q: np.ndarray) -> np.ndarray:
        """diag(J_m): the motors' inertias, which the motor brakes scale by."""
        return np.diag(self.motor_inertia)

    def begin_safe_stop(self) -> None:
        """Engage the motor brakes: remember where the motors come to rest, q_m + q_m'/w_b
        from the measured state (:meth:`~cr_sim.plants.base.Plant.brake_stop_position`)."""
        m = self.measurement()
        self._brake_hold = self.brake_stop_position(m.position[2:], m.velocity[2:])

    def safe_stop_command(self) -> np.ndarray:
        """Motor brakes, from the measured state: the spring torque compensated, the motors
        braked to rest (:func:`cr_control.models.brake.brake_torque` on J_m q_m'' = tau_m -
        K_s (q_m - q_l)) and held there,

            tau_m = K_s (q_m - q_l) - J_m (2 w_b q_m' + w_b^2 (q_m - q_m,stop)).
        """
        m = self.measurement()
        q_l, q_m, v_m = m.position[:2], m.position[2:], m.velocity[2:]
        hold = self._brake_hold if self._brake_hold is not None else self.brake_stop_position(q_m, v_m)
        return brake_torque(self.brake_inertia(q_m), self.stiffness * (q_m - q_l), q_m, v_m, hold,
                            self.brake_frequency)
