"""The real-time plant's watchdog (libfranka's rule that commands keep coming,
``communication_constraints_violation``): ticks without a new command counted, the
reaction said once per silence.

The reaction is due after ``watchdog_missed_cycles`` such ticks in a row, or once no new
command has come for :data:`WALL_FACTOR` times that many periods of wall time over at
least :data:`WALL_MIN_SHARE` as many ticks (3 at least). The second rule is a backstop
for a plant whose ticks slowed down: a fresh-clone CI run (2026-11-26) saw a plant tick at ~90 Hz after its
controller's SIGKILL (its publishes blocked on the dead reader), so that 300 ticks took
3.3 s. One long tick of the plant's own (a stall), answered at once, trips nothing, and a
plant that only loses a few ticks reaches the tick count first: at a factor of 1 a CI run
braked after 295 ticks of a 300-tick watchdog (300 ms over 295 ticks), earlier than the
count the parameter states.
What the reaction is (a safe stop, holding the last command) is the node's to choose.
"""

from __future__ import annotations

#: The wall-time rule needs at least this share of ``missed_limit`` ticks (and 3) ...
WALL_MIN_SHARE = 0.1
#: ... and this many times ``missed_limit`` periods of wall time.
WALL_FACTOR = 2.0


class Watchdog:
    """Counts the ticks without a new command (:meth:`tick`); armed by the first command,
    disarmed by :meth:`disarm` (a resume: armed again by the next command)."""

    def __init__(self, missed_limit: int, period: float) -> None:
        self.missed_limit = missed_limit
        self.period = period
        #: Ticks the wall-time rule needs at least.
        self.wall_min_ticks = max(3, round(WALL_MIN_SHARE * missed_limit))
        #: Ticks without a new command so far, in a row.
        self.run = 0
        self._armed = False
        self._tripped = False
        self._last_command_at = 0.0

    def tick(self, now: float, new_command: bool) -> str | None:
        """A tick at ``now`` (monotonic s) that saw a ``new_command`` or not: why the
        reaction is due, once per silence; None otherwise."""
        if new_command:
            self._armed, self._tripped, self.run = True, False, 0
            self._last_command_at = now
            return None
        if not self._armed:
            return None
        self.run += 1
        silent = now - self._last_command_at
        limit = self.missed_limit
        due = self.run >= limit or (self.run >= self.wall_min_ticks
                                      and silent >= WALL_FACTOR * limit * self.period)
        if not due or self._tripped:
            return None
        self._tripped = True
        return (f"no new command for {self.run} consecutive cycles in {silent * 1e3:.0f} ms "
                f"(watchdog_missed_cycles {limit}: {limit * self.period * 1e3:.0f} ms)")

    def disarm(self) -> None:
        """Stop counting until the next command (after a resume from a safe stop)."""
        self.run, self._armed, self._tripped = 0, False, False
