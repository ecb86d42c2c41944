"""cr_fuzz's verdicts: what a case's recording says (:class:`Row`, :func:`judge`) and whether
it survived (:func:`verdict`): alive, finite, no safe stop, the controller commanding at the
end, its speed and force against the suite's baseline run, and against the robot's own
limits (the joints' speed share of their URDF velocity limits, a fixed force cap, and on a
position interface the commanded positions: finite, no step beyond one period of the
joint's velocity limit). The rules are stated in :mod:`cr_control.tools.fuzz`'s docstring.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from cr_control.robots import ROBOTS
from cr_control.tools.fuzz_case import Case

#: A case's max |q'| may exceed the baseline run's by this factor plus SPEED_FLOOR.
SPEED_MARGIN = 1.2
SPEED_FLOOR = 0.05
#: The speed is judged from this many seconds after the first state (start transients).
SETTLE_S = 1.0
#: "resumed": the last timing window's share of fresh cycles at least this fraction of the
#: baseline run's median window (the baseline: its own). A fixed 90 % failed the baseline
#: itself on a loaded day (its windows 54-92 %, 2026-11-25), and so did "10 pp below".
RESUMED_SHARE = 0.5
#: A timing window of fewer cycles (the plant's closing report) is not judged.
FULL_WINDOW_CYCLES = 100
#: A force-judged case's largest true contact force may exceed the baseline's by this factor
#: plus FORCE_FLOOR (N).
FORCE_MARGIN = 1.2
FORCE_FLOOR = 2.0


#: A commanded position's step may exceed one period of its joint's velocity limit by this
#: share (rounding: the command stream is limited to exactly that step).
JUMP_TOLERANCE = 1e-6

#: Counters that show an input refused: the plant's (/plant/timing), the controller's status.
PLANT_COUNTERS = ("commands_refused", "commands_foreign", "commands_oversized",
                  "commander_handovers")
CONTROLLER_COUNTERS = ("states_foreign", "inputs_oversized", "sensor_faults", "commands_stopped")


@dataclass
class Row:
    """What a case's recording says."""

    case: str
    alive: bool
    finite: bool
    max_speed: float
    safe_stop: bool
    resumed: bool
    miss_ms: float
    note: str = ""
    verdict: str = ""
    #: What the nodes counted (nonzero counters of /plant/timing and the controller's
    #: status) and the parameter answers: the evidence that the input was refused.
    seen: str = ""
    #: The median window's share of fresh commands (the reference of the cases' "resumed").
    fresh_median: float = math.nan
    #: The largest true contact force after the first second (N; /plant/contact_wrench,
    #: NaN if the plant publishes none).
    max_force: float = math.nan
    #: The largest joint speed after the first second as a share of the joint's URDF
    #: velocity limit (NaN on a thesis plant).
    speed_share: float = math.nan
    #: The robot's command interface ("" on a thesis plant); on "position": every commanded
    #: position finite, and the largest step between consecutive commands in control periods
    #: of the joint's velocity limit (NaN: fewer than two commands).
    interface: str = ""
    commands_finite: bool = True
    command_jump: float = math.nan
    #: Why and by when the safe stop engaged ("watchdog, by 1.0 s": the plant's reason and the
    #: end of the first timing window that reported it, from the first state).
    safe_stop_why: str = ""
    #: The first recorded state's stamp (s; real time: the wall clock's).
    first_state: float = math.nan


def commanding_at_end(fresh: np.ndarray, stopped: np.ndarray, reference: float,
                      cycles: np.ndarray | None = None) -> bool:
    """The controller commands at the end: its commands not stopped, and the last timing
    window's fresh share at least RESUMED_SHARE of ``reference``. With the windows'
    ``cycles``, the last window of at least FULL_WINDOW_CYCLES: the plant's closing report
    covers the few cycles after the last full second (17 of them, 0 % fresh, in one run),
    which says nothing about the controller."""
    if cycles is not None and len(cycles) == len(fresh):
        fresh = fresh[np.asarray(cycles) >= FULL_WINDOW_CYCLES]
    return bool(len(fresh) and len(stopped) and stopped[-1] == 0
                and fresh[-1] >= RESUMED_SHARE * reference)


