"""What every control scheme offers the generic controller node and the offline loop.

:meth:`Controller.step` wraps each scheme's :meth:`Controller.compute` with what every
scheme needs, as libfranka's and ros2_control's checks guard a real arm: physically absurd
inputs are held like NaN and the controller recovers on the next good state; integration
steps are clamped to ``max_dt`` and a gap in stamps restarts the stepping instead of being
integrated as one step; a non-finite internal state is restored; the status reports the
command actually sent.

A law that fails for good does not keep a command in force: after
``max_bad_cycles`` cycles in a row whose output was held because of the law (a
non-finite command or internal state) or had a command element at its limit on the same
side (+-max_effort, or the URDF effort the task-space kernels clip to: ``command_limits``),
or with answers too late (:mod:`cr_control.schemes.command_gate`),
:attr:`Controller.commanding` turns False. A scheme with a braking command
(:meth:`Controller.brake_command`: the task-space schemes) then outputs it every cycle and
the node keeps publishing it, because a real robot's forward_command_controller applies
the last command forever (ros2_controllers #95); a scheme without one stops publishing and
the plant's watchdog brakes. Commanding turns True again only after RESUME_CYCLES
consecutive fresh states whose output was finite and inside its limits (hysteretic, so it
never alternates every few cycles; meanwhile a braking scheme's law integrates nothing and
its clock stands: :mod:`cr_control.schemes.command_gate`; a law without a brake runs on,
because the offline loop still applies its command and a frozen law would act open-loop
there), unless the controller gave up for good
(:meth:`Controller.give_up`: a failed start check), which only an activation undoes.
Commands alternating between the two limits (the chatter of
fjr_robust_adaptive's measured q_m'') restart the count; cycles held because of the
input (a NaN state, a stamp gap) are not the law's doing and leave it alone. The count is
kept by :func:`accept_cycle`, per command element.

It is the 1 kHz hot path, and in a node every state arrives after an idle spell, when
every distinct piece of code runs several times slower than back to back (caches gone
cold on this kind of virtual machine). So a cycle is three compiled calls and no numpy
call from Python: :func:`admit_state` (the input checks), the scheme's kernel writing
into one of two preallocated output vectors (:class:`KernelOutput`), and
:func:`accept_cycle` (internal-state backup or restore, command checks and clipping).
Measured after a 0.9 ms sleep: 118-154 us per step with the checks, allocation, views
and backup done in Python and numpy, 48-66 us this way (docs/benchmark.md, "The hot path").
"""

from __future__ import annotations

import logging
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from cr_control.core.linalg import all_finite
from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.core.rate_limited_log import RateLimitedLog
from cr_control.core.topics import REFERENCE_FIELDS, STATUS_FIELDS
from cr_control.schemes.command_gate import (
    FRESH_MEAN_CYCLES,
    FRESH_STATE_CYCLES,
    RESUME,
    STOP_BAD,
    STOP_LATE,
    CommandGate,
)

#: ``max_dt``'s default (s): 5 periods of a 1 kHz driver, 2.5 of a 500 Hz one.
MAX_DT = 0.005
#: Where a controller declares its ``control_period`` T, max_dt's default is at least this
#: many periods: every regular state is integrated whole, and one late by a period too.
MAX_DT_PERIODS = 2.0


def max_dt_default(period: float | None) -> float:
    """max_dt's default (s) for a driver of ``period`` (s; None: not declared):
    max(MAX_DT, MAX_DT_PERIODS T)."""
    return MAX_DT if not period or period <= 0.0 else max(MAX_DT, MAX_DT_PERIODS * period)


def max_dt_refusal(values: dict[str, Any]) -> str | None:
    """Why ``max_dt`` is refused beside ``control_period`` (one line), or None: shorter than
    the period, every cycle would be integrated short (the law's internal states, and
    behind a position or velocity interface its virtual arm, would run slower than the
    stamps its reference follows)."""
    period = values.get("control_period")
    if period is None or "max_dt" not in values or float(values["max_dt"]) >= float(period):
        return None
    return (f"max_dt {float(values['max_dt']):g} s is shorter than control_period "
            f"{float(period):g} s: every cycle would be integrated short, the law's states "
            f"falling behind the stamps its reference follows (default: "
            f"{max_dt_default(float(period)):.4g} s)")


