"""One rate-limited logger for faults that can come with every message or cycle.

A node that logs a refused input, a sensor fault or a bad cycle every time it happens
floods its log at the loop's rate (a flood of 1000 refused commands a second is 1000
lines a second). :class:`RateLimitedLog` lets one line per key through at most every
``period_s`` and says, in the next line it lets through, how many it held back, so the
count is never lost. It is the same idea as rclpy's ``throttle_duration_sec`` and
roscpp's ``ROS_WARN_THROTTLE``
(https://docs.ros.org/en/jazzy/Tutorials/Demos/Logging-and-logger-configuration.html),
without their cost on the hot path: rclpy's logger reads the caller's frame and source
file on every call (~0.5 ms), this check is one dict lookup; and the text may be a
callable, built only when a line is let through (it may query the ROS graph).

``period_s`` = ``math.inf`` logs each key once (a warning that is only worth one line).

It lives in ``core`` so that every layer uses the same one: the nodes' input guards
(:mod:`cr_control.supervision`), the parameter gate, the plant's supervision, and the laws'
own lines (a held cycle, a refused zeroing, a clamped target).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

#: ``emit(severity, text)``: severity is "debug", "info", "warn" or "error".
Emit = Callable[[str, str], None]
#: A line's text, or a callable building it (only called when the line is let through).
Text = str | Callable[[], str]

#: The default period (s): one line per key at most every 5 s.
PERIOD_S = 5.0


def logger_emit(logger) -> Emit:
    """An :data:`Emit` onto a logger with ``debug``/``info``/``warn``/``error`` methods
    (rclpy's, or a :class:`logging.Logger`). One call site per severity: rclpy's logger
    refuses two severities from one line of code."""
    def emit(severity: str, text: str) -> None:
        if severity == "error":
            logger.error(text)
        elif severity == "warn":
            logger.warn(text)
        elif severity == "info":
            logger.info(text)
        else:
            logger.debug(text)
    return emit


class RateLimitedLog:
    """``log(key, severity, text)``: emits at most one line per ``key`` every ``period_s``
    of ``clock`` (monotonic seconds); the next line let through for that key ends with how
    many were suppressed since the last one. ``counts[key]``: lines asked for in all."""

    def __init__(self, emit: Emit, period_s: float = PERIOD_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not period_s >= 0.0:
            raise ValueError(f"period_s must be >= 0, not {period_s!r}")
        self.emit, self.period_s, self.clock = emit, period_s, clock
        self._at: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        #: Lines asked for per key (emitted or suppressed).
        self.counts: dict[str, int] = {}

    def __call__(self, key: str, severity: str, text: Text) -> bool:
        """Emit ``text`` (built now if callable) unless a line of ``key`` was emitted less
        than ``period_s`` ago; True if emitted."""
        self.counts[key] = self.counts.get(key, 0) + 1
        now = self.clock()
        at = self._at.get(key)
        if at is not None and (self.period_s == math.inf or now - at < self.period_s):
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return False
        self._at[key] = now
        held = self._suppressed.pop(key, 0)
        line = text() if callable(text) else text
        if held:
            line += f" ({held} more since the last such line)"
        self.emit(severity, line)
        return True

    def suppressed(self, key: str) -> int:
        """Lines of ``key`` suppressed since the last one emitted."""
        return self._suppressed.get(key, 0)