@cache
def velocity_limits(robot: str) -> dict[str, float]:
    """Joint name -> URDF velocity limit (rad/s or m/s) of ``robot``'s chain."""
    from cr_control.models.urdf import load_chain

    r = ROBOTS[robot]
    chain = load_chain("", r.urdf_file, r.base_link, r.tip_link)
    return dict(zip(chain.joint_names, map(float, chain.limits.velocity), strict=True))


def limits_of(robot: str, names: list[str]) -> np.ndarray:
    """The velocity limits of the joints ``names`` (inf for a joint not in the chain)."""
    limits = velocity_limits(robot)
    return np.array([limits.get(name, math.inf) for name in names])


def command_steps(position: np.ndarray, limits: np.ndarray, period: float) -> tuple[bool, float]:
    """(every commanded position finite, the largest step between consecutive commands in
    units of ``period`` times the joint's velocity limit) of the commands' ``position``
    (rows: messages in order; a row of NaN carried no position and is left out)."""
    position = position[~np.all(np.isnan(position), axis=1)]
    finite = bool(np.isfinite(position).all())
    if len(position) < 2:
        return finite, math.nan
    with np.errstate(invalid="ignore"):
        steps = np.abs(np.diff(position, axis=0)) / (limits * period)
    return finite, float(np.nanmax(steps)) if (~np.isnan(steps)).any() else math.nan


def judge_robot(row: Row, session, robot: str | None) -> None:
    """Fill ``row``'s judgments against ``robot``'s own limits: the joints' speed share of
    their velocity limits and, on a position interface, the commanded positions."""
    if robot is None:
        return
    states, commands = session.joint_states, session.joint_commands
    if states is not None and len(states.time):
        late = states.time >= states.time[0] + SETTLE_S
        if late.any():
            share = np.abs(states.velocity[late]) / limits_of(robot, states.names)
            row.speed_share = float(np.nanmax(share))
    row.interface = ROBOTS[robot].command_interface
    if row.interface == "position" and commands is not None:
        row.commands_finite, row.command_jump = command_steps(
            commands.position, limits_of(robot, commands.names), 1.0 / ROBOTS[robot].rate_hz)


def safe_stop_why(timing: dict[str, np.ndarray], start: float) -> str:
    """The plant's reason for its first safe stop and by when (s from ``start``)."""
    from cr_sim.loop_stats import SAFE_STOP_REASONS

    first = int(np.flatnonzero(timing["safe_stop"] > 0)[0])
    reason = timing.get("safe_stop_reason", np.zeros(first + 1))[first]
    return f"{SAFE_STOP_REASONS.get(int(reason), 'unknown')}, by {timing['stamp'][first] - start:.1f} s"