#: Parameters of every controller node.
COMMON_PARAMETERS = [
    Param("joint_names", ["joint1", "joint2"], "Joints commanded, in command order.",
          "string_list", read_only=True),
    Param("max_effort", 100.0, "Commands are clipped to +-max_effort (N m, or m for position "
          "commands); the thesis schemes stay inside the default, except fjr_robust_adaptive "
          "with the measured q_m'' (its torque then sits at the clip).", "positive",
          bound=Bound.EFFORT),
    Param("forward_command_topic", "",
          "If set, also publish commands as Float64MultiArray here (ros2_control "
          "forward_command_controller, e.g. /effort_controller/commands).", "string",
          read_only=True),
    # 1000: no joint turns 160 times or moves 1 km, nor at 160 turns/s; the defaults are
    # already far beyond any arm.
    Param("max_joint_position", 100.0, "States whose joint positions have a Euclidean norm "
          "above this (rad or m) are absurd: held like NaN.", "positive", bound=1000.0),
    Param("max_joint_velocity", 100.0, "States whose joint velocities have a Euclidean norm "
          "above this (rad/s or m/s) are absurd: held like NaN.", "positive", bound=1000.0),
    # 1 s: a law integrated over a longer step than that is no longer a 1 kHz control law.
    Param("max_dt", MAX_DT, "Longest integration step (s) of the control law's internal "
          "states; longer intervals between states are integrated as this.", "positive",
          bound=1.0),
    # 10 s: a gap beyond it is a restart whatever this says.
    Param("max_stamp_gap", 0.05, "A state stamped more than this (s) after the previous one, "
          "or before it, is held and the stepping restarts from it (a gap is never "
          "integrated as one step).", "positive", bound=10.0),
    Param("diagnostics_every", 1, "Publish ~/reference and ~/status every this many cycles "
          "(integer >= 1). 1 = every cycle, as the thesis figures and the lockstep "
          "determinism tests need; costs one in/out message pair per cycle (out_time_us).",
          "integer", bound=10000),    # every 10 s at 1 kHz
    Param("autostart", True, "Configure and activate this (lifecycle) node at start, so it "
          "answers states at once; false: it waits unconfigured until told through "
          "~/change_state (ros2 lifecycle set, cr_lifecycle).", "bool", read_only=True),
    Param("lockstep", False, "The plant steps on this node's commands (cr_session --mode "
          "lockstep sets it): every 250 cycles the node waits until every reader of its "
          "topics (a recorder) acknowledged them, so a recording loses nothing. Leave it off "
          "against a plant in real time: such a wait can last a heartbeat (10 ms).", "bool",
          read_only=True),
    # 50: the thesis runs have no such cycle but fjr_robust_adaptive with the
    # measured q_m'', whose torque chatters between the two clips (at most 10-24 cycles in a
    # row at one clip for K_s = 10-100 I at 1 kHz); 10 000 = 10 s at 1 kHz.
    Param("max_bad_cycles", 50, "Commands stop after this many cycles in a row in which the "
          "law's output was not usable (non-finite command or internal state: held) or a "
          "command sat at its limit (+-max_effort or the URDF effort) on the same side; the "
          "plant's watchdog then brakes. Commanding resumes after 200 consecutive fresh "
          "states with an output finite and inside its limits (integer >= 1; see "
          "docs/safety.md).", "integer", bound=10000),
    # 1e4 N: the range of the largest 6-axis force/torque sensors.
    Param("max_sensor_force", 1000.0, "A measured contact force above this (N, Euclidean "
          "norm), or a non-finite one, is a sensor fault: the last sane reading is used "
          "instead. 1000 N is ~10x what these arms can press (the thesis arms' 20 N m joints, "
          "the Panda's 87 N m) and the weight of 100 kg.", "positive", bound=1e4),
]

#: Faults are logged at most this often (s); the count in between is reported.
WARN_EVERY_S = 5.0

#: Verdicts of :func:`accept_cycle`.
ACCEPTED, INTERNAL_RESTORED, WRONG_COMMAND_SIZE, COMMAND_NOT_FINITE = 0, 1, 2, 3
_NO_INTERNAL = np.zeros(0)

