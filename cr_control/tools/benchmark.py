"""Real-time figures of cr_control against a bare rclpy echo pair, in one run.

Runs, one after another, each on a ROS_DOMAIN_ID of its own (localhost discovery):

1. a real-time session (plant + ``adaptive_impedance`` controller) across processes,
2. the same session composed (plant and controller in one process),
3. the bare echo pair (:mod:`cr_control.tools.echo_pair`, same messages, QoS and executor,
   no math) across processes and in one process, as the baseline of each layout,
4. lockstep sessions (across processes and composed) and the offline loop (no ROS):
   how many times faster than real time the same plant and controller run.

Sessions run without the recorder. Whole-run loop figures come from the last
``/plant/timing`` message (``total_*`` fields) and the plant's "done:" log line; CPU is
read from ``/proc/<pid>/stat`` (utime + stime) between the first and the last timing
message, so start-up and shutdown are excluded; "anything else" is the machine's busy
time (``/proc/stat``) not spent by the run, to flag runs disturbed by other work. The
controller's compute time per cycle comes from its status topic, read by a best-effort
raw subscriber in this process (~5% of a core, shown as "benchmark listener"; it did not
change the loop processes' CPU measurably; ``--no-compute-time`` turns it off).

    cr_benchmark                         # ~1 min on a 2-core machine
    cr_benchmark --duration 5 --json /tmp/bench.json --skip-offline
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import struct
import sys
import tempfile
import threading
import time
from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cr_control.core import topics
from cr_control.core.ros_env import (
    DOMAIN_SPAN,
    FIRST_DOMAIN,
    free_domain_id,
    isolate_this_process,
    isolated_env,
)
from cr_control.tools.echo_pair import parse_result
from cr_control.tools.session import STARTUP_TIMEOUT_S, ProcessGroup, Session, SessionConfig, SessionError

SCHEME = "adaptive_impedance"
#: CPU used by other processes (% of one core) above which a run is flagged as disturbed.
DISTURBED_PCT = 20.0

DONE_RE = re.compile(r"done: ([\d.eE+-]+) s simulated in ([\d.eE+-]+) s wall, (\d+) cycles")


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


def parse_machine_stat(text: str) -> int:
    """Busy clock ticks of all CPUs together from the text of ``/proc/stat`` (its "cpu" line:
    user, nice, system, irq, softirq, steal; idle and iowait left out)."""
    for line in text.splitlines():
        if line.startswith("cpu "):
            v = [int(x) for x in line.split()[1:]]
            return v[0] + v[1] + v[2] + v[5] + v[6] + (v[7] if len(v) > 7 else 0)
    raise ValueError("no aggregate cpu line")


def read_machine_ticks() -> int | None:
    """Busy clock ticks of the whole machine so far (None where there is no /proc/stat)."""
    try:
        with open("/proc/stat") as f:
            return parse_machine_stat(f.read())
    except (OSError, ValueError, IndexError):
        return None


MACHINE = "machine"
LISTENER = "listener"

CLOCK_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def cpu_percent(ticks0: int, ticks1: int, wall_s: float, clk_tck: float = CLOCK_TICKS) -> float:
    """Share of one core (%) used between two tick counts ``wall_s`` seconds apart."""
    if wall_s <= 0:
        return math.nan
    return 100.0 * (ticks1 - ticks0) / clk_tck / wall_s


def cpu_from_samples(samples: Sequence[tuple[float, dict[str, int | None]]]) -> dict[str, float]:
    """% of one core per process from (wall time, {name: ticks or None}) samples: each process
    between its first and last readable sample."""
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
        if t1 > t0:
            out[name] = cpu_percent(v0, v1, t1 - t0)
    return out


def parse_done_line(text: str) -> tuple[float, float, int] | None:
    """(simulated s, wall s, cycles) from the last plant/source "done:" log line, or None."""
    matches = DONE_RE.findall(text)
    if not matches:
        return None
    sim, wall, cycles = matches[-1]
    return float(sim), float(wall), int(cycles)


def timing_dict(label: str, data: Sequence[float]) -> dict[str, float]:
    """A labelled /plant/timing array as {field: value}."""
    return dict(zip(topics.fields_of(label), (float(v) for v in data), strict=False))


def percentile(values: Sequence[float], p: float) -> float:
    """The ``p``-th percentile (linear interpolation) of ``values``; nan if empty."""
    if not len(values):
        return math.nan
    s = sorted(values)
    k = (len(s) - 1) * p / 100.0
    lo = math.floor(k)
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)


def last_double(buf: bytes, count_from_end: int) -> float:
    """The double ``count_from_end`` places from the end of a CDR-serialised message whose
    last member is a float64 sequence (e.g. Float64MultiArray), honouring the
    encapsulation's endianness and end padding."""
    little = buf[1] & 1
    padding = buf[3] & 0x3
    end = len(buf) - padding
    return struct.unpack_from("<d" if little else ">d", buf, end - 8 * count_from_end)[0]


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


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


