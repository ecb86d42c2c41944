"""Any task-space law on an arm that takes joint positions or velocities: the admittance outer
loop.

Most arms' drivers take no torque (ur_robot_driver's forward_position_controller and
forward_velocity_controller, franka_ros2's joint position interface, xarm_ros2, ros2_kortex):
a law written for torques cannot act on them directly. This loop gives every task-space law
(:class:`cr_control.schemes.impedance.base.TaskSpaceController`, chapters 3 and 5) such an arm
without a change to the law: the law computes its torque as on an effort arm, for a *virtual
arm*, and the virtual arm's motion becomes the command.

Each cycle (period T, the measured joints q_m, the measured wrench):

1. **The law** (its whole :meth:`step`: guards, wrist-sensor compensation, targets, adaptation)
   reads the virtual arm's state (q_v, q_v') and the measured wrench, and answers a torque tau
   (it runs as on a robot that compensates its own gravity and friction: the virtual arm has
   neither).
2. **The virtual arm** is the chain's own model (the URDF's masses and inertias, with the tool
   on the wrist sensor, unscaled whatever model the law is given; no gravity, no joint
   friction), driven by tau and the contact force the law measured, f (base frame, at the
   tip; the force the law reports, after its wrist-sensor compensation):

       M(q_v) q_v'' + C(q_v, q_v') q_v' = tau + J_v(q_v)^T f

   integrated with classical RK4, tau and f held (as an effort arm holds a command). Law and
   virtual arm run at ``virtual_rate_hz`` at least: a longer period T is split into k =
   ceil(T rate) equal steps, the law stepped at each (the measured wrench held), so that a
   law tuned for 1 kHz is not run at a driver's 500 or 150 Hz. T is the time since the last
   state, at most ``max_dt``, which is at least the driver's period (by default 2 periods
   where that is longer than 5 ms): the law's reference follows the stamps, so a virtual
   arm integrated over less than the period falls behind it every cycle (the xArm's 6.7 ms
   cut to 5 ms left the chapter 3 laws' circle 10 mm small).
   While the law holds the arm still for its start-up zeroing (the wrist sensor's bias still
   unknown), the virtual arm is held still too.
3. **The command**, anchored to the measured joints every cycle: the pose error between the
   virtual tip and the measured one, e = [r_v - r_m; log(R_v R_m^T)] (base frame; the
   orientation rows where the arm has joints for them beside its position task), mapped by
   damped least squares at q_m, plus the virtual arm's posture in the null space:

       q_c = q_m + J^+ e + (I - J^+ J)(q_v - q_m),   J^+ = J^T (J J^T + lambda^2 I)^-1

   (J the measured tip's Jacobian rows, lambda = ``ik_damping``). Nothing is integrated from
   joint increments, so nothing drifts: the commanded pose is the virtual arm's to first
   order, whatever the joints did. A velocity interface is sent
   q_c' = J^+ (J(q_v) q_v' + k_a e) + (I - J^+ J)(q_v' + k_a (q_v - q_m)), k_a =
   ``anchor_gain``: the virtual arm's velocity and the way back to it.
4. **Limits**: the command is held inside the joints' URDF position and velocity limits,
   ``command_acceleration_limit`` and ``command_jerk_limit`` (libfranka's rate limiter with a
   jerk limit, :mod:`cr_control.models.joint_rate_limit`), so the stream is smooth to the
   jerk whatever the law asks. Where a joint was clipped, the
   virtual arm is moved onto the command (the joint's position shifted by the clip, its
   velocity the command's): it never runs ahead of what the robot is sent. Where the virtual
   tip is more than ``max_lead`` from the measured one (a robot that stopped: its own safe
   stop, an obstacle the law does not feel), the virtual arm is drawn back towards the
   measured joints to that distance: a robot that resumes is not sent a far pose.

The brake on these interfaces (the law gave up, the node is deactivated) is a command that
decelerates to rest: from the last command's velocity v_0, every joint by one factor (the tool
stops on its path) along v_0 (1 - smoothstep(s / tau)), tau the shortest time in which no
joint's deceleration (1.5 |v_0| / tau) nor jerk (6 |v_0| / tau^2) exceeds its limits, then
held; the virtual arm follows it, so the law resumes from where the brake left the arm.

What the laws' quantities mean here: the law's arm is the virtual arm, so its estimates are
the virtual arm's. The chapter 3 laws' c_hat (3.8, 3.11-3.14) adapts the task acceleration to
what the virtual arm needs (exactly modelled: what remains is the servo's lag seen through the
measured force); the robust law's switching term answers the model error it is given
(``model_mass_scale``) against the exact virtual arm; the NN law learns the virtual arm's
dynamics (exact rigid-body terms, no gravity, no friction); the chapter 5 impedances are
imposed on the virtual arm, so their (m_m, d_m, k_m) are the admittance the real arm follows
through its servo. The contact force is the measured one: the real arm's contact acts on the
virtual arm through the force sensor, with the servo's and the driver's lag.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pinocchio as pin
from numba import njit

from cr_control.core.linalg import matmul, matvec, spd_inverse, tmatvec
from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.joint_rate_limit import (
    limiter_state,
    packed_limits,
    per_joint,
    rate_limit,
)
from cr_control.schemes.blocks.task_space import task_model
from cr_control.schemes.controller import Controller, ControlOutput, KernelOutput

#: The command interfaces a task-space law runs on: its own torques, or this loop.
INTERFACES = ("effort", "position", "velocity")
#: The law's robot side on the virtual arm: it has no gravity and no friction to compensate.
VIRTUAL_ROBOT_SIDE = {"robot_compensates_gravity": True, "robot_compensates_friction": True}
#: The law and the virtual arm run at least this often (Hz) by default: as the laws on the
#: Panda's 1 kHz effort interface.
VIRTUAL_RATE_HZ = 1000.0
#: Deceleration (rad/s^2) of a brake on joints without an acceleration limit.
BRAKE_DECELERATION = 5.0

COMMAND_INTERFACE = Param(
    "command_interface", "effort", "What the robot takes: effort (the law's torques), position "
    "or velocity (the law drives a virtual arm whose motion is sent as joint positions or "
    "velocities: the admittance outer loop, for forward_position_controller / "
    "forward_velocity_controller drivers).", "choice", read_only=True, choices=INTERFACES)

PARAMETERS = [
    Param("ik_damping", 0.01, "Damped least squares from the virtual tip's pose to the joints: "
          "lambda in J^T (J J^T + lambda^2 I)^-1 (m, and rad for the orientation rows); it "
          "limits the joint step near singularities.", "positive", bound=1.0),
    Param("command_acceleration_limit", [5.0], "Joint acceleration limits of the command "
          "stream (rad/s^2 or m/s^2): one value or one per joint. 5: ur_description's "
          "placeholder (UR publishes none); the robot profiles set their robot's.",
          "positive_vector", read_only=True, bound=1e4),
    Param("command_jerk_limit", [], "Joint jerk limits of the command stream (rad/s^3): one "
          "value or one per joint; empty: none (libfranka rejects a stream whose jerk exceeds "
          "the Panda's: set them there).", "positive_vector", read_only=True, bound=1e6),
    Param("virtual_rate_hz", VIRTUAL_RATE_HZ, "The law and the virtual arm run at least this "
          "often (Hz): a longer control period (the UR's 2 ms, the xArm's 6.7 ms) is split into "
          "equal steps, the measured wrench held over them, so the law's gains meet the period "
          "they were tuned for, not the driver's. 1000: at 500 the chapter 3 laws' force "
          "admittance set 10x (damping 1500 N s/m over 1 kg) left the explicit step's "
          "stability (d T / m = 3 > 2) and pressed 33 N.", "positive", read_only=True,
          bound=1e4),
    Param("max_lead", 0.02, "Farthest the virtual tip may lead the measured one (m, and rad "
          "for the orientation): beyond it the virtual arm is drawn back towards the measured "
          "joints.", "positive", bound=Bound.LENGTH),
    Param("anchor_gain", 10.0, "Velocity interface: the rate (1/s) at which the command "
          "brings the measured joints back to the virtual arm's.", "positive",
          bound=Bound.BANDWIDTH),
]

#: Status fields of the loop, after the law's: the command per joint (command order), the
#: virtual tip's lead on the measured one (m) and the joints clipped this cycle.
def status_fields(n: int) -> list[str]:
    """The loop's own status fields for ``n`` joints."""
    return [f"q_c_{i + 1}" for i in range(n)] + ["virtual_lead", "command_clipped"]


