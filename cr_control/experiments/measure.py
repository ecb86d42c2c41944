"""Ray's cost figures for the README (printed, never asserted): start-up time and memory of
a local instance, per-point overhead against the offline loop, parallel efficiency on 2
cores against 1. Run it on a quiet machine::

    python -m cr_control.experiments.measure --points 8 --duration 4

Per-point overhead = (wall time of the points on Ray with one CPU, workers already up - the
time spent inside the tasks) / points, relative to a point's time inside its task (both
measured in the same run, so the machine's load cancels out mostly). Parallel
efficiency = T(1 CPU) / (2 T(2 CPUs)) over the same points, workers already up (their start,
a one-time cost per worker, is printed apart). The load average is printed alongside.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Iterable

from cr_control.experiments import engine
from cr_control.experiments.points import points
from cr_control.experiments.spec import parse_spec
from cr_control.experiments.sweep import jobs_of


def _rss_mb(root: int) -> tuple[float, int]:
    """RSS (MB) of ``root``'s descendants (Ray's processes of a local instance) and their count."""
    out = subprocess.run(["ps", "-eo", "pid=,ppid=,rss="], capture_output=True, text=True).stdout
    rows = [tuple(map(int, line.split())) for line in out.splitlines()]
    kids: dict[int, list[tuple[int, int]]] = {}
    for pid, ppid, rss in rows:
        kids.setdefault(ppid, []).append((pid, rss))
    total, count, stack = 0, 0, [root]
    while stack:
        for pid, rss in kids.get(stack.pop(), []):
            total, count = total + rss, count + 1
            stack.append(pid)
    return total / 1024, count


def timed_chunk(scheme: str, duration: float, jobs) -> float:
    """Seconds ``engine.run_chunk`` takes inside a worker (the body of a measuring task)."""
    t0 = time.perf_counter()
    engine.run_chunk(scheme, None, duration, jobs)
    return time.perf_counter() - t0


def _timed(jobs, scheme: str, duration: float, cpus: int, chunk: int) -> tuple[float, float]:
    """(wall time of ``jobs`` on Ray, ``cpus`` tasks in flight; seconds spent inside tasks)."""
    # lazy: Ray takes seconds to import and only runs sweeps, tuning and the report
    import ray

    task = ray.remote(timed_chunk)
    chunks = [jobs[i:i + chunk] for i in range(0, len(jobs), chunk)]
    t0 = time.perf_counter()
    inside, pending, queue = 0.0, [], list(chunks)
    while queue or pending:
        while queue and len(pending) < cpus:
            pending.append(task.remote(scheme, duration, queue.pop(0)))
        ready, pending = ray.wait(pending, num_returns=1)
        inside += ray.get(ready[0])
    return time.perf_counter() - t0, inside


def main(argv: Iterable[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m cr_control.experiments.measure")
    p.add_argument("--points", type=int, default=8)
    p.add_argument("--duration", type=float, default=4.0)
    args = p.parse_args(None if argv is None else list(argv))
    spec, targets = parse_spec({"scheme": "adaptive_impedance", "duration": args.duration,
                                "vary": {"plant.stiffness": [100.0 + 10 * i
                                                             for i in range(args.points)]}})
    jobs = jobs_of(spec, targets, points(spec, targets))
    print(f"load average before: {os.getloadavg()}")
    engine.run_chunk(spec.scheme, None, 0.01, jobs[:1])          # kernels loaded
    t0 = time.perf_counter()
    engine.run_chunk(spec.scheme, None, spec.duration, jobs)
    per_point = (time.perf_counter() - t0) / len(jobs)
    print(f"offline loop in process: {per_point:.3f} s per {args.duration:g} s point")
    wall = {}
    for cpus in (1, 2):
        t0 = time.perf_counter()
        engine.start(None, cpus)
        started = time.perf_counter() - t0
        rss, count = _rss_mb(os.getpid())
        t0 = time.perf_counter()
        warm = [(i, {}, {}, {}) for i in range(cpus)]       # every worker up, kernels loaded
        engine.run(spec.scheme, None, 0.01, warm, cpus, lambda _: None, 1)
        print(f"{cpus} CPU: ray.init {started:.1f} s, first tasks (worker start, imports, "
              f"kernels) {time.perf_counter() - t0:.1f} s; {count} Ray processes, RSS "
              f"{rss:.0f} MB after init, {_rss_mb(os.getpid())[0]:.0f} MB with workers")
        chunk = engine.chunk_size(len(jobs), spec.duration, cpus)
        wall[cpus], inside = _timed(jobs, spec.scheme, spec.duration, cpus, chunk)
        print(f"{cpus} CPU: {len(jobs)} points in {wall[cpus]:.2f} s ({chunk} per task), "
              f"{inside:.2f} s of it inside the tasks")
        if cpus == 1:
            overhead = (wall[1] - inside) / len(jobs)
            print(f"per-point overhead on Ray (1 CPU, wall - time inside the tasks): "
                  f"{overhead * 1e3:.1f} ms = {100 * overhead / (inside / len(jobs)):.2f} % of "
                  f"a {args.duration:g} s point ({inside / len(jobs):.3f} s)")
        engine.stop()
    print(f"parallel efficiency 2 CPUs vs 1: {100 * wall[1] / (2 * wall[2]):.0f} %")
    print(f"load average after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
