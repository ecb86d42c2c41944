"""Per-second and whole-run statistics of a state -> command loop (no ROS).

Round trip ("command age"): wall time from publishing a state to receiving the command
computed from it. A cycle is fresh when the command applied at a tick answers the state
published at the tick before. The plant node also reports its safety state here (safe
stop and its reason, commands clipped and refused, publishers on its topics, the one
commander's refusals and handovers): attributes
it sets, so every loop that uses these statistics publishes the same PLANT_TIMING_FIELDS.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

#: Values of ``safe_stop_reason`` (PLANT_TIMING_FIELDS): why the plant's safe stop is engaged.
SAFE_STOP_NONE = 0
SAFE_STOP_WATCHDOG = 1
SAFE_STOP_CONTACT_FORCE = 2
SAFE_STOP_JOINT_VELOCITY = 3
#: The reasons in words (log lines).
SAFE_STOP_REASONS = {SAFE_STOP_NONE: "none", SAFE_STOP_WATCHDOG: "watchdog",
                     SAFE_STOP_CONTACT_FORCE: "contact force reflex",
                     SAFE_STOP_JOINT_VELOCITY: "joint velocity reflex"}

BIN_S = 10e-6       # histogram resolution of whole-run round trips
MAX_AGE_S = 1.0     # longer round trips are counted in the last bin


def percentiles(values: Sequence[float], *ps: float) -> list[float]:
    """The ``ps``-th percentiles of ``values`` from one sort, interpolated linearly between
    neighbours (numpy.percentile's default), in plain Python: numpy's costs ~1 ms here.
    nan for each if ``values`` is empty."""
    ordered = sorted(values)
    if not ordered:
        return [math.nan for _ in ps]
    out = []
    for p in ps:
        position = p / 100.0 * (len(ordered) - 1)
        below = int(position)
        above = min(below + 1, len(ordered) - 1)
        out.append(ordered[below] + (ordered[above] - ordered[below]) * (position - below))
    return out


class LoopStats:
    """Accumulates cycles, freshness and round trips; reports PLANT_TIMING_FIELDS values."""

    def __init__(self) -> None:
        self.histogram = np.zeros(int(MAX_AGE_S / BIN_S) + 1, dtype=np.int64)
        self.total_cycles = 0
        self.total_fresh = 0
        self.total_max_age = 0.0
        self._top_bin = 0          # highest histogram bin used
        self._window_ages: list[float] = []
        self._window_cycles = 0
        self._window_fresh = 0
        self._window_step_time = 0.0
        self._window_publish_time = 0.0
        self._window_start: float | None = None
        #: Safety state, set by the plant node (0 where a loop has none).
        self.safe_stop = 0.0
        self.safe_stop_reason = SAFE_STOP_NONE
        self.commands_clipped = 0
        self.commands_refused = 0
        self.command_publishers = 0
        self.state_publishers = 0
        #: Longest run of consecutive ticks without a new command in the window.
        self.window_max_missed_run = 0
        #: One commander at a time: commands refused because another publisher
        #: commands, commands refused unread for their size, and changes of commander.
        self.commands_foreign = 0
        self.commands_oversized = 0
        self.commander_handovers = 0

    def cycle(self, fresh: bool, step_time: float = 0.0) -> None:
        """Count one tick of the loop; ``step_time`` (s) is the time spent computing it."""
        self.total_cycles += 1
        self._window_cycles += 1
        self.total_fresh += fresh
        self._window_fresh += fresh
        self._window_step_time += step_time

    def published(self, publish_time: float) -> None:
        """Add the time (s) one cycle spent building and publishing its outgoing messages."""
        self._window_publish_time += publish_time

    def round_trip(self, age: float) -> None:
        """Record one state -> command round trip (s)."""
        self._window_ages.append(age)
        i = min(int(age / BIN_S), len(self.histogram) - 1)
        self.histogram[i] += 1
        if i > self._top_bin:
            self._top_bin = i
        self.total_max_age = max(self.total_max_age, age)

    def _total_percentiles(self, *ps: float) -> list[float]:
        """Whole-run round-trip percentiles (s) from the histogram, one pass over its bins
        up to the highest one used (a pass over all 100 001 per percentile cost ~3 ms of
        the loop's thread once a second: ticks missed)."""
        cumulative = np.cumsum(self.histogram[:self._top_bin + 1])
        count = cumulative[-1]
        if count == 0:
            return [0.0 for _ in ps]
        indices = np.searchsorted(cumulative, [p / 100.0 * count for p in ps])
        return [(int(i) + 0.5) * BIN_S for i in indices]

    def report(self, now: float) -> list[float]:
        """Values of topics.PLANT_TIMING_FIELDS after ``stamp`` for the window ending ``now``
        (wall seconds); starts a new window."""
        start = self._window_start if self._window_start is not None else now
        elapsed = now - start
        ages = self._window_ages or [0.0]
        window_p50, window_p99 = percentiles(ages, 50, 99)
        total_p50, total_p99 = self._total_percentiles(50, 99)
        cycles = max(self._window_cycles, 1)
        values = [
            self._window_cycles / elapsed if elapsed > 0 else 0.0,
            float(self._window_cycles),
            self._window_fresh / cycles,
            window_p50 * 1e3,
            window_p99 * 1e3,
            max(ages) * 1e3,
            float(self.total_cycles),
            self.total_fresh / max(self.total_cycles, 1),
            float(self.total_cycles - self.total_fresh),
            total_p50 * 1e3,
            total_p99 * 1e3,
            self.total_max_age * 1e3,
            self._window_step_time / cycles * 1e6,
            self._window_publish_time / cycles * 1e6,
            float(self.safe_stop),
            float(self.commands_clipped),
            float(self.commands_refused),
            float(self.command_publishers),
            float(self.state_publishers),
            float(self.window_max_missed_run),
            float(self.safe_stop_reason),
            float(self.commands_foreign),
            float(self.commands_oversized),
            float(self.commander_handovers),
        ]
        self._window_ages.clear()
        self._window_cycles = self._window_fresh = 0
        self._window_step_time = self._window_publish_time = 0.0
        self.window_max_missed_run = 0
        self._window_start = now
        return values

    def start(self, now: float) -> None:
        """Begin the first window at ``now`` (wall seconds)."""
        self._window_start = now