def law_settings(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` as the law on the virtual arm sees them: its period the split period
    (``control_period`` / k, ``virtual_rate_hz``) and no transport delay (the virtual arm has
    none), where the interface is position or velocity and a period is declared; the gains'
    discrete-time bounds follow from these, not from the driver's."""
    if values.get("command_interface", "effort") not in INTERFACES[1:] or \
            "control_period" not in values:
        return values
    rate = float(values.get("virtual_rate_hz", VIRTUAL_RATE_HZ))
    period = float(values["control_period"])
    split = max(1, math.ceil(period * rate - 1e-9))
    return {**values, "control_period": period / split, "command_delay_cycles": 0}


def parameters(given: dict[str, Any] | None) -> list[Param]:
    """``command_interface``, and this loop's parameters where it is position or velocity."""
    interface = (given or {}).get("command_interface", "effort")
    return [COMMAND_INTERFACE] + (PARAMETERS if interface in INTERFACES[1:] else [])


# -- compiled: the same numbers in a node and in the offline loop (numpy's BLAS may round the
# last bit differently with the arrays' alignment, and the contact loop amplifies it) ---------
@njit(cache=True, error_model="numpy")
def external_torque(J, f, tau):
    """tau + J_v^T f (J the 6 x n tip Jacobian, linear rows first)."""
    return tau + tmatvec(J[:3].copy(), f)


@njit(cache=True, error_model="numpy")
def dls_command(J, rows, lam2, e, q_m, q_v, v_v, Jv, anchor, velocity):
    """The command before the limits (module docstring, 3.): q_m + J^+ e + N (q_v - q_m), or
    J^+ (J_v(q_v) q_v' + k_a e) + N (q_v' + k_a (q_v - q_m)) on a velocity interface; J^+ =
    J^T (J J^T + lambda^2 I)^-1 over the task rows, N = I - J^+ J."""
    k, n = rows.shape[0], q_m.shape[0]
    Jr = np.empty((k, n))
    er = np.empty(k)
    for i in range(k):
        Jr[i] = J[rows[i]]
        er[i] = e[rows[i]]
    A = matmul(Jr, Jr.T.copy())
    for i in range(k):
        A[i, i] += lam2
    pinv = matmul(Jr.T.copy(), spd_inverse(A))
    null = -matmul(pinv, Jr)
    for i in range(n):
        null[i, i] += 1.0
    if velocity:
        task = np.empty(k)
        twist = matvec(Jv, v_v)
        for i in range(k):
            task[i] = twist[i] + anchor * er[i]
        return matvec(pinv, task) + matvec(null, v_v + anchor * (q_v - q_m))
    return q_m + matvec(pinv, er) + matvec(null, q_v - q_m)


class AdmittanceOuterLoop(Controller):
    """The task-space law ``law_class`` on a position or velocity interface (module
    docstring); ``law`` is the law's own controller, driving the virtual arm."""

    TASK_SPACE = True

    def __init__(self, law_class: type[Controller], values: dict[str, Any]):
        interface = values["command_interface"]
        if interface not in INTERFACES[1:]:
            raise ParameterError(f"the admittance outer loop drives a position or velocity "
                                 f"interface, not {interface!r}")
        own = {p.name for p in PARAMETERS}
        law_values = {k: v for k, v in law_settings(values).items() if k not in own}
        law_values.update(VIRTUAL_ROBOT_SIDE, command_interface="effort")
        self.law = law_class(law_values)
        law = self.law
        self.scheme = law.scheme
        self.command_interface = interface
        self._velocity = interface == "velocity"
        self.reference_fields = law.reference_fields
        self.command_status_fields = status_fields(law.n_joints)[:law.n_joints]
        super().__init__({**values, "joint_names": law.values["joint_names"]})
        self._virtual_model(values)
        self.command_limits = np.full(self.n_joints, np.inf)
        self._output = KernelOutput(self)
        self.internal = np.zeros(5 * self.n_joints)      # [q_v, q_v', limiter p, v, a]
        self._fresh = True
        self._period = float(values["max_dt"])
        self._stop_profile: list[Any] | None = None
        self._law_status = law.status_fields
        axes = law.model.position_axes
        self._force_at = [law.status_fields.index(f"f_{a}") - 1 for a in axes]
        self._force_rows = ["xyz".index(a) for a in axes]
        self._extras_at = len(law.status_fields) - 1
        self.pack_gains()
        # the law's lines go where this controller's go (the node sets those after start)
        law.log_warning = lambda message: self.log_warning(message)
        law.log_error = lambda message: self.log_error(message)
        law.log_info = lambda message: self.log_info(message)

    # -- construction ---------------------------------------------------------------------
    def _virtual_model(self, values: dict[str, Any]) -> None:
        """The virtual arm's model: the chain with the tool, no gravity, unscaled; the rows of
        the pose error; the command's limits."""
        law = self.law
        exact = {**law.values, "model_mass_scale": 1.0, "model_inertia_scale": 1.0,
                 **VIRTUAL_ROBOT_SIDE}
        chain_model = task_model(exact).chain_model
        self.chain_model = chain_model
        self._pin, self._data = chain_model.model, chain_model.model.createData()
        self._measured_data = chain_model.model.createData()
        self._tip = chain_model.tip
        task = law.model.task
        m, m_o, n = int(task[1]), int(task[2]), chain_model.n
        rows = [int(r) for r in task[3:3 + m]]
        if n >= m + m_o:
            rows += [3 + int(r) for r in task[6:6 + m_o]]
        self._rows = np.array(rows, dtype=np.int64)
        self._no_jacobian = np.zeros((len(rows), n))
        self._order = law.command_order.astype(int)     # command index -> chain index
        lim = chain_model.limits
        try:
            acceleration = per_joint(values["command_acceleration_limit"], n,
                                     "command_acceleration_limit")
            jerk = per_joint(values["command_jerk_limit"], n, "command_jerk_limit")
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self._limits = packed_limits(lim.lower, lim.upper, lim.velocity, acceleration, jerk)
        self._deceleration = np.where(np.isfinite(acceleration), acceleration,
                                      BRAKE_DECELERATION)

    # -- what the node and the loop ask ----------------------------------------------------
    def read_joint_names(self) -> list[str]:
        return list(self.law.state_joint_names)

    def status_field_names(self) -> list[str]:
        return list(self.law.status_fields) + status_fields(self.law.n_joints)

    def pack_gains(self) -> None:
        self._ik_damping = float(self.values["ik_damping"])
        self._max_lead = float(self.values["max_lead"])
        self._anchor = float(self.values["anchor_gain"])
        self._virtual_rate = float(self.values["virtual_rate_hz"])

    def check_parameter(self, name: str, value: Any) -> str | None:
        """The law's check where the law has the parameter, and the loop's own (``max_dt``
        beside the driver's period: the law sees the split one)."""
        why = None
        if name in self.law.values and name not in VIRTUAL_ROBOT_SIDE:
            why = self.law.check_parameter(name, value)
        return why or super().check_parameter(name, value)

    def set_parameter(self, name: str, value: Any) -> None:
        if name in self.law.values and name not in VIRTUAL_ROBOT_SIDE:
            self.law.set_parameter(name, value)
        super().set_parameter(name, value)

    # the task-space API of the node: the law's
    def set_target_pose(self, position: np.ndarray, quaternion: np.ndarray) -> bool:
        return self.law.set_target_pose(position, quaternion)

    def set_target_wrench(self, force: np.ndarray) -> bool:
        return self.law.set_target_wrench(force)

    def zero_ft(self, force: bool = False) -> tuple[bool, str]:
        return self.law.zero_ft(force)

    def zero_ft_refused(self, message: str) -> tuple[bool, str]:
        return self.law.zero_ft_refused(message)

    @property
    def reads_wrench(self) -> bool:
        return self.law.reads_wrench

    def __getattr__(self, name: str) -> Any:
        """What the loop does not say itself is its law's (wrist, targets, reach, ...)."""
        if name == "law" or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.law, name)

    # -- lifecycle -------------------------------------------------------------------------
    def warm_up(self) -> None:
        """The law's warm-up, and one cycle of this loop's numerics on a throw-away state."""
        self.law.warm_up()
        n = self.n_state
        q = np.clip(np.full(n, 0.3), self.chain_model.limits.lower, self.chain_model.limits.upper)
        saved = self.internal.copy()
        self.internal[:] = np.concatenate([q, np.zeros(n), limiter_state(q)])
        self._virtual_step(np.zeros(n), np.zeros(3), 1e-3)
        self._command(q, 1e-3, np.zeros(n))
        self.internal[:] = saved

    def reset(self, keep_time: bool) -> None:
        super().reset(keep_time)
        self.law.reset(keep_time)
        self._fresh = True
        self._stop_profile = None

    def observe(self, stamp: float) -> None:
        super().observe(stamp)
        self.law.observe(stamp)

    def step(self, stamp: float, q: np.ndarray, v: np.ndarray, force: np.ndarray) -> ControlOutput:
        out = super().step(stamp, q, v, force)
        if self.commanding:
            self._stop_profile = None
        return out

    # -- the cycle ---------------------------------------------------------------------------
    def compute(self, t, dt, q, v, force) -> ControlOutput:
        n = self.n_state
        x = self.internal
        if self._fresh:               # the virtual arm starts where the robot is
            x[:n], x[n:2 * n] = q, v
            x[2 * n:] = limiter_state(q, v)
            self._fresh = False
        if dt > 0.0:
            self._period = dt
        k = max(1, math.ceil(dt * self._virtual_rate - 1e-9))
        h = dt / k
        tau = np.empty(n)
        f = np.zeros(3)
        wrist = getattr(self.law, "wrist", None)
        for i in range(k):
            stamp = t if i == k - 1 else t - (k - 1 - i) * h      # the state's own stamp last
            law = self.law.step(stamp, x[:n].copy(), x[n:2 * n].copy(), force)
            tau[self._order] = law.command
            f[self._force_rows] = law.status[self._force_at]
            holding = wrist is not None and wrist.active and wrist.holding
            if h > 0.0 and not holding:
                self._virtual_step(tau, f, h)
        command, lead, clipped = self._command(q, dt, v)
        out = self._output.new()
        views = self._output.views(out)
        views.command[:] = command[self._order]
        views.reference[:] = law.reference
        k = self._extras_at
        views.status[:k] = law.status
        views.status[k:k + self.n_joints] = views.command
        views.status[k + self.n_joints] = lead
        views.status[k + self.n_joints + 1] = clipped
        return views

    def _virtual_step(self, tau: np.ndarray, f: np.ndarray, dt: float) -> None:
        """RK4 over dt of M q'' + C q' = tau + J_v^T f, tau and f held (module docstring)."""
        n = self.n_state
        x = self.internal
        q0, v0 = x[:n].copy(), x[n:2 * n].copy()

        def acceleration(q, v):
            qp = self.chain_model.configuration(q)
            J = pin.computeFrameJacobian(self._pin, self._data, qp, self._tip,
                                         pin.LOCAL_WORLD_ALIGNED)
            return pin.aba(self._pin, self._data, qp, v, external_torque(J, f, tau))

        k1v, k1a = v0, acceleration(q0, v0)
        k2v = v0 + 0.5 * dt * k1a
        k2a = acceleration(q0 + 0.5 * dt * k1v, k2v)
        k3v = v0 + 0.5 * dt * k2a
        k3a = acceleration(q0 + 0.5 * dt * k2v, k3v)
        k4v = v0 + dt * k3a
        k4a = acceleration(q0 + dt * k3v, k4v)
        x[:n] = q0 + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        x[n:2 * n] = v0 + dt / 6.0 * (k1a + 2.0 * k2a + 2.0 * k3a + k4a)

    def _pose(self, data: pin.Data, q: np.ndarray) -> pin.SE3:
        pin.framesForwardKinematics(self._pin, data, self.chain_model.configuration(q))
        return data.oMf[self._tip]

    def _command(self, q_m: np.ndarray, dt: float, v_m: np.ndarray) -> tuple[np.ndarray, float, int]:
        """The command (chain order) from the virtual arm, anchored to the measured joints q_m,
        inside the limits; the virtual tip's lead (m) and the joints clipped (module
        docstring, 3. and 4.)."""
        n = self.n_state
        x = self.internal
        q_v, v_v = x[:n], x[n:2 * n]
        e, J = self._pose_error(q_m, q_v)
        lead = math.sqrt(sum(x * x for x in e.tolist()))
        if lead > self._max_lead:            # draw the virtual arm back towards the robot
            scale = self._max_lead / lead
            q_v[:] = q_m + scale * (q_v - q_m)
            v_v *= scale
            e, J = self._pose_error(q_m, q_v)
        if self._velocity:
            qp_v = self.chain_model.configuration(q_v)
            Jv = np.array(pin.computeFrameJacobian(self._pin, self._data, qp_v, self._tip,
                                                   pin.LOCAL_WORLD_ALIGNED))[self._rows]
        else:
            Jv = self._no_jacobian
        wanted = dls_command(J, self._rows, self._ik_damping ** 2, e, np.asarray(q_m, dtype=float),
                             q_v.copy(), v_v.copy(), Jv, self._anchor, self._velocity)
        if dt <= 0.0 or not self.commanding:   # the first state (nothing to rate-limit), or
            # braking: the brake's command replaces this one and steps the limiter itself
            return (np.zeros(n) if self._velocity else q_m.copy()), lead, 0
        limiter = x[2 * n:]
        if self._velocity:
            limiter[:n] = q_m                # position limits: from where the joints are
        out = np.empty(n)
        clipped = rate_limit(limiter, self._limits, wanted, self._velocity, dt, out)
        if clipped:
            moved = np.abs(out - wanted) > 1e-9
            if not self._velocity:
                q_v[moved] += (out - wanted)[moved]
            v_v[moved] = limiter[n:2 * n][moved]
        return out, lead, clipped

    def _pose_error(self, q_m: np.ndarray, q_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """e = [r_v - r_m; log(R_v R_m^T)] (6, base frame) and the measured tip's Jacobian
        (6 x n, LOCAL_WORLD_ALIGNED)."""
        virtual = self._pose(self._data, q_v)
        r_v, R_v = virtual.translation.copy(), virtual.rotation.copy()
        qp = self.chain_model.configuration(q_m)
        J = pin.computeFrameJacobian(self._pin, self._measured_data, qp, self._tip,
                                     pin.LOCAL_WORLD_ALIGNED)
        measured = self._measured_data.oMf[self._tip]
        e = np.concatenate([r_v - measured.translation,
                            pin.log3(matmul(R_v, measured.rotation.T.copy()))])
        return e, np.array(J)

    def tip_positions(self, positions: np.ndarray) -> np.ndarray:
        """The measured tip's positions (k x 3, base frame) for joint positions (k x n, chain
        order): the robot's path, where the status's r is the virtual arm's."""
        data = self._pin.createData()
        out = np.empty((len(positions), 3))
        for i, q in enumerate(np.asarray(positions, dtype=float)):
            out[i] = self._pose(data, q).translation
        return out

    # -- the brake ----------------------------------------------------------------------------
    @property
    def brakes(self) -> bool:
        return True

    def brake_command(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The next command of a stop: from the last command's position and velocity, every
        joint by one factor at the command's deceleration, then held (module docstring);
        the virtual arm follows it. In command order."""
        n, T = self.n_state, self._period
        x = self.internal
        limiter = x[2 * n:]
        if self._fresh:                      # nothing sent yet: hold the measured joints
            x[:n], x[n:2 * n] = q, 0.0
            limiter[:] = limiter_state(q)
            self._fresh = False
        if self._stop_profile is None:
            p0, v0 = limiter[:n].copy(), limiter[n:2 * n].copy()
            speed = np.abs(v0)
            jerk = self._limits[4 * n:]
            duration = float(max(np.max(1.5 * speed / self._deceleration, initial=0.0),
                                 np.max(np.sqrt(6.0 * speed / jerk), initial=0.0)))
            self._stop_profile = [p0, v0, duration, 0.0]
        p0, v0, duration, s = self._stop_profile
        s = min(s + T, duration)
        self._stop_profile[3] = s
        x_s = s / duration if duration > 0.0 else 1.0
        wanted = v0 * (1.0 - x_s * x_s * (3.0 - 2.0 * x_s))     # smoothstep: jerk bounded
        # the velocity profile through the limiter (a position stream integrates it: a
        # jerk-limited stream asked to stop at a fixed position would ring about it)
        out = np.empty(n)
        rate_limit(limiter, self._limits, wanted, True, T, out)
        x[:n], x[n:2 * n] = limiter[:n], limiter[n:2 * n]      # the virtual arm follows
        command = out if self._velocity else limiter[:n].copy()
        if math.isfinite(command.sum()):
            return command[self._order]
        return (np.zeros(n) if self._velocity else q.copy())[self._order]
