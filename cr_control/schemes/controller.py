"""What every control scheme offers the generic controller node and the offline loop."""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np

from cr_control.core.parameters import Param
from cr_control.core.topics import REFERENCE_FIELDS, STATUS_FIELDS

#: Parameters of every controller node.
COMMON_PARAMETERS = [
    Param("joint_names", ["joint1", "joint2"], "Joints commanded, in command order.",
          "string_list", read_only=True),
    Param("max_effort", 100.0, "Commands are clipped to +-max_effort (N m, or m for position "
          "commands); the thesis schemes stay well inside the default.", "positive"),
    Param("forward_command_topic", "",
          "If set, also publish commands as Float64MultiArray here (ros2_control "
          "forward_command_controller, e.g. /effort_controller/commands).", "string",
          read_only=True),
]


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
    checks, a held finite command when anything is not finite, clipping and timing.
    """

    scheme: str = ""
    PARAMETERS: list[Param] = []
    command_interface = "effort"
    reference_fields: list[str] = REFERENCE_FIELDS
    extra_status_fields: list[str] = []

    def __init__(self, values: dict[str, Any]):
        self.values = dict(values)
        self.n_joints = len(self.values["joint_names"])
        self.status_fields = STATUS_FIELDS + list(self.extra_status_fields)
        self._i_compute = self.status_fields.index("compute_time_us") - 1
        self._i_held = self.status_fields.index("held") - 1
        self._last: ControlOutput | None = None
        self._t0: float | None = None
        self._t_prev: float | None = None
        self.held_cycles = 0

    @classmethod
    def parameters(cls) -> list[Param]:
        """Every parameter of this scheme: common ones first."""
        return COMMON_PARAMETERS + cls.PARAMETERS

    def set_parameter(self, name: str, value: Any) -> None:
        """Apply an already validated value; it is used from the next cycle on."""
        self.values[name] = value

    @abstractmethod
    def compute(self, t: float, dt: float, q: np.ndarray, v: np.ndarray,
                force: np.ndarray) -> ControlOutput:
        """The control law at time t (s since the first state), dt since the last call."""

    def step(self, stamp: float, q: np.ndarray, v: np.ndarray, force: np.ndarray) -> ControlOutput:
        """One control cycle for the state measured at ``stamp`` (s).

        Inputs of the wrong size or not finite, or a non-finite result, leave the last
        finite command in force (zero before the first) and set ``held`` in the status.
        """
        start = time.perf_counter()
        n = self.n_joints
        # A sum is finite only if every term is (or the values are absurdly large).
        ok = (q.shape == (n,) and v.shape == (n,) and force.shape[0] >= 2
              and math.isfinite(stamp + q.sum() + v.sum() + force.sum()))
        out = None
        if ok:
            if self._t0 is None:
                self._t0 = self._t_prev = stamp
            dt = max(stamp - self._t_prev, 0.0)
            out = self.compute(stamp - self._t0, dt, q, v, force)
            if out.command.shape == (n,) and math.isfinite(out.command.sum()):
                self._t_prev = stamp
            else:
                out = None
        if out is None:
            self.held_cycles += 1
            out = self._held_output()
        else:
            limit = self.values["max_effort"]
            if np.abs(out.command).max() > limit:
                np.clip(out.command, -limit, limit, out=out.command)
            self._last = out
        out.status[self._i_compute] = (time.perf_counter() - start) * 1e6
        return out

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