def fmt(value: Any, spec: str = ".1f", suffix: str = "") -> str:
    """A table cell: formatted number, or "-" when missing / not finite."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, str):
        return value
    return f"{value:{spec}}{suffix}"


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
    ("CPU total (% core)", "cpu_total_pct", ".1f", ""),
    ("CPU benchmark listener (% core)", "cpu_listener_pct", ".1f", ""),
    ("CPU anything else (% core)", "cpu_others_pct", ".1f", ""),
    ("plant step, mean (us)", "plant_step_us", ".1f", ""),
    ("controller compute p50 (us)", "compute_p50_us", ".1f", ""),
    ("controller compute p99 (us)", "compute_p99_us", ".1f", ""),
    ("vs baseline: fresh (pp)", "fresh_diff_pp", "+.2f", ""),
    ("vs baseline: round trip p99", "p99_ratio", ".2f", "x"),
    ("vs baseline: CPU total", "cpu_ratio", ".2f", "x"),
]


def format_realtime_table(runs: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """The real-time figures of ``runs`` ((column title, figures)) as a text table."""
    label_w = max(len(r[0]) for r in REALTIME_ROWS)
    col_w = max([14, *(len(title) + 2 for title, _ in runs)])
    lines = ["".ljust(label_w) + "".join(title.rjust(col_w) for title, _ in runs)]
    for label, key, spec, suffix in REALTIME_ROWS:
        cells = []
        for _, fig in runs:
            cells.append(("failed" if fig.get("error") and key == "rate_hz" else
                          fmt(fig.get(key), spec, suffix)).rjust(col_w))
        lines.append(label.ljust(label_w) + "".join(cells))
    return "\n".join(lines)


def format_speed_table(rows: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """Lockstep / offline speeds ((title, figures)) as a text table."""
    head = ["", "simulated s", "wall s", "x real time", "cycles/s", "rt p50 (ms)", "rt p99 (ms)",
            "CPU (% core)", "others (%)"]
    title_w = max([len("offline loop (no ROS)"), *(len(t) for t, _ in rows)])
    out = [head[0].ljust(title_w) + "".join(h.rjust(13) for h in head[1:])]
    for title, fig in rows:
        if fig.get("error"):
            out.append(title.ljust(title_w) + "failed".rjust(13))
            continue
        cells = [fmt(fig.get("simulated_s"), ".2f"), fmt(fig.get("wall_s"), ".2f"),
                 fmt(fig.get("speed"), ".2f", "x"), fmt(fig.get("rate_hz"), ".0f"),
                 fmt(fig.get("rt_p50_ms"), ".3f"), fmt(fig.get("rt_p99_ms"), ".3f"),
                 fmt(fig.get("cpu_total_pct"), ".0f"), fmt(fig.get("cpu_others_pct"), ".0f")]
        out.append(title.ljust(title_w) + "".join(c.rjust(13) for c in cells))
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
        fig.update(rt_p50_ms=timing.get("total_age_p50_ms"), rt_p99_ms=timing.get("total_age_p99_ms"),
                   rt_max_ms=timing.get("total_age_max_ms"),
                   fresh_pct=100.0 * timing.get("total_fresh_share", math.nan),
                   missed_cycles=timing.get("total_missed_cycles"), timing_covers_s=timing.get("stamp"))
    return fig


# -- ROS side: a listener in this process ----------------------------------------------
class Listener:
    """One node on ``domain_id`` in its own context, spun by an EventsExecutor in a thread.

    Keeps every /plant/timing report and, on each, samples the CPU time of the
    processes ``pids()`` names (and of this process); optionally the controller's
    ``compute_time_us`` from its status topic (best effort, raw CDR: cheap).
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
        self.compute_us = array("d")
        self.status_received = 0
        self._status_index: int | None = None  # counted from the end of the data
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
        self.cpu_samples.append((now, ticks))

    def _on_status(self, buf: bytes) -> None:
        self.status_received += 1
        if self._status_index is None or not self._status_raw_ok:
            from rclpy.serialization import deserialize_message

            msg = deserialize_message(buf, self._msg_cls)
            fields = topics.fields_of(msg.layout.dim[0].label if msg.layout.dim else "")
            if "compute_time_us" not in fields:
                return
            i = fields.index("compute_time_us")
            value = float(msg.data[i])
            if self._status_index is None:
                self._status_index = len(msg.data) - i
                try:
                    self._status_raw_ok = last_double(buf, self._status_index) == value
                except (struct.error, IndexError):
                    self._status_raw_ok = False
            self.compute_us.append(value)
            return
        self.compute_us.append(last_double(buf, self._status_index))

    def last_timing(self) -> dict[str, float] | None:
        return self.timing[-1][1] if self.timing else None

    def close(self) -> None:
        if not self._stop.done():
            self._stop.set_result(True)
        self._thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


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