_log = logging.getLogger("cr_control.controller")


@dataclass
class ControlOutput:
    """One cycle's command and the labelled values published beside it (without stamps)."""

    command: np.ndarray
    reference: np.ndarray
    status: np.ndarray


@njit(cache=True, error_model="numpy")
def admit_state(n, max_q, max_v, stamp, q, v, force):
    """Whether a state may reach the law: ``n`` joint positions and velocities (1-D
    arrays) with Euclidean norms |q| <= max_q and |q'| <= max_v, at least two force
    components, and a finite stamp and force. A NaN or inf anywhere fails a comparison."""
    if q.shape[0] != n or v.shape[0] != n or force.shape[0] < 2:
        return False
    q2 = v2 = 0.0
    for i in range(n):
        q2 += q[i] * q[i]
        v2 += v[i] * v[i]
    total = stamp
    for i in range(force.shape[0]):
        total += force[i]
    return math.sqrt(q2) <= max_q and math.sqrt(v2) <= max_v and math.isfinite(total)


@njit(cache=True, error_model="numpy")
def accept_cycle(n, max_effort, limits, internal, good, command, status, command_slots, guard):
    """Judge a computed cycle; returns (verdict, run): the verdict one of ACCEPTED,
    INTERNAL_RESTORED, WRONG_COMMAND_SIZE, COMMAND_NOT_FINITE, and run the number of cycles
    in a row, this one included, in which the law failed (0 after a good cycle).

    A non-finite ``internal`` is restored in place from ``good`` (its last finite value);
    a finite one is copied into ``good``. A command of ``n`` finite values is clipped to
    +-max_effort, and the clipped values are written to ``status[command_slots]``.

    ``guard`` (2 n values, zero at the start) keeps the run per command element: its count
    ``guard[j]`` and the side ``guard[n + j]`` (+-1, 0 for none) of its limit, min(max_effort,
    limits[j]). A held cycle (any verdict but ACCEPTED: the last command stays in force)
    counts for every element; an accepted one counts for an element at its limit, from 1
    again if it was at the other limit before, and clears an element inside its limits."""
    verdict = ACCEPTED
    if not all_finite(internal):
        internal[:] = good
        verdict = INTERNAL_RESTORED
    else:
        good[:] = internal
        if command.shape[0] != n:
            verdict = WRONG_COMMAND_SIZE
        elif not all_finite(command):
            verdict = COMMAND_NOT_FINITE
    run = 0.0
    for j in range(n):
        if verdict != ACCEPTED:
            guard[j] += 1.0
        else:
            c = command[j]
            if c > max_effort or c < -max_effort:
                c = min(max(c, -max_effort), max_effort)
                command[j] = c
                if command_slots.shape[0] == n:
                    status[command_slots[j]] = c
            limit = min(max_effort, limits[j])
            side = 1.0 if c >= limit else (-1.0 if c <= -limit else 0.0)
            if side == 0.0:
                guard[j] = 0.0
            elif guard[j] > 0.0 and guard[n + j] != -side:
                guard[j] += 1.0
            else:
                guard[j] = 1.0
            guard[n + j] = side
        run = max(run, guard[j])
    return verdict, int(run)


#: Reference values of the 2-D schemes (topics.REFERENCE_FIELDS without the stamp).
N_REFERENCE = len(REFERENCE_FIELDS) - 1


def field_at(fields: list[str], name: str) -> int:
    """Where field ``name`` of ``fields`` (a topic's, the stamp first) is in the published
    vector, which has no stamp."""
    return fields.index(name) - 1


@njit(cache=True, error_model="numpy")
def split_output(out, n):
    """(command, reference, status) views of a 2-D scheme's output vector
    [command (n) | reference (N_REFERENCE) | status]."""
    return out[:n], out[n:n + N_REFERENCE], out[n + N_REFERENCE:]


