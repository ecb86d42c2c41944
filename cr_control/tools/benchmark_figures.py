"""The benchmark's constants and pure figure helpers (no ROS, tested alone): parsing
``/proc`` and the nodes' log lines, CPU shares and CPU per cycle, timing summaries, the
scalings that carry cost figures to the issue-6 machine, medians over repeated pairs, the
"disturbed run" rule and the PASS/FAIL verdict. Used by :mod:`cr_control.tools.benchmark`.
"""

from __future__ import annotations

import math
import os
import re
import struct
from collections.abc import Callable, Sequence
from typing import Any

from cr_control.core import topics

SCHEME = "adaptive_impedance"
#: CPU taken by other processes and by the hypervisor's steal (% of one core) above which
#: a run is disturbed: flagged, and a session/echo pair with a disturbed run is run again
#: (at most ``--retries`` times per layout).
DISTURBED_PCT = 20.0
#: ns per plain Python loop iteration of the machine the cost targets are stated for.
REFERENCE_LOOP_NS = 300.0
#: The code the "before" table of docs/benchmark.md was measured on (the last commit before the work on it).
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
    if not finite_value(value) or not finite_value(loop_ns) or loop_ns <= 0:
        return None
    return value * reference_ns / loop_ns


def scaled_speed(value: float | None, loop_ns: float | None,
                 reference_ns: float = REFERENCE_LOOP_NS) -> float | None:
    """A speed (× real time) measured at ``loop_ns`` per loop iteration, on the reference one."""
    if not finite_value(value) or not finite_value(loop_ns) or loop_ns <= 0:
        return None
    return value * loop_ns / reference_ns


def reference_scaled(value: float | None, today: float | None, before: float | None) -> float | None:
    """One of our figures as it would read on the machine of the "before" table:
    ``value`` × ``before`` / ``today``, where ``today`` is the same figure of the code the
    issue measured (:data:`REFERENCE_REV`), measured in this run, and ``before`` the issue's.
    Costs and speeds alike: the ratio of ours to that code's is what carries over."""
    if not (finite_value(value) and finite_value(today) and finite_value(before)) or today <= 0:
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
        numbers = sorted(v for v in values if finite_value(v))
        dicts = [v for v in values if isinstance(v, dict)]
        if numbers:
            mid = len(numbers) // 2
            out[key] = numbers[mid] if len(numbers) % 2 else (numbers[mid - 1] + numbers[mid]) / 2
        elif dicts:
            out[key] = _medians(dicts)
        else:
            out[key] = next((v for v in values if v is not None), None)
    return out


def fmt(value: Any, spec: str = ".1f", suffix: str = "") -> str:
    """A table cell: formatted number, "-" when missing / not finite."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, str):
        return value
    return f"{value:{spec}}{suffix}"


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


def finite_value(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def ratios(run: dict[str, Any], baseline: dict[str, Any]) -> dict[str, float]:
    """A run against the baseline of the same layout: fresh share difference (percentage
    points), p99 round trip ratio, total CPU ratio."""
    out = {"fresh_diff_pp": math.nan, "p99_ratio": math.nan, "cpu_ratio": math.nan}
    if finite_value(run.get("fresh_pct")) and finite_value(baseline.get("fresh_pct")):
        out["fresh_diff_pp"] = run["fresh_pct"] - baseline["fresh_pct"]
    if (finite_value(run.get("rt_p99_ms")) and finite_value(baseline.get("rt_p99_ms"))
            and baseline["rt_p99_ms"] > 0):
        out["p99_ratio"] = run["rt_p99_ms"] / baseline["rt_p99_ms"]
    if finite_value(run.get("cpu_total_pct")) and finite_value(baseline.get("cpu_total_pct")) \
            and baseline["cpu_total_pct"] > 0:
        out["cpu_ratio"] = run["cpu_total_pct"] / baseline["cpu_total_pct"]
    return out


def verdict(value: Any, op: str, limit: Any) -> str:
    """"PASS" when ``value op limit`` holds (op ">=" or "<="), "FAIL" when not, "n/a" when
    either is missing or not finite."""
    if not finite_value(value) or not finite_value(limit):
        return "n/a"
    if op == ">=":
        return "PASS" if value >= limit else "FAIL"
    if op == "<=":
        return "PASS" if value <= limit else "FAIL"
    raise ValueError(f"unknown comparison {op!r}")