def _steady_figures(listener: Listener | None, names: dict[str, str]) -> dict[str, Any]:
    """CPU per role (names: role -> process name) and plant step time from the listener."""
    fig: dict[str, Any] = {}
    if listener is None:
        return fig
    cpu = cpu_from_samples(listener.cpu_samples)
    ours = {k: v for k, v in cpu.items() if k not in (LISTENER, MACHINE)}
    for role, proc in names.items():
        fig[f"cpu_{role}_pct"] = cpu.get(proc)
    fig["cpu_total_pct"] = sum(ours.values()) if ours else None
    fig["cpu_listener_pct"] = cpu.get(LISTENER)
    fig["cpu_per_process_pct"] = ours
    if MACHINE in cpu:
        fig["cpu_others_pct"] = max(0.0, cpu[MACHINE] - sum(ours.values()) - cpu.get(LISTENER, 0.0))
    windows = [(t.get("step_time_us", 0.0), t.get("window_cycles", 0.0)) for _, t in listener.timing]
    cycles = sum(n for _, n in windows)
    fig["timing_reports"] = len(listener.timing)
    fig["plant_step_us"] = sum(us * n for us, n in windows) / cycles if cycles > 0 else None
    if len(listener.compute_us):
        fig["compute_p50_us"] = percentile(listener.compute_us, 50)
        fig["compute_p99_us"] = percentile(listener.compute_us, 99)
        fig["compute_samples"] = len(listener.compute_us)
    return fig


def run_session(title: str, domain: int, out: Path, duration: float, mode: str, composed: bool,
                progress: Progress, compute_time: bool) -> dict[str, Any]:
    """One session without recorder; its loop, CPU and compute figures."""
    progress.begin(title)
    name = re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")
    session = Session(SessionConfig(scheme=SCHEME, duration=duration, mode=mode, composed=composed,
                                    record=False, out=out, domain_id=domain, name=name), progress=progress)
    listener = None
    fig: dict[str, Any] = {"domain_id": domain, "logs": str(session.logs)}
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
    fig.update(_steady_figures(listener, roles))
    if listener is not None:
        fig["status_received"] = listener.status_received
    if done is None and "error" not in fig:
        fig["error"] = f"no 'done:' line in {log}"
    if "simulated_s" in fig and fig.get("wall_s"):
        fig["speed"] = fig["simulated_s"] / fig["wall_s"]
    return fig


def run_echo(title: str, domain: int, out: Path, duration: float, composed: bool,
             progress: Progress, rate_hz: float = 1000.0) -> dict[str, Any]:
    """The bare echo pair, across two processes or in one; its loop and CPU figures."""
    progress.begin(title)
    logs = out / re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")
    logs.mkdir(parents=True, exist_ok=True)
    env = isolated_env(domain)
    env.setdefault("PYTHONUNBUFFERED", "1")
    progress(f"echo pair {logs} (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, "
             f"discovery {env['ROS_AUTOMATIC_DISCOVERY_RANGE']})")
    group = ProcessGroup(logs, env, progress)

    def start(name: str, role: str) -> None:
        group.start(name, [sys.executable, "-m", "cr_control.tools.echo_pair", role,
                           "--duration", str(duration), "--rate", str(rate_hz)])

    fig: dict[str, Any] = {"domain_id": domain, "logs": str(logs)}
    listener = Listener(domain, lambda: {k: p.pid for k, p in list(group.processes.items())})
    main_name = "echo_pair" if composed else "source"
    try:
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
    fig.update(_steady_figures(listener, roles))
    fig["plant_step_us"] = None
    if done is None and "error" not in fig:
        fig["error"] = f"no 'done:' line in {logs / main_name}.log"
    return fig


