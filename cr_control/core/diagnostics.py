"""The levels of /diagnostics by stated rules, as diagnostic_updater would set them (no ROS).

Once a second the plant and every controller publish one ``diagnostic_msgs/DiagnosticStatus``
(in a ``DiagnosticArray`` on ``/diagnostics``, which ``rqt_robot_monitor`` and Foxglove
read): a level, a one-line message naming every rule that fired, and the figures as
key/values. The rules judge the last second (the window), so a level goes back to OK one
window after its cause is gone, except where the cause itself lasts (a safe stop, a
controller that stopped commanding); counts since the start are in the key/values.

Plant (:class:`PlantRules`, from the /plant/timing figures, ``topics.PLANT_TIMING_FIELDS``):

- ERROR: a safe stop is engaged (watchdog or a reflex; it lasts until ``resume``).
- WARN: in real time, the achieved rate below ``RATE_WARN_FRACTION`` of ``rate_hz`` or the
  share of ticks with a fresh command below ``FRESH_WARN_SHARE``; in lockstep, no step in
  the window (waiting for a command); in either mode, commands clipped, refused (bad,
  foreign or oversized) in the window, or more than one publisher on /joint_commands or
  /joint_states.
- OK otherwise.

Controller (:class:`ControllerRules`, from the node's counters and its compute times):

- ERROR: the law restored a non-finite internal state in the window, or it stopped
  commanding (``max_bad_cycles``: the node publishes no command).
- WARN: cycles held in the window (absurd input, non-finite or wrong-size output), compute
  p99 above ``COMPUTE_WARN_FRACTION`` of the period (the state stamps' spacing), no state in
  the window after states came, or states from a foreign publisher, oversized inputs or
  sensor faults in the window.
- OK otherwise (also before the first state: "waiting for states").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

#: diagnostic_msgs/DiagnosticStatus levels.
OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}

#: Plant, real time: WARN below this fraction of rate_hz (990 Hz at 1 kHz: the analysis's
#: "behind" line, cr_control.analysis.metrics.BEHIND_RATE_HZ).
RATE_WARN_FRACTION = 0.99
#: Plant, real time: WARN below this share of ticks applying a fresh command (the analysis's
#: BEHIND_FRESH_SHARE).
FRESH_WARN_SHARE = 0.95
#: Controller: WARN when the compute time's p99 over the window exceeds this fraction of
#: the period (near it: what is left of the period is too short for the round trip).
COMPUTE_WARN_FRACTION = 0.8


@dataclass
class Status:
    """One DiagnosticStatus: level, message, name, hardware id, key/values (strings)."""

    name: str
    hardware_id: str
    level: int = OK
    message: str = "OK"
    values: dict[str, str] = field(default_factory=dict)


def _judge(status: Status, errors: Sequence[str], warnings: Sequence[str], ok: str) -> Status:
    """Level = the worst rule that fired; message = those rules, worst first (else ``ok``)."""
    status.level = ERROR if errors else WARN if warnings else OK
    status.message = "; ".join([*errors, *warnings]) or ok
    return status


def _text(value: float) -> str:
    """A figure as a key/value string: integers without a point, others to 4 significant digits."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, int) or (math.isfinite(value) and value == int(value) and abs(value) < 1e15):
        return str(int(value))
    return f"{value:.4g}"


class _Deltas:
    """Increase of cumulative counters since the previous window."""

    def __init__(self) -> None:
        self._last: dict[str, float] = {}

    def __call__(self, name: str, total: float) -> float:
        previous = self._last.get(name, 0.0)
        self._last[name] = total
        return max(total - previous, 0.0)


class PlantRules:
    """The plant's status from one /plant/timing report (``figures``: field -> value)."""

    def __init__(self, name: str, hardware_id: str, rate_hz: float, realtime: bool,
                 safe_stop_reasons: Mapping[int, str]) -> None:
        self.name, self.hardware_id = name, hardware_id
        self.rate_hz, self.realtime = rate_hz, realtime
        self.reasons = safe_stop_reasons        #: safe_stop_reason -> words
        self._delta = _Deltas()

    def status(self, figures: Mapping[str, float]) -> Status:
        f = figures
        clipped = self._delta("commands_clipped", f["commands_clipped"])
        refused = self._delta("commands_refused", f["commands_refused"])
        foreign = self._delta("commands_foreign", f["commands_foreign"])
        oversized = self._delta("commands_oversized", f["commands_oversized"])
        errors, warnings = [], []
        if f["safe_stop"]:
            reason = self.reasons.get(int(f["safe_stop_reason"]), "unknown")
            errors.append(f"safe stop ({reason}): braking until resume")
        if self.realtime:
            if f["rate_hz"] < RATE_WARN_FRACTION * self.rate_hz:
                warnings.append(f"low rate {f['rate_hz']:.0f} Hz (< {RATE_WARN_FRACTION:g} x "
                                f"{self.rate_hz:g})")
            if f["window_fresh_share"] < FRESH_WARN_SHARE:
                warnings.append(f"fresh commands {100 * f['window_fresh_share']:.1f}% "
                                f"(< {100 * FRESH_WARN_SHARE:g}%)")
        elif f["window_cycles"] == 0:
            warnings.append("no step in the last window: waiting for a command")
        if clipped:
            warnings.append(f"{clipped:.0f} commands clipped")
        if refused + foreign + oversized:
            warnings.append(f"{refused + foreign + oversized:.0f} commands refused")
        if f["command_publishers"] > 1 or f["state_publishers"] > 1:
            warnings.append(f"{f['command_publishers']:.0f} command / {f['state_publishers']:.0f} "
                            "state publishers (expected 1)")
        values = {k: _text(v) for k, v in f.items()}
        values.update(mode="realtime" if self.realtime else "lockstep", rate_target_hz=_text(self.rate_hz),
                      window_commands_clipped=_text(clipped),
                      window_commands_refused=_text(refused + foreign + oversized))
        return _judge(Status(self.name, self.hardware_id, values=values), errors, warnings,
                      "running")


