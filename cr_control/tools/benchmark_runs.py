"""The benchmark's runs: a real-time or lockstep session, the bare echo pair, the recorder
under synthetic load, the offline loop, and the issue-6 reference code run by its own
benchmark. Each returns its figures as a dict; :mod:`cr_control.tools.benchmark` orders
them and prints the tables.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import re
import subprocess
import sys
import tarfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cr_control.core import topics
from cr_control.core.ros_env import (
    DomainBusyError,
    claim_consecutive_domains,
    isolated_env,
)
from cr_control.tools.benchmark_calibration import mcap_log_times
from cr_control.tools.benchmark_figures import (
    ISSUE_BEFORE,
    LISTENER,
    MACHINE,
    RECORDER_MODULE,
    SCHEME,
    STEAL,
    cpu_from_samples,
    cpu_per_cycle,
    cpu_percent,
    finite_value,
    parse_done_line,
    parse_published,
    parse_recorder_missed,
    read_machine_ticks,
    window_mean,
)
from cr_control.tools.benchmark_listener import Listener, TickSampler
from cr_control.tools.benchmark_report import (
    COST_TARGETS,
    cost_figures,
    fmt,
    loop_figures,
    recorder_window_cost,
    samples_between,
)
from cr_control.tools.echo_pair import parse_result
from cr_control.tools.session import (
    STARTUP_TIMEOUT_S,
    ProcessGroup,
    Session,
    SessionConfig,
    SessionError,
)
from cr_sim.loop_stats import percentiles


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
    # lazy: loaded when the command runs (cr_control.tools)
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
    if finite_value(publish):  # the source's own publish time: the floor under the plant's
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
    # lazy: loaded when the command runs (cr_control.tools)
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
    # lazy: loaded when the command runs (cr_control.tools)
    from cr_control.offline import run_scheme

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
    """The code the "before" table measured (git revision ``rev`` of this repository) run by its own
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
    lines = [f"reference: the code the 'before' table measured ({reference['rev']}), run by its "
             "own benchmark in this run, against that table's figures of it",
             "".ljust(36) + "this run".rjust(12) + "issue".rjust(12) + "ratio".rjust(10)]
    for name, key, _op, _limit, unit in COST_TARGETS:
        today, before = reference.get(key), ISSUE_BEFORE[key]
        ratio = before / today if finite_value(today) and today > 0 else None
        spec = ".2f" if unit == "x" else ".1f"
        lines.append(name.ljust(36) + fmt(today, spec, unit).rjust(12) + fmt(before, spec, unit).rjust(12)
                     + fmt(ratio, ".2f", "x").rjust(10))
    return "\n".join(lines)
