"""``cr_sweep SPEC.yaml --out DIR [--address ADDR]``: one offline run per point, on Ray.

Writes DIR/results.csv and DIR/results.parquet (:mod:`.table`: one row per point, its inputs,
``status`` and ``cr_analyze``'s metrics), DIR/plots/ (:mod:`.plots`), and keeps every finished
point in DIR/points.jsonl as it finishes (:mod:`.store`): running the same command again skips
them, so a killed sweep loses only the points that were in flight. The table is the same, bit
for bit, whatever the number of workers (rows sorted by point index, each point computed on
its own). SPEC format: :mod:`.spec`. Engine: :mod:`.engine` (loopback only).

Example::

    cr_sweep sweep.yaml --out /tmp/stiffness            # local Ray, every core
    cr_sweep sweep.yaml --out /tmp/stiffness --address 127.0.0.2:6379
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cr_control.experiments import engine, evaluate, plots, table
from cr_control.experiments.points import points
from cr_control.experiments.progress import Progress
from cr_control.experiments.spec import SpecError, SweepSpec, Targets, load_spec, shown
from cr_control.experiments.store import Store

#: Simulated seconds (at most) of the run that learns the metric names when the SPEC lists
#: some (chapter 5's figures need the disturbance, at 2 s by default).
PROBE_S = 10.0


@dataclass
class SweepResult:
    """What a sweep produced: the table, and how many points it computed and skipped."""

    columns: list[str]
    rows: list[dict[str, Any]]
    computed: int
    skipped: int
    figures: list[Path] = field(default_factory=list)

    def counts(self) -> Counter:
        return Counter(row["status"] for row in self.rows)


def jobs_of(spec: SweepSpec, targets: Targets, todo: Iterable[tuple[int, dict[str, Any]]]
            ) -> list[engine.Job]:
    """(index, inputs, controller overrides, plant overrides) of each point; SpecError
    naming the point if a node refuses its values together."""
    jobs = []
    for index, inputs in todo:
        values = {**spec.fixed, **inputs}
        try:
            targets.check(values)
        except SpecError as exc:
            raise SpecError(f"point {index} {inputs}: {exc}") from None
        controller, plant = targets.split(values)
        jobs.append((index, inputs, controller, plant))
    return jobs


def check_metrics(spec: SweepSpec, targets: Targets, known: Iterable[str] | None) -> None:
    """SpecError for a SPEC metric no point has (names from ``known``, else a short run)."""
    if spec.metrics is None:
        return
    if known is None:
        controller, plant = targets.split(spec.fixed)
        result = evaluate.run_point(spec.scheme, spec.robot, min(PROBE_S, spec.duration),
                                     controller, plant)
        if result["status"] == "failed":
            raise SpecError(f"{spec.scheme} does not run: {result['reason']}")
        known = result
    names = set(known) - set(table.STATUS)
    unknown = [m for m in spec.metrics if m not in names]
    if unknown:
        raise SpecError(f"metrics: unknown metric {shown(unknown[0])} (known: "
                        f"{', '.join(sorted(names))})")


def sweep(spec: SweepSpec, targets: Targets, out: Path, address: str | None = None,
          workers: int | None = None, chunk: int | None = None, show_progress: bool = True,
          plot: bool = True) -> SweepResult:
    """Run the points of ``spec`` not yet in ``out`` and write the table and figures.

    ``workers``: CPUs of a local Ray instance (default: every core), or at most that many
    tasks in flight on a cluster; ``chunk``: points per task (default: engine.chunk_size).
    Uses a Ray instance the caller started, if any. SpecError / EngineError (one line).
    """
    store = Store(out, spec)
    try:
        every = points(spec, targets)
        finished = store.finished()
        todo = [(i, inputs) for i, inputs in every if i not in finished]
        jobs = jobs_of(spec, targets, todo)
        known = next((r["result"] for r in finished.values() if r["result"]["status"] != "failed"),
                     None)
        check_metrics(spec, targets, known)
        bar = None
        if jobs:
            capacity = engine.start(address, workers)
            bar = Progress(len(every), len(every) - len(todo)) if show_progress else None

            def done(records: list[dict[str, Any]]) -> None:
                store.add(records)
                finished.update((r["point"], r) for r in records)
                if bar is not None:
                    bar.advance(len(records))

            try:
                engine.run(spec.scheme, spec.robot, spec.duration, jobs, capacity, done, chunk)
            finally:
                if bar is not None:
                    bar.close()
        elif show_progress:
            Progress(len(every), len(every)).close()
    finally:
        store.close()
    inputs = list(spec.vary)
    records = [finished[i] for i, _ in every]
    names, rows = table.write(Path(out), records, inputs, spec.metrics)
    figures = plots.plot(Path(out), names, rows, inputs, spec.metrics, grid=not spec.is_random) \
        if plot else []
    return SweepResult(names, rows, len(jobs), len(every) - len(jobs), figures)


def main(argv: Iterable[str] | None = None) -> int:
    """Entry point of ``cr_sweep``; returns the exit status."""
    parser = argparse.ArgumentParser(
        prog="cr_sweep", description="Offline runs of a scheme over a grid or random draws of "
        "its parameters, on Ray; a results table (CSV, parquet) and figures.")
    parser.add_argument("spec", type=Path, metavar="SPEC.yaml", help="the sweep (see "
                        "cr_control/experiments/spec.py)")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR",
                        help="results directory; a rerun resumes the sweep there")
    parser.add_argument("--address", metavar="HOST:PORT",
                        help="join this Ray cluster (default: a local instance)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="local CPUs (default: every core); with --address, most tasks "
                             "in flight")
    parser.add_argument("--no-plots", action="store_true", help="no figures")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(None if argv is None else list(argv))

    def error(message: str, status: int = 2) -> int:
        print(f"cr_sweep: error: {message}", file=sys.stderr)
        return status

    if args.workers is not None and args.workers < 1:
        return error(f"--workers must be >= 1, got {args.workers}")
    try:
        spec, targets = load_spec(args.spec)
        if args.address is not None:
            engine.parse_address(args.address)
        result = sweep(spec, targets, args.out, args.address, args.workers,
                       show_progress=not args.quiet, plot=not args.no_plots)
    except SpecError as exc:
        return error(str(exc))
    except engine.EngineError as exc:
        return error(str(exc), 1)
    except KeyboardInterrupt:
        return error(f"interrupted: the finished points are kept in {args.out}; run the same "
                     "command to resume", 130)
    finally:
        engine.stop()
    counts = result.counts()
    print(f"{len(result.rows)} points ({result.computed} computed, {result.skipped} from an "
          f"earlier run): {counts.get('ok', 0)} ok, {counts.get('stopped', 0)} stopped by a "
          f"reflex, {counts.get('diverged', 0)} diverged, {counts.get('failed', 0)} failed")
    print(f"wrote {args.out / 'results.csv'}, results.parquet and {len(result.figures)} figures")
    return 0


if __name__ == "__main__":
    sys.exit(main())
