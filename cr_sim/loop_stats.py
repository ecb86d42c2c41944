"""Per-second and whole-run statistics of a state -> command loop (no ROS).

Round trip ("command age"): wall time from publishing a state to receiving the command
computed from it. A cycle is fresh when the command applied at a tick answers the state
published at the tick before. The plant node also reports its safety state here (safe
stop, commands clipped and refused, publishers on its topics): attributes it sets, so
every loop that uses these statistics publishes the same PLANT_TIMING_FIELDS.
"""

from __future__ import annotations

import numpy as np

BIN_S = 10e-6       # histogram resolution of whole-run round trips
MAX_AGE_S = 1.0     # longer round trips are counted in the last bin


class LoopStats:
    """Accumulates cycles, freshness and round trips; reports PLANT_TIMING_FIELDS values."""

    def __init__(self) -> None:
        self.histogram = np.zeros(int(MAX_AGE_S / BIN_S) + 1, dtype=np.int64)
        self.total_cycles = 0
        self.total_fresh = 0
        self.total_max_age = 0.0
        self._window_ages: list[float] = []
        self._window_cycles = 0
        self._window_fresh = 0
        self._window_step_time = 0.0
        self._window_publish_time = 0.0
        self._window_start: float | None = None
        #: Safety state, set by the plant node (0 where a loop has none).
        self.safe_stop = 0.0
        self.commands_clipped = 0
        self.commands_refused = 0
        self.command_publishers = 0
        self.state_publishers = 0
        #: Longest run of consecutive ticks without a new command in the window.
        self.window_max_missed_run = 0

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
        self.histogram[min(int(age / BIN_S), len(self.histogram) - 1)] += 1
        self.total_max_age = max(self.total_max_age, age)

    def _total_percentile(self, p: float) -> float:
        count = self.histogram.sum()
        if count == 0:
            return 0.0
        index = int(np.searchsorted(np.cumsum(self.histogram), p / 100.0 * count))
        return (index + 0.5) * BIN_S

    def report(self, now: float) -> list[float]:
        """Values of topics.PLANT_TIMING_FIELDS after ``stamp`` for the window ending ``now``
        (wall seconds); starts a new window."""
        start = self._window_start if self._window_start is not None else now
        elapsed = now - start
        ages = np.array(self._window_ages) if self._window_ages else np.zeros(1)
        cycles = max(self._window_cycles, 1)
        values = [
            self._window_cycles / elapsed if elapsed > 0 else 0.0,
            float(self._window_cycles),
            self._window_fresh / cycles,
            float(np.percentile(ages, 50)) * 1e3,
            float(np.percentile(ages, 99)) * 1e3,
            float(ages.max()) * 1e3,
            float(self.total_cycles),
            self.total_fresh / max(self.total_cycles, 1),
            float(self.total_cycles - self.total_fresh),
            self._total_percentile(50) * 1e3,
            self._total_percentile(99) * 1e3,
            self.total_max_age * 1e3,
            self._window_step_time / cycles * 1e6,
            self._window_publish_time / cycles * 1e6,
            float(self.safe_stop),
            float(self.commands_clipped),
            float(self.commands_refused),
            float(self.command_publishers),
            float(self.state_publishers),
            float(self.window_max_missed_run),
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
