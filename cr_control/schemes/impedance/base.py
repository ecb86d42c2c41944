"""What the five impedance schemes share: one base, thin per-law subclasses (as FZI's
cartesian_controllers).

A :class:`TaskSpaceController` runs on any serial arm from its URDF
(:mod:`cr_control.schemes.blocks.task_space`): the robot parameters name the chain, the
task rows follow from it (the position axes the tip can move; the rotation axes it can turn
besides), and every m x m gain of the law is sized by it. Each cycle is one compiled call:
the common front (task frame, desired motion) -> the scheme's law -> the common back
(null-space orientation and posture, joint limit guard, effort clip, output vector).

Defaults. On the thesis's arm (the class's default ``urdf_file`` and no
``robot_description``) every parameter defaults to the thesis's value, so that case is
the thesis's run. On any other robot the laws keep the thesis's gains (m x m, the same
diagonal), the reference holds the start pose (``reference_relative`` with zero
amplitude) and the desired force is zero until a target arrives: a controller started on
an unknown robot holds still.

Targets: :meth:`TaskSpaceController.set_target_pose` and :meth:`set_target_wrench` (the
node's ``~/target_pose`` and ``~/target_wrench``) take effect from the next cycle
(:mod:`cr_control.schemes.blocks.references`). Targets the arm cannot or must not follow
are dealt with here, each with a reason logged at most once every 5 s (with a count):
a non-finite value or a zero quaternion is refused; the quaternion is normalised without
overflow (scaled by its largest element first: a quaternion of norm 1e200 is a rotation,
not zeros); a position farther from the first joint than TARGET_REACH_FRACTION (90 %) of
the chain's reach is moved onto that sphere along the same direction (:func:`chain_reach`:
the farthest the tip gets from the first joint, searched within the joint limits; along the
task's position axes; the full stretch is singular) and out of TARGET_AXIS_FRACTION (15 %)
of it from the first joint's axis (:func:`cr_control.models.reach.off_the_axis`: over the
base the arm is singular too); each cycle the target is then held
within a depth into the surface, a lead along it and an angle of the measured tip
(:mod:`cr_control.schemes.blocks.target_bounds`: the normal force stays the force loop's);
a force above ``max_target_force``
is scaled down to it. The reference then follows a pose at most ``target_max_speed`` and
the force given to the law changes at most ``target_force_rate``
(:mod:`cr_control.schemes.blocks.references`). Measured before (the Panda's wiping task,
offline, no reflex): a target pose 10 m up made the reference ask 17.5 m/s, the tip reached
3 m/s and the law saturated and braked; a 1e6 N target wrench pressed 231 N before braking;
a quaternion of norm 1e200 became zeros.

Wrist sensor: with ``sensor_frame``, ``tool_mass``, ``ft_bias`` or
``zero_ft_at_start`` set, the wrench given to :meth:`compute` (force, or force and torque, in
the sensor frame) becomes the contact force in the base frame, f = R_S (F_S - b_F) - m g,
before the law sees it; :meth:`zero_ft` zeroes the bias
(:mod:`cr_control.schemes.blocks.wrist_sensor`). Without them the force goes to the law as
given, bit for bit.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pinocchio as pin

from cr_control.core.packing import Layout
from cr_control.core.parameters import Param, ParameterError, resolve, validate
from cr_control.models.reach import chain_reach, first_axis, off_the_axis
from cr_control.models.urdf import JOINT_FRICTION_EPSILON
from cr_control.schemes.blocks import (
    admittance_outer_loop,
    contact_guard,
    gain_bounds,
    references,
    safe_stop,
    wrist_sensor,
)
from cr_control.schemes.blocks.references import TARGETS, reference_gains, reference_state
from cr_control.schemes.blocks.task_space import (
    NULL_SPACE_GAINS,
    NULL_SPACE_PARAMETERS,
    ROBOT_PARAMETERS,
    TaskModel,
    common_gains_layout,
    status_fields,
    task_model,
)
from cr_control.schemes.controller import (
    COMMON_PARAMETERS,
    MAX_DT_PERIODS,
    Controller,
    ControlOutput,
    KernelOutput,
    max_dt_default,
)

#: joint_names of a task-space scheme: the chain's joints unless given (then their order is
#: the command order, e.g. a forward_command_controller's ``joints``).
JOINT_NAMES = Param("joint_names", [], "Joints commanded, in the order of the commands and of "
                    "forward_command_topic's array; empty = the chain's joints from base_link to "
                    "tip_link (a permutation of them is allowed).", "string_list", read_only=True)

#: max_effort on a URDF arm is at most this times the chain's largest ``<limit effort>``:
#: every joint is clipped at its own limit first, so a larger value clips nothing (a slip
#: of units, N mm for N m).
EFFORT_LIMIT_FACTOR = 10.0


#: Target positions are held within this fraction of :func:`chain_reach`: at the full stretch
#: the arm is singular (its task mass capped, ``singularity_mass``) and a target there, 10 m
#: up, drove the robust law's switching term into a growing joint 2/4 oscillation until
#: joint 6 passed its velocity limit (Panda, offline). Of the triangle inequality's bound,
#: 80 % (0.87 m on the Panda, 0.99 m on the UR5) still let a target along the table take
#: the UR5's tip 0.945 m from its first joint, 99.5 % of its farthest: the elbow passed its
#: velocity limit (three of five schemes); at 90 % of the farthest (0.85 m on the Panda,
#: 0.86 m on the UR5: the makers' 855 and 850 mm reach plus the tool) none did.
TARGET_REACH_FRACTION = 0.9
#: ... and at least this fraction of it from the first joint's axis (models.reach.off_the_axis):
#: a target 10 m straight up put the UR5's tip over its base, where joint 1 spun up to its
#: velocity reflex (nn_adaptive_impedance, offline); 0.14 m on the Panda and the UR5.
TARGET_AXIS_FRACTION = 0.15


def lightest_joint(chain_model, posture) -> tuple[int, float]:
    """(index, velocity limit) of the chain joint whose diagonal of the joint-space inertia
    M(q) (Pinocchio's CRBA, the tool included) is smallest at ``posture`` (the zero
    configuration if empty): the joint a delay makes oscillate first."""
    q = np.asarray(posture, dtype=float)
    if q.shape != (chain_model.n,):
        q = np.zeros(chain_model.n)
    data = chain_model.model.createData()
    M = pin.crba(chain_model.model, data, chain_model.configuration(q))
    j = int(np.argmin(np.diag(M)[:chain_model.n]))
    return j, float(chain_model.limits.velocity[j])


def safe_norm(x: np.ndarray) -> float:
    """|x| without overflow or underflow (scaled by its largest element first)."""
    scale = float(np.max(np.abs(x))) if x.size else 0.0
    return 0.0 if scale == 0.0 else scale * float(np.linalg.norm(x / scale))


def max_effort_on(param: Param, model: TaskModel) -> Param:
    """The common ``max_effort`` bounded by the chain's effort limits (where the URDF gives
    them), its default lowered to that bound if it was above (the same commands either way)."""
    effort = model.chain_model.limits.effort
    effort = effort[np.isfinite(effort) & (effort > 0)]
    if effort.size == 0:
        return param
    bound = min(param.bound, EFFORT_LIMIT_FACTOR * float(effort.max()))
    return replace(param, default=min(param.default, bound), bound=bound, description=(
        f"{param.description} At most {EFFORT_LIMIT_FACTOR:g}x the URDF's largest <limit "
        "effort> (each joint is clipped at its own limit first)."))


def max_dt_on(param: Param, given: dict[str, Any] | None) -> Param:
    """The common ``max_dt`` at the driver's ``control_period`` T in ``given``: its default
    max(5 ms, 2 T) (:func:`~cr_control.schemes.controller.max_dt_default`), so that each
    state of a driver slower than 200 Hz (the xArm's 150 Hz) is integrated whole; the param
    as it is where that leaves the default alone."""
    period = (given or {}).get("control_period")
    default = max_dt_default(None if period is None else float(period))
    if default == param.default:
        return param
    return replace(param, default=default, description=(
        f"{param.description} Default: {MAX_DT_PERIODS:g} control periods where that is "
        f"longer than {param.default:g} s; at least control_period (shorter, every cycle "
        "would be integrated short)."))


class TaskSpaceController(Controller):
    """A task-space law on any URDF arm (module docstring).

    Subclasses set ``scheme``, ``ROBOT_DEFAULTS`` (thesis values of the robot parameters)
    and :meth:`reference_defaults`; a law declares itself with ``kernel(chain, gains,
    state, targets, t, dt, q, v, force, out)`` and five hooks: its parameters
    (:meth:`law_parameters`, thesis defaults, m axes), its status fields
    (:meth:`law_status_fields`, after the task-space ones), its packed gains
    (:meth:`law_gains_layout`, filled by name from :meth:`law_gain_values`) and its state
    (:meth:`law_initial_state`). A family of laws (:mod:`.sliding`, :mod:`.unidirectional`)
    declares its shared part with the same hooks; its schemes extend them with ``super()``,
    their own gains, state and status fields after the family's.
    """

    TASK_SPACE = True

    def __new__(cls, values: dict | None = None, *args: Any, **kwargs: Any):
        """The law itself on an effort interface; on a position or velocity interface
        (``command_interface``) the law inside the admittance outer loop
        (:class:`~cr_control.schemes.blocks.admittance_outer_loop.AdmittanceOuterLoop`), which
        drives a virtual arm with it and sends that arm's motion."""
        if (values or {}).get("command_interface", "effort") != "effort":
            return admittance_outer_loop.AdmittanceOuterLoop(cls, values)
        return super().__new__(cls)

    JOINT_NAMES_PARAMETER = JOINT_NAMES
    #: Overrides of ROBOT_PARAMETERS' defaults (name -> (default, description)).
    ROBOT_DEFAULTS: dict[str, tuple[Any, str]] = {}
    #: True for a law that must not use a model of the arm's dynamics (3.76).
    MODEL_FREE = False
    #: False for a law with its own desired force (5.9: f_dm along the normal).
    HAS_DESIRED_FORCE = True
    kernel = None

    # -- parameters ------------------------------------------------------------------------
    @classmethod
    def robot_parameters(cls) -> list[Param]:
        """ROBOT_PARAMETERS with this scheme's thesis defaults."""
        out = []
        for p in ROBOT_PARAMETERS:
            if p.name in cls.ROBOT_DEFAULTS:
                default, description = cls.ROBOT_DEFAULTS[p.name]
                p = replace(p, default=default, description=description)
            out.append(p)
        return out

    @classmethod
    def robot_values(cls, given: dict[str, Any] | None) -> dict[str, Any]:
        """The robot parameters from ``given`` (any superset; defaults where absent)."""
        specs = cls.robot_parameters()
        names = {p.name for p in specs}
        return resolve(specs, {k: v for k, v in (given or {}).items() if k in names})

    @classmethod
    def is_thesis_robot(cls, robot: dict[str, Any]) -> bool:
        """True for the thesis's arm: no robot_description and the default urdf_file."""
        default = next(p.default for p in cls.robot_parameters() if p.name == "urdf_file")
        return not robot["robot_description"].strip() and robot["urdf_file"] == default

    @classmethod
    def parameters(cls, given: dict[str, Any] | None = None) -> list[Param]:
        """Every parameter on the robot ``given`` names (the thesis's arm by default)."""
        robot = cls.robot_values(given)
        model = task_model(robot, cls.MODEL_FREE)
        thesis = cls.is_thesis_robot(robot)
        own = {"joint_names": JOINT_NAMES, "max_effort": max_effort_on(
            next(p for p in COMMON_PARAMETERS if p.name == "max_effort"), model),
            "max_dt": max_dt_on(next(p for p in COMMON_PARAMETERS if p.name == "max_dt"), given)}
        common = [own.get(p.name, p) for p in COMMON_PARAMETERS]
        # the gains' bounds at the law's own period and delay (the virtual arm's behind a
        # position or velocity interface)
        law = admittance_outer_loop.law_settings(given or {})
        specs = (common + cls.robot_parameters() + safe_stop.parameters(thesis)
                 + wrist_sensor.PARAMETERS + cls.reference_parameters(model.m, thesis)
                 + cls.null_space_parameters(model, thesis, law)
                 + gain_bounds.parameters(thesis) + cls.law_parameters(model, thesis)
                 + admittance_outer_loop.parameters(given))
        return specs if thesis else cls.bounded_law_gains(specs, law)

    @classmethod
    def bounded_law_gains(cls, specs: list[Param], given: dict[str, Any]) -> list[Param]:
        """``specs`` with the law's gains (and the force admittance's) bounded on a robot by
        the discrete-time rule beside the others (:func:`gain_bounds.law_parameters`: the
        loops each law closes); the thesis's arm keeps the thesis's gains and plain bounds."""
        values = {p.name: validate(p, given.get(p.name, p.default))[2] for p in specs
                  if p.name in gain_bounds.LAW_GAINS}
        values = {k: v for k, v in values.items() if v is not None}
        period, delay = gain_bounds.loop_settings(given, False)
        task = cls.gain_loops(cls.carried_model(given), given, False)["task"].inertia
        return gain_bounds.law_parameters(specs, values, period, delay, task)

    @classmethod
    def null_space_parameters(cls, model: TaskModel, thesis: bool,
                              given: dict[str, Any]) -> list[Param]:
        """The null-space gains, bounded on a robot by the discrete-time rule at its period
        and delay (:mod:`cr_control.schemes.blocks.gain_bounds`: defaults lowered into the
        bounds, values beyond them refused); the thesis's arm has no null space."""
        if thesis:
            return NULL_SPACE_PARAMETERS
        return gain_bounds.null_space_parameters(
            NULL_SPACE_PARAMETERS, cls.gain_loops(cls.carried_model(given), given, thesis))

    @classmethod
    def carried_model(cls, given: dict[str, Any]) -> TaskModel:
        """The task model with the tool the wrist sensor carries (as :meth:`__init__` builds
        it): the inertias the gains act through."""
        wrist = resolve(wrist_sensor.PARAMETERS, {p.name: given[p.name]
                                                  for p in wrist_sensor.PARAMETERS if p.name in given})
        return task_model({**cls.robot_values(given), **wrist}, cls.MODEL_FREE)

    @classmethod
    def gain_loops(cls, model: TaskModel, values: dict[str, Any],
                   thesis: bool) -> dict[str, gain_bounds.Loop]:
        """The discrete-time rule's loops on ``model`` at the period and delay ``values``
        declare (:func:`gain_bounds.loops`)."""
        period, delay = gain_bounds.loop_settings(values, thesis)
        return gain_bounds.loops(model, gain_bounds.home_pose(model, values), period, delay)

    @classmethod
    def reference_parameters(cls, m: int, thesis: bool) -> list[Param]:
        """The desired motion's parameters: the thesis's path on its arm, else hold."""
        if thesis:
            return references.reference_parameters(m, **cls.reference_defaults())
        zeros = [0.0] * m
        return references.reference_parameters(m, zeros, zeros, zeros, 0.0, True,
                                               zeros if cls.HAS_DESIRED_FORCE else None,
                                               "default: hold the start position")

    @classmethod
    def reference_defaults(cls) -> dict[str, Any]:
        """Keyword arguments of references.reference_parameters for the thesis's arm."""
        raise NotImplementedError

    @classmethod
    def law_parameters(cls, model: TaskModel, thesis: bool) -> list[Param]:
        """The law's own parameters on ``model`` (thesis defaults)."""
        return []

    @classmethod
    def model_free(cls, values: dict) -> bool:
        """Whether the cycle's frame must carry no dynamics model (M = I, no gravity)."""
        return cls.MODEL_FREE

    # -- the law's packed gains, state and status ------------------------------------------
    def law_status_fields(self) -> list[str]:
        """The scheme's own status fields (after the task-space ones)."""
        return []

    def law_gains_layout(self) -> Layout:
        """Layout of the scheme's own packed gains (empty by default)."""
        return Layout()

    def law_gain_values(self) -> dict[str, Any]:
        """Values of the scheme's own packed gains by name (default: its parameters)."""
        return self.values

    def law_initial_state(self) -> np.ndarray:
        """The scheme's own internal state at t = 0 (none by default)."""
        return np.zeros(0)

    # -- construction --------------------------------------------------------------------------
    def __init__(self, values: dict):
        self.model = task_model(values, self.model_free(values))
        chain_joints = list(self.model.joint_names)
        given = list(values["joint_names"])
        if given and sorted(given) != sorted(chain_joints):
            raise ParameterError(f"joint_names {given} are not the chain's joints {chain_joints} "
                                 f"({values['base_link']} -> {values['tip_link']})")
        values = {**values, "joint_names": given or chain_joints}
        self._check_sizes(values)
        self.check_values(values)
        self.check_gains(values)
        #: The largest delay (cycles) these gains tolerate (the node's start-up round-trip
        #: check: cr_control.supervision.delay_watch); None on the thesis's arm.
        self.tolerated_delay = self.tolerated_delay_of(values)
        self.reference_fields, base_status = status_fields(self.model)
        self._law_fields = self.law_status_fields()
        self._status = base_status + self._law_fields
        super().__init__(values)
        n, m = self.model.n, self.model.m
        self.command_order = np.array([chain_joints.index(j) for j in values["joint_names"]],
                                      dtype=float)
        self._order = self.command_order.astype(int)
        # the kernel clips each command to its URDF effort: Controller.step's saturation guard
        self.command_limits = self.model.limits[3 * n:][self.command_order.astype(int)].copy()
        self.common = common_gains_layout(n, m)
        self.law_gains = self.law_gains_layout()
        self.gains = np.zeros(self.common.size + self.law_gains.size)
        self.pack_gains()
        self.reference_state = reference_state(m, n)
        self.internal = np.concatenate([np.zeros(self.reference_state.size),
                                        self.law_initial_state()])
        self.targets = np.zeros(TARGETS.size)
        self.targets[TARGETS.offset("quaternion")] = 1.0
        self._output = KernelOutput(self)
        self._kernel = type(self).kernel
        #: Where the guard's state starts in ``internal``, its event counter and the
        #: events already logged (:meth:`_log_guard_events`).
        self._guard_at = self.reference_state.offset("guard")
        guard_state = contact_guard.guard_state(m)
        self._events_at = self._guard_at + guard_state.offset("events")
        self._crossings_at = self._guard_at + guard_state.offset("crossings")
        self._events_seen = 0.0
        self._guard_seen = contact_guard.event_state(self.internal, self._guard_at, m)
        self._hold_data = None
        self._new_wrist_sensor()
        self._robot_side()
        self._target_checks()

    def _robot_side(self) -> None:
        """What the robot does and does not do for the law (``robot_compensates_*``): the
        URDF joint friction the controller adds, the model its brake uses (real gravity,
        whatever the law's model has) and the start check's indices."""
        chain, values, n = self.model.chain_model, self.values, self.model.n
        if values["wrench_sign"] not in (1, -1):
            raise ParameterError(f"wrench_sign must be 1 or -1, got {values['wrench_sign']}")
        self._reaction = values["wrench_sign"] == -1
        friction = not values["robot_compensates_friction"] and (
            np.any(chain.damping != 0.0) or np.any(chain.friction != 0.0))
        self._friction = (chain.damping.copy(), chain.friction.copy()) if friction else None
        self._brake_model = chain.model.copy()
        self._brake_model.gravity.linear = np.asarray(values["gravity"], dtype=float)
        self._brake_data = self._brake_model.createData()
        self._brake_hold: np.ndarray | None = None
        self._brake_stop = 0
        self._brake_holds_gravity = not values["robot_compensates_gravity"]
        axes = self.model.position_axes
        self._i_tip_v = [self._status.index(f"v_{a}") - 1 for a in axes]
        self._i_oscillation = self._status.index("oscillation_rms") - 1
        self._i_ref_v = [self.reference_fields.index(f"v_d_{a}") - 1 for a in axes]
        self._gravity_axes = np.array([values["gravity"]["xyz".index(a)] for a in axes])
        self._velocity_limit = self.model.limits[2 * n:3 * n].copy()

    def _target_checks(self) -> None:
        """The sphere target positions are held to (:func:`chain_reach`) and the rate
        limits of the targets' log lines."""
        self.reach_centre, full = chain_reach(self.model.chain_model)
        self.reach = TARGET_REACH_FRACTION * full
        self.reach_axis = first_axis(self.model.chain_model)
        self.reach_inner = TARGET_AXIS_FRACTION * full
        self._i_tip = [self._status.index(f"r_{a}") - 1 for a in self.model.position_axes]
        self._position_rows = self.model.task[3:3 + self.model.m].astype(int)
        self.target_notes = {"pose": wrist_sensor.RateLimitedLog(),
                             "wrench": wrist_sensor.RateLimitedLog()}

    def _target_note(self, which: str, message: str) -> None:
        self.target_notes[which](self.log_warning, f"{self.scheme}: {message}")

    def _new_wrist_sensor(self) -> None:
        """The wrist sensor's compensation and zeroing state, as at start."""
        self.wrist = wrist_sensor.WristSensor(self.values, self.model)
        self.wrist.log = lambda message: self.log_info(f"{self.scheme}: {message}")
        self.wrist.warn = lambda message: self.log_warning(f"{self.scheme}: {message}")

    def status_field_names(self) -> list[str]:
        return self._status

    def read_joint_names(self) -> list[str]:
        """The state is read in the chain's order (the node reorders by name)."""
        return list(self.model.joint_names)

    def _check_sizes(self, values: dict) -> None:
        posture = values.get("posture", [])
        if len(posture) not in (0, self.model.n):
            raise ParameterError(f"posture needs {self.model.n} values (one per chain joint "
                                 f"{list(self.model.joint_names)}) or none, got {len(posture)}")

    def check_values(self, values: dict) -> None:
        """Refuse a posture outside the chain's URDF position limits (``posture`` is bounded
        by Bound.JOINT alone; a joint without limits has no more)."""
        posture = values.get("posture", [])
        if len(posture) != self.model.n:
            return
        lim = self.model.chain_model.limits
        for name, q, lower, upper in zip(self.model.joint_names, posture, lim.lower, lim.upper,
                                         strict=True):
            if not lower <= q <= upper:
                raise ParameterError(f"posture: {name} = {q:g} is outside its URDF limits "
                                     f"[{lower:g}, {upper:g}]")

    def check_gains(self, values: dict, changed: str | None = None) -> None:
        """Refuse a stiffness and damping pair of the null space that the discrete-time rule
        finds unstable together (:func:`gain_bounds.check_pairs`; ``changed``: the parameter
        being set, named first in the line)."""
        robot = self.robot_values(values)
        if self.is_thesis_robot(robot):
            return
        loops = self.gain_loops(self.model, values, False)
        gain_bounds.check_pairs(values, loops, changed)
        period, delay = gain_bounds.loop_settings(values, False)
        why = gain_bounds.law_refusal(values, period, delay, loops["task"].inertia)
        if why is not None:
            raise ParameterError(why)

    def tolerated_delay_of(self, values: dict) -> int | None:
        """``tolerated_delay_cycles``, or where it is 0 the discrete-time rule's figure for the
        joint-space gains in ``values`` (:func:`gain_bounds.tolerated_delay`); None on the
        thesis's arm."""
        if self.is_thesis_robot(self.robot_values(values)):
            return None
        given = int(values.get("tolerated_delay_cycles", 0))
        return given or gain_bounds.tolerated_delay(values,
                                                    self.gain_loops(self.model, values, False))

    def check_parameter(self, name: str, value: Any) -> str | None:
        try:
            self.check_gains({**self.values, name: value}, name)
        except ValueError as exc:
            return str(exc)
        return super().check_parameter(name, value)

    def pack_gains(self) -> None:
        """Copy the parameter values into the packed gains the kernel reads."""
        values, n, m = self.values, self.model.n, self.model.m
        common = self.common
        common.view(self.gains, "task")[:] = self.model.task
        common.view(self.gains, "limits")[:] = self.model.limits
        common.view(self.gains, "order")[:] = self.command_order
        NULL_SPACE_GAINS.pack(values, common.view(self.gains, "null_space"))
        posture = values["posture"]
        guarded = contact_guard.guard_gain_values(values, m, self.default_approach_direction(),
                                                  *self._oscillation_joint)
        reference_gains(m, n).pack({
            **guarded, "reference_relative": float(values["reference_relative"]),
            "desired_force": values.get("desired_force", np.zeros(m)),
            "posture": posture if len(posture) else np.zeros(n),
            "posture_given": float(len(posture) > 0),
            "guard": contact_guard.guard_gains(m).pack(guarded)},
            common.view(self.gains, "reference"))
        self.law_gains.pack(self.law_gain_values(), self.gains[common.size:])

    @property
    def reads_wrench(self) -> bool:
        """True if the law is given the sensor's force and torque (a wrist sensor to
        compensate), False if the force alone (the ideal sensor)."""
        return self.wrist.active

    def zero_ft(self, force: bool = False) -> tuple[bool, str]:
        """Start zeroing the wrist sensor (``~/zero_ft``; ``force``: ``~/zero_ft_force``,
        the operator vouching that the tool touches nothing): (accepted, message). A refusal
        is also logged, at most one line every few seconds
        (:mod:`cr_control.schemes.blocks.wrist_sensor`)."""
        desired = None
        if self._last is not None and "f_d_x" in self.reference_fields:
            i = self.reference_fields.index("f_d_x") - 1
            desired = self._last.reference[i:i + self.model.m]
        answer = self.wrist.request_zero(desired, self.values["zero_ft_max_change"], force)
        if not answer[0]:
            self.wrist.refused(f"~/zero_ft{'_force' if force else ''} refused: {answer[1]}")
        return answer

    def zero_ft_refused(self, message: str) -> tuple[bool, str]:
        """A ``~/zero_ft`` the node refuses itself (no wrench yet): logged as the
        controller's refusals are (rate-limited); (False, message)."""
        self.wrist.refused(f"~/zero_ft refused: {message}")
        return False, message

    def warm_up(self) -> None:
        super().warm_up()
        self._new_wrist_sensor()    # the throw-away state must not start its zeroing

    def reset(self, keep_time: bool) -> None:
        """:meth:`Controller.reset`; an activation after states were seen does not zero the
        wrist sensor at start (``zero_ft_at_start``: the arm may be in contact by then) and
        keeps the bias in use: call ``~/zero_ft`` out of contact for a new one."""
        seen = self._t0 is not None
        super().reset(keep_time)
        self._brake_hold = None
        self._brake_holds_gravity = not self.values["robot_compensates_gravity"]
        self._events_seen = self.internal[self._events_at]     # the guard's, from the start
        self._guard_seen = contact_guard.event_state(self.internal, self._guard_at, self.model.m)
        if seen:
            self.wrist.skip_start()

    @property
    def _oscillation_joint(self) -> tuple[int, float]:
        """(the chain joint of smallest inertia at the posture (the first state's pose: the
        zero configuration stands in for it), its velocity limit): what the contact-stability
        monitor's joint channel watches (:mod:`contact_guard`)."""
        known = getattr(self, "_lightest", None)
        if known is None:
            known = lightest_joint(self.model.chain_model, self.values.get("posture", []))
            self._lightest = known
        return known

    def default_approach_direction(self) -> np.ndarray:
        """The guarded approach's direction when approach_direction is zero: against the
        desired force (into the surface that pushes back with it); zero if there is none
        (then a target wrench gives it, :mod:`contact_guard`)."""
        f_d = np.asarray(self.values.get("desired_force", np.zeros(self.model.m)), dtype=float)
        norm = float(np.linalg.norm(f_d))
        return -f_d / norm if norm > 0.0 else np.zeros(self.model.m)

    # -- targets ---------------------------------------------------------------------------------
    def set_target_pose(self, position: np.ndarray, quaternion: np.ndarray) -> bool:
        """A new target pose (base frame; quaternion [w, x, y, z]), from the next cycle;
        False if refused (module docstring: non-finite, zero quaternion), a position beyond
        the reach moved onto it."""
        position = np.array(position, dtype=float).reshape(3)
        q = np.array(quaternion, dtype=float).reshape(4)
        if not (np.all(np.isfinite(position)) and np.all(np.isfinite(q))):
            self._target_note("pose", "~/target_pose with a non-finite value refused")
            return False
        scale = float(np.max(np.abs(q)))
        if scale == 0.0:
            self._target_note("pose", "~/target_pose with a zero quaternion refused")
            return False
        q = q / scale
        q /= np.linalg.norm(q)
        rows = self._position_rows
        offset = position[rows] - self.reach_centre[rows]
        distance = safe_norm(offset)
        if distance > self.reach:
            given = position.copy()
            position[rows] = self.reach_centre[rows] + (offset / distance) * self.reach
            self._target_note("pose", f"~/target_pose position {given.tolist()} is {distance:.3g} "
                              f"m from the first joint, beyond {TARGET_REACH_FRACTION:.0%} of "
                              f"the arm's reach, {self.reach:.3g} m: moved there, to "
                              f"{np.round(position, 4).tolist()}")
        self._off_the_axis(position, rows)
        t = self.targets
        t[TARGETS.offset("position"):TARGETS.offset("position") + 3] = position
        t[TARGETS.offset("quaternion"):TARGETS.offset("quaternion") + 4] = q
        t[TARGETS.offset("pose_seq")] += 1.0
        return True

    def _off_the_axis(self, position: np.ndarray, rows: np.ndarray) -> None:
        """``position`` (in place) at least reach_inner from the first joint's axis and still
        within the reach (models.reach.off_the_axis); a point on the axis moves out towards
        the tip's last measured position."""
        offset = position - self.reach_centre
        away = np.zeros(3)
        if self._last is not None:
            away[rows] = self._last.status[self._i_tip] - self.reach_centre[rows]
        moved, was_near = off_the_axis(offset, self.reach_axis, self.reach_inner, away)
        if not was_near:
            return
        if safe_norm(moved[rows]) > self.reach:          # pushed out of the sphere: back onto it
            along = float(moved @ self.reach_axis)
            moved += (np.copysign(np.sqrt(max(self.reach ** 2 - self.reach_inner ** 2, 0.0)),
                                  along) - along) * self.reach_axis
        given = position.copy()
        position[rows] = self.reach_centre[rows] + moved[rows]
        self._target_note("pose", f"~/target_pose position {np.round(given, 4).tolist()} is "
                          f"within {self.reach_inner:.3g} m of the first joint's axis (over the "
                          f"base the arm is singular): moved out to "
                          f"{np.round(position, 4).tolist()}")

    def set_target_wrench(self, force: np.ndarray) -> bool:
        """A new desired contact force (base frame, N), from the next cycle; False if
        refused (non-finite), scaled down to ``max_target_force`` if above it."""
        force = np.array(force, dtype=float).reshape(3)
        if not np.all(np.isfinite(force)):
            self._target_note("wrench", "~/target_wrench with a non-finite value refused")
            return False
        size, bound = safe_norm(force), self.values["max_target_force"]
        if size > bound:
            given = force.copy()
            force = (force / size) * bound
            self._target_note("wrench", f"~/target_wrench force {given.tolist()} N: |f| = "
                              f"{size:.3g} N is above max_target_force {bound:g} N: scaled "
                              f"down to {np.round(force, 3).tolist()} N")
        t = self.targets
        t[TARGETS.offset("force"):TARGETS.offset("force") + 3] = force
        t[TARGETS.offset("wrench_seq")] += 1.0
        return True

    # -- the cycle ---------------------------------------------------------------------------------
    def compute(self, t, dt, q, v, force) -> ControlOutput:
        if self._reaction:
            force = -force          # the robot reports the reaction (wrench_sign -1)
        views = self._law(t, dt, q, v, force)
        if self._friction is not None:
            D, F = self._friction
            views.command += (D * v + F * np.tanh(v / JOINT_FRICTION_EPSILON))[self._order]
            self._report_command(views)
        if self.commanding:         # not while braking: the brake, not the law, moves the arm
            self._check_start(t, v, views)
        return views

    def _law(self, t, dt, q, v, force) -> ControlOutput:
        """The law's cycle after the wrist sensor's compensation: the start-up hold, then
        the law blended in from it."""
        out = self._output.new()
        if self.wrist.active:
            force = self.wrist.compensate(t, q, v, force)
            if self.wrist.holding:
                return self._hold(q, v, force, out)
            t -= self.wrist.law_start
        else:
            self.wrist.observe(t, v, force)     # what ~/zero_ft judges by (references only)
        views = self.cycle(t, dt, q, v, force, out)
        if self.wrist.at_start and t < wrist_sensor.HOLD_BLEND_S:
            # from the hold's G(q) to the law's command without a jump (smoothstep)
            G = self._gravity(q)
            views.command[:] = G + wrist_sensor.blend(t / wrist_sensor.HOLD_BLEND_S) * (
                views.command - G)
            self._report_command(views)
        return views

    def _report_command(self, views: ControlOutput) -> None:
        """The status's command fields after the command was changed here."""
        if len(self._command_slots) == self.n_joints:
            views.status[self._command_slots] = views.command

    def _check_start(self, t: float, v: np.ndarray, views: ControlOutput) -> None:
        """The start check (:func:`safe_stop.start_check`); on a mismatch: give up, brake."""
        if t >= self.values["start_check_time"]:
            return
        error = views.status[self._i_tip_v] - views.reference[self._i_ref_v]
        mismatch = safe_stop.start_check(self.scheme, t, error, self._gravity_axes, v,
                                         list(self.model.joint_names), self._velocity_limit,
                                         self.values, views.status[self._i_oscillation],
                                         self.internal[self._crossings_at])
        if mismatch is not None:
            self._brake_holds_gravity = mismatch.brake_holds_gravity
            self.give_up(mismatch.message)

    @property
    def brakes(self) -> bool:
        return True

    def brake_command(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """tau_b = G_b - M(q) (2 w_b q' + w_b^2 (q - q_b)) (:mod:`safe_stop`), q_b where
        braking began; G_b the URDF's gravity with the tool where the robot does not add it
        (or, after a failed start check, where it likely does not)."""
        model, data = self._brake_model, self._brake_data
        if self._brake_hold is None or self._brake_stop != self.stops:
            self._brake_hold, self._brake_stop = q.copy(), self.stops     # each stop anew
        qp = self.model.chain_model.configuration(q)
        M = pin.crba(model, data, qp)
        M = np.triu(M) + np.triu(M, 1).T
        G = (np.array(pin.computeGeneralizedGravity(model, data, qp))
             if self._brake_holds_gravity else None)
        tau = safe_stop.brake_torque(M, G, q, v, self._brake_hold, self.values["brake_frequency"])
        return tau[self._order]

    def cycle(self, t, dt, q, v, force, out: np.ndarray) -> ControlOutput:
        """The law's cycle into the output vector ``out`` (the contact force ``force`` in
        the base frame): the scheme's kernel; a scheme with more to do overrides this."""
        self._kernel(self.model.chain, self.gains, self.internal, self.targets, t, dt, q, v,
                     force, out)
        if self.internal[self._events_at] != self._events_seen:
            self._log_guard_events(t)
        return self._output.views(out)

    def _gravity(self, q: np.ndarray) -> np.ndarray:
        """G(q) of the URDF model with the tool, in command order (the start-up hold)."""
        chain = self.model.chain_model
        if self._hold_data is None:
            self._hold_data = chain.model.createData()
        G = pin.computeGeneralizedGravity(chain.model, self._hold_data, chain.configuration(q))
        return np.asarray(G)[self.command_order.astype(int)]

    def _hold(self, q: np.ndarray, v: np.ndarray, force: np.ndarray,
              out: np.ndarray) -> ControlOutput:
        """The start-up zeroing's cycle (:mod:`cr_control.schemes.blocks.wrist_sensor`): the
        arm held still by gravity compensation G(q) of the URDF model with the tool; the
        law's cycle at its time zero (dt = 0: nothing integrates) fills reference and status.
        Once the law runs, its command is blended in from G(q) over HOLD_BLEND_S."""
        views = self.cycle(0.0, 0.0, q, v, force, out)
        views.command[:] = self._gravity(q)
        self._report_command(views)
        return views

    def _log_guard_events(self, t: float) -> None:
        """One line per guard event (contact found or not, a target going stale or fresh
        again, chatter detected or calmed): the kernel counts them, this says which."""
        self._events_seen = self.internal[self._events_at]
        m = self.model.m
        seen = contact_guard.event_state(self.internal, self._guard_at, m)
        phase, stale, active, detections, joint_active = seen
        old_phase, old_stale, old_active, _, old_joint = self._guard_seen
        self._guard_seen = seen
        g = self.values
        if phase != old_phase and phase == contact_guard.IN_CONTACT:
            self.log_info(f"{self.scheme}: contact at t = {t:.3f} s (force against the approach "
                          f"above {g['contact_threshold']:g} N): the law takes over from here")
        if phase != old_phase and phase == contact_guard.NO_CONTACT:
            self.log_warning(f"{self.scheme}: no contact within approach_distance "
                             f"{g['approach_distance']:g} m: holding there (t = {t:.3f} s)")
        for bit, what, action in ((1, "target_pose", "holding the current pose"),
                                  (2, "target_wrench", "decaying the wrench to zero over "
                                   f"{g['wrench_timeout_decay']:g} s")):
            now, before = int(stale) & bit, int(old_stale) & bit
            if now and not before:
                self.log_warning(f"{self.scheme}: ~/{what} stale (none for "
                                 f"{g['target_timeout']:g} s, t = {t:.3f} s): {action}")
            elif before and not now:
                self.log_info(f"{self.scheme}: ~/{what} fresh again (t = {t:.3f} s)")
        if active and not old_active:
            self.log_warning(f"{self.scheme}: contact force oscillating (RMS above "
                             f"{g['stability_threshold']:g} N, detection {int(detections)}, "
                             f"t = {t:.3f} s): stiffness x{g['stability_stiffness_scale']:g}, "
                             f"damping x{g['stability_damping_scale']:g}")
        elif old_active and not active:
            self.log_info(f"{self.scheme}: contact calm again: nominal impedance restored "
                          f"(t = {t:.3f} s)")
        joint = self.model.joint_names[self._oscillation_joint[0]]
        if joint_active and not old_joint:
            self.log_warning(f"{self.scheme}: {joint} oscillating (RMS of its velocity above "
                             f"{contact_guard.JOINT_OSCILLATION_THRESHOLD:g} of its limit, "
                             f"t = {t:.3f} s): orientation and posture gains "
                             f"x{g['stability_stiffness_scale']:g}")
        elif old_joint and not joint_active:
            self.log_info(f"{self.scheme}: {joint} calm again: orientation and posture gains "
                          f"restored (t = {t:.3f} s)")
