"""What a control engineer asks first of a session (:func:`metrics`): RMS/max position and
force error, settling time, peak torque, compute time and loop timing percentiles, the
recording's integrity (cross-talk, restarts), and the metrics table of ``cr_analyze``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from cr_control.analysis import robot
from cr_control.analysis.session_file import CONTROL_ROLES, Session

#: Settling: ||e|| stays within max(SETTLING_FRACTION * ||e(t0)||, SETTLING_BAND_M).
SETTLING_FRACTION = 0.02
SETTLING_BAND_M = 1e-3


# -- metrics -----------------------------------------------------------------------------

def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else math.nan


def settling_time(t: np.ndarray, error_norm: np.ndarray) -> float:
    """Time from the first sample until ``error_norm`` stays within its settling band.

    The band is max(SETTLING_FRACTION * error_norm[0], SETTLING_BAND_M). Returns 0 if the
    error never leaves it and NaN if the last sample is outside it (not settled).
    """
    if not len(t):
        return math.nan
    band = max(SETTLING_FRACTION * float(error_norm[0]), SETTLING_BAND_M)
    outside = np.flatnonzero(error_norm > band)
    if not len(outside):
        return 0.0
    if outside[-1] == len(t) - 1:
        return math.nan
    return float(t[outside[-1] + 1] - t[0])


def _percentiles(prefix: str, values: np.ndarray, unit: str) -> dict[str, float]:
    values = values[np.isfinite(values)]
    if not len(values):
        return {}
    p50, p99 = np.percentile(values, [50, 99])
    return {f"{prefix}_p50_{unit}": float(p50), f"{prefix}_p99_{unit}": float(p99),
            f"{prefix}_max_{unit}": float(np.max(values))}


def metrics(session: Session) -> dict[str, Any]:
    """Tracking, torque, compute-time and loop-timing figures of merit (flat, SI units).

    Keys end with their unit. RMS and max are over samples; "last half" is the second
    half of the run in time. ``pos_err_*`` and settling are of the error norm over all
    position axes (x, y and, on a spatial arm, z); force errors and forces per axis.
    Settling: see :func:`settling_time`. A robot session adds the wiping task's metrics
    (:func:`cr_control.analysis.robot.robot_metrics`). Loop timing comes from the last
    plant timing message (whole-run totals) plus the mean of the per-second rates. Parts
    missing from the recording are absent from the result.
    """
    out: dict[str, Any] = {"controller": " -> ".join(session.controllers) or "-"}
    for t, name in session.switches:
        out[f"switch_to_{name}_at_s"] = float(t - session.status["stamp"][0])
    status = session.status
    if len(status.get("stamp", ())):
        t = status["stamp"]
        out["duration_s"] = float(t[-1] - t[0])
        out["samples"] = len(t)
        if "e_x" in status and "e_y" in status:
            e = robot.error_norm(status)
            last = t >= t[0] + 0.5 * (t[-1] - t[0])
            out["pos_err_rms_m"] = _rms(e)
            out["pos_err_max_m"] = float(np.max(e))
            out["pos_err_rms_last_half_m"] = _rms(e[last])
            out["pos_err_max_last_half_m"] = float(np.max(e[last]))
            out["settling_time_s"] = settling_time(t, e)
        for axis in robot.AXES:
            name = f"f_err_{axis}"
            if name in status:
                err = status[name]
                out[f"{name}_rms_N"] = _rms(err)
                out[f"{name}_max_N"] = float(np.max(err))
                out[f"{name}_min_N"] = float(np.min(err))
        for axis in robot.AXES:
            if f"f_{axis}" in status:
                out[f"f_{axis}_min_N"] = float(np.min(status[f"f_{axis}"]))
                out[f"f_{axis}_max_N"] = float(np.max(status[f"f_{axis}"]))
        out.update(robot.robot_metrics(session))
        if "compute_time_us" in status:
            out.update(_percentiles("compute_time", status["compute_time_us"], "us"))
        out.update(lateness_and_oscillation(status))
    commands = session.joint_commands
    if commands is not None and np.isfinite(commands.effort).any():
        for j, name in enumerate(commands.names):
            column = np.abs(commands.effort[:, j])
            if np.isfinite(column).any():
                out[f"tau_peak_{name}_Nm"] = float(np.nanmax(column))
    else:
        for name in sorted(k for k in status if k.startswith("tau_")):
            out[f"{name}_peak_Nm"] = float(np.max(np.abs(status[name])))
    timing = session.timing
    if len(timing.get("stamp", ())):
        last = {name: float(values[-1]) for name, values in timing.items()}
        if "rate_hz" in timing:
            out["loop_rate_hz"] = last["rate_hz"]
            out["loop_rate_mean_hz"] = float(np.mean(timing["rate_hz"]))
        for source, key in (("total_cycles", "loop_cycles"),
                            ("total_fresh_share", "loop_fresh_share"),
                            ("total_missed_cycles", "loop_missed_cycles"),
                            ("total_age_p50_ms", "loop_age_p50_ms"),
                            ("total_age_p99_ms", "loop_age_p99_ms"),
                            ("total_age_max_ms", "loop_age_max_ms")):
            if source in last:
                value = last[source]
                out[key] = int(value) if key.endswith("cycles") else value
    out.update(integrity(session))
    return out


def lateness_and_oscillation(status: dict[str, np.ndarray]) -> dict[str, float]:
    """What a transport delay or late answers do, as the controller saw them: the command
    age (``command_age``, control periods the command in force had stood when each state
    came: 1 when every state is answered; p50, p99, max) and the lightest joint's oscillation
    (``joint_oscillation``: the RMS of its velocity above 5 Hz over 0.1 s, as a fraction of
    its velocity limit; p50, p99, max), with the smallest ``joint_scale`` the
    contact-stability monitor set (1: it never acted), and the wrench's age (``wrench_age_ms``:
    how much older the wrench the law read was than the state it answered; p50, p99, max).
    Absent where the status has none."""
    out: dict[str, float] = {}
    if "command_age" in status:
        age = status["command_age"]
        out.update(_percentiles("command_age", age[age > 0.0], "cycles"))
    if "wrench_age_ms" in status:
        age = status["wrench_age_ms"]
        out.update(_percentiles("wrench_age", age[age >= 0.0], "ms"))
    if "joint_oscillation" in status:
        out.update(_percentiles("joint_oscillation", status["joint_oscillation"], "of_limit"))
    if "joint_scale" in status and len(status["joint_scale"]):
        out["joint_scale_min"] = float(np.min(status["joint_scale"]))
    return out


def integrity(session: Session) -> dict[str, int]:
    """Is the recording one session's own? Publishers per control topic (where known; a
    live switch's controllers each have a /joint_commands publisher),
    stamps going backwards or repeating on the joint topics, and ``data_warnings``: how
    many of those look wrong (see :func:`integrity_warnings`)."""
    out = {f"publishers_{role}": session.publishers[role]
           for role in CONTROL_ROLES if role in session.publishers}
    if len(session.controllers) > 1:    # a live switch: each controller has its publisher
        out["publishers_expected_joint_commands"] = len(session.controllers)
    for role in ("joint_states", "joint_commands"):
        series = getattr(session, role)
        if series is not None:
            out[f"stamps_backwards_{role}"] = series.stamps_backwards
            out[f"stamps_repeated_{role}"] = series.stamps_repeated
    out["data_warnings"] = len(integrity_warnings(out))
    return out


def integrity_warnings(values: dict[str, Any]) -> list[str]:
    """One sentence per integrity problem in metrics ``values`` (see :func:`integrity`)."""
    found = []
    for role in CONTROL_ROLES:
        count = values.get(f"publishers_{role}", 1)
        if count > values.get(f"publishers_expected_{role}", 1):
            found.append(f"{count} publishers on /{role}: another run shares this "
                         "ROS_DOMAIN_ID (cross-talk); its data is mixed in")
    for role in ("joint_states", "joint_commands"):
        backwards = values.get(f"stamps_backwards_{role}", 0)
        repeated = values.get(f"stamps_repeated_{role}", 0)
        if backwards:
            found.append(f"stamps on /{role} went backwards {backwards} times: a second "
                         "publisher (cross-talk) or a restarted plant")
        if repeated:
            found.append(f"stamps on /{role} repeated {repeated} times: a second publisher, "
                         "or states resent by a stalled lockstep loop")
    return found


#: A real-time loop "fell behind" below these (docs/benchmark.md's targets for this machine).
BEHIND_FRESH_SHARE = 0.95
BEHIND_RATE_HZ = 990.0


def loop_summary(values: dict[str, Any], realtime: bool = True) -> list[str]:
    """The plant loop in one line, then a plain warning if a real-time loop fell behind
    (rate below BEHIND_RATE_HZ or fewer than BEHIND_FRESH_SHARE of the cycles with a command
    computed from the state before). Empty without plant timing."""
    if "loop_fresh_share" not in values:
        return []
    rate = values.get("loop_rate_mean_hz", values.get("loop_rate_hz", math.nan))
    fresh = values["loop_fresh_share"]
    lines = [f"loop: {rate:.1f} Hz, {100 * fresh:.2f} % of cycles with a fresh command, "
             f"round trip p50/p99 {values.get('loop_age_p50_ms', math.nan):.3f}/"
             f"{values.get('loop_age_p99_ms', math.nan):.3f} ms"]
    if realtime and (fresh < BEHIND_FRESH_SHARE or rate < BEHIND_RATE_HZ):
        lines.append(f"WARNING: the real-time loop fell behind ({rate:.0f} Hz, "
                     f"{100 * (1 - fresh):.1f} % of cycles applied a stale command): the "
                     "machine was too busy for 1 kHz; see the timing plot and `make benchmark`")
    return lines


def _format_value(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool | int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return "n/a" if math.isnan(value) else f"{value:.4g}"
    return str(value)


def format_metrics(rows: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """An aligned text table: one row per metric, one column per (name, metrics) pair."""
    keys: list[str] = []
    for _, values in rows:
        keys += [k for k in values if k not in keys]
    table = [["metric", *(name for name, _ in rows)]]
    table += [[key, *(_format_value(values.get(key)) for _, values in rows)] for key in keys]
    widths = [max(len(line[i]) for line in table) for i in range(len(table[0]))]
    lines = ["  ".join(cell.ljust(w) if i == 0 else cell.rjust(w)
                       for i, (cell, w) in enumerate(zip(line, widths, strict=True))).rstrip()
             for line in table]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines += [f"WARNING: {name}: {text}" for name, values in rows
              for text in integrity_warnings(values)]
    return "\n".join(lines)