class KernelOutput:
    """The output vector a scheme's cycle kernel fills, from two preallocated ones: the
    kernel writes the spare while the other keeps the last accepted cycle (a held
    command refers to it), and :meth:`keep` swaps them once a cycle is accepted. A
    :class:`ControlOutput` is valid until the second accepted cycle after it."""

    def __init__(self, controller: Controller):
        n_status = len(controller.status_fields) - 1
        self.n = controller.n_joints
        self.n_reference = len(controller.reference_fields) - 1
        self.size = self.n + self.n_reference + n_status
        #: Where the scheme's own status fields (``extra_status_fields``) start.
        self.extras_at = n_status - len(controller.extra_status_fields)
        self._vectors = (np.zeros(self.size), np.zeros(self.size))
        self._views = tuple(self._split(vector) for vector in self._vectors)
        self._spare = 0

    def _split(self, out: np.ndarray) -> ControlOutput:
        n, k = self.n, self.n + self.n_reference
        return ControlOutput(out[:n], out[n:k], out[k:])

    def new(self) -> np.ndarray:
        """The output vector for this cycle (the spare one)."""
        return self._vectors[self._spare]

    def views(self, out: np.ndarray) -> ControlOutput:
        """command, reference and status views of a filled output vector."""
        spare = self._spare
        return self._views[spare] if out is self._vectors[spare] else self._split(out)

    def keep(self) -> None:
        """The cycle just written was accepted: the other vector becomes the spare."""
        self._spare ^= 1


