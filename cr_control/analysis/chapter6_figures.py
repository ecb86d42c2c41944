"""Chapter 6 figures: one run under the thesis's figure numbers (robust K_s = 10: 6.2-6.6,
K_s = 50: 6.7-6.11; singular perturbation: 6.12-6.15, without tau_s: 6.16-6.18; ``ch6_*``
names for runs the thesis does not show) plus measured vs filtered q_m'' for the robust
scheme (:func:`plot_chapter6`), and the overlays of the K_s cases and of SP with vs without
tau_s (:func:`compare_chapter6`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cr_control.analysis.chapter2 import RMS_WINDOW_S, robust_ylim, running_rms
from cr_control.analysis.chapter6_metrics import metrics_table
from cr_control.analysis.chapter6_runs import (
    AUTO,
    FIGURES,
    ROBUST,
    SP,
    WINDOWS,
    Divergence,
    FlexRun,
    before_divergence,
    divergence,
    from_session,
    is_chapter6,
    thesis_case,
    true_p,
)
from cr_control.analysis.figures import column_figure
from cr_control.analysis.figures import save_figure as save

# -- figures -----------------------------------------------------------------------------
DESIRED = dict(color="k", ls="-", lw=1.8, alpha=0.45)


def _name(numbers: dict[str, str], key: str, stem: str) -> str:
    number = numbers.get(key)
    return f"fig{number.replace('.', '_')}_{stem}.png" if number else f"ch6_{stem}.png"


def _cf(numbers: dict[str, str], key: str) -> str:
    number = numbers.get(key)
    return f" (cf. thesis fig. {number})" if number else ""


def _mark(axes: Sequence[Any], div: Divergence | None) -> None:
    if div is not None:
        for ax in axes:
            ax.axvline(div.time, color="r", ls=":", lw=1.0)


def _title(run: FlexRun, what: str, numbers: dict[str, str], key: str,
           div: Divergence | None) -> str:
    text = f"{run.label}: {what}{_cf(numbers, key)}"
    if div is not None:
        text += f"\n(red dotted: diverged at {div.time:.3f} s, {div.reason})"
    return text


def _error_norm_panel(ax: Any, runs: Sequence[FlexRun], colours: Sequence[str]) -> None:
    for run, colour in zip(runs, colours, strict=True):
        t, keep = run.time, before_divergence(run)
        rms = np.where(keep, running_rms(t, np.nan_to_num(run.e_q_norm)), np.nan)
        ax.semilogy(t, np.maximum(rms * 1e3, 1e-6), color=colour, lw=1.0,
                    label=run.label if len(runs) > 1 else r"$\|e_q\| = \|q_{ld} - q_l\|$")
    ax.set_ylabel(r"$\|e_q\|$ running RMS" + f"\n({RMS_WINDOW_S:g} s) [mrad], log")


def plot_chapter6(run: FlexRun, out_dir: str | Path, case: str | None = AUTO) -> list[Path]:
    """The figures of one run as PNG in ``out_dir``, named after the thesis figures of
    ``case`` (a key of FIGURES; AUTO: :func:`thesis_case`; None or a run the thesis does not
    show: ``ch6_*`` names): positions (θ1, θ2 desired solid vs actual dashed, and |e_q|),
    force (λ vs λ_d), torques (τ_m1, τ_m2; and τ_s for the SP scheme); robust: p_hat (the
    two blocks of 5), ks_inv_hat, and ch6_qddot_m_filter (measured vs filtered q_m'');
    SP: estimates (p_hat, |Γ^-1|, γ(t)). Returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    case = thesis_case(run) if case == AUTO else case
    if case is not None and case not in FIGURES:
        raise ValueError(f"unknown case {case!r}; known: {sorted(FIGURES)}")
    numbers = FIGURES.get(case or "", {})
    written: list[Path] = []
    t = run.time
    div = divergence(run)
    keep = before_divergence(run, div)
    tk = t[keep]

    fig, axes = column_figure(3, 2.2)
    q_l = run.q_l
    for j, ax in enumerate(axes[:2]):
        ax.plot(t, run.q_ld[:, j], **DESIRED, label=rf"$\theta_{{{j + 1}d}}$ (desired)")
        ax.plot(t, q_l[:, j], f"C{j}--", lw=1.0, label=rf"$\theta_{{{j + 1}}}$ (actual)")
        ax.set_ylabel(rf"link $\theta_{j + 1}$ [rad]")
        robust_ylim(ax, [(tk, q_l[keep, j]), (tk, run.q_ld[keep, j])])
    _error_norm_panel(axes[2], [run], ["C2"])
    _mark(axes, div)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(_title(run, "link position tracking", numbers, "positions", div))
    save(fig, out / _name(numbers, "positions", "positions"), written)

    fig, axes = column_figure(2, 2.2, sharex=False)
    early = t <= min(1.0, float(t[-1]))
    for ax, w, span in ((axes[0], slice(None), "whole run"), (axes[1], early, "first second")):
        ax.plot(t[w], run.lam_d[w], **DESIRED, label=r"$\lambda_d$ (desired)")
        ax.plot(t[w], run.lam[w], "C3--", lw=1.0, label=r"$\lambda$ (actual)")
        ax.set_ylabel(r"$\lambda$ [N]")
        ax.set_title(span, fontsize="small", loc="left")
        ax.set_xlabel("t [s]")
    robust_ylim(axes[0], [(tk, run.lam[keep])], floor=[float(np.nanmax(run.lam_d))])
    _mark(axes, div)
    fig.suptitle(_title(run, "constraint force", numbers, "force", div))
    save(fig, out / _name(numbers, "force", "force"), written)

    tau_s = [run.extras.get(f"tau_s_{i}") for i in (1, 2)]
    has_tau_s = all(x is not None for x in tau_s)
    fig, axes = column_figure(2 + has_tau_s, 2.2, sharex=False)
    for ax, w, span in ((axes[0], slice(None), "whole run"), (axes[1], early, "first second")):
        ax.plot(t[w], run.tau[w, 0], "C0-", lw=1.0, label=r"$\tau_{m1}$ (joint 1)")
        ax.plot(t[w], run.tau[w, 1], "C1--", lw=1.0, label=r"$\tau_{m2}$ (joint 2)")
        ax.set_ylabel(r"$\tau_m$ [N m]")
        ax.set_title(span, fontsize="small", loc="left")
        ax.set_xlabel("t [s]")
    robust_ylim(axes[0], [(tk, run.tau[keep, 0]), (tk, run.tau[keep, 1])])
    if has_tau_s:
        axes[2].plot(t, tau_s[0], "C0-", lw=1.0, label=r"$\tau_{s1}$")
        axes[2].plot(t, tau_s[1], "C1--", lw=1.0, label=r"$\tau_{s2}$")
        axes[2].set_ylabel(r"slow control $\tau_s$ [N m]")
        axes[2].set_xlabel("t [s]")
        robust_ylim(axes[2], [(tk, tau_s[0][keep]), (tk, tau_s[1][keep])], floor=[0.0])
    _mark(axes, div)
    fig.suptitle(_title(run, "motor torques (solid: joint 1, dashed: joint 2)", numbers,
                        "torques", div))
    save(fig, out / _name(numbers, "torques", "torques"), written)

    p = run.p_hat()
    truth = true_p(run)
    if run.kind == ROBUST:
        if p is not None:
            blocks = [(0, min(5, p.shape[1]))] + ([(5, p.shape[1])] if p.shape[1] > 5 else [])
            fig, axes = column_figure(len(blocks), 2.4)
            for ax, (a, b), joint in zip(axes, blocks, (1, 2), strict=False):
                for i in range(a, b):
                    ax.plot(t, p[:, i], color=f"C{i - a}", lw=1.0, label=rf"$\hat p_{{{i + 1}}}$")
                    if truth is not None:
                        ax.axhline(truth[i], color=f"C{i - a}", ls=":", lw=1.0)
                ax.set_ylabel(rf"$\hat p$, block $p_{joint}$" + f"\n(joint {joint})"
                              + (r" (dotted: $p/k_s$)" if truth is not None else ""))
            _mark(axes, div)
            axes[-1].set_xlabel("t [s]")
            fig.suptitle(_title(run, "parameter estimates p̂ (Property 6.5 blocks)", numbers,
                                "p_hat", div))
            save(fig, out / _name(numbers, "p_hat", "p_hat"), written)
        ks = [run.extras.get(f"ks_inv_hat_{i}") for i in (1, 2)]
        if all(x is not None for x in ks):
            fig, axes = column_figure(1, 3.0)
            for i, x in enumerate(ks):
                axes[0].plot(t, x, f"C{i}{'-' if i == 0 else '--'}", lw=1.0,
                             label=rf"$\hat k_{{s{i + 1}}}^{{-1}}$")
            if run.joint_stiffness:
                axes[0].axhline(1.0 / run.joint_stiffness, color="k", ls=":", lw=1.0,
                                label=rf"true $1/k_s = {1.0 / run.joint_stiffness:.3g}$")
            axes[0].set_ylabel(r"$\hat k_s^{-1}$ [rad/(N m)]")
            axes[0].set_xlabel("t [s]")
            _mark(axes, div)
            fig.suptitle(_title(run, "stiffness estimates", numbers, "ks_inv_hat", div))
            save(fig, out / _name(numbers, "ks_inv_hat", "ks_inv_hat"), written)
        written += _plot_qddot_m(run, out, div)
    else:
        panels = [k for k in ("p_hat", "gamma_inv_norm", "forgetting")
                  if (p is not None if k == "p_hat" else k in run.extras)]
        if panels:
            fig, axes = column_figure(len(panels), 2.2)
            for ax, panel in zip(axes, panels, strict=True):
                if panel == "p_hat":
                    for i in range(p.shape[1]):
                        ax.plot(t, p[:, i], color=f"C{i}", lw=1.0, label=rf"$\hat p_{{{i + 1}}}$")
                        if truth is not None:
                            ax.axhline(truth[i], color=f"C{i}", ls=":", lw=1.0)
                    ax.set_ylabel(r"$\hat p$" + (" (dotted: true p)" if truth is not None else ""))
                elif panel == "gamma_inv_norm":
                    ax.plot(t, run.extras[panel], "C5", lw=1.0, label=r"$\|\Gamma^{-1}\|$")
                    ax.set_ylabel(r"$\|\Gamma^{-1}\|$")
                else:
                    ax.plot(t, run.extras[panel], "C6", lw=1.0, label=r"$\gamma(t)$")
                    ax.set_ylabel(r"forgetting $\gamma(t)$")
            _mark(axes, div)
            axes[-1].set_xlabel("t [s]")
            fig.suptitle(_title(run, "parameter estimates (least squares with forgetting)",
                                numbers, "estimates", div))
            save(fig, out / _name(numbers, "estimates", "estimates"), written)
    return written