@dataclass
class ControllerWindow:
    """What a controller node counted in one window, and its counters since the start."""

    cycles: int                     #: states answered in the window
    compute_s: Sequence[float]      #: compute time of each of them (s)
    period_s: float                 #: spacing of the state stamps (s; nan if unknown)
    held_cycles: int                #: totals since the start, as the Controller counts them
    restored_cycles: int
    commanding: bool
    stops: int
    states_foreign: int
    inputs_oversized: int
    sensor_faults: int
    states_seen: bool               #: any state answered since the start
    active: bool = True             #: lifecycle state active (an inactive node answers none)
    #: publishers on /joint_states that the state reader did not match (not followed)
    unfollowed_publishers: int = 0


def nearest_rank(values: Sequence[float], *ps: float) -> list[float]:
    """The ``ps``-th percentiles of ``values`` by nearest rank, from one sort (nan if empty)."""
    ordered = sorted(values)
    n = len(ordered)
    return [ordered[min(n - 1, max(0, math.ceil(p / 100.0 * n) - 1))] if n else math.nan
            for p in ps]


class ControllerRules:
    """A controller's status from one window of its counters."""

    def __init__(self, name: str, hardware_id: str) -> None:
        self.name, self.hardware_id = name, hardware_id
        self._delta = _Deltas()

    def status(self, w: ControllerWindow) -> Status:
        held = self._delta("held", w.held_cycles)
        restored = self._delta("restored", w.restored_cycles)
        foreign = self._delta("foreign", w.states_foreign)
        oversized = self._delta("oversized", w.inputs_oversized)
        faults = self._delta("faults", w.sensor_faults)
        p50, p99, worst = nearest_rank(w.compute_s, 50, 99, 100)
        errors, warnings = [], []
        if restored:
            errors.append(f"{restored:.0f} cycles restored a non-finite internal state")
        if not w.commanding:
            errors.append("stopped commanding (max_bad_cycles or the start check): braking")
        if held:
            warnings.append(f"{held:.0f} cycles held")
        if p99 > COMPUTE_WARN_FRACTION * w.period_s:
            warnings.append(f"compute p99 {p99 * 1e6:.0f} us > {COMPUTE_WARN_FRACTION:g} x period "
                            f"{w.period_s * 1e6:.0f} us")
        if w.states_seen and w.cycles == 0 and w.active:
            warnings.append("no state in the last window")
        if foreign:
            warnings.append(f"{foreign:.0f} states from a foreign publisher")
        if w.unfollowed_publishers:
            warnings.append(f"{w.unfollowed_publishers} other state publisher(s), not followed")
        if oversized:
            warnings.append(f"{oversized:.0f} oversized inputs dropped")
        if faults:
            warnings.append(f"{faults:.0f} sensor faults")
        values = {
            "cycles": _text(w.cycles), "period_us": _text(w.period_s * 1e6),
            "compute_p50_us": _text(p50 * 1e6), "compute_p99_us": _text(p99 * 1e6),
            "compute_max_us": _text(worst * 1e6), "window_held_cycles": _text(held),
            "held_cycles": _text(w.held_cycles), "restored_cycles": _text(w.restored_cycles),
            "commanding": _text(w.commanding), "command_stops": _text(w.stops),
            "states_foreign": _text(w.states_foreign), "inputs_oversized": _text(w.inputs_oversized),
            "sensor_faults": _text(w.sensor_faults),
            "unfollowed_publishers": _text(w.unfollowed_publishers),
            "lifecycle": "active" if w.active else "inactive",
        }
        return _judge(Status(self.name, self.hardware_id, values=values), errors, warnings,
                      "inactive (lifecycle): no command" if not w.active else
                      "running" if w.states_seen else "waiting for states")