class Controller(ABC):
    """A control law: measured joint state and contact force in, joint command out.

    Subclasses set ``scheme``, ``PARAMETERS`` (thesis defaults), ``extra_status_fields``
    and implement :meth:`compute`. :meth:`step` adds what every scheme needs: input
    checks, a held finite command when anything is absurd or not finite, clipping,
    internal-state recovery and timing.

    Internal state contract: ``self.internal`` is a 1-D float64 array holding ALL of the
    law's evolving state (estimates, integrals, filters; subclasses keep views into it
    and update it in place), or None while a scheme has not adopted it (then it is not
    checked). After each compute, a non-finite ``internal`` is restored in place to its
    last finite value (or its value at the first cycle) and the cycle is held.
    """

    scheme: str = ""
    #: Whether the law takes live targets (``set_target_pose``, ``set_target_wrench``) and has a
    #: wrist sensor to zero (``zero_ft``): the task-space schemes.
    TASK_SPACE: bool = False
    PARAMETERS: list[Param] = []
    command_interface = "effort"
    reference_fields: list[str] = REFERENCE_FIELDS
    extra_status_fields: list[str] = []
    #: Status fields that report the command (overwritten with the clipped command).
    command_status_fields: list[str] | None = None
    #: Fields of the plant's extra measurements (topics.PLANT_SENSORS, labelled) the law
    #: reads, e.g. motor accelerations (assumption 6.3). Before every step the node (or the
    #: offline loop) writes the values measured with the state into ``plant_sensors``, in
    #: this order; NaN where the plant did not send one for that state.
    plant_sensor_fields: tuple[str, ...] = ()

    def __init__(self, values: dict[str, Any]):
        self.values = dict(values)
        why = max_dt_refusal(self.values)
        if why is not None:
            raise ParameterError(why)
        self.n_joints = len(self.values["joint_names"])
        #: Joints whose states the law reads, in the order of q and q' given to compute().
        self.state_joint_names = self.read_joint_names()
        self.n_state = len(self.state_joint_names)
        self.plant_sensors = np.full(len(self.plant_sensor_fields), np.nan)
        self.status_fields = self.status_field_names()
        self._i_compute = self.status_fields.index("compute_time_us") - 1
        self._i_held = self.status_fields.index("held") - 1
        names = self.command_status_fields or [f"tau_{i + 1}" for i in range(self.n_joints)]
        self._command_slots = np.array(
            [self.status_fields.index(f) - 1 for f in names]
            if all(f in self.status_fields for f in names) else [], dtype=np.int64)
        self.internal: np.ndarray | None = None
        self._internal_good = _NO_INTERNAL
        self._internal_of: np.ndarray | None = None      # the array _internal_good backs up
        #: The scheme's output vectors (schemes set ``self._output = KernelOutput(self)``).
        self._output: KernelOutput | None = None
        self._last: ControlOutput | None = None
        self._t0: float | None = None
        self._t_prev: float | None = None     # stamp of the last state the law was given
        self._t_step: float | None = None     # ... up to which the internal state is integrated
        self.held_cycles = 0
        self.restored_cycles = 0
        #: Each command element's own limit besides max_effort, in command order (a
        #: task-space scheme's URDF efforts, which its kernel clips to); inf where none.
        self.command_limits = np.full(self.n_joints, np.inf)
        #: False while the law's output has failed for more than max_bad_cycles cycles in a
        #: row (module docstring): the node then publishes no command.
        self.commanding = True
        #: Cycles in a row in which the law failed (held because of it, or at a limit).
        self.bad_run = 0
        #: How often commanding stopped.
        self.stops = 0
        #: True after :meth:`give_up`: commanding stays off until :meth:`reset`.
        self.gave_up = False
        #: The give-up and resume rule (:mod:`cr_control.schemes.command_gate`); the stamp
        #: commanding stopped at (the law's clock stands from there until it resumes).
        self.gate = CommandGate(self.values["max_bad_cycles"], self.values.get("control_period"))
        self._stopped_at: float | None = None
        self._guard = np.zeros(2 * self.n_joints)
        #: Where fault warnings go (the controller node routes them to its ROS logger), and
        #: the one-off lines of a stop (error) and of resuming (info).
        self.log_warning: Callable[[str], None] = _log.warning
        self.log_error: Callable[[str], None] = _log.error
        self.log_info: Callable[[str], None] = _log.info
        self._held_log = RateLimitedLog(lambda _severity, text: self.log_warning(text),
                                        WARN_EVERY_S)
        self._gate_log = RateLimitedLog(self._emit, WARN_EVERY_S)

    def read_joint_names(self) -> list[str]:
        """Joints whose states the law reads: the ``state_joint_names`` parameter where a
        scheme has one (flexible joints: link and motor joints), else the commanded joints."""
        return list(self.values.get("state_joint_names") or self.values["joint_names"])

    def status_field_names(self) -> list[str]:
        """Fields of the status (stamp first): topics.STATUS_FIELDS and the scheme's own."""
        return STATUS_FIELDS + list(self.extra_status_fields)

    #: The scheme's own ``joint_names`` parameter (its plant's joints as the default), in
    #: place of the common one (the 2-link arm's); None keeps the common one.
    JOINT_NAMES_PARAMETER: Param | None = None

    @classmethod
    def parameters(cls, given: dict[str, Any] | None = None) -> list[Param]:
        """Every parameter of this scheme, common ones first. ``given``: values the node or
        session was given (schemes whose parameters depend on the robot read it)."""
        own = cls.JOINT_NAMES_PARAMETER
        common = COMMON_PARAMETERS if own is None else [
            own if p.name == "joint_names" else p for p in COMMON_PARAMETERS]
        return common + cls.PARAMETERS

    def check_values(self, values: dict[str, Any]) -> None:
        """Raise ValueError (one line, the reason) if ``values`` together are not allowed:
        constraints between parameters that no single spec can express. Nothing by default."""
        return

    def check_parameter(self, name: str, value: Any) -> str | None:
        """Why changing ``name`` to ``value`` is refused with the other values in force
        (:meth:`check_values`), or None; the node asks before rclpy stores a change, so a
        refused value never reaches the law and the old one stays in force."""
        why = max_dt_refusal({**self.values, name: value})
        if why is not None:
            return why
        try:
            self.check_values({**self.values, name: value})
        except ValueError as exc:
            return str(exc)
        return None

    def set_parameter(self, name: str, value: Any) -> None:
        """Apply an already validated value; it is used from the next cycle on."""
        self.values[name] = value
        self.pack_gains()

    def pack_gains(self) -> None:
        """Copy the parameter values into whatever the compiled law reads (packed gains);
        called on every accepted change. Nothing to do for a law that reads ``values``."""
        return

    @abstractmethod
    def compute(self, t: float, dt: float, q: np.ndarray, v: np.ndarray,
                force: np.ndarray) -> ControlOutput:
        """The control law at time t (s since the first state), dt since the last call."""

    def warm_up(self) -> None:
        """Run the law and :meth:`step`'s checks once on a throw-away state (the argument
        types a node passes), so the first real cycle does not pay for loading (or, in a
        fresh install, compiling) the compiled kernels; ``internal`` is restored afterwards."""
        saved = None if self.internal is None else self.internal.copy()
        n = self.n_state
        q, v, force = np.full(n, 0.3), np.zeros(n), np.zeros(3)
        values = self.values
        admit_state(n, values["max_joint_position"], values["max_joint_velocity"], 0.0, q, v, force)
        saved_sensors = self.plant_sensors.copy()
        self.plant_sensors[:] = 0.0
        out = self.compute(0.0, 1e-3, q, v, force)
        self.plant_sensors[:] = saved_sensors
        scratch = (_NO_INTERNAL if saved is None else saved).copy()
        accept_cycle(self.n_joints, values["max_effort"], self.command_limits, scratch,
                     scratch.copy(), out.command, out.status, self._command_slots,
                     self._guard.copy())
        if saved is not None:
            np.copyto(self.internal, saved)

    def step(self, stamp: float, q: np.ndarray, v: np.ndarray, force: np.ndarray) -> ControlOutput:
        """One control cycle for the state measured at ``stamp`` (s).

        Held (the last finite command stays in force, zero before the first, and
        ``held`` is set in the status) when: an input has the wrong size or is not
        finite; |q| > max_joint_position or |q'| > max_joint_velocity (Euclidean
        norms); the stamp goes back or jumps by more than max_stamp_gap from the previous
        state the law was given (the stepping then restarts from that stamp); the command
        or ``self.internal`` comes out non-finite (``internal`` is restored). The law
        integrates the time since the last cycle whose internal state it kept, at most
        max_dt. Commands beyond +-max_effort are clipped and the status reports the clipped
        command.

        :attr:`commanding` turns False (one error line) once the law has failed for more
        than max_bad_cycles cycles in a row (held because of the law, or a command element
        at its limit on the same side: :func:`accept_cycle`), and True again (one info
        line) with the first cycle whose output is finite and inside its limits (not after
        :meth:`give_up`). While it is False a scheme with a braking command outputs that
        (:meth:`brake_command`, clipped like a command) and the node publishes it; a scheme
        without one outputs the law's command, which the offline loop (no watchdog) applies
        and the node does not publish.
        """
        start = time.perf_counter()
        values = self.values
        out = None
        if math.isfinite(stamp):
            self.gate.stamp(stamp)  # its age: how long the command in force has stood
        admitted = admit_state(self.n_state, values["max_joint_position"],
                               values["max_joint_velocity"], stamp, q, v, force)
        if not admitted:
            reason = self._refused_state(stamp, q, v, force)
        else:
            if self._t0 is None:
                self._t0 = stamp
            if self._t_prev is None:
                self._t_prev = self._t_step = stamp
            gap = stamp - self._t_prev
            if 0.0 <= gap <= values["max_stamp_gap"]:
                self._t_prev = stamp
                # stopped with a brake in force: the law integrates nothing (command_gate)
                dt = (min(stamp - self._t_step, values["max_dt"]) if self._stopped_at is None
                      else 0.0)
                out, reason = self._compute(stamp, dt, q, v, force)
            else:
                reason = (f"stamp {'went back' if gap < 0.0 else 'jumped'} by {gap:.6g} s "
                          f"(max_stamp_gap {values['max_stamp_gap']:g} s): stepping restarts")
                self._t_prev = self._t_step = stamp
                if gap > 0.0:       # a state this late stops commanding too (command_gate)
                    self._judge(self.bad_run, reason, stamp)
        if out is None:
            self.held_cycles += 1
            self._warn(reason)
            out = self._held_output()
        else:
            self._last = out
        if not self.commanding and admitted:
            self._brake(out, q, v)      # the law gave up: brake from the measured state
        out.status[self._i_compute] = (time.perf_counter() - start) * 1e6
        return out

    def brake_command(self, q: np.ndarray, v: np.ndarray) -> np.ndarray | None:
        """The command that brakes the robot at the measured state (q, q') while this
        controller does not command (module docstring), in command order; None (the
        default): the scheme has none, the node stops publishing and the plant's watchdog
        brakes."""
        return None

    @property
    def brakes(self) -> bool:
        """True if the scheme outputs a braking command while it does not command."""
        return False

    def braking(self, q: np.ndarray, v: np.ndarray) -> np.ndarray | None:
        """The braking command at (q, q') clipped like a command (a deactivated node
        publishes it); None where the scheme has none or it is not finite."""
        brake = self.brake_command(q, v) if self.brakes else None
        if brake is None or not np.all(np.isfinite(brake)):
            return None
        limit = np.minimum(self.values["max_effort"], self.command_limits)
        return np.clip(brake, -limit, limit)

    def _brake(self, out: ControlOutput, q: np.ndarray, v: np.ndarray) -> None:
        """Replace this cycle's command by the braking command (where the scheme has one)."""
        brake = self.braking(q, v)
        if brake is None:
            return
        out.command[:] = brake
        if len(self._command_slots) == self.n_joints:
            out.status[self._command_slots] = out.command

    def give_up(self, reason: str) -> None:
        """Stop commanding for good (one error line): the brake, where the scheme has one,
        until :meth:`reset` (a lifecycle activation)."""
        if self.gave_up:
            return
        self.gave_up = True
        self.commanding = False
        self.gate.stop()
        self.stops += 1
        self.log_error(reason)

    def reset(self, keep_time: bool) -> None:
        """Start the law afresh from the next state, as a lifecycle activation does: the
        internal state (estimates, integrators, filters, the reference's anchors and its
        admittance) back to its initial value, the stepping restarted (the next state
        integrates nothing), the bad-cycle run cleared and commanding on. Parameters stay
        as they are. ``keep_time``: the law's clock keeps its origin (the first state this
        controller ever saw), so an absolute reference (the thesis paths) goes on where it
        is; else the next state is t = 0, as at a fresh start."""
        if self.internal is not None and self._internal_of is self.internal:
            np.copyto(self.internal, self._internal_initial)
            self._internal_good = self._internal_initial.copy()
        if not keep_time:
            self._t0 = None
        self._t_prev = self._t_step = None
        self._guard[:] = 0.0
        self.bad_run = 0
        self.commanding = True
        self.gave_up = False
        self.gate.reset()
        self._stopped_at = None
        self._last = None

    def observe(self, stamp: float) -> None:
        """A state seen while the law does not run (an inactive node): it fixes the law's
        time origin if none is set yet, nothing else."""
        if self._t0 is None and math.isfinite(stamp):
            self._t0 = stamp

    def _refused_state(self, stamp: float, q: np.ndarray, v: np.ndarray, force: np.ndarray) -> str:
        """Why :func:`admit_state` refused a state (the rare path: numpy is fine here)."""
        n = self.n_state
        if q.shape != (n,) or v.shape != (n,) or force.shape[0] < 2:
            return f"state of the wrong size (q {q.shape}, v {v.shape}, force {force.shape})"
        q_norm, v_norm = math.hypot(*q.tolist()), math.hypot(*v.tolist())  # never overflow
        return (f"absurd or non-finite state (|q| = {q_norm:.3g}, |v| = {v_norm:.3g}, "
                f"force {force}, stamp {stamp})")

    def _compute(self, stamp: float, dt: float, q: np.ndarray, v: np.ndarray,
                 force: np.ndarray) -> tuple[ControlOutput | None, str]:
        """compute() judged by :func:`accept_cycle`; (output or None, reason)."""
        internal = _NO_INTERNAL if self.internal is None else self.internal
        if internal is not self._internal_of:
            self._internal_good, self._internal_of = internal.copy(), internal  # initial value
            self._internal_initial = internal.copy()
        # stopped: the law's clock stands where it stopped (command_gate)
        law_stamp = stamp if self._stopped_at is None else self._stopped_at
        out = self.compute(law_stamp - self._t0, dt, q, v, force)
        values = self.values
        verdict, run = accept_cycle(self.n_joints, values["max_effort"], self.command_limits,
                                    internal, self._internal_good, out.command, out.status,
                                    self._command_slots, self._guard)
        self.bad_run = run
        if verdict != INTERNAL_RESTORED:
            self._t_step = stamp        # the internal state integrated up to here is kept
        if verdict == ACCEPTED:
            if self._output is not None:
                self._output.keep()
            reason = ""
        elif verdict == INTERNAL_RESTORED:
            self.restored_cycles += 1
            reason = "internal state not finite: restored to its last finite value"
        elif verdict == WRONG_COMMAND_SIZE:
            reason = f"command of the wrong size {out.command.shape}"
        else:
            reason = f"non-finite command {out.command}"
        self._judge(run, reason, stamp)
        return (out, "") if verdict == ACCEPTED else (None, reason)

    def _judge(self, run: int, reason: str, stamp: float) -> None:
        """The give-up and resume rule on this cycle (:mod:`cr_control.schemes.command_gate`;
        nothing after :meth:`give_up`)."""
        if self.gave_up:
            return
        gate = self.gate
        gate.max_bad_cycles = self.values["max_bad_cycles"]
        event = gate.cycle(run)
        if event == STOP_BAD:
            self._stop(f"more than {self.values['max_bad_cycles']} cycles in a row "
                       "(max_bad_cycles) with a non-finite or saturated output ("
                       f"{reason or self._at_limit()})", stamp)
        elif event == STOP_LATE:
            self._stop(gate.late_text(), stamp)
        elif event == RESUME:
            self._resume(stamp)

    def _at_limit(self) -> str:
        """Which command element sits at its limit longest, and where (for the stop line)."""
        n = self.n_joints
        j = int(np.argmax(self._guard[:n]))
        names = self.values["joint_names"]
        limit = min(self.values["max_effort"], float(self.command_limits[j]))
        return (f"{names[j]}'s command at {self._guard[n + j] * limit:+.6g} for "
                f"{int(self._guard[j])} cycles (its limit: max_effort "
                f"{self.values['max_effort']:g}"
                + (f", URDF effort {self.command_limits[j]:g})" if math.isfinite(
                    self.command_limits[j]) else ")"))

    def _emit(self, severity: str, text: str) -> None:
        """A gate line to the logger of its severity, one call site each (rclpy's logger
        refuses two severities from one line of code)."""
        if severity == "error":
            self.log_error(text)
        else:
            self.log_info(text)

    def _stop(self, reason: str, stamp: float) -> None:
        """Stop commanding (the gate already has): one line, later ones rate-limited."""
        self.commanding = False
        self.stops += 1
        # a braking scheme's law stands while its brake acts; one without a brake runs on
        # (its command is still applied offline: frozen, it would act open-loop)
        self._stopped_at = stamp if self.brakes else None
        gate = self.gate
        self._gate_log("stop", "error", lambda: (
            f"{self.scheme}: {reason}: "
            + ("braking (the braking command is published in its place)" if self.brakes
               else "commands stopped; the plant's watchdog will brake")
            + f". Commanding resumes after {gate.resume_cycles} cycles in a row with fresh "
            f"states (at most {FRESH_STATE_CYCLES:g} periods apart, {FRESH_MEAN_CYCLES:g} on "
            "average) and the law's output finite and inside its limits"
            + ("; until then the law integrates nothing and its clock stands" if self.brakes else "")
            + f" (stop {self.stops})"))

    def _resume(self, stamp: float) -> None:
        self.commanding = True
        if self._stopped_at is not None and self._t0 is not None:
            self._t0 += stamp - self._stopped_at      # the law's clock goes on where it stood
        self._stopped_at = None
        self._gate_log("resume", "info", lambda: (
            f"{self.scheme}: {self.gate.resume_cycles} cycles in a row with fresh states and "
            "the law's output finite and inside its limits: commanding resumes (a plant in "
            "safe stop stays there until resumed)"))

    def _warn(self, reason: str) -> None:
        """Log why a cycle was held, at most every WARN_EVERY_S with a count in between."""
        self._held_log("held", "warn", lambda: f"{self.scheme}: holding the last command: {reason}")

    def _held_output(self) -> ControlOutput:
        if self._last is None:
            ref = np.zeros(len(self.reference_fields) - 1)
            status = np.zeros(len(self.status_fields) - 1)
            last = ControlOutput(np.zeros(self.n_joints), ref, status)
        else:
            last = self._last
        status = last.status.copy()
        status[self._i_held] = 1.0
        return ControlOutput(last.command.copy(), last.reference.copy(), status)