def judge(recording: Path | None, case: str, alive: bool, note: str,
          reference: float | None = None, robot: str | None = None) -> Row:
    """The row of a case from its recording (None: nothing recorded); ``reference``: the
    baseline's median fresh share (None: the run's own, for the baseline); ``robot``: the
    session's robot profile (None: a thesis plant), whose limits judge_robot reads."""
    from cr_control.analysis.analyze import load_session
    from cr_control.analysis.session_file import SessionError

    if recording is None or not recording.exists():
        return Row(case, alive, False, math.nan, False, False, math.nan, note or "no recording")
    try:
        session = load_session(recording)
    except SessionError as exc:              # e.g. a session that never started: no messages
        return Row(case, alive, False, math.nan, False, False, math.nan,
                   note or str(exc).rsplit(": ", 1)[-1])
    states, timing = session.joint_states, session.timing
    # Rows with none of the plant's joints (a 10 MB state of other names) carry no value.
    finite = states is not None
    if states is not None:
        carried = ~np.all(np.isnan(states.position), axis=1)
        finite = bool(np.isfinite(states.position[carried]).all()
                      and np.isfinite(states.velocity[carried]).all())
    speed = math.nan
    if states is not None and len(states.time):
        late = states.time >= states.time[0] + SETTLE_S
        speed = float(np.nanmax(np.abs(states.velocity[late]))) if late.any() else math.nan
    safe_stop = bool(np.any(timing.get("safe_stop", np.zeros(1)) > 0))
    fresh = timing.get("window_fresh_share", np.zeros(0))
    stopped = session.status.get("commands_stopped", np.zeros(1))
    median = float(np.median(fresh)) if len(fresh) else math.nan
    resumed = commanding_at_end(fresh, stopped, median if reference is None else reference,
                                timing.get("window_cycles"))
    miss = timing.get("window_max_missed_run", np.full(1, math.nan))
    counted = [f"{name} {int(np.nanmax(values[name]))}" for values, names in (
        (timing, PLANT_COUNTERS), (session.status, CONTROLLER_COUNTERS))
        for name in names if name in values and np.nanmax(values[name]) > 0]
    held = int(np.sum(session.status.get("held", np.zeros(0)) > 0))
    counted += [f"held cycles {held}"] if held else []
    sources = int(np.nanmax(timing.get("state_publishers", np.zeros(1))))
    counted += [f"state_publishers {sources}"] if sources > 1 else []   # the rest unfollowed
    force = math.nan
    contact = session.contact_wrench
    if contact is not None and states is not None and len(contact.time) and len(states.time):
        late = contact.time >= states.time[0] + SETTLE_S
        force = float(np.nanmax(np.linalg.norm(contact.force[late], axis=1))) if late.any() \
            else math.nan
    row = Row(case, alive, finite, speed, safe_stop, resumed, float(np.nanmax(miss)), note,
              seen=", ".join(counted), fresh_median=median, max_force=force)
    if states is not None and len(states.time):
        row.first_state = float(states.time[0])
    if safe_stop:
        row.safe_stop_why = safe_stop_why(timing, row.first_state)
    judge_robot(row, session, robot)
    return row


def verdict(row: Row, case: Case, baseline: Row | None) -> str:
    """``survived`` or ``FAILED: <first reason>``."""
    reasons = [text for bad, text in (
        (not row.alive, "a process died"), (not row.finite, "non-finite state"),
        (row.safe_stop, "safe stop" + (f" ({row.safe_stop_why})" if row.safe_stop_why else "")),
        (not row.resumed, "controller not commanding at the end"))
        if bad]
    if baseline is not None and case.name != baseline.case:
        allowed = baseline.max_speed * SPEED_MARGIN + SPEED_FLOOR
        if case.speed_judged and not row.max_speed <= allowed:
            reasons.append(f"max |q'| {row.max_speed:.3g} > {allowed:.3g} (baseline's)")
        allowed_force = baseline.max_force * FORCE_MARGIN + FORCE_FLOOR
        if case.force_judged and not row.max_force <= allowed_force:
            reasons.append(f"max |f| {row.max_force:.3g} N > {allowed_force:.3g} N (baseline's)")
        if case.miss_margin is not None and not row.miss_ms <= baseline.miss_ms + case.miss_margin:
            reasons.append(f"missed {row.miss_ms:.0f} ms > baseline {baseline.miss_ms:.0f} + "
                           f"{case.miss_margin:.0f}")
    reasons += robot_reasons(row, case)
    return f"FAILED: {reasons[0]}" if reasons else "survived"


def robot_reasons(row: Row, case: Case) -> list[str]:
    """Why ``row`` breaks what ``case`` holds it to against the robot's own limits (empty: it
    does not): the joints' speed share, the contact force, the commanded positions."""
    reasons = []
    share = case.speed_limit_share
    if share is not None and not row.speed_share <= share:
        reasons.append(f"a joint at {row.speed_share:.3g} of its velocity limit > {share:g}")
    if case.force_limit is not None and not row.max_force <= case.force_limit:
        reasons.append(f"max |f| {row.max_force:.3g} N > {case.force_limit:g} N")
    if case.commands_judged and row.interface == "position":
        if not row.commands_finite:
            reasons.append("a non-finite commanded position")
        elif not row.command_jump <= 1.0 + JUMP_TOLERANCE:
            reasons.append(f"a commanded position jumped {row.command_jump:.3g} periods of "
                           "its velocity limit")
    return reasons
