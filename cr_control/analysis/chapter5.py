"""Chapter 5 analysis: unilateral contact on the circular surface (thesis figs. 5.3-5.9).

Works on a recorded session (:func:`from_session`) or an offline run (:func:`from_offline`)
of the ``impedance`` or ``fuzzy_unidirectional`` scheme: both publish the normal force
f_m = n^T f, the gap to the surface |r - c| - R (negative = penetration) and d_m, k_m in
their status (:mod:`cr_control.schemes.blocks.unidirectional_impedance`).

:func:`contact_metrics` gives the two chapter 5 schemes' figures side by side: time separated, minimum
normal force, force RMS error after the disturbance, position RMS error, peak torque,
d_m range. :func:`plot_chapter5` draws per scheme: position (figs. 5.3, 5.6), normal force
with the f_min/f_max band and the disturbance window (5.4, 5.7), torques (5.5, 5.8), d_m
(5.9); :func:`compare_chapter5` overlays several runs in one figure and writes one table.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cr_control.analysis.figures import column_figure
from cr_control.analysis.figures import save_figure as _save
from cr_control.core.parameters import resolve

#: Status fields that mark a chapter 5 run.
REQUIRED = ("f_m", "gap", "d_m", "k_m", "e_x", "e_y", "r_x", "r_y")
#: The tool counts as separated when it is farther than this outside the surface (m).
GAP_TOL = 1e-6
#: Start-up excluded from the minimum force (the run starts touching at zero force).
STARTUP_S = 0.5


@dataclass
class ContactRun:
    """Time series of one chapter 5 run, on a time axis starting at 0."""

    label: str
    time: np.ndarray
    r: np.ndarray          #: (k, 2) measured tool position
    r_d: np.ndarray        #: (k, 2) desired position
    e: np.ndarray          #: (k, 2) r_d - r
    f_m: np.ndarray        #: measured force along the outward normal (N)
    gap: np.ndarray        #: |r - c| - R (m), > 0 separated
    d_m: np.ndarray
    k_m: np.ndarray
    tau_time: np.ndarray
    tau: np.ndarray        #: (k, joints) applied torque
    f_dm: float
    f_min: float | None
    f_max: float | None
    disturbance: tuple[float, float]   #: (start, duration) s; duration 0 = none

    @property
    def disturbance_end(self) -> float:
        return self.disturbance[0] + self.disturbance[1]


def _float(values: dict[str, Any], name: str, default: float | None) -> float | None:
    value = values.get(name, default)
    return None if value is None else float(value)


def _disturbance(plant: dict[str, Any]) -> tuple[float, float]:
    if float(plant.get("disturbance_magnitude", 0.0) or 0.0) <= 0.0:
        return float(plant.get("disturbance_start", 0.0)), 0.0
    return float(plant.get("disturbance_start", 2.0)), float(plant.get("disturbance_duration", 0.06))


def is_chapter5(status: dict[str, np.ndarray] | Sequence[str]) -> bool:
    """True if the status carries the chapter 5 fields."""
    return all(name in status for name in REQUIRED)


def from_offline(run: Any, label: str, controller_values: dict[str, Any],
                 plant_values: dict[str, Any]) -> ContactRun:
    """A ContactRun from :class:`cr_control.offline.OfflineRun` and the converted
    parameter values of its controller and plant."""
    col = run.column
    t = run.time - run.time[0]
    return ContactRun(
        label, t, np.column_stack([col("r_x"), col("r_y")]),
        np.column_stack([col("r_d_x"), col("r_d_y")]), np.column_stack([col("e_x"), col("e_y")]),
        col("f_m"), col("gap"), col("d_m"), col("k_m"), t, np.asarray(run.command),
        float(controller_values["f_dm"]), _float(controller_values, "f_min", None),
        _float(controller_values, "f_max", None), _disturbance(plant_values))


def from_session(session: Any) -> ContactRun:
    """A ContactRun from a loaded session (:func:`cr_control.analysis.analyze.load_session`)."""
    s, ref = session.status, session.reference
    t = session.relative_time(s["stamp"])
    controller = session.parameters.get(session.controller or "", {})
    plant = session.parameters.get("plant", {})
    commands = session.joint_commands
    if commands is not None and np.isfinite(commands.effort).any():
        tau_t, tau = session.relative_time(commands.time), commands.effort
    else:
        names = sorted(k for k in s if k.startswith("tau_"))
        tau_t, tau = t, np.column_stack([s[k] for k in names])
    if "r_d_x" in ref and len(ref["r_d_x"]) == len(t):
        r_d = np.column_stack([ref["r_d_x"], ref["r_d_y"]])
    else:
        r_d = np.column_stack([s["r_x"] + s["e_x"], s["r_y"] + s["e_y"]])
    return ContactRun(
        session.name, t, np.column_stack([s["r_x"], s["r_y"]]), r_d,
        np.column_stack([s["e_x"], s["e_y"]]), s["f_m"], s["gap"], s["d_m"], s["k_m"],
        tau_t, tau, float(controller.get("f_dm", 10.0)), _float(controller, "f_min", None),
        _float(controller, "f_max", None), _disturbance(plant))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def contact_metrics(run: ContactRun) -> dict[str, float]:
    """The side-by-side figures of the chapter 5 schemes (SI units, keys end with the unit).

    ``separated_s``: time the tool spent outside the surface (gap > GAP_TOL = 1 um);
    ``no_force_s``: time with no pushing force (f_m <= 0) after t = 0;
    ``f_m_min_N``: minimum normal force after the start-up (t >= 0.5 s);
    ``f_m_min_after_N``: minimum from the disturbance on;
    ``f_err_rms_after_N``: RMS of f_dm - f_m from the disturbance on;
    ``pos_err_rms_m`` / ``pos_err_rms_after_m``: RMS of |r_d - r| over the run / from the
    disturbance on (r_d lies on the surface, so it includes the penetration f_m/K_e);
    ``pos_err_max_after_m``; ``gap_max_m``: farthest the tool got from the surface;
    ``tau_peak_Nm``; ``d_m_min``, ``d_m_max`` (N s/m).
    """
    t, dt = run.time, float(np.median(np.diff(run.time))) if len(run.time) > 1 else 0.0
    after = t >= run.disturbance[0]
    e = np.hypot(run.e[:, 0], run.e[:, 1])
    return {
        "separated_s": float(np.count_nonzero(run.gap > GAP_TOL) * dt),
        "no_force_s": float(np.count_nonzero((run.f_m <= 0.0) & (t > 0.0)) * dt),
        "f_m_min_N": float(np.min(run.f_m[t >= STARTUP_S])) + 0.0,     # + 0.0: no -0.0
        "f_m_min_after_N": float(np.min(run.f_m[after])) + 0.0,
        "f_err_rms_after_N": _rms(run.f_dm - run.f_m[after]),
        "pos_err_rms_m": _rms(e),
        "pos_err_rms_after_m": _rms(e[after]),
        "pos_err_max_after_m": float(np.max(e[after])),
        "gap_max_m": float(np.max(run.gap)),
        "tau_peak_Nm": float(np.max(np.abs(run.tau))),
        "d_m_min": float(np.min(run.d_m)),
        "d_m_max": float(np.max(run.d_m)),
    }


#: Columns of :func:`metrics_table`: (key, header, scale, format).
TABLE_COLUMNS = [
    ("separated_s", "sep. [ms]", 1e3, "{:.0f}"),
    ("f_m_min_after_N", "min f_m [N]", 1.0, "{:.2f}"),
    ("f_err_rms_after_N", "f err RMS [N]", 1.0, "{:.3f}"),
    ("pos_err_rms_m", "e RMS [mm]", 1e3, "{:.2f}"),
    ("pos_err_max_after_m", "e max [mm]", 1e3, "{:.2f}"),
    ("tau_peak_Nm", "tau max [Nm]", 1.0, "{:.2f}"),
    ("d_m_min", "d_m min", 1.0, "{:.2f}"),
    ("d_m_max", "d_m max", 1.0, "{:.2f}"),
]
#: What the columns mean (printed under the table).
TABLE_NOTE = ("sep.: time outside the surface; min f_m, f err RMS (f_dm - f_m), e max: from "
              "the disturbance on; e RMS: |r_d - r| over the run; tau max: peak |tau| of "
              "both joints; d_m range over the run.")


def metrics_table(rows: Sequence[tuple[str, dict[str, float]]]) -> str:
    """A Markdown table of contact metrics, one row per (label, metrics)."""
    header = "| run | " + " | ".join(h for _, h, _, _ in TABLE_COLUMNS) + " |"
    lines = [header, "|" + "---|" * (len(TABLE_COLUMNS) + 1)]
    for label, m in rows:
        cells = [fmt.format(m[key] * scale) for key, _, scale, fmt in TABLE_COLUMNS]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# -- figures -----------------------------------------------------------------------------
def _figure(rows: int, height: float = 2.3):
    return column_figure(rows, height)


def _mark_disturbance(ax: Any, run: ContactRun, label: bool = True) -> None:
    if run.disturbance[1] > 0.0:
        ax.axvspan(run.disturbance[0], run.disturbance_end, color="red", alpha=0.15,
                   label="disturbance" if label else None)


def _force_panel(ax: Any, runs: Sequence[ContactRun]) -> None:
    first = runs[0]
    for i, run in enumerate(runs):
        ax.plot(run.time, run.f_m, color=f"C{i}", lw=1.0,
                label=f"f_m {run.label}" if len(runs) > 1 else "f_m (measured)")
    ax.axhline(first.f_dm, color="k", ls="--", lw=0.8, label="f_dm")
    banded = [run for run in runs if run.f_min is not None and run.f_max is not None]
    if banded:
        ax.axhspan(banded[0].f_min, banded[0].f_max, color="green", alpha=0.08,
                   label="[f_min, f_max]")
    ax.axhline(0.0, color="k", lw=0.5)
    _mark_disturbance(ax, first)
    ax.set_ylabel("normal force f_m [N]")


def plot_chapter5(run: ContactRun, out_dir: str | Path) -> list[Path]:
    """Figs. 5.3-5.9 of one run as PNG in ``out_dir``: ch5_position, ch5_force, ch5_torques,
    ch5_impedance (d_m, k_m and the gap). Returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    fuzzy = run.f_min is not None
    figs = ("5.6", "5.7", "5.8", "5.9") if fuzzy else ("5.3", "5.4", "5.5", None)

    fig, axes = _figure(2)
    for ax, i, axis in zip(axes, (0, 1), ("x", "y"), strict=True):
        ax.plot(run.time, run.r[:, i], label=f"{axis}")
        ax.plot(run.time, run.r_d[:, i], "k--", lw=0.8, label=f"{axis}_d")
        _mark_disturbance(ax, run, label=i == 0)
        ax.set_ylabel(f"{axis} [m]")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{run.label}: position (cf. thesis fig. {figs[0]})")
    _save(fig, out / "ch5_position.png", written)

    fig, axes = _figure(2)
    _force_panel(axes[0], [run])
    axes[1].plot(run.time, run.gap * 1e3, label="gap |r - c| - R")
    axes[1].axhline(0.0, color="k", lw=0.5)
    _mark_disturbance(axes[1], run, label=False)
    axes[1].set_ylabel("gap [mm] (<0: pressed in)")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{run.label}: normal force and contact (cf. thesis fig. {figs[1]})")
    _save(fig, out / "ch5_force.png", written)

    fig, axes = _figure(run.tau.shape[1], height=1.9)
    for j, ax in enumerate(axes):
        ax.plot(run.tau_time, run.tau[:, j], label=f"tau_{j + 1}")
        _mark_disturbance(ax, run, label=j == 0)
        ax.set_ylabel(f"tau_{j + 1} [N m]")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{run.label}: joint torques (cf. thesis fig. {figs[2]})")
    _save(fig, out / "ch5_torques.png", written)

    fig, axes = _figure(2, height=1.9)
    axes[0].plot(run.time, run.d_m, label="d_m")
    axes[0].set_ylabel("d_m [N s/m]")
    axes[1].plot(run.time, run.k_m, label="k_m")
    axes[1].set_ylabel("k_m [N/m]")
    for ax in axes:
        _mark_disturbance(ax, run, label=False)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{run.label}: impedance parameters"
                 + (f" (cf. thesis fig. {figs[3]})" if figs[3] else " (fixed)"))
    _save(fig, out / "ch5_impedance.png", written)
    return written


