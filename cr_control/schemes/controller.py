"""What every control scheme offers the generic controller node and the offline loop.

:meth:`Controller.step` wraps each scheme's :meth:`Controller.compute` with what every
scheme needs (issue 7, "Controller robustness"): physically absurd inputs are held like
NaN and the controller recovers on the next good state; integration steps are clamped
to ``max_dt`` and a gap in stamps restarts the stepping instead of being integrated as
one step; a non-finite internal state is restored; the status reports the command
actually sent. It is the 1 kHz hot path: a handful of numpy calls per cycle.
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

from cr_control.core.linalg import all_finite
from cr_control.core.parameters import Param
from cr_control.core.topics import REFERENCE_FIELDS, STATUS_FIELDS

#: Parameters of every controller node.
COMMON_PARAMETERS = [
    Param("joint_names", ["joint1", "joint2"], "Joints commanded, in command order.",
          "string_list", read_only=True),
    Param("max_effort", 100.0, "Commands are clipped to +-max_effort (N m, or m for position "
          "commands); the thesis schemes stay inside the default, except fjr_robust_adaptive "
          "with the measured q_m'' (its torque then sits at the clip).", "positive"),
    Param("forward_command_topic", "",
          "If set, also publish commands as Float64MultiArray here (ros2_control "
          "forward_command_controller, e.g. /effort_controller/commands).", "string",
          read_only=True),
    Param("max_joint_position", 100.0, "States whose joint positions have a Euclidean norm "
          "above this (rad or m) are absurd: held like NaN.", "positive"),
    Param("max_joint_velocity", 100.0, "States whose joint velocities have a Euclidean norm "
          "above this (rad/s or m/s) are absurd: held like NaN.", "positive"),
    Param("max_dt", 0.005, "Longest integration step (s) of the control law's internal "
          "states; longer intervals between states are integrated as this.", "positive"),
    Param("max_stamp_gap", 0.05, "A state stamped more than this (s) after the previous one, "
          "or before it, is held and the stepping restarts from it (a gap is never "
          "integrated as one step).", "positive"),
    Param("diagnostics_every", 1, "Publish ~/reference and ~/status every this many cycles "
          "(integer >= 1). 1 = every cycle, as the thesis figures and the lockstep "
          "determinism tests need; costs one in/out message pair per cycle (out_time_us).",
          "integer"),
]

#: Faults are logged at most this often (s); the count in between is reported.
WARN_EVERY_S = 5.0

_log = logging.getLogger("cr_control.controller")


@dataclass
class ControlOutput:
    """One cycle's command and the labelled values published beside it (without stamps)."""

    command: np.ndarray
    reference: np.ndarray
    status: np.ndarray


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
        self.n_joints = len(self.values["joint_names"])
        #: Joints whose states the law reads, in the order of q and q' given to compute():
        #: the ``state_joint_names`` parameter where a scheme has one (flexible joints: link
        #: and motor joints), else the commanded joints.
        self.state_joint_names = list(self.values.get("state_joint_names")
                                      or self.values["joint_names"])
        self.n_state = len(self.state_joint_names)
        self.plant_sensors = np.full(len(self.plant_sensor_fields), np.nan)
        self.status_fields = STATUS_FIELDS + list(self.extra_status_fields)
        self._i_compute = self.status_fields.index("compute_time_us") - 1
        self._i_held = self.status_fields.index("held") - 1
        names = self.command_status_fields or [f"tau_{i + 1}" for i in range(self.n_joints)]
        self._command_slots = ([self.status_fields.index(f) - 1 for f in names]
                               if all(f in self.status_fields for f in names) else None)
        self.internal: np.ndarray | None = None
        self._internal_good: np.ndarray | None = None
        self._last: ControlOutput | None = None
        self._t0: float | None = None
        self._t_prev: float | None = None
        self.held_cycles = 0
        self.restored_cycles = 0
        #: Where fault warnings go (the controller node routes them to its ROS logger).
        self.log_warning: Callable[[str], None] = _log.warning
        self._warned_at = -math.inf
        self._unwarned = 0

    #: The scheme's own ``joint_names`` parameter (its plant's joints as the default), in
    #: place of the common one (the 2-link arm's); None keeps the common one.
    JOINT_NAMES_PARAMETER: Param | None = None

    @classmethod
    def parameters(cls) -> list[Param]:
        """Every parameter of this scheme: common ones first."""
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
        """Run the law once on a throw-away state so the first real cycle does not pay for
        loading (or compiling) its compiled kernels; ``internal`` is restored afterwards."""
        saved = None if self.internal is None else self.internal.copy()
        n = self.n_state
        saved_sensors = self.plant_sensors.copy()
        self.plant_sensors[:] = 0.0
        self.compute(0.0, 1e-3, np.full(n, 0.3), np.zeros(n), np.zeros(3))
        self.plant_sensors[:] = saved_sensors
        if saved is not None:
            np.copyto(self.internal, saved)

    def step(self, stamp: float, q: np.ndarray, v: np.ndarray, force: np.ndarray) -> ControlOutput:
        """One control cycle for the state measured at ``stamp`` (s).

        Held (the last finite command stays in force, zero before the first, and
        ``held`` is set in the status) when: an input has the wrong size or is not
        finite; |q| > max_joint_position or |q'| > max_joint_velocity (Euclidean
        norms); the stamp goes back or jumps by more than max_stamp_gap (the stepping
        then restarts from that stamp); the command or ``self.internal`` comes out
        non-finite (``internal`` is restored). The law integrates at most max_dt per
        cycle. Commands beyond +-max_effort are clipped and the status reports the
        clipped command.
        """
        start = time.perf_counter()
        n = self.n_state
        values = self.values
        out = None
        reason = ""
        if q.shape != (n,) or v.shape != (n,) or force.shape[0] < 2:
            reason = f"state of the wrong size (q {q.shape}, v {v.shape}, force {force.shape})"
        else:
            # hypot is NaN or inf for NaN/inf entries and never overflows (no numpy
            # warning): one comparison checks finiteness and the bound at once.
            q_norm, v_norm = math.hypot(*q.tolist()), math.hypot(*v.tolist())
            if not (q_norm <= values["max_joint_position"] and v_norm <= values["max_joint_velocity"]
                    and math.isfinite(stamp + sum(force.tolist()))):
                reason = (f"absurd or non-finite state (|q| = {q_norm:.3g}, |v| = {v_norm:.3g}, "
                          f"force {force}, stamp {stamp})")
        if not reason:
            if self._t0 is None:
                self._t0 = self._t_prev = stamp
            gap = stamp - self._t_prev
            if 0.0 <= gap <= values["max_stamp_gap"]:
                out, reason = self._compute(stamp, min(gap, values["max_dt"]), q, v, force)
            else:
                reason = (f"stamp {'went back' if gap < 0.0 else 'jumped'} by {gap:.6g} s "
                          f"(max_stamp_gap {values['max_stamp_gap']:g} s): stepping restarts")
                self._t_prev = stamp
        if out is None:
            self.held_cycles += 1
            self._warn(reason)
            out = self._held_output()
        else:
            self._last = out
        out.status[self._i_compute] = (time.perf_counter() - start) * 1e6
        return out

    def _compute(self, stamp: float, dt: float, q: np.ndarray, v: np.ndarray,
                 force: np.ndarray) -> tuple[ControlOutput | None, str]:
        """compute() with the internal-state and command checks; (output or None, reason)."""
        internal = self.internal
        if internal is not None and (self._internal_good is None
                                     or self._internal_good.shape != internal.shape):
            self._internal_good = internal.copy()            # the initial value
        out = self.compute(stamp - self._t0, dt, q, v, force)
        if internal is not None:
            if all_finite(internal):
                np.copyto(self._internal_good, internal)
            else:
                np.copyto(internal, self._internal_good)
                self.restored_cycles += 1
                return None, "internal state not finite: restored to its last finite value"
        command = out.command
        if command.shape != (self.n_joints,):
            return None, f"command of the wrong size {command.shape}"
        limit = self.values["max_effort"]
        if not math.hypot(*command.tolist()) <= limit:       # NaN, inf or maybe beyond the limit
            if not math.isfinite(sum(command.tolist())):
                return None, f"non-finite command {command}"
            if np.abs(command).max() > limit:
                np.clip(command, -limit, limit, out=command)
                if self._command_slots is not None:
                    out.status[self._command_slots] = command
        self._t_prev = stamp
        return out, ""

    def _warn(self, reason: str) -> None:
        """Log why a cycle was held, at most every WARN_EVERY_S with a count in between."""
        self._unwarned += 1
        now = time.monotonic()
        if now - self._warned_at < WARN_EVERY_S:
            return
        more = self._unwarned - 1
        more = f" ({more} more held cycles since the last warning)" if more else ""
        self._warned_at, self._unwarned = now, 0
        self.log_warning(f"{self.scheme}: holding the last command: {reason}{more}")

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
