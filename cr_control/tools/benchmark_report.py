"""The benchmark's targets and tables: the real-time layouts and their targets
(docs/benchmark.md), the cost targets carried to the "before" table's machine, and the text tables
:mod:`cr_control.tools.benchmark` prints (real time, speed, recorder load).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from cr_control.tools.benchmark_figures import (
    CLOCK_TICKS,
    ISSUE_BEFORE,
    REFERENCE_LOOP_NS,
    REFERENCE_REV,
    fmt,
    reference_scaled,
    scaled_cost,
    scaled_speed,
    verdict,
)


@dataclass
class Target:
    """One benchmark target: what is compared, the measured value, the limit, the verdict."""

    name: str
    value: float | None
    op: str
    limit: float | None
    unit: str = ""
    note: str = ""

    @property
    def verdict(self) -> str:
        return verdict(self.value, self.op, self.limit)

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "value": self.value, "op": self.op, "limit": self.limit,
                "unit": self.unit, "note": self.note, "verdict": self.verdict}


def realtime_targets(layout: str, session: dict[str, Any], echo: dict[str, Any],
                     rules: str | None = None) -> list[Target]:
    """The real-time targets of one layout: the session against the echo pair of the
    same layout, measured in the same run. ``rules``: whose targets ("processes", "composed"
    or "recorder"; default ``layout``'s own)."""
    rules = rules or layout
    fresh_pp = {"processes": 2.0, "composed": 1.0, "recorder": 2.0}[rules]
    out = [Target(f"{layout}: fresh command vs echo pair", session.get("fresh_diff_pp"), ">=",
                  -fresh_pp, " pp", f"within {fresh_pp:g} pp of the echo pair")]
    if rules == "recorder":
        out.append(Target(f"{layout}: achieved rate", session.get("rate_hz"), ">=",
                          echo.get("rate_hz"), " Hz", "at least the echo pair + recorder's"))
    else:
        out.append(Target(f"{layout}: achieved rate", session.get("rate_hz"), ">=", 990.0, " Hz"))
    if rules != "composed":
        out.append(Target(f"{layout}: round trip p99 vs echo pair", session.get("p99_ratio"), "<=",
                          1.5, "x"))
    return out


@dataclass(frozen=True)
class Layout:
    """A real-time layout: a session and the echo pair it is judged against (run in pairs)."""

    name: str                          # for --only, and the targets' prefix
    session_title: str
    echo_title: str
    composed: bool = False
    record: bool = False               # both with the recorder (the session's as cr_session runs it)
    robot: str | None = None           # the session on this robot's wiping task (cr_session --robot)
    echo_args: tuple[str, ...] = ()    # echo_pair options: its messages' shape
    rules: str | None = None           # whose real-time targets (realtime_targets); default its name
    compute_p50_us: float | None = None  # a limit on the controller's compute p50 in the node


#: The real-time layouts, in the order they run. The Panda publishes 9 joints (7 arm + 2
#: locked fingers, :mod:`cr_control.robots`) and is commanded 7: the echo pair carries
#: messages of that shape, with the recorder as beside the thesis arm; the targets
#: there: the recorder's, and the controller's compute p50 <= 100 us. The
#: UR5 runs at ur_robot_driver's 500 Hz (6 joints), its echo pair at the same rate; so do the
#: position-interface UR5 (the admittance outer loop: the law and its virtual arm stepped
#: twice a cycle, no compute limit set) and the xArm at xarm_ros2's 150 Hz (7 joints, the
#: law stepped seven times a cycle), each against an echo pair of its rate and shape.
LAYOUTS = (
    Layout("processes", "session processes", "echo processes"),
    Layout("composed", "session composed", "echo composed", composed=True),
    Layout("recorder", "session + recorder", "echo + recorder", record=True),
    Layout("panda", "session panda + recorder", "echo panda + recorder", record=True, robot="panda",
           echo_args=("--joints", "9", "--command-joints", "7", "--joint-prefix", "panda_"),
           rules="recorder", compute_p50_us=100.0),
    Layout("ur5", "session ur5 @ 500 Hz + recorder", "echo ur5 @ 500 Hz + recorder", record=True,
           robot="ur5", echo_args=("--joints", "6", "--command-joints", "6", "--joint-prefix",
                                   "ur5_", "--rate", "500"),
           rules="recorder", compute_p50_us=100.0),
    Layout("ur5_position", "session ur5_position @ 500 Hz + recorder",
           "echo ur5_position @ 500 Hz + recorder", record=True, robot="ur5_position",
           echo_args=("--joints", "6", "--command-joints", "6", "--joint-prefix", "ur5_",
                      "--rate", "500"), rules="recorder"),
    Layout("xarm7", "session xarm7 @ 150 Hz + recorder", "echo xarm7 @ 150 Hz + recorder",
           record=True, robot="xarm7", echo_args=("--joints", "7", "--command-joints", "7",
                                                  "--rate", "150"), rules="recorder"),
)


def select_layouts(only: Sequence[str] | None = None, skip: Sequence[str] = ()) -> list[Layout]:
    """The layouts named in ``only`` (all if None) but not in ``skip``, in :data:`LAYOUTS`' order."""
    return [lay for lay in LAYOUTS if (only is None or lay.name in only) and lay.name not in skip]


def layout_targets(layout: Layout, session: dict[str, Any], echo: dict[str, Any]) -> list[Target]:
    """The targets of one layout's row: the real-time ones (:func:`realtime_targets`) and,
    where the layout sets one, a limit on the controller's compute p50 in the node, as measured
    (not carried to another machine)."""
    out = realtime_targets(layout.name, session, echo, layout.rules)
    if layout.compute_p50_us is not None:
        out.append(Target(f"{layout.name}: controller compute p50 in the node", session.get("compute_p50_us"),
                          "<=", layout.compute_p50_us, " us", "as measured in this run, not scaled"))
    return out


#: The cost targets: (name, figure key in ISSUE_BEFORE, comparison, limit, unit).
COST_TARGETS = (
    ("controller compute p50 in the node", "compute_p50_us", "<=", 100.0, " us"),
    ("plant step, mean", "plant_step_us", "<=", 80.0, " us"),
    ("offline loop speed", "offline_speed", ">=", 10.0, "x"),
    ("lockstep composed speed", "lockstep_composed_speed", ">=", 2.0, "x"),
)


def cost_figures(session: dict[str, Any], lockstep_composed: dict[str, Any],
                 offline: dict[str, Any]) -> dict[str, float | None]:
    """The four figures the cost targets are about, by ISSUE_BEFORE's keys."""
    return {"compute_p50_us": session.get("compute_p50_us"), "plant_step_us": session.get("plant_step_us"),
            "offline_speed": offline.get("speed"), "lockstep_composed_speed": lockstep_composed.get("speed")}


def cost_targets(session: dict[str, Any], lockstep_composed: dict[str, Any],
                 offline: dict[str, Any], loop_ns: float | None,
                 reference: dict[str, Any] | None = None) -> list[Target]:
    """The cost targets. With ``reference`` (the "before" code measured in this run,
    :func:`run_reference`), on our figures carried to the issue's machine by that code's
    ratio (:func:`reference_scaled`), followed by the same targets by the loop-iteration
    scaling, marked "[loop scaling]"; without it, by the loop-iteration scaling alone."""
    ours = cost_figures(session, lockstep_composed, offline)
    loop_note = f"scaled to {REFERENCE_LOOP_NS:g} ns/loop iteration"
    out = []
    if reference and not reference.get("error"):
        rev = reference.get("rev", REFERENCE_REV)
        for name, key, op, limit, unit in COST_TARGETS:
            today, before = reference.get(key), ISSUE_BEFORE[key]
            note = f"x {fmt(before, '.3g')} / {fmt(today, '.3g')}: {rev} in the issue vs in this run"
            out.append(Target(name, reference_scaled(ours[key], today, before), op, limit, unit, note))
    suffix = " [loop scaling]" if out else ""
    for name, key, op, limit, unit in COST_TARGETS:
        scale = scaled_cost if unit == " us" else scaled_speed
        out.append(Target(name + suffix, scale(ours[key], loop_ns), op, limit, unit, loop_note))
    return out


def format_targets(targets: Sequence[Target]) -> str:
    """The targets as a text table: name, measured, required, verdict."""
    name_w = max([len("target"), *(len(t.name) for t in targets)])
    lines = ["target".ljust(name_w) + "measured".rjust(14) + "required".rjust(16) + "  verdict"]
    for t in targets:
        spec = ".2f" if t.unit in ("x", " pp") else ".1f"
        measured = fmt(t.value, spec, t.unit)
        required = f"{t.op} {fmt(t.limit, spec, t.unit)}"
        lines.append(t.name.ljust(name_w) + measured.rjust(14) + required.rjust(16) + f"  {t.verdict}"
                     + (f"  ({t.note})" if t.note else ""))
    return "\n".join(lines)


def recorder_window_cost(ticks0: int, ticks1: int, wall0_ns: int, wall1_ns: int,
                         log_times_ns: Sequence[int], clk_tck: float = CLOCK_TICKS) -> dict[str, float]:
    """The recorder's CPU per message between two samples of its CPU ticks taken at wall
    times ``wall0_ns`` < ``wall1_ns``; ``log_times_ns`` (sorted): the receive times of the
    messages it wrote."""
    wall = (wall1_ns - wall0_ns) / 1e9
    n = bisect.bisect_right(log_times_ns, wall1_ns) - bisect.bisect_right(log_times_ns, wall0_ns)
    cpu_s = (ticks1 - ticks0) / clk_tck
    return {"window_s": wall, "messages": n, "msgs_per_s": n / wall if wall > 0 else math.nan,
            "cpu_pct": 100.0 * cpu_s / wall if wall > 0 else math.nan,
            "us_per_msg": cpu_s * 1e6 / n if n > 0 else math.nan}


def samples_between(samples: Sequence[tuple[int, int | None]], lo_ns: int, hi_ns: int,
                    ) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """First and last (wall ns, ticks) sample with readable ticks inside [lo_ns, hi_ns]."""
    inside = [(t, v) for t, v in samples if v is not None and lo_ns <= t <= hi_ns]
    return (inside[0], inside[-1]) if len(inside) >= 2 else None


def cell(fig: dict[str, Any], key: str, spec: str, suffix: str = "") -> str:
    """A table cell of ``fig[key]``: "n/a" when the run measured the figure but a node did
    not publish it (the key is there, its value None); "-" when it does not apply."""
    if key in fig and fig[key] is None:
        return "n/a"
    return fmt(fig.get(key), spec, suffix)


# Rows of the real-time table: (label, key in a run's figures, format spec, suffix).
REALTIME_ROWS = [
    ("achieved rate (Hz)", "rate_hz", ".1f", ""),
    ("cycles", "cycles", ".0f", ""),
    ("round trip p50 (ms)", "rt_p50_ms", ".3f", ""),
    ("round trip p99 (ms)", "rt_p99_ms", ".3f", ""),
    ("round trip max (ms)", "rt_max_ms", ".2f", ""),
    ("fresh command (%)", "fresh_pct", ".2f", ""),
    ("cycles without fresh command", "missed_cycles", ".0f", ""),
    ("CPU plant / source (% core)", "cpu_state_pct", ".1f", ""),
    ("CPU controller / echo (% core)", "cpu_command_pct", ".1f", ""),
    ("CPU recorder (% core)", "cpu_recorder_pct", ".1f", ""),
    ("CPU total (% core)", "cpu_total_pct", ".1f", ""),
    ("CPU benchmark listener (% core)", "cpu_listener_pct", ".1f", ""),
    ("CPU anything else (% core)", "cpu_others_pct", ".1f", ""),
    ("CPU stolen by the hypervisor (% core)", "cpu_steal_pct", ".1f", ""),
    ("CPU/cycle plant / source (us)", "cycle_cpu_state_us", ".1f", ""),
    ("CPU/cycle controller / echo (us)", "cycle_cpu_command_us", ".1f", ""),
    ("CPU/cycle recorder (us)", "cycle_cpu_recorder_us", ".1f", ""),
    ("CPU/cycle total (us)", "cycle_cpu_total_us", ".1f", ""),
    ("CPU/cycle total, scaled (us)", "cycle_cpu_total_scaled_us", ".1f", ""),
    ("plant step, mean (us)", "plant_step_us", ".1f", ""),
    ("plant step, scaled (us)", "plant_step_scaled_us", ".1f", ""),
    ("plant publish, mean (us)", "plant_publish_us", ".1f", ""),
    ("controller in p50 (us)", "in_p50_us", ".1f", ""),
    ("controller compute p50 (us)", "compute_p50_us", ".1f", ""),
    ("controller compute p50, scaled (us)", "compute_p50_scaled_us", ".1f", ""),
    ("controller compute p99 (us)", "compute_p99_us", ".1f", ""),
    ("controller out p50 (us)", "out_p50_us", ".1f", ""),
    ("recorder messages/s", "recorder_msgs_per_s", ".0f", ""),
    ("recorder CPU/message (us)", "recorder_us_per_msg", ".1f", ""),
    ("recorder messages missed", "recorder_missed", ".0f", ""),
    ("vs baseline: fresh (pp)", "fresh_diff_pp", "+.2f", ""),
    ("vs baseline: round trip p99", "p99_ratio", ".2f", "x"),
    ("vs baseline: CPU total", "cpu_ratio", ".2f", "x"),
]


def format_realtime_table(runs: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """The real-time figures of ``runs`` ((column title, figures)) as a text table."""
    label_w = max(len(r[0]) for r in REALTIME_ROWS)
    widths = [max(14, len(title) + 2) for title, _ in runs]
    lines = ["".ljust(label_w) + "".join(title.rjust(w) for (title, _), w in zip(runs, widths, strict=True))]
    for label, key, spec, suffix in REALTIME_ROWS:
        cells = []
        for (_, fig), w in zip(runs, widths, strict=True):
            cells.append(("failed" if fig.get("error") and key == "rate_hz" else
                          cell(fig, key, spec, suffix)).rjust(w))
        lines.append(label.ljust(label_w) + "".join(cells))
    return "\n".join(lines)


def format_speed_table(rows: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """Lockstep / offline speeds ((title, figures)) as a text table."""
    head = ["", "simulated s", "wall s", "x real time", "x scaled", "cycles/s", "rt p50 (ms)",
            "rt p99 (ms)", "CPU (% core)", "others (%)", "stolen (%)"]
    title_w = max([len("offline loop (no ROS)"), *(len(t) for t, _ in rows)])
    out = [head[0].ljust(title_w) + "".join(h.rjust(13) for h in head[1:])]
    for title, fig in rows:
        if fig.get("error"):
            out.append(title.ljust(title_w) + "failed".rjust(13))
            continue
        cells = [fmt(fig.get("simulated_s"), ".2f"), fmt(fig.get("wall_s"), ".2f"),
                 fmt(fig.get("speed"), ".2f", "x"), fmt(fig.get("speed_scaled"), ".2f", "x"),
                 fmt(fig.get("rate_hz"), ".0f"),
                 fmt(fig.get("rt_p50_ms"), ".3f"), fmt(fig.get("rt_p99_ms"), ".3f"),
                 fmt(fig.get("cpu_total_pct"), ".0f"), fmt(fig.get("cpu_others_pct"), ".0f"),
                 fmt(fig.get("cpu_steal_pct"), ".0f")]
        out.append(title.ljust(title_w) + "".join(c.rjust(13) for c in cells))
    return "\n".join(out)


def format_recorder_load(rows: Sequence[tuple[str, dict[str, Any]]], loop_ns: float | None) -> str:
    """The recorder under synthetic load ((title, figures)) as a text table."""
    head = ["", "messages/s", "CPU (% core)", "us/message", "us/msg scaled", "published", "recorded",
            "lost", "missed (own)"]
    title_w = max([len("recorder, synthetic load"), *(len(t) for t, _ in rows)])
    out = [head[0].ljust(title_w) + "".join(h.rjust(14) for h in head[1:])]
    for title, fig in rows:
        if fig.get("error"):
            out.append(title.ljust(title_w) + "failed".rjust(14))
            continue
        cells = [fmt(fig.get("msgs_per_s"), ".0f"), fmt(fig.get("cpu_pct"), ".1f"),
                 fmt(fig.get("us_per_msg"), ".2f"), fmt(scaled_cost(fig.get("us_per_msg"), loop_ns), ".1f"),
                 fmt(fig.get("published"), "d"), fmt(fig.get("recorded"), "d"), fmt(fig.get("lost"), "d"),
                 fmt(fig.get("missed"), "d")]
        out.append(title.ljust(title_w) + "".join(c.rjust(14) for c in cells))
    return "\n".join(out)


def loop_figures(timing: dict[str, float] | None, done: tuple[float, float, int] | None) -> dict[str, Any]:
    """Whole-run loop figures from the last timing report and the "done:" line."""
    fig: dict[str, Any] = {}
    if done is not None:
        sim, wall, cycles = done
        fig.update(simulated_s=sim, wall_s=wall, cycles=cycles,
                   rate_hz=cycles / wall if wall > 0 else math.nan)
    if timing:
        fig.setdefault("cycles", int(timing.get("total_cycles", 0)))
        ages = [timing.get(k) for k in ("total_age_p50_ms", "total_age_p99_ms", "total_age_max_ms")]
        if not any(ages):  # no command ever came back: no round trip to report
            ages = [None, None, None]
        fig.update(rt_p50_ms=ages[0], rt_p99_ms=ages[1], rt_max_ms=ages[2],
                   fresh_pct=100.0 * timing.get("total_fresh_share", math.nan),
                   missed_cycles=timing.get("total_missed_cycles"), timing_covers_s=timing.get("stamp"))
    return fig
