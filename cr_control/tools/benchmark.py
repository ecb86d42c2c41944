"""Real-time figures of cr_control against a bare rclpy echo pair, in one run.

Runs, one after another, each on a ROS_DOMAIN_ID of its own (localhost discovery):

1. a real-time session (plant + ``adaptive_impedance`` controller) across processes,
   against the bare echo pair (:mod:`cr_control.tools.echo_pair`: same messages, QoS and
   executor, no math) across processes;
2. the same two in one process each (composed);
3. the session with the recorder exactly as ``make demo`` runs it (cr_session's
   recorder, its parameters and topics) against the echo pair plus the same recorder
   recording the echo pair's topics;
4. the same on the Panda (``cr_session --robot panda``: 9 joints in /joint_states, 7
   commanded, 3-D status and reference) against the echo pair carrying messages of the
   Panda's shape, with the same recorder (issue 20: real time at 7 joints);
5. the recorder alone under a synthetic load (a recorded session's 1 kHz topics): its
   CPU per message, and whether it lost any;
6. lockstep sessions (across processes and composed) and the offline loop (no ROS):
   how many times faster than real time the same plant and controller run.

Two ways to carry the cost figures to the machine the targets of issue 6 are stated for:

- **by the issue's own code** (default; ``--reference REV``): the code the issue measured
  (:data:`REFERENCE_REV`, taken from this repository's git history) runs its own benchmark
  in this run, and each of our cost figures is multiplied by that code's figure in the
  issue's "before" table (:data:`ISSUE_BEFORE`) over the same figure measured now. This
  compares like with like on the same machine in the same run.
- **by a calibration** (ns per plain Python loop iteration, µs per Pinocchio ABA call on
  the 2-link arm), measured at the start and the end of the run: costs × reference /
  calibration, speeds × calibration / reference, for :data:`REFERENCE_LOOP_NS` ns per
  loop iteration. Printed as "[loop scaling]"; it describes pure interpreter work, not
  compiled kernels or rclpy's C paths, and it does not reproduce the issue's own figures
  (docs/benchmark.md, "Real time").

Every target is printed with its measured value and PASS/FAIL. With ``--repeat N`` each
session/echo pair runs N times in ABBA order and the tables and targets show medians (of
the pairwise differences and ratios for the "vs baseline" rows), each repeat printed. A
pair during whose session or echo run other processes and the hypervisor's steal took
more than :data:`DISTURBED_PCT` of a core measured the machine's neighbours, not the
loop: it is printed as discarded and run again, at most ``--retries`` times per layout
(the machine's own counts, ``/proc/stat``; the same rule for session and echo pair).

Whole-run loop figures come from the last ``/plant/timing`` message (``total_*`` fields)
and the plant's "done:" log line; CPU is read from ``/proc/<pid>/stat`` (utime + stime)
between the first and the last timing message, so start-up and shutdown are excluded,
and divided by the cycles counted between them (CPU per control cycle); "anything else"
is the machine's busy time (``/proc/stat``) not spent by the run and "stolen" the time
the hypervisor gave to other machines while ours wanted to run, to flag runs disturbed
by other work. Where a cycle's time goes is read by name from the plant timing
(``step_time_us``, ``publish_time_us``) and the controller status (``in_time_us``,
``compute_time_us``, ``out_time_us``), "n/a" where a node does not publish a field. The
status is read by a best-effort raw subscriber in this process (~5% of a core, shown as
"benchmark listener"; ``--no-compute-time`` turns it off).

    cr_benchmark                         # ~4 min on a 2-core machine
    cr_benchmark --repeat 3              # ~8 min: the figures of docs/benchmark.md
    cr_benchmark --duration 5 --json /tmp/bench.json --skip-offline
    cr_benchmark --only-recorder-load    # the recorder's CPU per message, ~15 s
    cr_benchmark --only panda --repeat 1 --duration 5    # one layout's pair alone, ~20 s
"""

from __future__ import annotations

import argparse
import bisect
import io
import json
import math
import os
import re
import struct
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from array import array
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cr_control.core import topics
from cr_control.core.ros_env import (
    DOMAIN_SPAN,
    FIRST_DOMAIN,
    DomainBusyError,
    claim_consecutive_domains,
    claim_free_domain,
    isolate_this_process,
    isolated_env,
)
from cr_control.tools.echo_pair import parse_result
from cr_control.tools.session import (
    STARTUP_TIMEOUT_S,
    ProcessGroup,
    Session,
    SessionConfig,
    SessionError,
    session_parameters,
)
from cr_sim.loop_stats import percentiles

SCHEME = "adaptive_impedance"
#: CPU taken by other processes and by the hypervisor's steal (% of one core) above which
#: a run is disturbed: flagged, and a session/echo pair with a disturbed run is run again
#: (at most ``--retries`` times per layout).
DISTURBED_PCT = 20.0
#: ns per plain Python loop iteration of the machine the cost targets are stated for.
REFERENCE_LOOP_NS = 300.0
#: The code issue 6 measured its "before" table on (the last commit before the work on it).
REFERENCE_REV = "0659bc7"
#: That code's figures in the issue's "before" table: the machine the cost targets are for.
ISSUE_BEFORE = {"compute_p50_us": 382.0, "plant_step_us": 247.0, "offline_speed": 2.6,
                "lockstep_composed_speed": 0.90}
#: The recorder executable's module (``--recorder-module`` swaps it, for A/B comparisons).
RECORDER_MODULE = "cr_control.recording.recorder"
#: Timing fields of the controller status read by name (absent ones print "n/a").
STATUS_TIME_FIELDS = ("in_time_us", "compute_time_us", "out_time_us")

DONE_RE = re.compile(r"done: ([\d.eE+-]+) s simulated in ([\d.eE+-]+) s wall, (\d+) cycles")
PUBLISHED_RE = re.compile(r"published: (\d+) messages")
RECORDER_RE = re.compile(r"recorder: wrote (\d+) messages to .*?(?:; (\d+) missed|$)", re.MULTILINE)


# -- pure helpers (tested without ROS) ------------------------------------------------
def parse_proc_stat(text: str) -> int:
    """utime + stime (clock ticks) from the text of ``/proc/<pid>/stat``.

    The command name (field 2) is in parentheses and may hold spaces or ')'; the fields
    after its last ')' start with field 3 (state), so utime (14) and stime (15) are the
    12th and 13th of them.
    """
    rest = text[text.rindex(")") + 1:].split()
    return int(rest[11]) + int(rest[12])


