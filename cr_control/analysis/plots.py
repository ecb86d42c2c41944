"""A session's figures as PNG (:func:`plot_session`: position, force, torque, estimates,
loop timing, and the chapter's and robot's own figures) and several sessions side by side
(:func:`compare`).
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from cr_control.analysis import chapter2, chapter4, chapter5, chapter6, robot
from cr_control.analysis.figures import save_figure as _save
from cr_control.analysis.metrics import format_metrics, metrics
from cr_control.analysis.session_file import Session

#: Network-norm pairs of the NN schemes (true, estimate), thesis figs 3.12-3.14.
NORM_PAIRS = [("M_r_norm", "M_r_hat_norm"), ("C_r_norm", "C_r_hat_norm"),
              ("G_r_norm", "G_r_hat_norm")]
ESTIMATE_PREFIXES = ("A_hat", "B_hat", "c_hat")


# -- figures -----------------------------------------------------------------------------

def _figure(rows: int, cols: int = 1, height: float = 2.4):
    from matplotlib.figure import Figure  # lazy: no plotting cost for --no-plots

    fig = Figure(figsize=(7.5 if cols == 1 else 4.5 * cols, 0.8 + height * rows),
                 layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
    return fig, axes


def _has(series: dict[str, np.ndarray], *names: str) -> bool:
    return all(name in series for name in names) and len(series.get("stamp", ())) > 0


def _torques(session: Session) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(label, time, torque) per joint: commanded efforts, else status tau_*."""
    commands = session.joint_commands
    if commands is not None and np.isfinite(commands.effort).any():
        return [(name, commands.time, commands.effort[:, j])
                for j, name in enumerate(commands.names)
                if np.isfinite(commands.effort[:, j]).any()]
    return [(name, session.status["stamp"], session.status[name])
            for name in sorted(k for k in session.status if k.startswith("tau_"))]


