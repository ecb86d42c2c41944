"""How a real-time plant's wall clock becomes simulation steps, and when each state left.

- :class:`CatchUp`: a tick integrates the wall time elapsed since the last one in whole
  periods, the remainder carried to the next tick, so every step has the same dt (an LTI
  plant's exact discretisation is then computed once, not every tick: ~190 us -> ~4 us for
  the chapter 4 plant) and simulated time follows wall time to within a period. After a
  gap (a stalled tick) at most ``max_periods`` are integrated: the rest of the gap is
  dropped (simulated time falls behind wall time; counted in ``dropped_s``) rather than
  integrated under a command held that long.
- :class:`PublishTimes`: the wall times of the last states published, by stamp, so that a
  command answering one of them gives the round trip (once per state).
"""

from __future__ import annotations


class CatchUp:
    """Whole periods of wall time to integrate at each tick (module docstring)."""

    def __init__(self, period: float, max_periods: int) -> None:
        self.period = period
        self.max_periods = max_periods
        self.carry = 0.0          # wall time not yet simulated (s)
        self.dropped_s = 0.0      # wall time of stalls not simulated (s)

    def periods(self, elapsed: float) -> int:
        """The periods to integrate for ``elapsed`` s of wall time since the last tick."""
        due = elapsed + self.carry
        periods = max(1, round(due / self.period))
        if periods > self.max_periods:
            self.dropped_s += (periods - self.max_periods) * self.period
            periods, due = self.max_periods, self.max_periods * self.period
        self.carry = max(due - periods * self.period, -self.period)
        return periods


class PublishTimes:
    """The wall times the last ``size`` states were published, by stamp (integer ns)."""

    def __init__(self, size: int = 64) -> None:
        self._stamps: list[int | None] = [None] * size
        self._times = [0.0] * size
        self._i = 0

    def sent(self, stamp: int, now: float) -> None:
        self._i = (self._i + 1) % len(self._stamps)
        self._stamps[self._i], self._times[self._i] = stamp, now

    def answered(self, stamp: int) -> float | None:
        """When the state stamped ``stamp`` was published, once (None if not among the last,
        or already answered)."""
        stamps, size = self._stamps, len(self._stamps)
        for k in range(size):
            j = (self._i - k) % size
            if stamps[j] == stamp:
                stamps[j] = None      # one round trip per state
                return self._times[j]
        return None