#: Span (s) of the zoomed panel of the q_m'' figure.
ZOOM_S = 0.5


def _plot_qddot_m(run: FlexRun, out: Path, div: Divergence | None) -> list[Path]:
    """Measured vs filtered q_m'' of the robust scheme (ch6_qddot_m_filter.png)."""
    names = [(f"qddot_m_{i}", f"qddot_m_filtered_{i}") for i in (1, 2)]
    if not all(a in run.extras and b in run.extras for a, b in names):
        return []
    written: list[Path] = []
    t = run.time
    keep = before_divergence(run, div)
    fig, axes = column_figure(3, 2.1, sharex=False)
    for j, (raw, filt) in enumerate(names):
        axes[j].plot(t, run.extras[raw], color="0.6", lw=0.7, label=r"measured $\ddot q_m$")
        axes[j].plot(t, run.extras[filt], f"C{j}", lw=1.0, label=r"filtered")
        axes[j].set_ylabel(rf"$\ddot q_{{m{j + 1}}}$ [rad/s²]")
        robust_ylim(axes[j], [(t[keep], run.extras[raw][keep]),
                              (t[keep], run.extras[filt][keep])])
    end = float(t[keep][-1])
    a = max(0.0, min(5.0, end / 2.0))
    w = (t >= a) & (t <= a + ZOOM_S)
    raw, filt = names[0]
    axes[2].plot(t[w], run.extras[raw][w], color="0.6", lw=0.7, marker=".", ms=2,
                 label=r"measured $\ddot q_{m1}$")
    axes[2].plot(t[w], run.extras[filt][w], "C0", lw=1.2, label="filtered")
    axes[2].set_ylabel(r"$\ddot q_{m1}$ [rad/s²]" + f"\n(zoom {a:g}–{a + ZOOM_S:g} s)")
    for ax in axes:
        ax.set_xlabel("t [s]")
    _mark(axes[:2], div)
    used = (f"τ_m (6.58) uses the {run.motor_acceleration} one"
            if run.motor_acceleration in ("measured", "filtered") else "either may feed τ_m (6.58)")
    fig.suptitle(f"{run.label}: motor accelerations q̈_m, measured (plant sensor) vs filtered "
                 f"(state-variable filter on q̇_m)\n({used})"
                 + (f"\n(red dotted: diverged at {div.time:.3f} s)" if div else ""))
    save(fig, out / "ch6_qddot_m_filter.png", written)
    return written


