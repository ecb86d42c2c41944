"""Chapter 2 analysis: a robot constrained by a moving object (thesis figs. 2.4-2.12).

Works on a recorded session (:func:`from_session`) or an offline run (:func:`from_offline`)
of ``moving_object_adaptive`` or ``moving_object_nn``: both publish the object position x_o,
the contact point on the object x_co, their errors, e^1 = q_d^1 - q^1, the contact force
lambda and its error, and tau_1..tau_3 (tau^1 of the arm, tau^2 = the prismatic axis's
force) in their status (:mod:`cr_control.schemes.closed_chain.moving_object_model`); the adaptive scheme
adds P_hat_1..7, the network scheme |M^1|, |M^_nn|, |C^1|, |C^_nn|, |G^1|, |G^_nn|.

:func:`object_metrics` gives the chapter 2 schemes' figures side by side, per time window: RMS/max
of |e^1|, x_o and x_co errors, lambda range and error, peak torques; :func:`run_summary`
the whole-run numbers (lambda < 0 intervals, final estimates and norm errors).
:func:`plot_chapter2` draws per scheme: object and contact-point tracking (figs. 2.4, 2.7),
lambda vs lambda_d (2.5, 2.8), tau^1 and tau^2 (2.6, 2.9), the network norms (2.10-2.12)
or the adaptive estimates P_hat against the true P; :func:`compare_chapter2` overlays both
schemes in one figure and writes one table.

``python -m cr_control.analysis.chapter2 OUT_DIR [DURATION]`` runs both schemes offline
(default 20 s each) and writes all of it there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cr_control.analysis.figures import column_figure
from cr_control.analysis.figures import save_figure as save

#: Status fields that mark a chapter 2 run.
REQUIRED = ("lambda", "lambda_err", "x_o", "x_o_err", "x_co", "x_co_err", "e1_1", "e1_2",
            "tau_1", "tau_2", "tau_3")
#: Network-norm pairs (true, estimate) of figs. 2.10-2.12.
NORM_PAIRS = (("M1_norm", "M1_hat_norm", "M1", "2.10"), ("C1_norm", "C1_hat_norm", "C1", "2.11"),
              ("G1_norm", "G1_hat_norm", "G1", "2.12"))
ESTIMATE_FIELDS = tuple(f"P_hat_{i + 1}" for i in range(7))
#: Windows (s) of the side-by-side table (cut to the run's length).
WINDOWS = ((0.0, 1.0), (1.0, 5.0), (5.0, 10.0), (10.0, 15.0), (15.0, 20.0))
SCHEMES = ("moving_object_adaptive", "moving_object_nn")
SHORT = {"moving_object_adaptive": "adaptive (2.27)", "moving_object_nn": "network (2.74)"}


@dataclass
class ObjectRun:
    """Time series of one chapter 2 run, on a time axis starting at 0."""

    label: str
    time: np.ndarray
    x_o: np.ndarray            #: object position (m)
    x_o_d: np.ndarray
    x_co: np.ndarray           #: contact point on the object's line, object frame (m)
    x_co_d: np.ndarray
    e1: np.ndarray             #: (k, 2) q_d^1 - q^1 (rad)
    lam: np.ndarray            #: contact force lambda along n_c (N)
    lam_d: np.ndarray
    tau: np.ndarray            #: (k, 3) tau^1 (N m, N m) and tau^2 (N)
    #: Adaptive estimates P_hat_i (empty for the network scheme).
    estimates: dict[str, np.ndarray] = field(default_factory=dict)
    #: Network norms (true and estimate) by field name (empty for the adaptive scheme).
    norms: dict[str, np.ndarray] = field(default_factory=dict)
    true_p: np.ndarray | None = None   #: the true P of section 2.4, where known


def is_chapter2(status: dict[str, np.ndarray] | Sequence[str]) -> bool:
    """True if the status carries the chapter 2 fields."""
    return all(name in status for name in REQUIRED)


def _true_p() -> np.ndarray:
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_control.schemes.closed_chain.moving_object_model import TRUE_P  # analysis -> schemes (one way)

    return np.asarray(TRUE_P, dtype=float)


def _build(label: str, t: np.ndarray, col: Any) -> ObjectRun:
    x_o, x_co, lam = col("x_o"), col("x_co"), col("lambda")
    run = ObjectRun(label, t, x_o, x_o + col("x_o_err"), x_co, x_co + col("x_co_err"),
                    np.column_stack([col("e1_1"), col("e1_2")]), lam, lam + col("lambda_err"),
                    np.column_stack([col("tau_1"), col("tau_2"), col("tau_3")]))
    return run


def from_offline(run: Any, label: str) -> ObjectRun:
    """An ObjectRun from :class:`cr_control.offline.OfflineRun`."""
    out = _build(label, run.time - run.time[0], run.column)
    names = set(run.status_fields)
    out.estimates = {n: run.column(n) for n in ESTIMATE_FIELDS if n in names}
    out.norms = {n: run.column(n) for pair in NORM_PAIRS for n in pair[:2] if n in names}
    out.true_p = _true_p() if out.estimates else None
    return out


def from_session(session: Any) -> ObjectRun:
    """An ObjectRun from a loaded session (:func:`cr_control.analysis.analyze.load_session`)."""
    s = session.status
    out = _build(session.name, session.relative_time(s["stamp"]), s.__getitem__)
    out.estimates = {n: s[n] for n in ESTIMATE_FIELDS if n in s}
    out.norms = {n: s[n] for pair in NORM_PAIRS for n in pair[:2] if n in s}
    out.true_p = _true_p() if out.estimates else None
    return out


# -- metrics -----------------------------------------------------------------------------
def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def windows(run: ObjectRun, spans: Sequence[tuple[float, float]] = WINDOWS
            ) -> list[tuple[float, float]]:
    """``spans`` cut to the run (windows past its end dropped, the last one cut)."""
    t = run.time
    end = float(t[-1] + (np.median(np.diff(t)) if len(t) > 1 else 1e-9)) if len(t) else 0.0
    last = float(t[-1]) if len(t) else -1.0
    return [(a, min(b, end)) for a, b in spans if a <= last]


def object_metrics(run: ObjectRun, a: float, b: float) -> dict[str, float]:
    """Numbers of the window [a, b) s (SI units; keys end with the unit)."""
    w = (run.time >= a) & (run.time < b)
    e1 = np.hypot(run.e1[w, 0], run.e1[w, 1])
    x_o_err, x_co_err = (run.x_o_d - run.x_o)[w], (run.x_co_d - run.x_co)[w]
    lam = run.lam[w]
    tau = np.abs(run.tau[w])
    return {
        "e1_rms_rad": _rms(e1), "e1_max_rad": float(np.max(e1)),
        "x_o_err_rms_m": _rms(x_o_err), "x_o_err_max_m": float(np.max(np.abs(x_o_err))),
        "x_co_err_rms_m": _rms(x_co_err), "x_co_err_max_m": float(np.max(np.abs(x_co_err))),
        "lambda_min_N": float(np.min(lam)), "lambda_max_N": float(np.max(lam)),
        "lambda_err_rms_N": _rms((run.lam_d - run.lam)[w]),
        "tau1_peak_Nm": float(np.max(tau[:, :2])), "tau2_peak_N": float(np.max(tau[:, 2])),
    }


def _negative_intervals(t: np.ndarray, lam: np.ndarray) -> list[tuple[float, float]]:
    neg = np.concatenate([[0], (lam < 0.0).astype(int), [0]])
    starts = np.flatnonzero(np.diff(neg) == 1)
    ends = np.flatnonzero(np.diff(neg) == -1) - 1
    return [(float(t[s]), float(t[e])) for s, e in zip(starts, ends, strict=True)]


def run_summary(run: ObjectRun, last: float = 5.0) -> dict[str, Any]:
    """Whole-run numbers: lambda range, the intervals with lambda < 0 (a real contact would
    separate there), peak torques, and the estimates: |P_hat - P| at the start and the end
    (adaptive), or the relative RMS error of each network norm over the last ``last`` s
    (network: |  |X| - |X^|  | RMS / |X| RMS)."""
    t = run.time
    out: dict[str, Any] = {
        "lambda_min_N": float(np.min(run.lam)), "lambda_max_N": float(np.max(run.lam)),
        "lambda_negative": _negative_intervals(t, run.lam),
        "tau1_peak_Nm": float(np.max(np.abs(run.tau[:, :2]))),
        "tau2_peak_N": float(np.max(np.abs(run.tau[:, 2]))),
    }
    if run.estimates and run.true_p is not None:
        p = np.column_stack([run.estimates[n] for n in ESTIMATE_FIELDS if n in run.estimates])
        if p.shape[1] == len(run.true_p):
            out["P_err_start"] = float(np.linalg.norm(p[0] - run.true_p))
            out["P_err_end"] = float(np.linalg.norm(p[-1] - run.true_p))
            out["P_hat_end"] = p[-1].tolist()
    late = t >= t[-1] - last
    for true, est, name, _ in NORM_PAIRS:
        if true in run.norms and est in run.norms:
            a, b = run.norms[true][late], run.norms[est][late]
            out[f"{name}_norm_rel_err"] = _rms(a - b) / max(_rms(a), 1e-12)
    return out


#: Columns of :func:`metrics_table`: (key, header, scale, format).
TABLE_COLUMNS = [
    ("e1_rms_rad", "‖e¹‖ RMS [mrad]", 1e3, "{:.3g}"),
    ("e1_max_rad", "‖e¹‖ max [mrad]", 1e3, "{:.3g}"),
    ("x_o_err_rms_m", "x_o err RMS [mm]", 1e3, "{:.3g}"),
    ("x_o_err_max_m", "x_o err max [mm]", 1e3, "{:.3g}"),
    ("x_co_err_rms_m", "x_co err RMS [mm]", 1e3, "{:.3g}"),
    ("x_co_err_max_m", "x_co err max [mm]", 1e3, "{:.3g}"),
    ("lambda_min_N", "λ min [N]", 1.0, "{:.3f}"),
    ("lambda_max_N", "λ max [N]", 1.0, "{:.3f}"),
    ("lambda_err_rms_N", "λ err RMS [N]", 1.0, "{:.3f}"),
    ("tau1_peak_Nm", "max \\|τ¹\\| [N m]", 1.0, "{:.3f}"),
    ("tau2_peak_N", "max \\|τ²\\| [N]", 1.0, "{:.3f}"),
]
TABLE_NOTE = ("Per window [a, b) s: e¹ = q_d¹ − q¹ (joint error of the arm), x_o err = "
              "x_o,d − x_o (object), x_co err = x_co,d − x_co (contact point on the object's "
              "line), λ the contact force along n_c (λ_d = 2 N), τ¹ the arm's two joint "
              "torques, τ² the prismatic axis's force.")


def metrics_table(runs: Sequence[ObjectRun], spans: Sequence[tuple[float, float]] = WINDOWS
                  ) -> str:
    """A Markdown table, one row per (run, window), then one summary line per run."""
    header = "| run | window [s] | " + " | ".join(h for _, h, _, _ in TABLE_COLUMNS) + " |"
    lines = [header, "|" + "---|" * (len(TABLE_COLUMNS) + 2)]
    for a, b in windows(runs[0], spans) if runs else []:
        for run in runs:
            m = object_metrics(run, a, b)
            cells = [fmt.format(m[key] * scale) for key, _, scale, fmt in TABLE_COLUMNS]
            lines.append(f"| {run.label} | {a:g}–{b:.3g} | " + " | ".join(cells) + " |")
    lines += ["", TABLE_NOTE, ""]
    for run in runs:
        s = run_summary(run)
        neg = s["lambda_negative"]
        text = (f"- **{run.label}**: λ ∈ [{s['lambda_min_N']:.3f}, {s['lambda_max_N']:.3f}] N "
                f"over the run; λ < 0 in {len(neg)} interval(s)"
                + (": " + ", ".join(f"[{x:.3f}, {y:.3f}] s" for x, y in neg[:5]) if neg else "")
                + f"; peak |τ¹| {s['tau1_peak_Nm']:.3f} N m, |τ²| {s['tau2_peak_N']:.3f} N")
        if "P_err_end" in s:
            text += (f"; ‖P̂ − P‖ {s['P_err_start']:.3f} → {s['P_err_end']:.3f}, P̂(end) = ["
                     + ", ".join(f"{x:.4f}" for x in s["P_hat_end"]) + "]")
        rel = [f"{name} {s[f'{name}_norm_rel_err']:.3f}" for _, _, name, _ in NORM_PAIRS
               if f"{name}_norm_rel_err" in s]
        if rel:
            text += "; relative RMS error of ‖·‖ vs ‖·̂‖ over the last 5 s: " + ", ".join(rel)
        lines.append(text + ".")
    return "\n".join(lines) + "\n"


# -- figures -----------------------------------------------------------------------------
def figure(rows: int, height: float = 2.2, sharex: bool = True):
    """A one-column figure of ``rows`` panels."""
    return column_figure(rows, height, sharex)


def _figs(run: ObjectRun) -> tuple[str, str, str]:
    return ("2.7", "2.8", "2.9") if run.norms else ("2.4", "2.5", "2.6")


#: Window (s) of the running RMS drawn for tracking errors (|e| itself crosses zero often).
RMS_WINDOW_S = 0.25
#: Start-up left out when y limits are chosen (the first cycles' peaks would flatten the rest).
STARTUP_S = 0.5


def running_rms(t: np.ndarray, x: np.ndarray, window: float = RMS_WINDOW_S) -> np.ndarray:
    """Centred running RMS of ``x`` over ``window`` s (uniform sampling assumed)."""
    if len(t) < 2:
        return np.abs(x)
    n = max(1, int(round(window / float(np.median(np.diff(t))))))
    kernel = np.ones(n) / n
    return np.sqrt(np.convolve(np.square(x), kernel, mode="same")
                   / np.convolve(np.ones_like(x), kernel, mode="same"))


def robust_ylim(ax: Any, pairs: Sequence[tuple[np.ndarray, np.ndarray]], skip: float = STARTUP_S,
                floor: Sequence[float] = ()) -> None:
    """y limits from the data after ``skip`` s (plus ``floor`` values, e.g. the desired one),
    with a margin; notes in the label when the start-up peaks are cut off."""
    kept, clipped = [], False
    for t, y in pairs:
        later = y[t >= min(skip, float(t[-1]))]
        later = later[np.isfinite(later)]
        if len(later):
            kept.append(later)
            clipped |= bool(np.nanmax(y) > later.max() or np.nanmin(y) < later.min())
    if not kept:
        return
    values = np.concatenate([*kept, np.asarray(floor, dtype=float)])
    lo, hi = float(values.min()), float(values.max())
    pad = 0.1 * (hi - lo) or 0.1 * max(abs(hi), 1.0)
    ax.set_ylim(lo - pad, hi + pad)
    if clipped:
        ax.set_ylabel(ax.get_ylabel() + "\n(start-up peaks off scale)")


def _error_panel(ax: Any, run: ObjectRun) -> None:
    t = run.time
    for y, style, name in ((run.x_o_d - run.x_o, "C0", r"$x_{o,d} - x_o$ [mm]"),
                           (run.x_co_d - run.x_co, "C1", r"$x_{co,d} - x_{co}$ [mm]"),
                           (np.hypot(run.e1[:, 0], run.e1[:, 1]), "C2",
                            r"$\|e^1\| = \|q^1_d - q^1\|$ [mrad]")):
        ax.semilogy(t, np.maximum(running_rms(t, y) * 1e3, 1e-6), style, lw=1.0, label=name)
    ax.set_ylabel(f"running RMS\n({RMS_WINDOW_S:g} s), log")


def plot_chapter2(run: ObjectRun, out_dir: str | Path) -> list[Path]:
    """Figs. 2.4-2.12 of one run as PNG in ``out_dir``: ch2_position, ch2_force,
    ch2_torques, and ch2_network (figs. 2.10-2.12) or ch2_estimates. Returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    t = run.time
    fig_pos, fig_force, fig_tau = _figs(run)
    desired = dict(color="k", ls="-", lw=1.8, alpha=0.45)

    fig, axes = figure(3)
    axes[0].plot(t, run.x_o_d, **desired, label=r"$x_{o,d}$ (desired)")
    axes[0].plot(t, run.x_o, "C0--", lw=1.0, label=r"$x_o$ (object)")
    axes[0].set_ylabel(r"object $x_o$ [m]")
    axes[1].plot(t, run.x_co_d, **desired, label=r"$x_{co,d}$ (desired)")
    axes[1].plot(t, run.x_co, "C1--", lw=1.0, label=r"$x_{co}$ ($= y_{co}$ on the line)")
    axes[1].set_ylabel(r"contact point $x_{co}$ [m]")
    _error_panel(axes[2], run)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{run.label}: object and contact-point tracking (cf. thesis fig. {fig_pos})")
    save(fig, out / "ch2_position.png", written)

    fig, axes = figure(2, sharex=False)
    early = t <= min(1.0, float(t[-1]))
    for ax, w, title in ((axes[0], slice(None), "whole run"), (axes[1], early, "first second")):
        ax.plot(t[w], run.lam_d[w], **desired, label=r"$\lambda_d$ (desired)")
        ax.plot(t[w], run.lam[w], "C3--", lw=1.0, label=r"$\lambda$ (measured)")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel(rf"$\lambda$ [N] ({title})")
        ax.set_xlabel("t [s]")
    robust_ylim(axes[0], [(t, run.lam)], floor=[0.0, float(run.lam_d.max())])
    fig.suptitle(f"{run.label}: constraint force (cf. thesis fig. {fig_force})")
    save(fig, out / "ch2_force.png", written)

    fig, axes = figure(2)
    axes[0].plot(t, run.tau[:, 0], "C0-", lw=1.0, label=r"$\tau^1_1$ (joint 1)")
    axes[0].plot(t, run.tau[:, 1], "C1--", lw=1.0, label=r"$\tau^1_2$ (joint 2)")
    axes[0].set_ylabel(r"$\tau^1$ [N m]")
    axes[1].plot(t, run.tau[:, 2], "C2-.", lw=1.0, label=r"$\tau^2$ (object axis)")
    axes[1].set_ylabel(r"$\tau^2$ [N]")
    robust_ylim(axes[0], [(t, run.tau[:, 0]), (t, run.tau[:, 1])])
    robust_ylim(axes[1], [(t, run.tau[:, 2])])
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{run.label}: torques/forces of the manipulators (cf. thesis fig. {fig_tau})")
    save(fig, out / "ch2_torques.png", written)

    pairs = [p for p in NORM_PAIRS if p[0] in run.norms and p[1] in run.norms]
    if pairs:
        fig, axes = figure(len(pairs), height=2.0)
        for ax, (true, est, name, number) in zip(axes, pairs, strict=True):
            sym = name[0]
            ax.plot(t, run.norms[true], **desired, label=rf"$\|{sym}^1\|$ (true)")
            ax.plot(t, run.norms[est], "C4--", lw=1.0,
                    label=rf"$\|\hat{{{sym}}}^1_{{nn}}\|$ (network)")
            ax.set_ylabel(rf"$\|{sym}^1\|$ (fig. {number})")
            robust_ylim(ax, [(t, run.norms[true]), (t, run.norms[est])], floor=[0.0])
        axes[-1].set_xlabel("t [s]")
        fig.suptitle(f"{run.label}: network approximation (cf. thesis figs. 2.10-2.12;\n"
                     "spectral norm of the 3x2 M, C; Euclidean of G; SI units)")
        save(fig, out / "ch2_network.png", written)
    if run.estimates:
        fig, axes = figure(1, height=3.2)
        for i, name in enumerate(ESTIMATE_FIELDS):
            if name in run.estimates:
                axes[0].plot(t, run.estimates[name], color=f"C{i}", lw=1.0,
                             label=rf"$\hat P_{i + 1}$")
                if run.true_p is not None and i < len(run.true_p):
                    axes[0].axhline(run.true_p[i], color=f"C{i}", ls=":", lw=1.0)
        axes[0].set_ylabel(r"$\hat P$ (dotted: true $P$)")
        axes[0].set_xlabel("t [s]")
        fig.suptitle(f"{run.label}: parameter estimates of the adaptation law (2.35)")
        save(fig, out / "ch2_estimates.png", written)
    return written