def read_cpu_ticks(pid: int | str) -> int | None:
    """CPU time (clock ticks) used so far by process ``pid`` ("self" for this one); None if gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return parse_proc_stat(f.read())
    except (OSError, ValueError, IndexError):
        return None


def parse_machine_stat(text: str, steal: bool = False) -> int:
    """Clock ticks of all CPUs together from the text of ``/proc/stat`` (its "cpu" line):
    busy ones (user, nice, system, irq, softirq; idle, iowait and steal left out), or with
    ``steal`` the ticks the hypervisor gave to other machines while ours wanted to run."""
    for line in text.splitlines():
        if line.startswith("cpu "):
            v = [int(x) for x in line.split()[1:]]
            if steal:
                return v[7] if len(v) > 7 else 0
            return v[0] + v[1] + v[2] + v[5] + v[6]
    raise ValueError("no aggregate cpu line")


def read_machine_ticks(steal: bool = False) -> int | None:
    """Busy (or, with ``steal``, stolen) clock ticks of the whole machine so far (None where
    there is no /proc/stat)."""
    try:
        with open("/proc/stat") as f:
            return parse_machine_stat(f.read(), steal)
    except (OSError, ValueError, IndexError):
        return None


MACHINE = "machine"
STEAL = "steal"
LISTENER = "listener"

CLOCK_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def cpu_percent(ticks0: int, ticks1: int, wall_s: float, clk_tck: float = CLOCK_TICKS) -> float:
    """Share of one core (%) used between two tick counts ``wall_s`` seconds apart."""
    if wall_s <= 0:
        return math.nan
    return 100.0 * (ticks1 - ticks0) / clk_tck / wall_s


def cpu_from_samples(samples: Sequence[tuple[float, dict[str, int | None]]],
                     min_window_s: float = 0.5) -> dict[str, float]:
    """% of one core per process from (wall time, {name: ticks or None}) samples: each process
    between its first and last readable sample, if they are at least ``min_window_s`` apart
    (clock ticks are 10 ms: a shorter window says nothing)."""
    first: dict[str, tuple[float, int]] = {}
    last: dict[str, tuple[float, int]] = {}
    for t, ticks in samples:
        for name, value in ticks.items():
            if value is None:
                continue
            first.setdefault(name, (t, value))
            last[name] = (t, value)
    out = {}
    for name, (t0, v0) in first.items():
        t1, v1 = last[name]
        if t1 - t0 >= min_window_s:
            out[name] = cpu_percent(v0, v1, t1 - t0)
    return out


def cpu_per_cycle(samples: Sequence[dict[str, int | None]], cycles: Sequence[float],
                  clk_tck: float = CLOCK_TICKS, min_cycles: float = 200) -> dict[str, float]:
    """µs of CPU per control cycle of each process: ``samples[i]`` are the tick counts
    ({name: ticks or None}) taken when the loop had run ``cycles[i]`` cycles in all; each
    process between its first and last readable sample, if at least ``min_cycles`` cycles
    apart (the same figure as CPU% × 10 / rate in kHz, without the rate's rounding)."""
    first: dict[str, tuple[int, float]] = {}
    last: dict[str, tuple[int, float]] = {}
    for ticks, n in zip(samples, cycles, strict=True):
        for name, value in ticks.items():
            if value is None:
                continue
            first.setdefault(name, (value, n))
            last[name] = (value, n)
    out = {}
    for name, (v0, n0) in first.items():
        v1, n1 = last[name]
        if n1 - n0 >= min_cycles:
            out[name] = (v1 - v0) / clk_tck * 1e6 / (n1 - n0)
    return out


def parse_done_line(text: str) -> tuple[float, float, int] | None:
    """(simulated s, wall s, cycles) from the last plant/source "done:" log line, or None."""
    matches = DONE_RE.findall(text)
    if not matches:
        return None
    sim, wall, cycles = matches[-1]
    return float(sim), float(wall), int(cycles)


def parse_published(text: str) -> int | None:
    """Messages the synthetic load published, from its "published:" log line, or None."""
    matches = PUBLISHED_RE.findall(text)
    return int(matches[-1]) if matches else None


def parse_recorder_missed(text: str) -> int | None:
    """Messages the recorder saw the middleware drop (its exit line: "N missed"), 0 if it
    reported none, None if it did not exit cleanly."""
    matches = RECORDER_RE.findall(text)
    if not matches:
        return None
    return int(matches[-1][1] or 0)


def timing_dict(label: str, data: Sequence[float]) -> dict[str, float]:
    """A labelled /plant/timing array as {field: value}."""
    return dict(zip(topics.fields_of(label), (float(v) for v in data), strict=False))


def window_mean(reports: Sequence[dict[str, float]], name: str) -> float | None:
    """Mean of a per-window mean field (e.g. ``step_time_us``) over timing reports, weighted
    by their ``window_cycles``; None when no report carries the field."""
    pairs = [(r[name], r.get("window_cycles", 0.0)) for r in reports if name in r]
    cycles = sum(n for _, n in pairs)
    if not pairs or cycles <= 0:
        return None
    return sum(v * n for v, n in pairs) / cycles


def last_double(buf: bytes, count_from_end: int) -> float:
    """The double ``count_from_end`` places from the end of a CDR-serialised message whose
    last member is a float64 sequence (e.g. Float64MultiArray), honouring the
    encapsulation's endianness and end padding."""
    little = buf[1] & 1
    padding = buf[3] & 0x3
    end = len(buf) - padding
    return struct.unpack_from("<d" if little else ">d", buf, end - 8 * count_from_end)[0]


def offsets_from_end(fields: Sequence[str], names: Sequence[str]) -> dict[str, int]:
    """{name: position counted from the end of the data} of those ``names`` in ``fields``."""
    return {name: len(fields) - fields.index(name) for name in names if name in fields}


def scaled_cost(value: float | None, loop_ns: float | None,
                reference_ns: float = REFERENCE_LOOP_NS) -> float | None:
    """A time measured on a machine of ``loop_ns`` per loop iteration, on the reference one."""
    if not _finite(value) or not _finite(loop_ns) or loop_ns <= 0:
        return None
    return value * reference_ns / loop_ns


def scaled_speed(value: float | None, loop_ns: float | None,
                 reference_ns: float = REFERENCE_LOOP_NS) -> float | None:
    """A speed (× real time) measured at ``loop_ns`` per loop iteration, on the reference one."""
    if not _finite(value) or not _finite(loop_ns) or loop_ns <= 0:
        return None
    return value * loop_ns / reference_ns


def reference_scaled(value: float | None, today: float | None, before: float | None) -> float | None:
    """One of our figures as it would read on the machine of issue 6's "before" table:
    ``value`` × ``before`` / ``today``, where ``today`` is the same figure of the code the
    issue measured (:data:`REFERENCE_REV`), measured in this run, and ``before`` the issue's.
    Costs and speeds alike: the ratio of ours to that code's is what carries over."""
    if not (_finite(value) and _finite(today) and _finite(before)) or today <= 0:
        return None
    return value * before / today


#: Per-repeat figures kept beside the medians (printed as the spread of a repeated run).
REPEAT_KEYS = ("rate_hz", "fresh_pct", "rt_p99_ms", "fresh_diff_pp", "p99_ratio", "cpu_others_pct",
               "cpu_steal_pct")


def median_figures(figs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One run's figures from repeats of it: per key the median of the finite numbers
    (nested dicts key by key), other values from the first repeat; ``repeats`` keeps each
    repeat's :data:`REPEAT_KEYS`, ``error`` joins the failed repeats' errors."""
    if len(figs) == 1:
        return dict(figs[0])
    out = _medians(figs)
    out["repeats"] = [{k: fig.get(k) for k in REPEAT_KEYS} for fig in figs]
    errors = [fig["error"] for fig in figs if fig.get("error")]
    out.pop("error", None)
    if errors:
        out["error"] = "; ".join(errors)
    return out


def _medians(figs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in dict.fromkeys(k for fig in figs for k in fig):
        values = [fig.get(key) for fig in figs]
        numbers = sorted(v for v in values if _finite(v))
        dicts = [v for v in values if isinstance(v, dict)]
        if numbers:
            mid = len(numbers) // 2
            out[key] = numbers[mid] if len(numbers) % 2 else (numbers[mid - 1] + numbers[mid]) / 2
        elif dicts:
            out[key] = _medians(dicts)
        else:
            out[key] = next((v for v in values if v is not None), None)
    return out


def format_repeats(runs: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """Each repeat of the repeated sessions: rate, fresh share and p99 against its echo pair."""
    lines = []
    for title, fig in runs:
        if not fig.get("repeats") or not title.startswith("session"):
            continue
        cells = [f"{fmt(r.get('rate_hz'), '.1f')} Hz {fmt(r.get('fresh_diff_pp'), '+.2f')} pp "
                 f"p99 {fmt(r.get('p99_ratio'), '.2f')}x" for r in fig["repeats"]]
        lines.append(f"{title} vs its echo pair, each repeat: " + "; ".join(cells))
    for title, fig in runs:
        for d in fig.get("discarded") or []:
            lines.append(f"{title} pair #{d['pair']} discarded (session: {_taken(d, 'cpu_')}; "
                         f"echo pair: {_taken(d, 'echo_')}): {fmt(d.get('rate_hz'), '.1f')} Hz "
                         f"{fmt(d.get('fresh_diff_pp'), '+.2f')} pp p99 {fmt(d.get('p99_ratio'), '.2f')}x")
    return "\n".join(lines)


RunFn = Callable[[str], dict[str, Any]]


def run_pairs(run_session: RunFn, run_echo: RunFn, repeat: int, retries: int,
              progress: Callable[[str], None]) -> tuple[list[dict], list[dict], list[dict]]:
    """``repeat`` session/echo pairs of one layout in ABBA order (each run function takes
    the pair's tag, " #1", " #2", ...). A pair with a :func:`disturbed` run (other
    processes and the hypervisor's steal above :data:`DISTURBED_PCT` of a core) is run
    again, ``retries`` times at most; returns the sessions (with :func:`ratios` to their
    echo pair), the echo pairs, and the discarded pairs (their :data:`REPEAT_KEYS` and the
    echo run's CPU taken by others and by steal)."""
    sessions: list[dict] = []
    echoes: list[dict] = []
    discarded: list[dict] = []
    attempt = 0
    while len(sessions) < repeat:
        attempt += 1
        tag = "" if repeat == 1 and attempt == 1 else f" #{attempt}"
        if attempt % 2:      # ABBA order: a drift of the machine hits both alike
            session, echo = run_session(tag), run_echo(tag)
        else:
            echo, session = run_echo(tag), run_session(tag)
        session.update(ratios(session, echo))
        if (disturbed(session) or disturbed(echo)) and len(discarded) < retries:
            discarded.append({"pair": attempt, "echo_others_pct": echo.get("cpu_others_pct"),
                              "echo_steal_pct": echo.get("cpu_steal_pct"),
                              **{k: session.get(k) for k in REPEAT_KEYS}})
            progress(f"pair #{attempt} disturbed: {_taken(session, 'cpu_')} (session), "
                     f"{_taken(echo, 'cpu_')} (echo pair): discarded, run again")
            continue
        sessions.append(session)
        echoes.append(echo)
    return sessions, echoes, discarded


def _taken(fig: dict[str, Any], prefix: str) -> str:
    return (f"others {fmt(fig.get(prefix + 'others_pct'), '.0f')} %, steal "
            f"{fmt(fig.get(prefix + 'steal_pct'), '.0f')} % of a core")


def disturbed(fig: dict[str, Any]) -> bool:
    """Whether other processes and the hypervisor's steal together took more than
    :data:`DISTURBED_PCT` of a core during a run."""
    return (fig.get("cpu_others_pct") or 0.0) + (fig.get("cpu_steal_pct") or 0.0) > DISTURBED_PCT


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def ratios(run: dict[str, Any], baseline: dict[str, Any]) -> dict[str, float]:
    """A run against the baseline of the same layout: fresh share difference (percentage
    points), p99 round trip ratio, total CPU ratio."""
    out = {"fresh_diff_pp": math.nan, "p99_ratio": math.nan, "cpu_ratio": math.nan}
    if _finite(run.get("fresh_pct")) and _finite(baseline.get("fresh_pct")):
        out["fresh_diff_pp"] = run["fresh_pct"] - baseline["fresh_pct"]
    if _finite(run.get("rt_p99_ms")) and _finite(baseline.get("rt_p99_ms")) and baseline["rt_p99_ms"] > 0:
        out["p99_ratio"] = run["rt_p99_ms"] / baseline["rt_p99_ms"]
    if _finite(run.get("cpu_total_pct")) and _finite(baseline.get("cpu_total_pct")) \
            and baseline["cpu_total_pct"] > 0:
        out["cpu_ratio"] = run["cpu_total_pct"] / baseline["cpu_total_pct"]
    return out


def verdict(value: Any, op: str, limit: Any) -> str:
    """"PASS" when ``value op limit`` holds (op ">=" or "<="), "FAIL" when not, "n/a" when
    either is missing or not finite."""
    if not _finite(value) or not _finite(limit):
        return "n/a"
    if op == ">=":
        return "PASS" if value >= limit else "FAIL"
    if op == "<=":
        return "PASS" if value <= limit else "FAIL"
    raise ValueError(f"unknown comparison {op!r}")


@dataclass
class Target:
    """One target of issue 6: what is compared, the measured value, the limit, the verdict."""

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
    """Issue 6's real-time targets of one layout: the session against the echo pair of the
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
    rules: str | None = None           # whose issue 6 targets (realtime_targets); default its name
    compute_p50_us: float | None = None  # a limit on the controller's compute p50 in the node


#: The real-time layouts, in the order they run. The Panda publishes 9 joints (7 arm + 2
#: locked fingers, :mod:`cr_control.tools.robots`) and is commanded 7: the echo pair carries
#: messages of that shape, with the recorder as beside the thesis arm; issue 20 (item 7)
#: asks for issue 6's recorder targets and the controller's compute p50 <= 100 us there.
LAYOUTS = (
    Layout("processes", "session processes", "echo processes"),
    Layout("composed", "session composed", "echo composed", composed=True),
    Layout("recorder", "session + recorder", "echo + recorder", record=True),
    Layout("panda", "session panda + recorder", "echo panda + recorder", record=True, robot="panda",
           echo_args=("--joints", "9", "--command-joints", "7", "--joint-prefix", "panda_"),
           rules="recorder", compute_p50_us=100.0),
)


def select_layouts(only: Sequence[str] | None = None, skip: Sequence[str] = ()) -> list[Layout]:
    """The layouts named in ``only`` (all if None) but not in ``skip``, in :data:`LAYOUTS`' order."""
    return [lay for lay in LAYOUTS if (only is None or lay.name in only) and lay.name not in skip]


def layout_targets(layout: Layout, session: dict[str, Any], echo: dict[str, Any]) -> list[Target]:
    """The targets of one layout's row: issue 6's real-time ones (:func:`realtime_targets`) and,
    where the layout sets one, a limit on the controller's compute p50 in the node, as measured
    (not carried to another machine)."""
    out = realtime_targets(layout.name, session, echo, layout.rules)
    if layout.compute_p50_us is not None:
        out.append(Target(f"{layout.name}: controller compute p50 in the node", session.get("compute_p50_us"),
                          "<=", layout.compute_p50_us, " us", "as measured in this run, not scaled"))
    return out


#: Issue 6's cost targets: (name, figure key in ISSUE_BEFORE, comparison, limit, unit).
COST_TARGETS = (
    ("controller compute p50 in the node", "compute_p50_us", "<=", 100.0, " us"),
    ("plant step, mean", "plant_step_us", "<=", 80.0, " us"),
    ("offline loop speed", "offline_speed", ">=", 10.0, "x"),
    ("lockstep composed speed", "lockstep_composed_speed", ">=", 2.0, "x"),
)


def cost_figures(session: dict[str, Any], lockstep_composed: dict[str, Any],
                 offline: dict[str, Any]) -> dict[str, float | None]:
    """The four figures issue 6's cost targets are about, by ISSUE_BEFORE's keys."""
    return {"compute_p50_us": session.get("compute_p50_us"), "plant_step_us": session.get("plant_step_us"),
            "offline_speed": offline.get("speed"), "lockstep_composed_speed": lockstep_composed.get("speed")}


def cost_targets(session: dict[str, Any], lockstep_composed: dict[str, Any],
                 offline: dict[str, Any], loop_ns: float | None,
                 reference: dict[str, Any] | None = None) -> list[Target]:
    """Issue 6's cost targets. With ``reference`` (the issue's own code measured in this run,
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


def fmt(value: Any, spec: str = ".1f", suffix: str = "") -> str:
    """A table cell: formatted number, "-" when missing / not finite."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, str):
        return value
    return f"{value:{spec}}{suffix}"


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


# -- calibration ---------------------------------------------------------------------------
def loop_ns_per_iteration(n: int = 300_000, repeats: int = 7) -> float:
    """ns per iteration of ``for i in range(n): pass``, best of ``repeats``."""
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _i in range(n):
            pass
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e9


def aba_us_per_call(n: int = 2000, repeats: int = 5) -> float | None:
    """µs per Pinocchio ABA call (TwoLinkArm.forward_dynamics), best of ``repeats``."""
    try:
        import numpy as np

        from cr_control.models.arm_model import TwoLinkArm
    except ImportError:
        return None
    arm = TwoLinkArm()
    q, v, tau = np.array([0.3, 0.5]), np.array([0.1, -0.2]), np.array([0.5, 0.1])
    fd = arm.forward_dynamics
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _i in range(n):
            fd(q, v, tau)
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def step_us_hot_and_after_idle(cycles: int = 400, idle_s: float = 0.0009) -> dict[str, float]:
    """Median µs of one ``Controller.step`` of the scheme back to back ("hot") and after
    sleeping ``idle_s`` before each, as a node does between its 1 kHz states ("after
    idle"): on a virtual machine the second is several times the first (caches and
    predictors go cold while the vCPU idles), which is why the compute time in a node
    exceeds the offline one."""
    import numpy as np

    from cr_control.schemes.registry import make_controller

    controller = make_controller(SCHEME)
    controller.log_warning = lambda _message: None
    q, v, force = np.array([0.3, 0.4]), np.zeros(2), np.zeros(3)
    out = {}
    stamp = 0.0
    for label, idle in (("step_hot_us", 0.0), ("step_after_idle_us", idle_s)):
        times = []
        for _ in range(cycles):
            if idle:
                time.sleep(idle)
            stamp += 1e-3
            t0 = time.perf_counter_ns()
            controller.step(stamp, q, v, force)
            times.append(time.perf_counter_ns() - t0)
        out[label] = percentiles(times, 50)[0] / 1e3
    return out


def warm_up(robots: Sequence[str] = ()) -> None:
    """A few offline cycles of the scheme in this process, on its thesis plant and on each of
    ``robots``: compiled kernels are built and cached (numba ``cache=True``) before the runs,
    so that no run's first cycle compiles."""
    from cr_control.tools.offline import run_scheme

    run_scheme(SCHEME, 0.01)
    for robot in robots:
        run_scheme(SCHEME, 0.01, robot=robot)


def calibrate() -> dict[str, float | None]:
    """This machine's speed now: ns per plain loop iteration, µs per ABA call, µs per
    controller step hot and after idling (:func:`step_us_hot_and_after_idle`)."""
    return {"loop_ns": loop_ns_per_iteration(), "aba_us": aba_us_per_call(), **step_us_hot_and_after_idle()}


def mcap_log_times(path: Path) -> list[int]:
    """Sorted log (receive) times of every message of an MCAP file, from its message
    indexes (no chunk is decompressed); from the messages themselves if it has no summary."""
    from mcap.opcode import Opcode
    from mcap.reader import make_reader

    times = array("q")
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None or not summary.chunk_indexes:
            times.extend(m.log_time for _, _, m in reader.iter_messages(log_time_order=False))
        else:
            for index in summary.chunk_indexes:
                for offset in index.message_index_offsets.values():
                    f.seek(offset)
                    opcode, _length, _channel, size = struct.unpack("<BQHI", f.read(15))
                    if opcode != Opcode.MESSAGE_INDEX:
                        continue
                    pairs = array("q")
                    pairs.frombytes(f.read(size))
                    if sys.byteorder != "little":
                        pairs.byteswap()
                    times.extend(pairs[0::2])
    return sorted(times)


# -- ROS side: a listener in this process ----------------------------------------------
class Listener:
    """One node on ``domain_id`` in its own context, spun by an EventsExecutor in a thread.

    Keeps every /plant/timing report and, on each, samples the CPU time of the
    processes ``pids()`` names (and of this process); optionally the controller's
    timing fields (:data:`STATUS_TIME_FIELDS`) from its status topic (best effort, raw
    CDR: cheap).
    """

    def __init__(self, domain_id: int, pids: Callable[[], dict[str, int]],
                 status_topic: str | None = None):
        import rclpy
        from rclpy.context import Context
        from rclpy.experimental import EventsExecutor
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from rclpy.task import Future
        from std_msgs.msg import Float64MultiArray

        from cr_control.nodes.qos import CONTROL_QOS

        self._rclpy = rclpy
        self.pids = pids
        self.timing: list[tuple[float, dict[str, float]]] = []
        self.cpu_samples: list[tuple[float, dict[str, int | None]]] = []
        self.wall_ns: list[int] = []  # time.time_ns() of each CPU sample
        self.status: dict[str, array] = {}
        self.status_received = 0
        self._offsets: dict[str, int] | None = None  # field -> position from the end of data
        self._status_raw_ok = True
        self._msg_cls = Float64MultiArray
        isolate_this_process(domain_id)  # localhost discovery for this process too
        self.context = Context()
        # No rclpy signal handlers: Ctrl-C must reach the benchmark as KeyboardInterrupt.
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node("cr_benchmark", context=self.context)
        self.node.create_subscription(Float64MultiArray, topics.PLANT_TIMING, self._on_timing,
                                      CONTROL_QOS)
        if status_topic:
            best_effort = QoSProfile(depth=topics.QOS_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)
            self.node.create_subscription(Float64MultiArray, status_topic, self._on_status, best_effort,
                                          raw=True)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = Future()
        self._thread = threading.Thread(target=self._spin, name="cr_benchmark_listener", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while self.context.ok() and not self._stop.done():
            try:
                self.executor.spin_until_future_complete(self._stop, timeout_sec=0.25)
            except Exception:  # noqa: BLE001 - shutting down
                break

    def _on_timing(self, msg) -> None:
        now = time.monotonic()
        label = msg.layout.dim[0].label if msg.layout.dim else ""
        self.timing.append((now, timing_dict(label, msg.data)))
        ticks: dict[str, int | None] = {name: read_cpu_ticks(pid) for name, pid in list(self.pids().items())}
        ticks[LISTENER] = read_cpu_ticks("self")
        ticks[MACHINE] = read_machine_ticks()
        ticks[STEAL] = read_machine_ticks(steal=True)
        self.cpu_samples.append((now, ticks))
        self.wall_ns.append(time.time_ns())

    def _on_status(self, buf: bytes) -> None:
        self.status_received += 1
        if self._offsets is None or not self._status_raw_ok:
            from rclpy.serialization import deserialize_message

            msg = deserialize_message(buf, self._msg_cls)
            fields = topics.fields_of(msg.layout.dim[0].label if msg.layout.dim else "")
            offsets = offsets_from_end(fields, STATUS_TIME_FIELDS)
            n = len(msg.data)
            if len(fields) != n:
                return
            values = {name: float(msg.data[n - k]) for name, k in offsets.items()}
            if self._offsets is None:
                self._offsets = offsets
                try:
                    self._status_raw_ok = all(
                        struct.pack("d", last_double(buf, k)) == struct.pack("d", values[name])
                        for name, k in offsets.items())
                except (struct.error, IndexError):
                    self._status_raw_ok = False
            for name, value in values.items():
                self.status.setdefault(name, array("d")).append(value)
            return
        for name, k in self._offsets.items():
            self.status.setdefault(name, array("d")).append(last_double(buf, k))

    def last_timing(self) -> dict[str, float] | None:
        return self.timing[-1][1] if self.timing else None

    def close(self) -> None:
        if not self._stop.done():
            self._stop.set_result(True)
        self._thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


class TickSampler:
    """Samples the CPU ticks of ``pids()`` every ``period`` s in a thread: [(wall ns, ticks)]."""

    def __init__(self, pids: Callable[[], dict[str, int]], period: float = 0.2):
        self.pids = pids
        self.period = period
        self.samples: list[tuple[int, dict[str, int | None]]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="cr_benchmark_sampler", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            ticks = {n: read_cpu_ticks(p) for n, p in list(self.pids().items())}
            self.samples.append((time.time_ns(), ticks))

    def of(self, name: str) -> list[tuple[int, int | None]]:
        """(wall ns, ticks) samples of one process."""
        return [(t, ticks.get(name)) for t, ticks in self.samples]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


# -- runs --------------------------------------------------------------------------------
@dataclass
class Progress:
    """Prints which run is going and for how long (stderr)."""

    stream: Any = sys.stderr
    run: str = ""
    t0: float = field(default_factory=time.monotonic)

    def begin(self, run: str) -> None:
        self.run, self.t0 = run, time.monotonic()
        self("starting")

    def __call__(self, line: str) -> None:
        elapsed = time.monotonic() - self.t0
        print(f"[{self.run} {elapsed:5.1f} s] {line.strip()}", file=self.stream, flush=True)


def _steady_figures(listener: Listener | None, names: dict[str, str],
                    mcap: Path | None = None) -> dict[str, Any]:
    """CPU (% core and µs per cycle) per role (names: role -> process name), where a cycle's
    time goes, and the recorder's CPU per message (``mcap``: its file) from the listener."""
    fig: dict[str, Any] = {}
    if listener is None:
        return fig
    cpu = cpu_from_samples(listener.cpu_samples)
    ours = {k: v for k, v in cpu.items() if k not in (LISTENER, MACHINE, STEAL)}
    for role, proc in names.items():
        fig[f"cpu_{role}_pct"] = cpu.get(proc)
    fig["cpu_total_pct"] = sum(ours.values()) if ours else None
    fig["cpu_listener_pct"] = cpu.get(LISTENER)
    fig["cpu_per_process_pct"] = ours
    if MACHINE in cpu:
        fig["cpu_others_pct"] = max(0.0, cpu[MACHINE] - sum(ours.values()) - cpu.get(LISTENER, 0.0))
    fig["cpu_steal_pct"] = cpu.get(STEAL)
    reports = [t for _, t in listener.timing]
    cycles = [t.get("total_cycles", math.nan) for t in reports]
    per_cycle = cpu_per_cycle([{k: v for k, v in ticks.items() if k not in (LISTENER, MACHINE, STEAL)}
                               for _, ticks in listener.cpu_samples], cycles)
    fig["cycle_cpu_per_process_us"] = per_cycle
    for role, proc in names.items():
        fig[f"cycle_cpu_{role}_us"] = per_cycle.get(proc)
    fig["cycle_cpu_total_us"] = sum(per_cycle.values()) if per_cycle else None
    fig["timing_reports"] = len(reports)
    if mcap is not None and "recorder" in names:
        fig.update(_recorder_in_window(listener, names["recorder"], mcap))
    return fig


def _recorder_in_window(listener: Listener, proc: str, mcap: Path) -> dict[str, Any]:
    samples = [(t, ticks.get(proc)) for t, (_, ticks) in zip(listener.wall_ns, listener.cpu_samples,
                                                              strict=True)]
    window = samples_between(samples, 0, 2**63 - 1)
    if window is None or not mcap.exists():
        return {"recorder_us_per_msg": None}
    try:
        log_times = mcap_log_times(mcap)
    except Exception as exc:  # noqa: BLE001 - a broken file is a finding, not a crash
        return {"recorder_us_per_msg": None, "recorder_error": f"cannot read {mcap}: {exc}"}
    (t0, v0), (t1, v1) = window
    cost = recorder_window_cost(v0, v1, t0, t1, log_times)
    return {"recorder_us_per_msg": cost["us_per_msg"], "recorder_msgs_per_s": cost["msgs_per_s"],
            "recorder_messages_written": len(log_times)}


def _time_breakdown(listener: Listener | None, controller: bool) -> dict[str, Any]:
    """Plant step/publish means and controller in/compute/out percentiles; None where a
    field is not published (printed "n/a")."""
    fig: dict[str, Any] = {}
    if listener is None:
        return fig
    reports = [t for _, t in listener.timing]
    fig["plant_step_us"] = window_mean(reports, "step_time_us")
    fig["plant_publish_us"] = window_mean(reports, "publish_time_us")
    if controller:
        for name, key in (("in_time_us", "in"), ("compute_time_us", "compute"), ("out_time_us", "out")):
            values = listener.status.get(name)
            fig[f"{key}_p50_us"], fig[f"{key}_p99_us"] = (percentiles(values, 50, 99) if values
                                                           else (None, None))
        fig["compute_samples"] = len(listener.status.get("compute_time_us", ()))
    return fig


def run_session(title: str, domain: int, out: Path, duration: float, mode: str, composed: bool,
                progress: Progress, compute_time: bool, record: bool = False,
                overrides: Sequence[str] = (), robot: str | None = None) -> dict[str, Any]:
    """One session (with the recorder as ``make demo`` runs it if ``record``; on ``robot``'s
    wiping task if given); its loop, CPU, time breakdown and, recorded, the recorder's CPU per
    message. ``overrides``: cr_session's ``NODE.PARAM=VALUE`` settings."""
    progress.begin(title)
    name = re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")
    session = Session(SessionConfig(scheme=SCHEME, duration=duration, mode=mode, composed=composed,
                                    overrides=list(overrides),
                                    record=record, out=out, domain_id=domain, name=name, robot=robot),
                      progress=progress)
    listener = None
    fig: dict[str, Any] = {"domain_id": domain, "logs": str(session.logs), "recorder": record, "robot": robot}
    try:
        listener = Listener(domain, lambda: {k: p.pid for k, p in list(session.processes.items())},
                            topics.status_topic(SCHEME) if compute_time and mode == "realtime" else None)
        session.run()
    except (SessionError, OSError) as exc:
        fig["error"] = str(exc)
        progress(f"FAILED: {exc}")
    finally:
        if listener is not None:
            time.sleep(0.2)
            listener.close()
    main = "container" if composed else "plant"
    log = session.logs / f"{main}.log"
    done = parse_done_line(log.read_text(errors="replace")) if log.exists() else None
    fig.update(loop_figures(listener.last_timing() if listener else None, done))
    roles = {} if composed else {"state": "plant", "command": SCHEME}
    if record:
        roles["recorder"] = "recorder"
        fig["mcap"] = str(session.mcap)
        fig["recorder_missed"] = _recorder_missed(session.logs / "recorder.log")
    fig.update(_steady_figures(listener, roles, session.mcap if record else None))
    fig.update(_time_breakdown(listener, controller=compute_time and mode == "realtime"))
    if listener is not None:
        fig["status_received"] = listener.status_received
    if done is None and "error" not in fig:
        fig["error"] = f"no 'done:' line in {log}"
    if "simulated_s" in fig and fig.get("wall_s"):
        fig["speed"] = fig["simulated_s"] / fig["wall_s"]
    return fig


def _write_recorder_params(path: Path, mcap: Path, record_topics: list[str], nodes: list[str]) -> None:
    import yaml

    path.write_text(yaml.safe_dump({"recorder": {"ros__parameters": {
        "output": str(mcap), "topics": record_topics, "parameter_nodes": nodes,
        "ready_timeout": 30.0}}}, sort_keys=False))


def run_echo(title: str, domain: int, out: Path, duration: float, composed: bool,
             progress: Progress, rate_hz: float = 1000.0, record: bool = False,
             recorder_module: str = RECORDER_MODULE, echo_args: Sequence[str] = ()) -> dict[str, Any]:
    """The bare echo pair, across two processes or in one (with ``record``: plus the
    session's recorder recording its topics); its loop and CPU figures. ``echo_args``:
    echo_pair options of both its processes (its messages' shape)."""
    progress.begin(title)
    logs = out / re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")
    logs.mkdir(parents=True, exist_ok=True)
    env = isolated_env(domain)
    env.setdefault("PYTHONUNBUFFERED", "1")
    progress(f"echo pair {logs} (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, "
             f"discovery {env['ROS_AUTOMATIC_DISCOVERY_RANGE']})")
    group = ProcessGroup(logs, env, progress)
    mcap = logs / "echo.mcap"

    def start(name: str, role: str) -> None:
        # The source starts once the listener (and the recorder) subscribe to its timing.
        extra = [] if role == "echo" else ["--timing-subscribers", str(1 + record)] + (
            ["--wait-for-recorder"] if record else [])
        group.start(name, [sys.executable, "-m", "cr_control.tools.echo_pair", role,
                           "--duration", str(duration), "--rate", str(rate_hz), *echo_args, *extra])

    fig: dict[str, Any] = {"domain_id": domain, "logs": str(logs), "recorder": record,
                           "echo_args": list(echo_args)}
    listener = Listener(domain, lambda: {k: p.pid for k, p in list(group.processes.items())})
    main_name = "echo_pair" if composed else "source"
    try:
        if record:
            params = logs / "recorder.yaml"
            _write_recorder_params(params, mcap, [topics.JOINT_STATES, topics.WRENCH, topics.JOINT_COMMANDS,
                                                  topics.PLANT_TIMING], ["echo_source", "echo"])
            group.start("recorder", [sys.executable, "-m", recorder_module, "--ros-args",
                                     "--params-file", str(params)])
            fig["mcap"] = str(mcap)
        if composed:
            start(main_name, "both")
        else:
            start("echo", "echo")
            start(main_name, "source")
        group.wait(main_name, STARTUP_TIMEOUT_S + 2 * duration, "] [echo_source]: t=")
    except SessionError as exc:
        fig["error"] = f"{exc}; logs in {logs}"
        progress(f"FAILED: {exc}")
    finally:
        time.sleep(0.2)
        listener.close()
        group.stop()
    text = (logs / f"{main_name}.log").read_text(errors="replace")
    result = parse_result(text)
    done = parse_done_line(text)
    fig.update(loop_figures(result or listener.last_timing(), done))
    roles = {} if composed else {"state": "source", "command": "echo"}
    if record:
        roles["recorder"] = "recorder"
        fig["recorder_missed"] = _recorder_missed(logs / "recorder.log")
    fig.update(_steady_figures(listener, roles, mcap if record else None))
    publish = window_mean([t for _, t in listener.timing], "publish_time_us")
    if _finite(publish):  # the source's own publish time: the floor under the plant's
        fig["plant_publish_us"] = publish
    if done is None and "error" not in fig:
        fig["error"] = f"no 'done:' line in {logs / main_name}.log"
    return fig


def run_recorder_load(title: str, domain: int, out: Path, duration: float, progress: Progress,
                      recorder_module: str = RECORDER_MODULE, rate_hz: float = 1000.0) -> dict[str, Any]:
    """The recorder as a session runs it, under the synthetic load of the echo pair's
    ``synthetic`` role (a session's five 1 kHz topics, the timing report, parameter
    events): its CPU per message in the steady part and how many messages it lost."""
    progress.begin(title)
    logs = out / re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")
    logs.mkdir(parents=True, exist_ok=True)
    env = isolated_env(domain)
    env.setdefault("PYTHONUNBUFFERED", "1")
    group = ProcessGroup(logs, env, progress)
    mcap = logs / "load.mcap"
    params = logs / "recorder.yaml"
    record_topics = [topics.JOINT_STATES, topics.WRENCH, topics.JOINT_COMMANDS, topics.PLANT_TIMING,
                     topics.PARAMETER_EVENTS, topics.reference_topic(SCHEME), topics.status_topic(SCHEME)]
    _write_recorder_params(params, mcap, record_topics, ["synthetic_load"])
    fig: dict[str, Any] = {"domain_id": domain, "logs": str(logs), "recorder_module": recorder_module,
                           "mcap": str(mcap), "rate_hz": rate_hz}
    sampler = TickSampler(lambda: {k: p.pid for k, p in list(group.processes.items())})
    try:
        group.start("recorder", [sys.executable, "-m", recorder_module, "--ros-args",
                                 "--params-file", str(params)])
        group.start("synthetic", [sys.executable, "-m", "cr_control.tools.echo_pair", "synthetic",
                                  "--duration", str(duration), "--rate", str(rate_hz),
                                  "--controller", SCHEME])
        group.wait("synthetic", STARTUP_TIMEOUT_S + 2 * duration, "published:")
    except SessionError as exc:
        fig["error"] = f"{exc}; logs in {logs}"
        progress(f"FAILED: {exc}")
    finally:
        sampler.close()
        group.stop()
    published = parse_published((logs / "synthetic.log").read_text(errors="replace"))
    if "error" in fig:
        return fig
    try:
        log_times = mcap_log_times(mcap)
        recorded = _recorded_except(mcap, topics.PARAMETER_EVENTS)
    except Exception as exc:  # noqa: BLE001 - an unreadable file is the finding
        fig["error"] = f"cannot read {mcap}: {exc}"
        return fig
    fig.update(published=published, recorded=recorded,
               lost=published - recorded if published is not None else None,
               missed=_recorder_missed(logs / "recorder.log"))
    if len(log_times) < 2:
        fig["error"] = f"{len(log_times)} messages recorded"
        return fig
    margin = 500_000_000  # leave out the first and last 0.5 s: start-up and drain
    window = samples_between(sampler.of("recorder"), log_times[0] + margin, log_times[-1] - margin)
    if window is None:
        fig["error"] = "run too short for a steady window (use a longer --recorder-duration)"
        return fig
    (t0, v0), (t1, v1) = window
    fig.update(recorder_window_cost(v0, v1, t0, t1, log_times))
    progress(f"{fig['msgs_per_s']:.0f} messages/s, {fig['us_per_msg']:.2f} us CPU per message, "
             f"{fig['lost']} lost")
    return fig


def _recorder_missed(log: Path) -> int | None:
    try:
        return parse_recorder_missed(log.read_text(errors="replace"))
    except OSError:
        return None


def _recorded_except(path: Path, skip: str) -> int:
    """Messages in an MCAP file (summary statistics) on every channel but ``skip``."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None or summary.statistics is None:
        raise ValueError("no summary")
    skipped = {cid for cid, ch in summary.channels.items() if ch.topic == skip}
    return sum(n for cid, n in summary.statistics.channel_message_counts.items() if cid not in skipped)


def run_offline(duration: float, progress: Progress) -> dict[str, Any]:
    """Wall time of the offline loop (no ROS) for ``duration`` simulated seconds."""
    progress.begin("offline loop")
    from cr_control.tools.offline import run_scheme

    t0, cpu0 = time.perf_counter(), time.process_time()
    machine0, steal0 = read_machine_ticks(), read_machine_ticks(steal=True)
    result = run_scheme(SCHEME, duration)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    machine1, steal1 = read_machine_ticks(), read_machine_ticks(steal=True)
    others = steal = None
    if machine0 is not None and machine1 is not None:
        others = max(0.0, cpu_percent(machine0, machine1, wall) - 100.0 * cpu / wall)
        steal = cpu_percent(steal0, steal1, wall)
    cycles = len(result.time)
    progress(f"{duration:g} s simulated in {wall:.2f} s wall")
    return {"simulated_s": duration, "wall_s": wall, "speed": duration / wall, "cycles": cycles,
            "rate_hz": cycles / wall, "cpu_total_pct": 100.0 * cpu / wall, "cpu_others_pct": others,
            "cpu_steal_pct": steal}


#: ROS domain ids the reference benchmark numbers its runs with, from one base id.
REFERENCE_DOMAINS = 6


def run_reference(rev: str, out: Path, args: argparse.Namespace, progress: Progress) -> dict[str, Any]:
    """The code issue 6 measured (git revision ``rev`` of this repository) run by its own
    benchmark in a subprocess, on this machine, in this run: the four figures of
    :data:`ISSUE_BEFORE` as it measures them today, or {"error": why} (no git history, say).
    Its runs use :data:`REFERENCE_DOMAINS` consecutive domain ids, all held meanwhile."""
    progress.begin(f"reference {rev}")
    repo = Path(__file__).resolve().parents[2]
    tree = out / f"reference-{rev}"
    try:
        archive = subprocess.run(["git", "-C", str(repo), "archive", "--format=tar", rev,
                                  "cr_control", "cr_sim", "config"],
                                 capture_output=True, check=True, timeout=60)
    except (OSError, subprocess.SubprocessError) as exc:
        why = getattr(exc, "stderr", b"") or b""
        message = why.decode(errors="replace").strip().splitlines()[-1:] or [str(exc)]
        progress(f"skipped: no revision {rev} here ({message[0]})")
        return {"rev": rev, "error": f"no revision {rev} in {repo}: {message[0]}"}
    tree.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(tree, filter="data")
    json_path = tree / "benchmark.json"
    cmd = [sys.executable, "-m", "cr_control.benchmark", "--duration", f"{args.duration:g}",
           "--lockstep-duration", f"{args.lockstep_duration:g}", "--json", str(json_path),
           "--out", str(tree / "logs")]
    passed_on = {"--skip-offline": args.skip_offline, "--skip-lockstep": args.skip_lockstep,
                 "--no-compute-time": args.no_compute_time}
    cmd += [flag for flag, on in passed_on.items() if on]
    try:
        locks = claim_consecutive_domains(REFERENCE_DOMAINS)
    except DomainBusyError as exc:
        return {"rev": rev, "error": str(exc)}
    cmd += ["--domain-base", str(locks[0].domain_id)]
    env = isolated_env()
    env["PYTHONPATH"] = os.pathsep.join([str(tree), *filter(None, [env.get("PYTHONPATH")])])
    try:
        with open(tree / "benchmark.log", "w") as log, subprocess.Popen(
                cmd, cwd=tree, env=env, stdout=log, stderr=subprocess.PIPE, text=True) as proc:
            for line in proc.stderr:
                if line.startswith("["):
                    progress(line)
                log.write(line)
    finally:
        for lock in locks:
            lock.release()
    if proc.returncode != 0 or not json_path.exists():
        return {"rev": rev,
                "error": f"its benchmark exited with {proc.returncode} (log: {tree / 'benchmark.log'})"}
    report = json.loads(json_path.read_text())
    realtime, speed = report.get("realtime", {}), report.get("speed", {})
    figures = cost_figures(realtime.get("session processes", {}), speed.get("lockstep composed", {}),
                           speed.get("offline loop (no ROS)", {}))
    runs = list(realtime.values()) + list(speed.values())
    return {"rev": rev, **figures, "json": str(json_path),
            "fresh_pct": realtime.get("session processes", {}).get("fresh_pct"),
            "cpu_others_max_pct": max((f.get("cpu_others_pct") or 0.0 for f in runs), default=None)}


def format_reference(reference: dict[str, Any]) -> str:
    """The issue's code measured in this run beside the issue's own figures of it."""
    if reference.get("error"):
        return f"reference: {reference['error']}; cost targets by the loop-iteration scaling only"
    lines = [f"reference: the code issue 6 measured ({reference['rev']}), run by its own benchmark "
             "in this run, against the issue's figures of it",
             "".ljust(36) + "this run".rjust(12) + "issue".rjust(12) + "ratio".rjust(10)]
    for name, key, _op, _limit, unit in COST_TARGETS:
        today, before = reference.get(key), ISSUE_BEFORE[key]
        ratio = before / today if _finite(today) and today > 0 else None
        spec = ".2f" if unit == "x" else ".1f"
        lines.append(name.ljust(36) + fmt(today, spec, unit).rjust(12) + fmt(before, spec, unit).rjust(12)
                     + fmt(ratio, ".2f", "x").rjust(10))
    return "\n".join(lines)


# -- command line ----------------------------------------------------------------------------
def domain_ids(base: int, count: int) -> list[int]:
    """``count`` consecutive domain ids from ``base``, wrapped into the automatic range."""
    return [FIRST_DOMAIN + (base - FIRST_DOMAIN + i) % DOMAIN_SPAN for i in range(count)]


def claimed_domains(base: int | None) -> Iterator[int]:
    """Domain ids for the runs, one per run: each is held machine-wide (the session runner's
    and the tests' locks, :mod:`cr_control.core.ros_env`) from when it is handed out until the
    next one is, so no other run on this machine meets a benchmark run. ``base``: where the
    search starts (default pid-based)."""
    lock = None
    i = 0
    try:
        while True:
            start = None if base is None else domain_ids(base, i + 1)[-1]
            new = claim_free_domain(start=start)  # before releasing: the next run gets a fresh id
            if lock is not None:
                lock.release()
            lock = new
            yield lock.domain_id
            i += 1
    finally:
        if lock is not None:
            lock.release()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cr_benchmark", description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=10.0,
                   help="seconds of each real-time run (default 10)")
    p.add_argument("--lockstep-duration", type=float, default=10.0,
                   help="simulated seconds of each lockstep run and of the offline loop (default 10)")
    p.add_argument("--recorder-duration", type=float, default=4.0,
                   help="seconds of synthetic load on the recorder (default 4)")
    p.add_argument("--repeat", type=int, default=1,
                   help="session/echo pairs per layout, in ABBA order; the tables and targets show "
                        "the median over the pairs, the spread is printed (default 1)")
    p.add_argument("--retries", type=int, default=3,
                   help=f"per layout, how many session/echo pairs may be run again because other "
                        f"processes and the hypervisor's steal took more than {DISTURBED_PCT:g}%% of "
                        "a core during one of their runs (default 3; the discarded pairs are printed)")
    p.add_argument("-p", "--set", action="append", default=[], metavar="NODE.PARAM=VALUE",
                   help="a parameter of the sessions, as cr_session's -p (e.g. "
                        f"{SCHEME}.diagnostics_every=10); the echo pairs stay as they are")
    p.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    p.add_argument("--out", type=Path, help="directory for the runs' logs (default: a new temp dir)")
    p.add_argument("--skip-offline", action="store_true", help="no offline-loop speed")
    p.add_argument("--skip-lockstep", action="store_true", help="no lockstep sessions")
    p.add_argument("--skip-composed", action="store_true", help="no one-process runs")
    p.add_argument("--skip-recorder", action="store_true",
                   help="no runs with the recorder (the recorder and panda layouts), no recorder load")
    p.add_argument("--skip-panda", action="store_true", help="no Panda session and its echo pair")
    p.add_argument("--only", action="append", choices=[lay.name for lay in LAYOUTS], metavar="LAYOUT",
                   help="run only this real-time layout's session/echo pairs (repeatable; of "
                        f"{', '.join(lay.name for lay in LAYOUTS)}): no recorder load, lockstep, "
                        "offline loop or reference run, so no cost targets")
    p.add_argument("--only-recorder-load", action="store_true",
                   help="only the calibration and the recorder under synthetic load")
    p.add_argument("--recorder-module", action="append",
                   help=f"module run as the recorder (default {RECORDER_MODULE}); given several "
                        "times, the recorder load runs each in turn (A/B comparison)")
    p.add_argument("--reference", default=REFERENCE_REV, metavar="REV",
                   help="git revision of the code issue 6 measured, run by its own benchmark beside "
                        f"ours to carry the cost targets to the issue's machine (default {REFERENCE_REV})")
    p.add_argument("--no-reference", action="store_true",
                   help="no reference run: cost targets by the loop-iteration scaling only")
    p.add_argument("--no-compute-time", action="store_true",
                   help="do not subscribe to the controller status (no compute time figures)")
    p.add_argument("--domain-base", type=int,
                   help="first ROS_DOMAIN_ID of the runs (default: pid-based); each run uses the next")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print its tables."""
    args = build_parser().parse_args(argv)
    if not args.duration > 0 or not args.lockstep_duration > 0 or not args.recorder_duration > 0:
        print("cr_benchmark: durations must be > 0", file=sys.stderr)
        return 2
    if args.repeat < 1:
        print("cr_benchmark: --repeat must be >= 1", file=sys.stderr)
        return 2
    if args.retries < 0:
        print("cr_benchmark: --retries must be >= 0", file=sys.stderr)
        return 2
    if args.only and args.only_recorder_load:
        print("cr_benchmark: --only and --only-recorder-load exclude each other", file=sys.stderr)
        return 2
    skipped = [name for name, on in (("composed", args.skip_composed), ("recorder", args.skip_recorder),
                                     ("panda", args.skip_recorder or args.skip_panda)) if on]
    layouts = [] if args.only_recorder_load else select_layouts(args.only, skipped)
    if args.only and not layouts:
        print(f"cr_benchmark: --only {' '.join(args.only)}: every one of them is skipped", file=sys.stderr)
        return 2
    robots = list(dict.fromkeys(lay.robot for lay in layouts if lay.robot))
    for robot in [None, *robots]:  # a setting no node would take is refused before any run starts
        try:
            session_parameters(SessionConfig(scheme=SCHEME, overrides=args.set, robot=robot),
                               Path(os.devnull))
        except SessionError as exc:
            print(f"cr_benchmark: {exc}" + (f" (the {robot} session)" if robot else ""), file=sys.stderr)
            return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="cr_benchmark-"))
    out.mkdir(parents=True, exist_ok=True)
    domains = claimed_domains(args.domain_base)
    progress = Progress()
    compute = not args.no_compute_time
    recorder_modules = args.recorder_module or [RECORDER_MODULE]
    t_start = time.monotonic()
    progress.begin("warm-up")
    warm_up(robots)
    progress.begin("calibration")
    calibration = {"start": calibrate()}
    progress(f"{calibration['start']['loop_ns']:.1f} ns per loop iteration, "
             f"{fmt(calibration['start']['aba_us'], '.2f')} us per ABA call")
    realtime: list[tuple[str, dict[str, Any]]] = []
    speeds: list[tuple[str, dict[str, Any]]] = []
    loads: list[tuple[str, dict[str, Any]]] = []
    targets: list[Target] = []
    reference: dict[str, Any] | None = None
    try:
        for layout in layouts:

            def session_run(tag, layout=layout):
                return run_session(layout.session_title + tag, next(domains), out, args.duration, "realtime",
                                   layout.composed, progress, compute, record=layout.record,
                                   overrides=args.set, robot=layout.robot)

            def echo_run(tag, layout=layout):
                return run_echo(layout.echo_title + tag, next(domains), out, args.duration, layout.composed,
                                progress, record=layout.record, recorder_module=recorder_modules[0],
                                echo_args=layout.echo_args)

            sessions, echoes, discarded = run_pairs(session_run, echo_run, args.repeat,
                                                    args.retries, progress)
            session, echo = median_figures(sessions), median_figures(echoes)
            session["discarded"] = discarded
            realtime += [(layout.session_title, session), (layout.echo_title, echo)]
            targets += layout_targets(layout, session, echo)
        if (not args.skip_recorder and not args.only) or args.only_recorder_load:
            for module in recorder_modules:
                title = "recorder, synthetic load" + ("" if len(recorder_modules) == 1 else f" ({module})")
                loads.append((title, run_recorder_load(title, next(domains), out, args.recorder_duration,
                                                       progress, module)))
        if not args.only_recorder_load and not args.only:
            if not args.skip_lockstep:
                for name, composed in [("processes", False)] + ([] if args.skip_composed
                                                                else [("composed", True)]):
                    title = f"lockstep {name}"
                    speeds.append((title, run_session(title, next(domains), out, args.lockstep_duration,
                                                      "lockstep", composed, progress, False,
                                                      overrides=args.set)))
            if not args.skip_offline:
                speeds.append(("offline loop (no ROS)",
                               run_offline(args.lockstep_duration, progress)))
            if not args.no_reference:
                reference = run_reference(args.reference, out, args, progress)
    except KeyboardInterrupt:
        print("cr_benchmark: interrupted", file=sys.stderr)
        return 130
    finally:
        domains.close()  # the last run's domain id is free again
    progress.begin("calibration")
    calibration["end"] = calibrate()
    total = time.monotonic() - t_start
    ends = [c["loop_ns"] for c in calibration.values() if _finite(c.get("loop_ns"))]
    calibration["loop_ns"] = sum(ends) / len(ends)
    abas = [c["aba_us"] for c in (calibration["start"], calibration["end"]) if _finite(c.get("aba_us"))]
    calibration["aba_us"] = sum(abas) / len(abas) if abas else None
    # Scaled figures with the run's mean calibration.
    loop_ns = calibration["loop_ns"]
    for _, fig in realtime + speeds:
        for key, scaled in (("plant_step_us", "plant_step_scaled_us"),
                            ("compute_p50_us", "compute_p50_scaled_us"),
                            ("cycle_cpu_total_us", "cycle_cpu_total_scaled_us")):
            if key in fig:  # None stays None: printed "n/a"
                fig[scaled] = scaled_cost(fig[key], loop_ns)
        if "speed" in fig:
            fig["speed_scaled"] = scaled_speed(fig["speed"], loop_ns)
    runs = dict(realtime + speeds)
    if "session processes" in runs:
        targets += cost_targets(runs["session processes"], runs.get("lockstep composed", {}),
                                runs.get("offline loop (no ROS)", {}), loop_ns, reference)

    print()
    print(f"cr_benchmark: {SCHEME}, real-time runs {args.duration:g} s at 1 kHz, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}, took {total:.0f} s"
          + (f"; sessions with {' '.join(args.set)}" if args.set else ""))
    print(f"calibration: {calibration['start']['loop_ns']:.1f} / {calibration['end']['loop_ns']:.1f} ns "
          f"per plain Python loop iteration (start / end of the run), "
          f"{fmt(calibration['start']['aba_us'], '.2f')} / {fmt(calibration['end']['aba_us'], '.2f')} us "
          f"per Pinocchio ABA call (2-link arm); scaled figures: x {REFERENCE_LOOP_NS:g} / {loop_ns:.1f} "
          f"(costs) or x {loop_ns:.1f} / {REFERENCE_LOOP_NS:g} (speeds)")
    steps = [f"{fmt(c.get('step_hot_us'), '.1f')} us hot / {fmt(c.get('step_after_idle_us'), '.1f')} us "
             f"after 0.9 ms idle ({when})" for when, c in (("start", calibration["start"]),
                                                            ("end", calibration["end"]))]
    print(f"controller step ({SCHEME}, offline), p50: {', '.join(steps)}: the node's compute time "
          "is the second kind")
    if realtime:
        print()
        print(format_realtime_table(realtime))
        if args.repeat > 1:
            print(f"(medians of {args.repeat} repeats, ABBA order)")
        if repeats := format_repeats(realtime):
            print(repeats)
    if loads:
        print()
        print(format_recorder_load(loads, loop_ns))
    if speeds:
        print()
        print(format_speed_table(speeds))
    if reference is not None:
        print()
        print(format_reference(reference))
    if targets:
        print()
        print(format_targets(targets))
    busy = [t for t, f in realtime + speeds if disturbed(f)]
    if busy:
        print(f"\nnote: other processes or other machines (hypervisor steal) took more than "
              f"{DISTURBED_PCT:g}% of a core during "
              f"{', '.join(busy)}: those figures may be disturbed; rerun on a quiet machine")
    print(f"\nlogs: {out}")
    if args.json:
        report = {
            "scheme": SCHEME, "duration_s": args.duration, "lockstep_duration_s": args.lockstep_duration,
            "repeat": args.repeat, "session_settings": args.set, "layouts": [lay.name for lay in layouts],
            "cpu_count": os.cpu_count(), "total_s": total, "calibration": calibration,
            "reference_loop_ns": REFERENCE_LOOP_NS, "reference": reference, "issue_before": ISSUE_BEFORE,
            "realtime": {title: fig for title, fig in realtime},
            "recorder_load": {title: fig for title, fig in loads},
            "speed": {title: fig for title, fig in speeds},
            "targets": [t.as_dict() for t in targets],
            "logs": str(out),
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(json_safe(report), indent=2))
        print(f"json: {args.json}")
    failed = [(t, f) for t, f in realtime + speeds + loads if f.get("error")]
    for title, fig in failed:
        print(f"{title}: {fig['error']}", file=sys.stderr)
    return 1 if failed else 0


def json_safe(obj: Any) -> Any:
    """``obj`` with non-finite floats as None (strict JSON) and unknown objects as strings."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    return str(obj)


if __name__ == "__main__":
    sys.exit(main())