def _tau_rms(run: FlexRun, j: int) -> np.ndarray:
    return running_rms(run.time, np.nan_to_num(run.tau[:, j]))


def overlay(runs: Sequence[FlexRun], path: Path, title: str) -> list[Path]:
    """The runs overlaid in one figure: |e_q| running RMS, λ (with λ_d), running RMS of
    τ_m1 and τ_m2 (the sampled boundary layer makes them chatter; peaks are in the table).
    A diverged run is drawn up to its divergence (dotted mark) and y limits come from the
    runs that did not diverge."""
    written: list[Path] = []
    colours = [f"C{i}" for i in range(len(runs))]
    divs = [divergence(r) for r in runs]
    good = [r for r, d in zip(runs, divs, strict=True) if d is None] or list(runs)
    fig, axes = column_figure(4, 1.9)
    _error_norm_panel(axes[0], runs, colours)
    axes[1].plot(runs[0].time, runs[0].lam_d, "k-", lw=1.8, alpha=0.45, label=r"$\lambda_d$")
    panels = ((axes[1], r"$\lambda$ [N]", lambda r: r.lam),
              (axes[2], r"$\tau_{m1}$ running RMS" + f"\n({RMS_WINDOW_S:g} s) [N m]",
               lambda r: _tau_rms(r, 0)),
              (axes[3], r"$\tau_{m2}$ running RMS" + f"\n({RMS_WINDOW_S:g} s) [N m]",
               lambda r: _tau_rms(r, 1)))
    for run, colour, div in zip(runs, colours, divs, strict=True):
        keep = before_divergence(run, div)
        for ax, _, get in panels:
            ax.plot(run.time, np.where(keep, get(run), np.nan), color=colour, lw=1.0,
                    label=run.label)
        if div is not None:
            for ax in axes:
                ax.axvline(div.time, color=colour, ls=":", lw=1.0)
    for ax, ylabel, get in panels:
        ax.set_ylabel(ylabel)
        robust_ylim(ax, [(r.time[before_divergence(r)], get(r)[before_divergence(r)]) for r in good],
                    floor=[0.0] if ax is not axes[1] else [])
    axes[-1].set_xlabel("t [s]")
    diverged = [f"{r.label} at {d.time:.3f} s" for r, d in zip(runs, divs, strict=True) if d]
    fig.suptitle(title + ("\n(dotted: diverged — " + ", ".join(diverged) + "; drawn up to there)"
                          if diverged else ""))
    save(fig, path, written)
    return written