def run_offline(duration: float, progress: Progress) -> dict[str, Any]:
    """Wall time of the offline loop (no ROS) for ``duration`` simulated seconds."""
    progress.begin("offline loop")
    from cr_control.tools.offline import run_scheme

    t0, cpu0, machine0 = time.perf_counter(), time.process_time(), read_machine_ticks()
    result = run_scheme(SCHEME, duration)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    machine1 = read_machine_ticks()
    others = None
    if machine0 is not None and machine1 is not None:
        others = max(0.0, cpu_percent(machine0, machine1, wall) - 100.0 * cpu / wall)
    cycles = len(result.time)
    progress(f"{duration:g} s simulated in {wall:.2f} s wall")
    return {"simulated_s": duration, "wall_s": wall, "speed": duration / wall, "cycles": cycles,
            "rate_hz": cycles / wall, "cpu_total_pct": 100.0 * cpu / wall, "cpu_others_pct": others}


# -- command line ----------------------------------------------------------------------------
def domain_ids(base: int, count: int) -> list[int]:
    """``count`` consecutive domain ids from ``base``, wrapped into the automatic range."""
    return [FIRST_DOMAIN + (base - FIRST_DOMAIN + i) % DOMAIN_SPAN for i in range(count)]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cr_benchmark", description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=10.0,
                   help="seconds of each real-time run (default 10)")
    p.add_argument("--lockstep-duration", type=float, default=10.0,
                   help="simulated seconds of each lockstep run and of the offline loop (default 10)")
    p.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    p.add_argument("--out", type=Path, help="directory for the runs' logs (default: a new temp dir)")
    p.add_argument("--skip-offline", action="store_true", help="no offline-loop speed")
    p.add_argument("--skip-lockstep", action="store_true", help="no lockstep sessions")
    p.add_argument("--skip-composed", action="store_true", help="no one-process runs")
    p.add_argument("--no-compute-time", action="store_true",
                   help="do not subscribe to the controller status (no compute time figures)")
    p.add_argument("--domain-base", type=int,
                   help="first ROS_DOMAIN_ID of the runs (default: pid-based); each run uses the next")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print its tables."""
    args = build_parser().parse_args(argv)
    if not args.duration > 0 or not args.lockstep_duration > 0:
        print("cr_benchmark: durations must be > 0", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="cr_benchmark-"))
    out.mkdir(parents=True, exist_ok=True)
    domains = iter(domain_ids(args.domain_base if args.domain_base is not None else free_domain_id(), 6))
    progress = Progress()
    compute = not args.no_compute_time
    t_start = time.monotonic()
    layouts = [("processes", False)] + ([] if args.skip_composed else [("composed", True)])
    realtime: list[tuple[str, dict[str, Any]]] = []
    try:
        for layout, composed in layouts:
            session = run_session(f"session {layout}", next(domains), out, args.duration, "realtime",
                                  composed, progress, compute)
            echo = run_echo(f"echo {layout}", next(domains), out, args.duration, composed, progress)
            session.update(ratios(session, echo))
            realtime += [(f"session {layout}", session), (f"echo {layout}", echo)]
        speeds: list[tuple[str, dict[str, Any]]] = []
        if not args.skip_lockstep:
            for layout, composed in layouts:
                title = f"lockstep {layout}"
                speeds.append((title, run_session(title, next(domains), out, args.lockstep_duration,
                                                  "lockstep", composed, progress, False)))
        if not args.skip_offline:
            speeds.append(("offline loop (no ROS)", run_offline(args.lockstep_duration, progress)))
    except KeyboardInterrupt:
        print("cr_benchmark: interrupted", file=sys.stderr)
        return 130
    total = time.monotonic() - t_start

    print()
    print(f"cr_benchmark: {SCHEME}, real-time runs {args.duration:g} s at 1 kHz, no recorder, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}, took {total:.0f} s")
    print(format_realtime_table(realtime))
    if speeds:
        print()
        print(format_speed_table(speeds))
    busy = [t for t, f in realtime + speeds if (f.get("cpu_others_pct") or 0.0) > DISTURBED_PCT]
    if busy:
        print(f"\nnote: other processes used more than {DISTURBED_PCT:g}% of a core during "
              f"{', '.join(busy)}: those figures may be disturbed; rerun on a quiet machine")
    print(f"\nlogs: {out}")
    if args.json:
        report = {
            "scheme": SCHEME, "duration_s": args.duration, "lockstep_duration_s": args.lockstep_duration,
            "recorder": False, "cpu_count": os.cpu_count(), "total_s": total,
            "realtime": {title: fig for title, fig in realtime},
            "speed": {title: fig for title, fig in speeds},
            "logs": str(out),
        }
        args.json.write_text(json.dumps(json_safe(report), indent=2))
        print(f"json: {args.json}")
    failed = [t for t, f in realtime + speeds if f.get("error")]
    for title in failed:
        print(f"{title}: {dict(realtime + speeds)[title]['error']}", file=sys.stderr)
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
