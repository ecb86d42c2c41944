"""The controller's check at start that its answers come back in time for its gains.

A real-time controller answers each state some time after it was stamped; a driver that
applies an answer on its next cycle (libfranka, ur_robot_driver's effort interface) then
applies it ``command_delay_cycles`` cycles late, and one more cycle for every whole period
the answer took. The gains tolerate a largest such delay (``tolerated_delay_cycles``: the
margin table of docs/safety.md, "Gains a sampled, delayed loop takes", measured per scheme
and robot profile, or the discrete-time rule's figure for the gains in force). Over its first
WINDOW answered states the controller measures how late each answer is (the wall clock at the
answer minus the state's stamp: a real-time plant and a ros2_control driver on the same
machine stamp with its clock) and, if the 99th percentile with the driver's delay goes
beyond the tolerated delay, says so once, in one line. Stamps on another clock (more than
CLOCK_MISMATCH_S apart from the wall clock: simulated time, another machine) are not
measured. No ROS here: the controller node hands it the stamps.
"""

from __future__ import annotations

import math

import numpy as np

#: Answered states measured at start (1 s at 1 kHz).
WINDOW = 1000
#: A state stamped further than this from the wall clock (s) is on another clock.
CLOCK_MISMATCH_S = 5.0


class DelayWatch:
    """The start-up round-trip check (module docstring): ``period`` (s), the driver's
    ``declared`` delay and the ``tolerated`` one (cycles)."""

    def __init__(self, period: float, declared: int, tolerated: int, window: int = WINDOW):
        self.period = float(period)
        self.declared = int(declared)
        self.tolerated = int(tolerated)
        self._late = np.empty(int(window))
        self._count = 0
        #: The measured delay (cycles: the driver's and the answers'), once the window is full.
        self.measured: int | None = None
        self.done = not (self.period > 0.0 and math.isfinite(self.period))

    def answered(self, stamp_s: float, now_s: float) -> str | None:
        """An answer to the state stamped ``stamp_s`` sent at ``now_s`` (wall clock, s): the
        one warning line when the window completes beyond the tolerated delay, else None."""
        if self.done:
            return None
        late = now_s - stamp_s
        if not abs(late) <= CLOCK_MISMATCH_S:
            self.done = True                 # another clock: nothing to measure
            return None
        self._late[self._count] = max(late, 0.0)
        self._count += 1
        if self._count < len(self._late):
            return None
        self.done = True
        p99 = float(np.percentile(self._late, 99.0))
        self.measured = self.declared + int(math.floor(p99 / self.period))
        if self.measured <= self.tolerated:
            return None
        return (f"the answers to the first {len(self._late)} states came back {p99 * 1e3:.3g} ms "
                f"after their stamps (99th percentile): with the driver's "
                f"{self.declared} cycle(s) that is a delay of {self.measured} cycles of "
                f"{self.period * 1e3:g} ms, beyond the {self.tolerated} this controller's gains "
                "tolerate (tolerated_delay_cycles; docs/safety.md, 'Gains a sampled, delayed "
                "loop takes'): expect the wrist to oscillate; give the controller a core of its "
                "own or lower the gains")


def delay_watch_for(controller, lockstep: bool) -> DelayWatch | None:
    """The check for a controller that declares its period, its driver's delay and the delay
    its gains tolerate (``tolerated_delay``); None in lockstep (simulated stamps) or for one
    that does not."""
    tolerated = getattr(controller, "tolerated_delay", None)
    values = controller.values
    if lockstep or tolerated is None or "control_period" not in values:
        return None
    return DelayWatch(values["control_period"], values["command_delay_cycles"], tolerated)