def compare_chapter5(runs: Sequence[ContactRun], out_dir: str | Path) -> list[Path]:
    """One figure overlaying the runs (normal force, gap, position error, d_m) and the
    metrics table (ch5_comparison.png, ch5_comparison.md)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    fig, axes = _figure(4, height=2.0)
    _force_panel(axes[0], runs)
    for i, run in enumerate(runs):
        kw = dict(color=f"C{i}", lw=1.0, label=run.label)
        axes[1].plot(run.time, run.gap * 1e3, **kw)
        axes[2].plot(run.time, np.hypot(run.e[:, 0], run.e[:, 1]) * 1e3, **kw)
        axes[3].plot(run.time, run.d_m, **kw)
    for ax, ylabel in zip(axes[1:], ("gap [mm]", "|r_d - r| [mm]", "d_m [N s/m]"), strict=True):
        _mark_disturbance(ax, runs[0], label=False)
        ax.set_ylabel(ylabel)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("Chapter 5: fixed impedance vs fuzzy unidirectional control")
    _save(fig, out / "ch5_comparison.png", written)
    table = out / "ch5_comparison.md"
    table.write_text(metrics_table([(run.label, contact_metrics(run)) for run in runs]))
    written.append(table)
    return written


def session_figures(session: Any, out_dir: str | Path) -> list[Path]:
    """Figs. 5.3-5.9 of a loaded session if it is a chapter 5 one (else nothing)."""
    return plot_chapter5(from_session(session), out_dir) if is_chapter5(session.status) else []


def compare_sessions(sessions: Sequence[Any], labels: Sequence[str],
                     out_dir: str | Path) -> list[Path]:
    """The chapter 5 comparison of the chapter 5 sessions among ``sessions`` (two or more)."""
    runs = []
    for session, label in zip(sessions, labels, strict=True):
        if is_chapter5(session.status):
            run = from_session(session)
            run.label = label
            runs.append(run)
    return compare_chapter5(runs, out_dir) if len(runs) > 1 else []


# -- offline reproduction ----------------------------------------------------------------
#: Disturbances of the side-by-side table: (label, plant overrides). The thesis's, then harder.
DISTURBANCES = [
    ("thesis 2 N, 60 ms", {}),
    ("4 N, 100 ms", {"disturbance_magnitude": 4.0, "disturbance_duration": 0.1}),
    ("8 N, 100 ms", {"disturbance_magnitude": 8.0, "disturbance_duration": 0.1}),
    ("10 N, 200 ms", {"disturbance_magnitude": 10.0, "disturbance_duration": 0.2}),
]
SCHEMES = ("impedance", "fuzzy_unidirectional")


def offline_run(scheme: str, duration: float = 10.0, plant: dict[str, Any] | None = None,
                controller: dict[str, Any] | None = None, label: str | None = None) -> ContactRun:
    """Run ``scheme`` offline on the circular surface and return its ContactRun."""
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_control.offline import run_scheme
    from cr_control.schemes.registry import controller_class
    from cr_sim.plants import circular_surface

    result = run_scheme(scheme, duration, controller_overrides=controller, plant_overrides=plant)
    controller_values = resolve(controller_class(scheme).parameters(), controller)
    plant_values = resolve(circular_surface.PARAMETERS, plant)
    return from_offline(result, label or scheme, controller_values, plant_values)


def side_by_side(duration: float = 10.0, disturbances=DISTURBANCES,
                 plant: dict[str, Any] | None = None) -> list[tuple[str, dict[str, float]]]:
    """(label, contact metrics) of both schemes under each disturbance (offline)."""
    rows = []
    for name, overrides in disturbances:
        for scheme in SCHEMES:
            run = offline_run(scheme, duration, {**(plant or {}), **overrides})
            rows.append((f"{scheme}, {name}", contact_metrics(run)))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m cr_control.analysis.chapter5 [OUT_DIR]``: the side-by-side table of both
    schemes under the thesis disturbance and harder ones (offline, 10 s each) and, with
    OUT_DIR, figs. 5.3-5.9 and the comparison of the thesis case there."""
    import sys

    args = sys.argv[1:] if argv is None else list(argv)
    print(metrics_table(side_by_side()) + "\n" + TABLE_NOTE)
    if args:
        out = Path(args[0])
        runs = [offline_run(scheme) for scheme in SCHEMES]
        for run in runs:
            plot_chapter5(run, out / run.label)
        for path in compare_chapter5(runs, out):
            print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