def compare_chapter6(runs: Sequence[FlexRun], out_dir: str | Path,
                     spans: Sequence[tuple[float, float]] = WINDOWS) -> list[Path]:
    """Overlays of the robust runs (the K_s cases, ch6_robust_ks.png) and of the SP runs
    (with vs without τ_s, ch6_sp_slow_control.png) when a kind has two or more runs, and the
    metrics table of all runs (ch6_comparison.md, last in the list)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    robust = [r for r in runs if r.kind == ROBUST]
    sp = [r for r in runs if r.kind == SP]
    if len(robust) > 1:
        written += overlay(robust, out / "ch6_robust_ks.png",
                           "Chapter 6: robust adaptive control (Theorem 6.2.1) for different K_s\n"
                           "(cf. thesis figs. 6.2-6.4 vs 6.7-6.9; numbers in ch6_comparison.md)")
    if len(sp) > 1:
        written += overlay(sp, out / "ch6_sp_slow_control.png",
                           "Chapter 6: singular-perturbation control with vs without the slow "
                           "control τ_s\n(cf. thesis figs. 6.12-6.14 vs 6.16-6.18)")
    table = out / "ch6_comparison.md"
    table.write_text(metrics_table(runs, spans))
    written.append(table)
    return written


def session_figures(session: Any, out_dir: str | Path) -> list[Path]:
    """Figs. 6.2-6.18 of a loaded session if it is a chapter 6 one (else nothing)."""
    return plot_chapter6(from_session(session), out_dir) if is_chapter6(session.status) else []


def compare_sessions(sessions: Sequence[Any], labels: Sequence[str],
                     out_dir: str | Path) -> list[Path]:
    """The chapter 6 comparison of the chapter 6 sessions among ``sessions`` (two or more)."""
    runs = []
    for session, label in zip(sessions, labels, strict=True):
        if is_chapter6(session.status):
            run = from_session(session)
            run.label = label
            runs.append(run)
    return compare_chapter6(runs, out_dir) if len(runs) > 1 else []