def compare_chapter2(runs: Sequence[ObjectRun], out_dir: str | Path,
                     spans: Sequence[tuple[float, float]] = WINDOWS) -> list[Path]:
    """One figure overlaying the runs (lambda with lambda_d, object and contact-point
    errors, torques) and the metrics table (ch2_comparison.png, ch2_comparison.md)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    fig, axes = figure(5, height=1.9)
    axes[0].plot(runs[0].time, runs[0].lam_d, "k-", lw=1.8, alpha=0.45, label=r"$\lambda_d$")
    for i, run in enumerate(runs):
        t = run.time
        kw = dict(color=f"C{i}", lw=1.0, label=run.label)
        axes[0].plot(t, run.lam, **kw)
        axes[1].semilogy(t, np.maximum(running_rms(t, run.x_o_d - run.x_o) * 1e3, 1e-6), **kw)
        axes[2].semilogy(t, np.maximum(running_rms(t, run.x_co_d - run.x_co) * 1e3, 1e-6), **kw)
        axes[3].plot(t, np.hypot(run.tau[:, 0], run.tau[:, 1]), **kw)
        axes[4].plot(t, run.tau[:, 2], **kw)
    for ax, ylabel in zip(axes, (r"$\lambda$ [N]", r"$x_{o,d} - x_o$" + "\nRMS [mm]",
                                 r"$x_{co,d} - x_{co}$" + "\nRMS [mm]", r"$\|\tau^1\|$ [N m]",
                                 r"$\tau^2$ [N]"), strict=True):
        ax.set_ylabel(ylabel)
    robust_ylim(axes[0], [(r.time, r.lam) for r in runs], floor=[0.0, float(runs[0].lam_d.max())])
    robust_ylim(axes[3], [(r.time, np.hypot(r.tau[:, 0], r.tau[:, 1])) for r in runs], floor=[0.0])
    robust_ylim(axes[4], [(r.time, r.tau[:, 2]) for r in runs])
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("Chapter 2: model-based adaptive vs RBF-network control\n"
                 f"(errors: running RMS over {RMS_WINDOW_S:g} s; numbers in ch2_comparison.md)")
    save(fig, out / "ch2_comparison.png", written)
    table = out / "ch2_comparison.md"
    table.write_text(metrics_table(runs, spans))
    written.append(table)
    return written


def session_figures(session: Any, out_dir: str | Path) -> list[Path]:
    """Figs. 2.4-2.12 of a loaded session if it is a chapter 2 one (else nothing)."""
    return plot_chapter2(from_session(session), out_dir) if is_chapter2(session.status) else []


def compare_sessions(sessions: Sequence[Any], labels: Sequence[str],
                     out_dir: str | Path) -> list[Path]:
    """The chapter 2 comparison of the chapter 2 sessions among ``sessions`` (two or more)."""
    runs = []
    for session, label in zip(sessions, labels, strict=True):
        if is_chapter2(session.status):
            run = from_session(session)
            run.label = label
            runs.append(run)
    return compare_chapter2(runs, out_dir) if len(runs) > 1 else []


# -- offline reproduction ----------------------------------------------------------------
def offline_run(scheme: str, duration: float = 20.0, controller: dict[str, Any] | None = None,
                plant: dict[str, Any] | None = None, label: str | None = None) -> ObjectRun:
    """Run ``scheme`` offline on the moving-object plant and return its ObjectRun."""
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_control.offline import run_scheme

    result = run_scheme(scheme, duration, controller_overrides=controller, plant_overrides=plant)
    return from_offline(result, label or SHORT.get(scheme, scheme))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m cr_control.analysis.chapter2 OUT_DIR [DURATION]``: both schemes offline
    (default 20 s), figs. 2.4-2.12 per scheme in OUT_DIR/<scheme>/, the comparison figure
    and table (ch2_comparison.png/.md) in OUT_DIR; prints the table."""
    import sys
    import time

    args = sys.argv[1:] if argv is None else list(argv)
    if not args or args[0] in ("-h", "--help"):
        print(main.__doc__)
        return 0 if args else 2
    out = Path(args[0])
    duration = float(args[1]) if len(args) > 1 else 20.0
    runs = []
    for scheme in SCHEMES:
        start = time.perf_counter()
        print(f"chapter 2: {scheme}, {duration:g} s simulated ...", flush=True)
        run = offline_run(scheme, duration)
        runs.append(run)
        paths = plot_chapter2(run, out / scheme)
        print(f"  done in {time.perf_counter() - start:.1f} s wall; {len(paths)} figures in "
              f"{out / scheme}", flush=True)
    written = compare_chapter2(runs, out)
    print(written[-1].read_text())
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
