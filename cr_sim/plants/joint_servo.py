"""Any URDF arm behind its joint position or velocity servos, pressing a compliant surface:
the arm of a robot whose driver takes joint positions or velocities, not torques.

Most arms' ROS 2 drivers take joint positions or velocities through a
forward_command_controller: ur_robot_driver's ``forward_position_controller`` and
``forward_velocity_controller`` (servoj / speedj over RTDE at 500 Hz), franka_ros2's joint
position interface (libfranka at 1 kHz), xarm_ros2's ``UFRobotSystemHardware`` (the xArm in
servo mode, ``set_servo_angle_j``, or in joint velocity mode, ``vc_set_joint_velocity``, at its
controller_manager's 150 Hz). The robot's own controller then turns the stream into torques.
This plant is that controller in front of the URDF plant (:class:`URDFSurface`, by
composition: its chain, contact, table friction, wrench sources, noise, reflex quantities and
substeps are the arm's): the same arm, the same table, only the command differs.

The robot's controller, per control period T (the plant node's, the profile's rate)
------------------------------------------------------------------------------------------
1. **Limits** (``command_interface`` position or velocity): the command is held inside the
   joints' limits as the real controller holds it (:mod:`cr_control.models.joint_rate_limit`):
   the URDF's position and velocity limits, ``acceleration_limit`` and, where given,
   ``jerk_limit`` (libfranka's rate limiter on the Panda; without a jerk limit the saturation
   of ros2_control's joint_limits package). A command outside them is clipped, never
   integrated into a jump; a non-finite one is refused and the last one kept.
2. **Reference**: the limited command as a segment over the period: position interface, from
   the last limited position to the new one at constant speed (velocity feed-forward = its
   slope); velocity interface, the limited velocity integrated from the reference's position
   (a velocity servo holds the position it integrates: pressed against a table it pushes
   harder while commanded into it, as a real one does).
3. **Servo** (the joint controllers, ``servo_substeps`` per period, at least one per
   millisecond and with omega_s h <= 0.1): inverse dynamics and a PD on the reference,

       tau = M(q) (omega_s^2 (q_r - q) + 2 zeta_s omega_s (q_r' - q')) + C(q, q') q' + G(q)
             + D q' + F tanh(q'/eps_q)

   clipped to the URDF's ``<limit effort>``: without contact each joint follows its
   reference as (2 zeta_s omega_s s + omega_s^2) / (s^2 + 2 zeta_s omega_s s + omega_s^2)
   (a PD on the reference's position and velocity; bandwidth ``servo_bandwidth``, damping
   ratio ``servo_damping``; a ramp is followed without lag; M(q) includes the joints'
   reflected rotor inertia, ``joint_armature``, which the arm's dynamics carry too); the
   URDF's joint damping D and
   friction F are compensated; a contact force f deflects the tip by about
   Lambda(q)^-1 f / omega_s^2 (Lambda the tip's apparent mass): the servo's stiffness.

The driver's transport delay (a command acting one or more periods after the state it
answers) is the plant node's (``command_delay_cycles``), in front of all this.

Servo figures (the profiles, :mod:`cr_control.robots`): UR publishes no servo bandwidth;
ur_robot_driver's servoj runs with ``servoj_gain`` 2000 and ``servoj_lookahead_time`` 0.03 s
(its defaults), read here as a PD on the target with the lookahead as derivative time:
omega_s = sqrt(2000) = 44.7 rad/s, zeta_s = 0.03 sqrt(2000) / 2 = 0.67 (our reading of two
documented parameters, not UR's statement). Franka's joint position interface runs its
joint impedance controller (libfranka's default stiffness 3000 N m/rad on the shoulder,
whose inertia is ~2 kg m^2 at the ready pose): omega_s ~ 40 rad/s. UFactory publishes none:
40 rad/s is assumed.

Safe stop
---------
What a driver does when the stream stops (a UR protective stop, stop category 2): the
reference decelerates from its velocity, every joint by one factor so that the tool stops on
its path, at the joints' acceleration limits (``stop_deceleration`` where none is given),
and then holds the position where it came to rest, which the servo holds. The brake's
command (:meth:`JointServoSurface.safe_stop_command`) is that reference; a position held
against a table keeps pressing what it pressed.

State
-----
The arm's [q, q'] (:attr:`state`) and the limiter's [p, v, a] (the reference); the held
command; the measured effort is the servo's torque.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pinocchio as pin

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.joint_rate_limit import (
    limiter_state,
    packed_limits,
    per_joint,
    rate_limit,
)
from cr_control.models.urdf import JOINT_FRICTION_EPSILON
from cr_sim.plants import urdf_surface
from cr_sim.plants.base import JointLimits, Measurement, Plant

NAME = "joint_servo"
#: The command interfaces this plant offers (a forward_command_controller's).
INTERFACES = ("position", "velocity")
#: The URDF plant's parameters that do not apply here: the servo compensates gravity and
#: joint friction itself (it is the robot's controller).
ROBOT_SIDE = ("robot_compensates_gravity", "robot_compensates_friction")
#: The servo is evaluated at least this often (s): real joint controllers run at kHz.
SERVO_PERIOD_MAX = 1e-3
#: ... and with omega_s h at most this.
SERVO_STEP_LIMIT = 0.1
#: Deceleration of the safe stop (rad/s^2) for joints without an acceleration limit: the
#: placeholder of ur_description's joint_limits.yaml ("acceleration limits are not publicly
#: available": max_acceleration 5.0).
DEFAULT_STOP_DECELERATION = 5.0

#: Defaults that differ from the URDF plant's: the thesis's two-link arm (in this package's
#: config directory, vertical plane), so that the scenario runs without a robot named.
DEFAULTS = {"urdf_file": ("two_link_arm.urdf", "the thesis's two-link arm"),
            "gravity": ([0.0, -9.8, 0.0], "the thesis's arm moves in a vertical plane")}


def _default(p: Param) -> Param:
    if p.name not in DEFAULTS:
        return p
    value, why = DEFAULTS[p.name]
    return replace(p, default=value, description=f"{p.description} Default: {why}.")


PARAMETERS = [_default(p) for p in urdf_surface.PARAMETERS if p.name not in ROBOT_SIDE] + [
    Param("command_interface", "position", "What the robot takes: joint positions "
          "(forward_position_controller) or joint velocities (forward_velocity_controller), "
          "in /joint_commands' position or velocity field.", "choice", read_only=True,
          choices=INTERFACES),
    Param("servo_bandwidth", 44.7, "Bandwidth omega_s of the joint servos (rad/s): each joint "
          "follows its reference as (2 zeta_s omega_s s + omega_s^2)/(s^2 + 2 zeta_s omega_s "
          "s + omega_s^2). "
          "44.7 = sqrt(2000): ur_robot_driver's servoj_gain read as a stiffness.", "positive",
          read_only=True, bound=Bound.BANDWIDTH),
    Param("servo_damping", 0.67, "Damping ratio zeta_s of the joint servos. 0.67: "
          "ur_robot_driver's servoj_lookahead_time 0.03 s read as a derivative time.",
          "positive", read_only=True, bound=Bound.SCALE),
    Param("servo_substeps", 0, "Servo evaluations per control period; 0 = automatic: at "
          "least one per millisecond and omega_s h <= 0.1.", "integer", read_only=True,
          bound=Bound.SUBSTEPS),
    Param("acceleration_limit", [], "Joint acceleration limits (rad/s^2 or m/s^2): one value "
          "for every joint or one per joint; empty: none (the URDF has no such tag).",
          "nonnegative_vector", read_only=True, bound=1e4),
    Param("jerk_limit", [], "Joint jerk limits (rad/s^3): one value or one per joint; empty: "
          "none. Given (with acceleration limits), the commands are limited as libfranka's "
          "rate limiter limits them.", "nonnegative_vector", read_only=True, bound=1e6),
    Param("joint_armature", [], "Reflected rotor inertia of each joint (kg m^2, added to "
          "the joint's own inertia: pinocchio's armature): one value or one per joint; "
          "empty: none. A geared joint's rotor is heavy seen through its gear: MuJoCo "
          "Menagerie's UR5e model sets 0.1 on every joint. It stiffens the servos of the "
          "light wrist joints (their stiffness is their inertia times omega_s^2).",
          "nonnegative_vector", read_only=True, bound=Bound.INERTIA),
    Param("stop_deceleration", DEFAULT_STOP_DECELERATION, "Safe stop: the deceleration (rad/s^2) "
          "of joints without an acceleration limit.", "positive", read_only=True, bound=1e4),
]

#: The parameters the arm (:class:`URDFSurface`) takes.
_ARM_PARAMETERS = tuple(p.name for p in urdf_surface.PARAMETERS)


def _limit(values: dict, name: str, n: int) -> np.ndarray:
    try:
        limit = per_joint(values[name], n, name)
    except ValueError as exc:
        raise ParameterError(str(exc)) from None
    limit[limit <= 0.0] = np.inf          # 0: none
    return limit


class JointServoSurface(Plant):
    """A URDF arm behind joint position or velocity servos, pressing a compliant plane or
    sphere (module docstring). ``arm`` is the URDF plant it drives."""

    command_interface = "position"

    def __init__(self, values: dict):
        arm_values = {k: v for k, v in values.items() if k in _ARM_PARAMETERS}
        arm_values.update(dict.fromkeys(ROBOT_SIDE, False))
        self.arm = urdf_surface.URDFSurface(arm_values)
        arm, n = self.arm, self.arm.chain.n
        self._n = n
        armature = _limit(values, "joint_armature", n)
        if np.any(np.isfinite(armature)):
            arm.model.armature = np.where(np.isfinite(armature), armature, 0.0)
            arm.step_rate = arm.stiffest_rate(arm.state[:n])     # the substep rule anew
        self.command_interface = values["command_interface"]
        self._velocity_interface = self.command_interface == "velocity"
        self.joint_names = arm.joint_names
        self.command_joint_names = arm.command_joint_names
        self.wrench_frame = arm.wrench_frame
        self.base_frame = arm.base_frame
        self.max_contact_force = arm.max_contact_force
        self.omega = float(values["servo_bandwidth"])
        self.zeta = float(values["servo_damping"])
        if values["servo_substeps"] < 0:
            raise ParameterError(f"servo_substeps must be >= 0, got {values['servo_substeps']}")
        self.servo_substeps = int(values["servo_substeps"])
        lim = arm.chain.limits
        self.acceleration = _limit(values, "acceleration_limit", n)
        self.jerk = _limit(values, "jerk_limit", n)
        if np.any(np.isfinite(self.jerk) & ~np.isfinite(self.acceleration)):
            raise ParameterError("jerk_limit needs acceleration_limit on the same joints")
        self.limits = packed_limits(lim.lower, lim.upper, lim.velocity, self.acceleration,
                                    self.jerk)
        self._effort = np.where(np.isfinite(lim.effort) & (lim.effort > 0), lim.effort, np.inf)
        self.stop_deceleration = np.where(np.isfinite(self.acceleration), self.acceleration,
                                          float(values["stop_deceleration"]))
        self._model, self._data = arm.model, arm.model.createData()
        q0 = arm.state[:n]
        #: The limiter's state [p, v, a]: the servo's reference at the end of the last period.
        self._limiter = limiter_state(q0)
        self._held = np.zeros(n) if self._velocity_interface else q0.copy()
        self._out = np.zeros(n)
        self._start = np.zeros(n)
        self.commands_clipped = 0
        self._stop: tuple[float, np.ndarray, np.ndarray, float] | None = None
        self._dt = 0.0
        self._x = arm._x                       # the arm's state [q, q'] (a view)
        self._t = arm.time

    # -- what the node and the loop ask ----------------------------------------------------
    @property
    def held(self) -> np.ndarray:
        """The command held now (the plant node starts with it: hold still)."""
        return self._held.copy()

    @property
    def reference(self) -> np.ndarray:
        """The servo's reference now: the limited command's position and velocity (2 n)."""
        return self._limiter[:2 * self._n].copy()

    def accept(self, command: np.ndarray) -> bool:
        return command.shape == (self._n,) and bool(np.all(np.isfinite(command)))

    def state_is_finite(self) -> bool:
        return math.isfinite(self._x.sum() + self._limiter.sum())

    def measurement(self) -> Measurement:
        return self.arm.measurement()

    def joint_limits(self) -> JointLimits:
        return self.arm.joint_limits()

    def acceleration_limits(self) -> np.ndarray:
        """The joints' acceleration limits (inf: none), in command order."""
        return self.acceleration.copy()

    def contact_force_magnitude(self) -> float:
        return self.arm.contact_force_magnitude()

    def true_velocity(self) -> list[float]:
        return self.arm.true_velocity()

    def __getattr__(self, name: str) -> Any:
        """What this plant does not say itself is the arm's (contact_force, contact_wrench,
        true_position, sensor_wrench, surface, chain, tip_position, ...)."""
        if name == "arm" or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.arm, name)

    # -- stepping ------------------------------------------------------------------------
    def substeps_for(self, dt: float) -> int:
        """Servo evaluations per period dt: ``servo_substeps``, or at least one per
        millisecond with omega_s h <= 0.1."""
        if self.servo_substeps > 0:
            return self.servo_substeps
        return max(1, math.ceil(dt / SERVO_PERIOD_MAX - 1e-9),
                   math.ceil(self.omega * dt / SERVO_STEP_LIMIT - 1e-9))

    def step(self, command: np.ndarray, dt: float) -> None:
        """One control period: the command limited (a refused one keeps the last), the
        reference segment, the servo on the arm (module docstring)."""
        command = np.asarray(command, dtype=float)
        if self.accept(command):
            self._held[:] = command
        n, state = self._n, self._limiter
        self._start[:] = state[:n]
        self.commands_clipped += rate_limit(state, self.limits, self._held,
                                            self._velocity_interface, dt, self._out) > 0
        speed = state[n:2 * n]
        k = self.substeps_for(dt)
        h = dt / k
        for i in range(k):
            self.arm.step(self.servo_torque(self._start + speed * (i * h), speed), h)
        self._t = self.arm.time
        self._dt = dt

    def servo_torque(self, q_r: np.ndarray, v_r: np.ndarray) -> np.ndarray:
        """The joint controllers' torque now for the reference (q_r, q_r') (module
        docstring, 3.), clipped to the URDF's effort limits."""
        n = self._n
        q, v = self._x[:n], self._x[n:]
        model, data = self._model, self._data
        w, z = self.omega, self.zeta
        # M(q) a + C(q, q') q' + G(q) in one recursive Newton-Euler pass
        tau = pin.rnea(model, data, self.arm.chain.configuration(q), v,
                       w * w * (q_r - q) + 2.0 * z * w * (v_r - v))
        chain = self.arm.chain
        tau += chain.damping * v + chain.friction * np.tanh(v / JOINT_FRICTION_EPSILON)
        return np.clip(tau, -self._effort, self._effort)

    # -- safe stop ------------------------------------------------------------------------
    def begin_safe_stop(self) -> None:
        """The reference decelerates from where it is, every joint by one factor, at the
        joints' deceleration, then holds (module docstring)."""
        n = self._n
        p, v = self._limiter[:n].copy(), self._limiter[n:2 * n].copy()
        duration = float(np.max(np.abs(v) / self.stop_deceleration, initial=0.0))
        self._stop = (self._t, p, v, duration)

    def _stop_reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The safe stop's reference (position, velocity) at plant time t."""
        t0, p, v, duration = self._stop
        s = min(max(t - t0, 0.0), duration)
        if duration <= 0.0:
            return p.copy(), np.zeros_like(v)
        return p + v * (s - s * s / (2.0 * duration)), v * (1.0 - s / duration)

    def safe_stop_command(self) -> np.ndarray:
        """The brake's command for the coming period: the stop's reference at its end
        (positions, or velocities on a velocity interface)."""
        if self._stop is None:
            self.begin_safe_stop()
        position, velocity = self._stop_reference(self._t + self._dt)
        return velocity if self._velocity_interface else position

    def contact_free_position(self) -> np.ndarray | None:
        return None

    def describe_safe_stop(self) -> str:
        if self._stop is None:
            return "the servo reference decelerating to rest, then held"
        _, _, v, duration = self._stop
        return (f"the servo reference decelerating from {np.round(v, 4).tolist()} to rest "
                f"within {duration:.3g} s (every joint by one factor, at most "
                f"{np.round(self.stop_deceleration, 3).tolist()} per s^2), then held where "
                "it stops")
