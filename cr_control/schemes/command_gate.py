"""When a controller commands and when it brakes: the give-up and resume rule, hysteretic.

A controller stops commanding (:class:`~cr_control.schemes.controller.Controller`: the brake,
where the scheme has one, else silence and the plant's watchdog) for one of two reasons:

1. **its law's output**: more than ``max_bad_cycles`` cycles in a row non-finite or with a
   command element at its limit on the same side (:func:`~cr_control.schemes.controller.
   accept_cycle`'s run);
2. **late answers**: the states' age (:attr:`CommandGate.age`: how many control periods
   the command in force has stood when a state comes, 1 when every state is answered; a
   node that falls behind answers only the newest state queued, so the ones it skipped
   show here; a state held for being absurd still counts as given) averaged over
   AGE_WINDOW_CYCLES above LATE_MEAN_CYCLES (the answers stand, on average, that much
   longer than the one cycle the laws are tuned for: an effective delay the Panda's wrist
   does not tolerate with the gains of a zero-delay tuning), or one state more than
   LATE_STATE_CYCLES periods after the last. A single stall of a few tens of
   milliseconds, or bursts of them on a few per cent of the cycles, do not stop it (a
   real-time session on a loaded 2-core machine has them; braking at each would stop the
   task for nothing); answers late on average do.

It resumes only after RESUME_CYCLES consecutive cycles that are both **fresh** (the state at
most FRESH_STATE_CYCLES periods after the last, the average at most FRESH_MEAN_CYCLES) and
**good** (the law's output finite and inside its limits). The thresholds are apart (a
hysteresis in the age) and the resume waits 200 cycles, so braking and commanding can no
longer alternate every few cycles: between two stops lie at least RESUME_CYCLES + 1 cycles,
and a lateness that comes back sooner keeps the controller braking, once.

Before (real time, an independent MuJoCo Panda, robust_adaptive_impedance, command age p99
11-14 cycles): the law stopped after 50 saturated cycles and resumed at the first good
output, so it alternated "braking" / "commanding resumes" every 70 ms for seconds, each
resume handing the arm a law whose integrators had run on meanwhile: joints at 6-40x their
velocity limits. While stopped, the law now integrates nothing (the controller runs it with
dt = 0 to judge its output: estimates, integrators and filters held) and its clock stands
(it resumes where it stopped, its path not run ahead by the time braked).

Said once: the first stop and the first resume are logged at once, later ones at most every
5 s with a count (:class:`~cr_control.core.rate_limited_log.RateLimitedLog`).

The period is the controller's ``control_period`` where it declares one, else estimated
from the stamp steps: an average of the steps below 3x the estimate (a real-time plant
stamps with the wall clock, so steps jitter around the period), taken down at once by a
step below a third of it (a late first step).
"""

from __future__ import annotations

import math

#: One state more than this many periods after the last is late (200: twice the plant's
#: watchdog, which has braked by then; a shorter stall restarts the law's stepping beyond
#: max_stamp_gap, and a loaded 2-core machine stalls for 60 ms now and then)...
LATE_STATE_CYCLES = 200.0
#: ... and so are states whose age averaged over AGE_WINDOW_CYCLES is above this.
LATE_MEAN_CYCLES = 3.0
AGE_WINDOW_CYCLES = 100.0
#: Fresh: the state at most this many periods after the last, the average at most this.
FRESH_STATE_CYCLES = 3.0
FRESH_MEAN_CYCLES = 1.5
#: Consecutive fresh and good cycles before commanding resumes.
RESUME_CYCLES = 200
#: The period estimate's averaging gain (per step).
PERIOD_GAIN = 0.01

#: Events of :meth:`CommandGate.cycle`.
NONE, STOP_BAD, STOP_LATE, RESUME = 0, 1, 2, 3


class CommandGate:
    """The give-up and resume rule (module docstring) as a plain object: fed each cycle's
    stamp and the law's bad-cycle run, it says whether to command."""

    def __init__(self, max_bad_cycles: int, period: float | None = None,
                 resume_cycles: int = RESUME_CYCLES) -> None:
        self.max_bad_cycles = int(max_bad_cycles)
        self.resume_cycles = int(resume_cycles)
        self.commanding = True
        #: The control period (s): given, or estimated (module docstring; None before two
        #: stamps).
        self.period: float | None = period if period and period > 0.0 else None
        self._estimate = self.period is None
        #: The last state's age (periods since the one given before it: how long the
        #: command in force has stood; 1 when every state is answered; 0 before the second),
        #: and its average over AGE_WINDOW_CYCLES.
        self.age = 0.0
        self.mean_age = 1.0
        #: Consecutive fresh and good cycles while stopped.
        self.fresh_run = 0
        #: States later than LATE_STATE_CYCLES, and the largest age.
        self.late_states = 0
        self.max_age = 0.0
        self._last_stamp: float | None = None

    @property
    def late(self) -> bool:
        """Whether the answers are late (module docstring)."""
        return self.age > LATE_STATE_CYCLES or self.mean_age > LATE_MEAN_CYCLES

    @property
    def fresh(self) -> bool:
        return self.age <= FRESH_STATE_CYCLES and self.mean_age <= FRESH_MEAN_CYCLES

    def stamp(self, stamp: float) -> float:
        """The age (periods) of the state stamped ``stamp`` against the last one given
        (:attr:`age`); its average and the period estimate updated."""
        last, self._last_stamp = self._last_stamp, stamp
        if last is None:
            self.age = 0.0
            return self.age
        step = stamp - last
        if self._estimate and step > 0.0:
            if self.period is None or step < self.period / 3.0:
                self.period = step
            elif step < 3.0 * self.period:
                self.period += PERIOD_GAIN * (step - self.period)
        self.age = step / self.period if self.period else 0.0
        self.mean_age += (self.age - self.mean_age) / AGE_WINDOW_CYCLES
        self.max_age = max(self.max_age, self.age)
        if self.age > LATE_STATE_CYCLES:
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
        if self.commanding:
            if bad_run > self.max_bad_cycles:
                return self._stop(STOP_BAD)
            if self.late:
                return self._stop(STOP_LATE)
            return NONE
        self.fresh_run = self.fresh_run + 1 if self.fresh and bad_run == 0 else 0
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
        self.mean_age = 1.0
        self.restart()

    def _stop(self, event: int) -> int:
        self.stop()
        return event

    def late_text(self) -> str:
        """Why late answers stopped commanding (for the stop line)."""
        period = self.period or math.nan
        if self.age > LATE_STATE_CYCLES:
            return (f"a state {self.age:.0f} periods ({self.age * period * 1e3:.3g} ms) after "
                    f"the last one, more than {LATE_STATE_CYCLES:g}")
        return (f"answers late: the command in force stood {self.mean_age:.3g} periods on "
                f"average over the last {AGE_WINDOW_CYCLES:g} states (the period "
                f"{period * 1e3:.3g} ms), more than {LATE_MEAN_CYCLES:g}: more delay than the "
                "law is tuned for")
