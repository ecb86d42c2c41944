"""When a controller commands and when it brakes: the give-up and resume rule, hysteretic.

A controller stops commanding (:class:`~cr_control.schemes.controller.Controller`: the brake,
where the scheme has one, else silence and the plant's watchdog) for one of two reasons:

1. **its law's output**: more than ``max_bad_cycles`` cycles in a row non-finite or with a
   command element at its limit on the same side (:func:`~cr_control.schemes.controller.
   accept_cycle`'s run);
2. **a late state**: a state stamped more than LATE_STATE_CYCLES control periods after the
   last one the controller was given (its :attr:`CommandGate.age`, in periods; a node that
   falls behind answers only the newest state queued, so the ones it skipped show here; a
   state held for being absurd is still counted as given): the command in force has
   stood that long unanswered, and the delay its answers arrive with is more than the
   laws are tuned for (a one-cycle transport delay; the Panda's lightest joint already
   oscillates at 3 cycles with the gains of a zero-delay tuning). A controller on a loaded
   machine answers such states in bursts; a law answering every burst with its full gains
   flailed (below).

It resumes only after RESUME_CYCLES consecutive cycles that are both **fresh** (stamped at
most FRESH_STATE_CYCLES periods after the last one given) and **good** (the law's output
finite and inside its limits). The two thresholds are apart (a hysteresis in the age, 2 and
10 periods) and the resume waits 200 cycles, so braking and commanding can no longer
alternate every few cycles: between two stops lie at least RESUME_CYCLES + 1 cycles, and a
lateness that comes back sooner keeps the controller braking, once.

Before (real time, an independent MuJoCo Panda, robust_adaptive_impedance, command age p99
11-14 cycles): the law stopped after 50 saturated cycles and resumed at the first good
output, so it alternated "braking" / "commanding resumes" every 70 ms for seconds, each
resume handing the arm a law whose integrators had run on meanwhile: joints at 6-40x their
velocity limits. While stopped, the law now integrates nothing (the controller runs it with
dt = 0 to judge its output: estimates, integrators and filters held) and its clock stands
(it resumes where it stopped, its path not run ahead by the time braked).

Said once: the first stop and the first resume are logged at once, later ones at most every
5 s with a count (:class:`~cr_control.core.rate_limited_log.RateLimitedLog`).

The period is the smallest positive stamp step seen (a controller is not told its plant's
rate; a late first step is corrected by the next on-time one).
"""

from __future__ import annotations

import math

#: A state stamped more than this many periods after the last one given is late.
LATE_STATE_CYCLES = 10.0
#: ... and at most this many is fresh.
FRESH_STATE_CYCLES = 2.0
#: Consecutive fresh and good cycles before commanding resumes.
RESUME_CYCLES = 200

#: Events of :meth:`CommandGate.cycle`.
NONE, STOP_BAD, STOP_LATE, RESUME = 0, 1, 2, 3


class CommandGate:
    """The give-up and resume rule (module docstring) as a plain object: fed each cycle's
    stamp and the law's bad-cycle run, it says whether to command."""

    def __init__(self, max_bad_cycles: int, resume_cycles: int = RESUME_CYCLES,
                 late_cycles: float = LATE_STATE_CYCLES,
                 fresh_cycles: float = FRESH_STATE_CYCLES) -> None:
        self.max_bad_cycles = int(max_bad_cycles)
        self.resume_cycles = int(resume_cycles)
        self.late_cycles = float(late_cycles)
        self.fresh_cycles = float(fresh_cycles)
        self.commanding = True
        #: The period (s): the smallest positive stamp step seen (None before two stamps).
        self.period: float | None = None
        #: The last state's age (periods since the one given before it: how long the
        #: command in force has stood; 1 when every state is answered; 0 before the second).
        self.age = 0.0
        #: Consecutive fresh and good cycles while stopped.
        self.fresh_run = 0
        #: Late states seen, and the largest age.
        self.late_states = 0
        self.max_age = 0.0
        self._last_stamp: float | None = None

    def stamp(self, stamp: float) -> float:
        """The age (periods) of the state stamped ``stamp`` against the last one given
        (:attr:`age`); the period estimate updated."""
        last, self._last_stamp = self._last_stamp, stamp
        if last is None:
            self.age = 0.0
            return self.age
        step = stamp - last
        if step > 0.0 and (self.period is None or step < self.period):
            self.period = step
        self.age = step / self.period if self.period else 0.0
        self.max_age = max(self.max_age, self.age)
        if self.age > self.late_cycles:
            self.late_states += 1
        return self.age

    def restart(self) -> None:
        """The stepping restarts (a stamp gap beyond max_stamp_gap, an activation): the next
        stamp has no age."""
        self._last_stamp = None
        self.age = 0.0

    def cycle(self, bad_run: int) -> int:
        """This cycle's event (NONE, STOP_BAD, STOP_LATE, RESUME) for the state last given to
        :meth:`stamp` and the law's bad-cycle run; :attr:`commanding` follows it."""
        late = self.age > self.late_cycles
        if self.commanding:
            if bad_run > self.max_bad_cycles:
                return self._stop(STOP_BAD)
            if late:
                return self._stop(STOP_LATE)
            return NONE
        fresh = self.age <= self.fresh_cycles and bad_run == 0
        self.fresh_run = self.fresh_run + 1 if fresh else 0
        if self.fresh_run >= self.resume_cycles:
            self.commanding = True
            self.fresh_run = 0
            return RESUME
        return NONE

    def stop(self) -> None:
        """Stop from outside the rule (a controller that gave up for good)."""
        self.commanding = False
        self.fresh_run = 0

    def reset(self) -> None:
        """Commanding again, as at a fresh start (a lifecycle activation)."""
        self.commanding = True
        self.fresh_run = 0
        self.restart()

    def _stop(self, event: int) -> int:
        self.stop()
        return event

    def late_text(self) -> str:
        """Why a late state stopped commanding (for the stop line)."""
        period = self.period or math.nan
        return (f"a state {self.age:.0f} periods ({self.age * period * 1e3:.3g} ms) after the "
                f"last one, more than {self.late_cycles:g}: answers this late are "
                "more than the law is tuned for")
