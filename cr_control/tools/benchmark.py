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
   Panda's shape, with the same recorder (real time at 7 joints), and on the UR5 at
   ur_robot_driver's 500 Hz (``--robot ur5``, 6 joints) against an echo pair at 500 Hz;
   the arms that take joint positions: ``ur5_position`` at 500 Hz and ``xarm7`` at 150 Hz
   (the admittance outer loop), each against an echo pair of its rate and shape;
5. the recorder alone under a synthetic load (a recorded session's 1 kHz topics): its
   CPU per message, and whether it lost any;
6. lockstep sessions (across processes and composed) and the offline loop (no ROS):
   how many times faster than real time the same plant and controller run.

Two ways to carry the cost figures to the machine the cost targets are stated for (the
"before" table of docs/benchmark.md):

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

This module is the command line; the code lives in :mod:`~cr_control.tools.benchmark_figures`
(constants, pure helpers), :mod:`~cr_control.tools.benchmark_report` (targets, tables),
:mod:`~cr_control.tools.benchmark_calibration`, :mod:`~cr_control.tools.benchmark_listener`
(the ROS listener) and :mod:`~cr_control.tools.benchmark_runs` (the runs).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from cr_control.core.ros_env import (
    DOMAIN_SPAN,
    FIRST_DOMAIN,
    claim_free_domain,
)
from cr_control.tools.benchmark_calibration import (
    aba_us_per_call,
    calibrate,
    loop_ns_per_iteration,
    mcap_log_times,
    step_us_hot_and_after_idle,
    warm_up,
)
from cr_control.tools.benchmark_figures import (
    CLOCK_TICKS,
    DISTURBED_PCT,
    ISSUE_BEFORE,
    RECORDER_MODULE,
    REFERENCE_LOOP_NS,
    REFERENCE_REV,
    SCHEME,
    STATUS_TIME_FIELDS,
    cpu_from_samples,
    cpu_per_cycle,
    cpu_percent,
    disturbed,
    finite_value,
    fmt,
    format_repeats,
    last_double,
    median_figures,
    offsets_from_end,
    parse_done_line,
    parse_machine_stat,
    parse_proc_stat,
    parse_published,
    parse_recorder_missed,
    ratios,
    read_cpu_ticks,
    read_machine_ticks,
    reference_scaled,
    run_pairs,
    scaled_cost,
    scaled_speed,
    timing_dict,
    verdict,
    window_mean,
)
from cr_control.tools.benchmark_report import (
    COST_TARGETS,
    LAYOUTS,
    REALTIME_ROWS,
    Target,
    cell,
    cost_targets,
    format_realtime_table,
    format_recorder_load,
    format_speed_table,
    format_targets,
    layout_targets,
    loop_figures,
    realtime_targets,
    recorder_window_cost,
    samples_between,
    select_layouts,
)
from cr_control.tools.benchmark_runs import (
    Progress,
    format_reference,
    run_echo,
    run_offline,
    run_recorder_load,
    run_reference,
    run_session,
)
from cr_control.tools.session import (
    SessionConfig,
    SessionError,
    session_parameters,
)

#: Names other modules and the tests import from here (their code lives in the modules above).
__all__ = [
    "CLOCK_TICKS", "COST_TARGETS", "ISSUE_BEFORE", "LAYOUTS", "Progress", "REALTIME_ROWS",
    "REFERENCE_REV", "STATUS_TIME_FIELDS", "aba_us_per_call", "cell", "cost_targets", "cpu_from_samples",
    "cpu_per_cycle", "cpu_percent", "disturbed", "fmt", "format_realtime_table", "format_recorder_load",
    "format_reference", "format_repeats", "format_speed_table", "format_targets", "last_double",
    "layout_targets", "loop_figures", "loop_ns_per_iteration", "mcap_log_times", "median_figures",
    "offsets_from_end", "parse_done_line", "parse_machine_stat", "parse_proc_stat", "parse_published",
    "parse_recorder_missed", "ratios", "read_cpu_ticks", "read_machine_ticks", "realtime_targets",
    "recorder_window_cost", "reference_scaled", "run_pairs", "run_reference", "samples_between",
    "scaled_cost", "scaled_speed", "select_layouts", "step_us_hot_and_after_idle", "timing_dict",
    "verdict", "window_mean",
]


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
    p.add_argument("--skip-ur5", action="store_true", help="no UR5 session (500 Hz) and its echo pair")
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
                   help="git revision of the code the 'before' table measured, run by its own "
                        "benchmark beside ours to carry the cost targets to that table's "
                        f"machine (default {REFERENCE_REV})")
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
                                     ("panda", args.skip_recorder or args.skip_panda),
                                     ("ur5", args.skip_recorder or args.skip_ur5),
                                     ("ur5_position", args.skip_recorder),
                                     ("xarm7", args.skip_recorder)) if on]
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
    ends = [c["loop_ns"] for c in calibration.values() if finite_value(c.get("loop_ns"))]
    calibration["loop_ns"] = sum(ends) / len(ends)
    abas = [c["aba_us"] for c in (calibration["start"], calibration["end"]) if finite_value(c.get("aba_us"))]
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
