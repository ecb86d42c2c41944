"""Analysis of recorded sessions (executable ``cr_analyze``): metrics, thesis figures, comparisons.

Reads any MCAP file the recorder wrote (or any ``ros2`` MCAP with this package's topics)
without ROS: messages are decoded with ``mcap_ros2``. A session gives what a control
engineer asks first: tracking metrics (RMS/max position and force error, settling time,
peak torque), controller compute time, loop timing, and the thesis's figures as PNG.
Metrics and figures cover the position axes the session has (x, y; and z on a spatial
arm); a robot session (``cr_session --robot``, wiping a table) also gets the wiping task's
metrics and figures of :mod:`cr_control.analysis.robot` (normal force, in-plane path error,
contact lost, orientation and posture error; 3-D and top-view path).

It also checks that the recording is one session's own: more than one publisher on a
control topic, or header stamps on /joint_states or /joint_commands that go backwards
or repeat, mean another run shared the ROS domain (cross-talk) or the plant restarted.
Such recordings get a ``WARNING`` line under the metrics and non-zero integrity fields.

Command line::

    cr_analyze FILE.mcap [FILE2.mcap ...] [--out DIR] [--no-plots] [--json]

prints the metrics table (one column per file) or JSON, and writes the figures (default:
``<stem>_plots/`` next to the first file; with several files, comparison figures there
and each session's own figures in a sub-directory per session). Exit status 2 on user
errors (missing, unreadable or non-MCAP files, no package topics).

This module is the command line; reading is :mod:`cr_control.analysis.session_file`, the
metrics :mod:`cr_control.analysis.metrics`, the figures :mod:`cr_control.analysis.plots`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from cr_control.analysis.metrics import (
    format_metrics,
    integrity,
    integrity_warnings,
    loop_summary,
    metrics,
    settling_time,
)
from cr_control.analysis.plots import compare, plot_session, session_labels
from cr_control.analysis.session_file import JointSeries, Session, SessionError, WrenchSeries, load_session

#: Names other modules and the tests import from here (their code lives in the modules above).
__all__ = [
    "JointSeries", "Session", "SessionError", "WrenchSeries", "compare", "format_metrics", "integrity",
    "integrity_warnings", "load_session", "loop_summary", "metrics", "plot_session", "session_labels",
    "settling_time",
]





# -- command line ------------------------------------------------------------------------

def _json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _folder_name(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in label).strip("_") or "session"


def _write_plots(sessions: Sequence[Session], out: Path) -> list[Path]:
    """Each session's own figures (in a sub-folder named by its label when several)."""
    if len(sessions) == 1:
        return plot_session(sessions[0], out)
    written = compare(sessions, out)
    for session, label in zip(sessions, session_labels(sessions), strict=True):
        written += plot_session(session, out / _folder_name(label))
    return written


def main(argv: Iterable[str] | None = None) -> int:
    """Entry point of ``cr_analyze``; returns the exit status."""
    parser = argparse.ArgumentParser(
        prog="cr_analyze",
        description="Metrics and thesis-style figures of recorded cr_control sessions.")
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE.mcap",
                        help="recorded sessions; several are compared side by side")
    parser.add_argument("--out", type=Path, metavar="DIR",
                        help="where to write figures (default: <first stem>_plots/ "
                             "next to the first file)")
    parser.add_argument("--no-plots", action="store_true", help="only print the metrics")
    parser.add_argument("--json", action="store_true",
                        help="print the metrics as JSON (one object per session)")
    args = parser.parse_args(None if argv is None else list(argv))

    def error(message: str) -> int:
        print(f"cr_analyze: error: {message}", file=sys.stderr)
        return 2

    sessions = []
    for path in args.files:
        try:
            sessions.append(load_session(path))
        except SessionError as exc:
            return error(str(exc))
    for session in sessions:
        for warning in session.warnings:
            print(f"cr_analyze: warning: {session.path}: {warning}", file=sys.stderr)

    labels = session_labels(sessions)
    rows = [(label, metrics(s)) for label, s in zip(labels, sessions, strict=True)]
    info = sys.stderr if args.json else sys.stdout
    if args.json:
        print(json.dumps({label: {k: _json_safe(v) for k, v in values.items()}
                          for label, values in rows}, indent=2))
        for label, values in rows:
            for text in integrity_warnings(values):
                print(f"WARNING: {label}: {text}", file=sys.stderr)
    else:
        print(format_metrics(rows))
    if not args.no_plots:
        first = args.files[0]
        out = args.out if args.out is not None else first.parent / f"{first.stem}_plots"
        try:
            written = _write_plots(sessions, out)
        except OSError as exc:
            return error(f"cannot write figures to {out}: {exc.strerror or exc}")
        print(f"wrote {len(written)} files to {out}", file=info)
    return 0


if __name__ == "__main__":
    sys.exit(main())
