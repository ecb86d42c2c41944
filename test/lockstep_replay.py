"""The offline run a lockstep session over ROS must reproduce, bit for bit: the one that read
what the controller node read.

The plant publishes each state's wrench before the state, and a controller node reads the
wrench it has when the state comes. Almost always that is the state's own; a wrench sample
lost on the way and resent (Fast DDS repairs a reliable sample only after a heartbeat), or
delivered after its state, leaves the node with an older one for a state or two, and the
runs part by a few 1e-5 N. The node reports the age of the wrench it read in its status
(``wrench_age_ms``); the comparison then replays those ages in the offline loop
(:func:`cr_control.offline.run`'s ``wrench_ages``) instead of asserting a race's outcome.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cr_control.offline import OfflineRun


def wrench_ages(status: dict[str, np.ndarray], rate_hz: float, steps: int) -> np.ndarray | None:
    """Per offline step, how many periods older than its state the wrench the node read was
    (-1: none yet), from the recorded status; None where it read every state's own (steps
    without a recorded status are taken as its own)."""
    ages_ms = status.get("wrench_age_ms")
    if ages_ms is None:
        return None
    rows = np.rint(status["stamp"] * rate_hz).astype(int)
    kept = (rows >= 0) & (rows < steps)
    ages = np.zeros(steps, dtype=int)
    ages[rows[kept]] = np.where(ages_ms[kept] < 0.0, -1, np.rint(ages_ms[kept] * rate_hz * 1e-3))
    return ages if ages.any() else None


def as_read(status: dict[str, np.ndarray], rate_hz: float, steps: int,
            offline: Callable[[np.ndarray | None], OfflineRun]) -> OfflineRun:
    """``offline(None)``, or, where the node read an older wrench, ``offline(ages)``: the
    offline run with the same wrench ages (printed, so a log shows when it happened)."""
    ages = wrench_ages(status, rate_hz, steps)
    if ages is not None:
        late = np.flatnonzero(ages)
        print(f"the controller read an older wrench at {len(late)} states (steps "
              f"{late[:10].tolist()}, ages {ages[late[:10]].tolist()} periods): replayed offline")
    return offline(ages)
