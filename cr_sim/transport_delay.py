"""The transport delay between a controller and a robot: what a driver applies is older than
what the controller just answered, and now and then a burst of answers comes late.

A real driver applies the command computed from the state of cycle k at cycle k + 1 or
later: libfranka calls the user's torque callback inside its 1 kHz cycle and the robot
applies the returned torque in the next one (libfranka's documentation, "Real-time
requirements" and "Control side": the answer to the state of one millisecond is executed in
the next); ur_robot_driver streams the effort interface's torques over RTDE at 500 Hz, each
applied on the controller's next 2 ms cycle; KUKA FRI's torque mode allows send periods of
several milliseconds. And a Python controller on a loaded machine answers some states tens
of milliseconds late; meanwhile the driver applies the last command it has (as ros2_control's
forward_command_controller and libfranka's last-command hold do).

:class:`TransportDelay` models both, per plant step (one control period):

- a constant delay of ``cycles`` steps: the command applied at step k is the one held at
  step k - ``cycles`` (a ring buffer; before that much history, the first command);
- late bursts: each step outside a burst starts one with probability ``burst_probability``
  (a seeded :class:`numpy.random.Generator`, so lockstep and the offline loop draw the same
  bursts), lasting a number of steps drawn uniformly from ``burst_cycles`` (inclusive);
  during it the driver keeps applying the command it applied last, then it catches up (the
  delayed stream again, its newest entry).

With ``cycles`` 0 and no bursts the command passes through untouched (the same object): a
run without delay is the loop without it, bit for bit. Nothing non-finite comes out if
nothing non-finite goes in: every output is a command that was pushed (the plant's
supervisor holds only finite ones).
"""

from __future__ import annotations

import numpy as np

#: The most steps a delay (or a burst) may last: 10 s at 1 kHz.
MAX_DELAY_CYCLES = 10000


class TransportDelay:
    """A driver's transport delay and its late bursts (module docstring)."""

    def __init__(self, cycles: int = 0, burst_probability: float = 0.0,
                 burst_cycles: tuple[int, int] = (20, 70), seed: int = 0) -> None:
        cycles = int(cycles)
        low, high = (int(burst_cycles[0]), int(burst_cycles[1]))
        if not 0 <= cycles <= MAX_DELAY_CYCLES:
            raise ValueError(f"a transport delay of {cycles} cycles: 0 to "
                             f"{MAX_DELAY_CYCLES} are allowed")
        if not 0.0 <= float(burst_probability) <= 1.0:
            raise ValueError(f"a late-burst probability of {burst_probability}: 0 to 1")
        if not 1 <= low <= high <= MAX_DELAY_CYCLES:
            raise ValueError(f"late bursts of {low} to {high} cycles: 1 <= min <= max <= "
                             f"{MAX_DELAY_CYCLES}")
        self.cycles = cycles
        self.burst_probability = float(burst_probability)
        self.burst_cycles = (low, high)
        self.seed = int(seed)
        self._rng = np.random.default_rng(self.seed)
        self._ring: list[np.ndarray] = []
        self._at = 0                            # where the next command goes in the ring
        self._applied: np.ndarray | None = None
        #: Steps left of the burst under way (0: none), and the totals so far.
        self.burst_left = 0
        self.bursts = 0
        self.late_cycles = 0

    @property
    def passes_through(self) -> bool:
        """True if every command is applied as pushed (no delay, no bursts)."""
        return self.cycles == 0 and self.burst_probability == 0.0

    def describe(self) -> str:
        """The delay in words (the plant node's first log line)."""
        text = f"transport delay {self.cycles} cycles"
        if self.burst_probability > 0.0:
            low, high = self.burst_cycles
            text += (f", late bursts of {low}-{high} cycles with probability "
                     f"{self.burst_probability:g} per cycle (seed {self.seed})")
        return text

    def __call__(self, command: np.ndarray) -> np.ndarray:
        """Push the command held at this step; the command the driver applies now."""
        if self.passes_through:
            return command
        # a copy: the caller may reuse its array (a controller's output buffer)
        delayed = np.array(command, dtype=float)
        if self.cycles > 0:
            ring = self._ring
            if not ring:                        # before any history: the first command
                ring.extend(delayed.copy() for _ in range(self.cycles + 1))
            ring[self._at] = delayed
            self._at = (self._at + 1) % len(ring)
            delayed = ring[self._at]            # the oldest: pushed `cycles` steps ago
        if self.burst_probability > 0.0 and self._applied is not None:
            if self.burst_left == 0 and self._rng.random() < self.burst_probability:
                low, high = self.burst_cycles
                self.burst_left = int(self._rng.integers(low, high + 1))
                self.bursts += 1
            if self.burst_left > 0:
                self.burst_left -= 1
                self.late_cycles += 1
                return self._applied            # late: the driver holds what it had
        self._applied = delayed
        return delayed