def plot_session(session: Session, out_dir: str | Path) -> list[Path]:
    """Write the session's figures (thesis style) as PNG into ``out_dir``; returns paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    rel, status, ref = session.relative_time, session.status, session.reference
    title = session.name

    position_axes = robot.position_axes(status)
    if _has(status, "r_x", "r_y"):
        fig, axes = _figure(len(position_axes))
        for ax, axis in zip(axes[:, 0], position_axes, strict=True):
            ax.plot(rel(status["stamp"]), status[f"r_{axis}"], label=f"{axis} (actual)")
            if _has(ref, f"r_d_{axis}"):
                ax.plot(rel(ref["stamp"]), ref[f"r_d_{axis}"], "k--", label=f"{axis}_d (desired)")
            ax.set_ylabel(f"{axis} [m]")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: position tracking (cf. thesis figs 3.2, 3.5, 3.8)")
        _save(fig, out / "position.png", written)

    if _has(status, "e_x", "e_y"):
        fig, axes = _figure(2)
        t = rel(status["stamp"])
        axes[0, 0].plot(t, robot.error_norm(status) * 1e3, label="‖e‖")
        for axis in position_axes:
            axes[0, 0].plot(t, status[f"e_{axis}"] * 1e3, lw=0.8, label=f"e_{axis}")
            if f"f_err_{axis}" in status:
                axes[1, 0].plot(t, status[f"f_err_{axis}"], label=f"f_err_{axis}")
        axes[0, 0].set_ylabel("position error [mm]")
        axes[1, 0].set_ylabel("force error [N]")
        axes[1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: tracking errors")
        _save(fig, out / "errors.png", written)

    force = session.wrench
    if _has(status, "f_x", "f_y") or force is not None:
        fig, axes = _figure(len(position_axes))
        for i, (ax, axis) in enumerate(zip(axes[:, 0], position_axes, strict=True)):
            if _has(status, f"f_{axis}"):
                ax.plot(rel(status["stamp"]), status[f"f_{axis}"], label=f"f_{axis} (measured)")
            elif force is not None:
                ax.plot(rel(force.time), force.force[:, i], label=f"f_{axis} (measured)")
            if _has(ref, f"f_d_{axis}"):
                ax.plot(rel(ref["stamp"]), ref[f"f_d_{axis}"], "k--", label=f"f_d{axis} (desired)")
            ax.set_ylabel(f"f_{axis} [N]")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: contact force (cf. thesis figs 3.3, 3.6, 3.9)")
        _save(fig, out / "force.png", written)

    torques = _torques(session)
    if torques:
        fig, axes = _figure(len(torques), height=1.9)
        for ax, (name, t, tau) in zip(axes[:, 0], torques, strict=True):
            ax.plot(rel(t), tau, label=name)
            ax.set_ylabel(f"{name} [N m]")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: joint torques (cf. thesis figs 3.4, 3.7, 3.11)")
        _save(fig, out / "torques.png", written)

    groups = [(prefix, [k for k in status if k.startswith(prefix)])
              for prefix in ESTIMATE_PREFIXES]
    groups = [(prefix, names) for prefix, names in groups if names]
    if groups and _has(status):
        fig, axes = _figure(len(groups), height=2.0)
        for ax, (prefix, names) in zip(axes[:, 0], groups, strict=True):
            for name in names:
                ax.plot(rel(status["stamp"]), status[name], label=name)
            ax.set_ylabel(prefix)
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: adaptive impedance estimates")
        _save(fig, out / "estimates.png", written)

    if _has(status, "s_x", "s_y"):
        fig, axes = _figure(1)
        for axis in (a for a in robot.AXES if f"s_{a}" in status):
            axes[0, 0].plot(rel(status["stamp"]), status[f"s_{axis}"], label=f"s_{axis}")
        axes[0, 0].set_ylabel("s [m/s]")
        axes[0, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: sliding variable")
        _save(fig, out / "sliding.png", written)

    pairs = [(true, est) for true, est in NORM_PAIRS if _has(status, true, est)]
    if pairs:
        fig, axes = _figure(len(pairs), height=2.0)
        for ax, (true, est) in zip(axes[:, 0], pairs, strict=True):
            t = rel(status["stamp"])
            ax.plot(t, status[true], "k--", label=f"‖{true.removesuffix('_norm')}‖ (true)")
            ax.plot(t, status[est], label=f"‖{est.removesuffix('_norm')}‖ (network)")
            ax.set_ylabel("norm")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: network estimates (cf. thesis figs 3.12-3.14)")
        _save(fig, out / "network_norms.png", written)

    timing = session.timing
    compute = _has(status, "compute_time_us")
    if _has(timing, "rate_hz") or compute:
        panels = [p for p, ok in (("rate", _has(timing, "rate_hz")),
                                  ("age", _has(timing, "window_age_p99_ms")),
                                  ("compute", compute)) if ok]
        fig, axes = _figure(len(panels), height=1.9)
        for ax, panel in zip(axes[:, 0], panels, strict=True):
            if panel == "rate":
                ax.plot(rel(timing["stamp"]), timing["rate_hz"], ".-", label="rate")
                ax.set_ylabel("loop rate [Hz]")
            elif panel == "age":
                for key in ("window_age_p50_ms", "window_age_p99_ms", "window_age_max_ms"):
                    if key in timing:
                        ax.plot(rel(timing["stamp"]), timing[key], ".-",
                                label=key.removeprefix("window_age_").removesuffix("_ms"))
                ax.set_ylabel("state→command [ms]")
            else:
                ax.plot(rel(status["stamp"]), status["compute_time_us"], lw=0.6,
                        label="compute time")
                ax.set_ylabel("compute [µs]")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"{title}: loop timing")
        _save(fig, out / "loop_timing.png", written)
    written += chapter5.session_figures(session, out)   # figs. 5.3-5.9 for chapter 5 runs
    written += chapter2.session_figures(session, out)   # figs. 2.4-2.12 for chapter 2 runs
    written += chapter4.session_figures(session, out)   # figs. 4.2-4.11, appendix C
    written += chapter6.session_figures(session, out)   # figs. 6.2-6.18 for chapter 6 runs
    written += robot.session_figures(session, out)      # a URDF arm wiping a table
    return written


def session_labels(sessions: Sequence[Session]) -> list[str]:
    """A distinct label per session: controller name, with the file stem when needed."""
    names = [s.name for s in sessions]
    labels = [f"{s.name} ({s.path.stem})" if names.count(s.name) > 1 and s.controller
              else s.name for s in sessions]
    return [f"{label} #{i + 1}" if labels.count(label) > 1 else label
            for i, label in enumerate(labels)]


def _overlay(sessions: Sequence[Session], labels: Sequence[str], path: Path, title: str,
             panels: Sequence[tuple[str, Callable[[Session], list[tuple[np.ndarray,
                                                                          np.ndarray, str]]]]],
             written: list[Path]) -> None:
    """One figure, a panel per quantity, one line per session (plus dashed references)."""
    panels = [(ylabel, get) for ylabel, get in panels if any(get(s) for s in sessions)]
    if not panels:
        return
    fig, axes = _figure(len(panels), height=2.2)
    for ax, (ylabel, get) in zip(axes[:, 0], panels, strict=True):
        for i, (session, label) in enumerate(zip(sessions, labels, strict=True)):
            for t, y, style in get(session):
                if style == "desired":
                    ax.plot(session.relative_time(t), y, "--", color=f"C{i}", lw=0.8, alpha=0.7)
                else:
                    ax.plot(session.relative_time(t), y, color=f"C{i}", lw=1.0,
                            label=label if style == "first" else None)
        ax.set_ylabel(ylabel)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    _save(fig, path, written)


def compare(sessions: Sequence[Session], out_dir: str | Path) -> list[Path]:
    """Side-by-side figures (one line per session) and the metrics table of ``sessions``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    labels = session_labels(sessions)
    written: list[Path] = []

    def status_line(name: str, scale: float = 1.0):
        def get(s: Session) -> list:
            return [(s.status["stamp"], scale * s.status[name], "first")] if _has(
                s.status, name) else []
        return get

    def tracked(actual: str, desired: str):
        def get(s: Session) -> list:
            lines = status_line(actual)(s)
            if lines and _has(s.reference, desired):
                lines.append((s.reference["stamp"], s.reference[desired], "desired"))
            return lines
        return get

    def error_norm(s: Session) -> list:
        if not _has(s.status, "e_x", "e_y"):
            return []
        return [(s.status["stamp"], 1e3 * robot.error_norm(s.status), "first")]

    _overlay(sessions, labels, out / "compare_position.png",
             "Position tracking (dashed: desired)",
             [("x [m]", tracked("r_x", "r_d_x")), ("y [m]", tracked("r_y", "r_d_y")),
              ("z [m]", tracked("r_z", "r_d_z")), ("‖e‖ [mm]", error_norm)], written)
    forces = [(f"f_{a} [N]", tracked(f"f_{a}", f"f_d_{a}")) for a in robot.AXES]
    forces += [(f"f_err_{a} [N]", status_line(f"f_err_{a}")) for a in robot.AXES]
    _overlay(sessions, labels, out / "compare_force.png", "Contact force (dashed: desired)",
             forces, written)
    _overlay(sessions, labels, out / "compare_robot.png", "Wiping the table (dashed: desired)",
             robot.compare_panels(), written)
    joints: list[str] = []
    for s in sessions:
        joints += [name for name, _, _ in _torques(s) if name not in joints]

    def torque(joint: str):
        def get(s: Session) -> list:
            return [(t, tau, "first") for name, t, tau in _torques(s) if name == joint]
        return get

    _overlay(sessions, labels, out / "compare_torques.png", "Joint torques",
             [(f"{j} [N m]", torque(j)) for j in joints], written)

    def timing_line(name: str):
        def get(s: Session) -> list:
            return [(s.timing["stamp"], s.timing[name], "first")] if _has(s.timing, name) else []
        return get

    _overlay(sessions, labels, out / "compare_loop_timing.png", "Loop timing",
             [("loop rate [Hz]", timing_line("rate_hz")),
              ("age p99 [ms]", timing_line("window_age_p99_ms")),
              ("compute [µs]", status_line("compute_time_us"))], written)

    rows = [(label, metrics(s)) for label, s in zip(labels, sessions, strict=True)]
    table = out / "comparison.txt"
    table.write_text(format_metrics(rows) + "\n")
    written.append(table)
    table_csv = out / "comparison.csv"
    with open(table_csv, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["metric", *labels])
        keys: list[str] = []
        for _, values in rows:
            keys += [k for k in values if k not in keys]
        for key in keys:
            writer.writerow([key, *(values.get(key, "") for _, values in rows)])
    written.append(table_csv)
    written += chapter5.compare_sessions(sessions, labels, out)   # chapter 5 runs: one table
    written += chapter2.compare_sessions(sessions, labels, out)   # chapter 2 runs: one table
    written += chapter4.compare_sessions(sessions, labels, out)   # chapter 4 / appendix C
    written += chapter6.compare_sessions(sessions, labels, out)   # chapter 6 runs: one table
    return written
