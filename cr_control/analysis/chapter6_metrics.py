"""Chapter 6 metrics: per time window RMS/max of |e_q|, the lambda range and error, peak/RMS
motor torques and the estimates at the window's end (:func:`window_metrics`), a run's
summary, and several runs side by side (:func:`metrics_table`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from cr_control.analysis.chapter2 import windows
from cr_control.analysis.chapter6_runs import (
    DIVERGENCE_RAD,
    FIGURES,
    ROBUST,
    WINDOWS,
    Divergence,
    FlexRun,
    divergence,
    thesis_case,
    true_p,
)


# -- metrics -----------------------------------------------------------------------------
def _finite(x: np.ndarray) -> np.ndarray:
    return x[np.isfinite(x)]


def _rms(x: np.ndarray) -> float:
    x = _finite(np.asarray(x, dtype=float))
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def _max(x: np.ndarray) -> float:
    x = _finite(np.asarray(x, dtype=float))
    return float(np.max(x)) if len(x) else float("nan")


def _min(x: np.ndarray) -> float:
    x = _finite(np.asarray(x, dtype=float))
    return float(np.min(x)) if len(x) else float("nan")


def window_metrics(run: FlexRun, a: float, b: float) -> dict[str, float]:
    """Numbers of the window [a, b) s (SI units; keys end with the unit). Estimates are
    taken at the window's last sample; NaN where the window is empty."""
    w = (run.time >= a) & (run.time < b)
    e = run.e_q_norm[w]
    lam, err = run.lam[w], (run.lam_d - run.lam)[w]
    tau = run.tau[w]
    out = {
        "e_q_rms_rad": _rms(e), "e_q_max_rad": _max(e),
        "lambda_min_N": _min(lam), "lambda_max_N": _max(lam),
        "lambda_err_rms_N": _rms(err), "lambda_err_max_N": _max(np.abs(err)),
        "tau1_peak_Nm": _max(np.abs(tau[:, 0])), "tau1_rms_Nm": _rms(tau[:, 0]),
        "tau2_peak_Nm": _max(np.abs(tau[:, 1])), "tau2_rms_Nm": _rms(tau[:, 1]),
        "held_fraction": float(np.mean(run.held[w])) if w.any() else float("nan"),
    }
    idx = np.flatnonzero(w)
    end = int(idx[-1]) if len(idx) else None
    p = run.p_hat()
    if p is not None:
        out["p_hat_norm_end"] = float(np.linalg.norm(p[end])) if end is not None else math.nan
    for name in ("ks_inv_hat_1", "ks_inv_hat_2", "gamma_inv_norm", "forgetting"):
        if name in run.extras:
            out[f"{name}_end"] = float(run.extras[name][end]) if end is not None else math.nan
    return out


def run_summary(run: FlexRun, last: float = 5.0) -> dict[str, Any]:
    """Whole-run numbers: the thesis case, the divergence, lambda range, peak torques,
    |e_q| and lambda-error RMS over the last ``last`` s, the final estimates."""
    t = run.time
    late = t >= t[-1] - last
    div = divergence(run)
    out: dict[str, Any] = {
        "case": thesis_case(run), "divergence": div,
        "lambda_min_N": _min(run.lam), "lambda_max_N": _max(run.lam),
        "tau_peak_Nm": [_max(np.abs(run.tau[:, 0])), _max(np.abs(run.tau[:, 1]))],
        "e_q_rms_late_rad": _rms(run.e_q_norm[late]),
        "lambda_err_rms_late_N": _rms((run.lam_d - run.lam)[late]),
        "phi_max_m": _max(np.abs(run.phi)),
    }
    if run.max_effort:
        clipped = np.abs(run.tau) >= run.max_effort * (1.0 - 1e-9)
        out["clipped_fraction"] = float(np.mean(clipped.any(axis=1)))
    p = run.p_hat()
    if p is not None:
        out["p_hat_end"] = p[-1].tolist()
        truth = true_p(run)
        if truth is not None:
            out["p_err_start"] = float(np.linalg.norm(p[0] - truth))
            out["p_err_end"] = float(np.linalg.norm(p[-1] - truth))
    for name in ("ks_inv_hat_1", "ks_inv_hat_2", "gamma_inv_norm", "forgetting"):
        if name in run.extras:
            out[f"{name}_end"] = float(run.extras[name][-1])
    return out


def _fmt(value: float, fmt: str, scale: float = 1.0) -> str:
    return fmt.format(value * scale) if math.isfinite(value) else "n/a"


#: Columns of :func:`metrics_table`: (keys, header, scale, format); several keys share a cell.
TABLE_COLUMNS: list[tuple[tuple[str, ...], str, float, str]] = [
    (("e_q_rms_rad",), "‖e_q‖ RMS [mrad]", 1e3, "{:.3g}"),
    (("e_q_max_rad",), "‖e_q‖ max [mrad]", 1e3, "{:.3g}"),
    (("lambda_min_N",), "λ min [N]", 1.0, "{:.3f}"),
    (("lambda_max_N",), "λ max [N]", 1.0, "{:.3f}"),
    (("lambda_err_rms_N",), "λ err RMS [N]", 1.0, "{:.3g}"),
    (("lambda_err_max_N",), "λ err max [N]", 1.0, "{:.3g}"),
    (("tau1_peak_Nm",), "max \\|τ_m1\\| [N m]", 1.0, "{:.3g}"),
    (("tau1_rms_Nm",), "τ_m1 RMS [N m]", 1.0, "{:.3g}"),
    (("tau2_peak_Nm",), "max \\|τ_m2\\| [N m]", 1.0, "{:.3g}"),
    (("tau2_rms_Nm",), "τ_m2 RMS [N m]", 1.0, "{:.3g}"),
    (("p_hat_norm_end",), "‖p̂‖ end", 1.0, "{:.4g}"),
    (("ks_inv_hat_1_end", "ks_inv_hat_2_end"), "k̂_s⁻¹ end [rad/(N m)]", 1.0, "{:.4g}"),
    (("gamma_inv_norm_end",), "‖Γ⁻¹‖ end", 1.0, "{:.4g}"),
    (("held_fraction",), "held [%]", 100.0, "{:.0f}"),
]
TABLE_NOTE = ("Per window [a, b) s: e_q = q_ld − q_l (link position error), λ the constraint "
              "force (λ_d = 2 N), τ_m the motor torques (6.2); estimates at the window's last "
              "sample: ‖p̂‖ (robust: both blocks of Property 6.5, 10 values; singular "
              "perturbation: 5), k̂_s⁻¹ (robust), ‖Γ⁻¹‖ of the least-squares law (singular "
              "perturbation); held = share of cycles the controller held its last command "
              f"(a diverged loop); '—' not published by the scheme, n/a no data. A run counts "
              f"as diverged from the first time ‖e_q‖ > {DIVERGENCE_RAD:g} rad, a value is "
              "non-finite or the controller holds.")


def _cells(m: dict[str, float]) -> list[str]:
    cells = []
    for keys, _, scale, fmt in TABLE_COLUMNS:
        if not all(k in m for k in keys):
            cells.append("—")
        else:
            cells.append(", ".join(_fmt(m[k], fmt, scale) for k in keys))
    return cells


def _summary_line(run: FlexRun) -> str:
    s = run_summary(run)
    case = s["case"]
    numbers = FIGURES[case] if case else {}
    div: Divergence | None = s["divergence"]
    scheme = "robust adaptive, Theorem 6.2.1" if run.kind == ROBUST else "singular perturbation"
    text = (f"- **{run.label}** ({scheme}"
            + (f"; K_s = {run.joint_stiffness:g}" if run.joint_stiffness is not None else "")
            + (f"; thesis figs. {min(numbers.values(), key=_fig_key)}–"
               f"{max(numbers.values(), key=_fig_key)}" if numbers else "; no thesis figure")
            + "): ")
    if div is None:
        text += f"no divergence (‖e_q‖ ≤ {DIVERGENCE_RAD:g} rad, finite, never held); "
    else:
        text += f"**diverged at t = {div.time:.3f} s** ({div.reason}); "
    text += (f"λ ∈ [{_fmt(s['lambda_min_N'], '{:.3f}')}, {_fmt(s['lambda_max_N'], '{:.3f}')}] N; "
             f"peak |τ_m| {_fmt(s['tau_peak_Nm'][0], '{:.3g}')}, "
             f"{_fmt(s['tau_peak_Nm'][1], '{:.3g}')} N m; last 5 s: ‖e_q‖ RMS "
             f"{_fmt(s['e_q_rms_late_rad'], '{:.3g}', 1e3)} mrad, λ err RMS "
             f"{_fmt(s['lambda_err_rms_late_N'], '{:.3g}')} N; max |Φ| "
             f"{_fmt(s['phi_max_m'], '{:.2g}')} m")
    if s.get("clipped_fraction"):
        text += (f"; τ_m at the ±{run.max_effort:g} N m clip (max_effort) in "
                 f"{100.0 * s['clipped_fraction']:.1f} % of the cycles")
    if "p_hat_end" in s:
        text += "; p̂(end) = [" + ", ".join(_fmt(x, "{:.4g}") for x in s["p_hat_end"]) + "]"
    if "p_err_end" in s:
        text += (f", ‖p̂ − p‖ {_fmt(s['p_err_start'], '{:.3g}')} → "
                 f"{_fmt(s['p_err_end'], '{:.3g}')}"
                 + (" (p of the robust scheme: Λ⁻¹p)" if run.kind == ROBUST else ""))
    if "ks_inv_hat_1_end" in s:
        text += (f", k̂_s⁻¹(end) = [{_fmt(s['ks_inv_hat_1_end'], '{:.4g}')}, "
                 f"{_fmt(s['ks_inv_hat_2_end'], '{:.4g}')}]")
        if run.joint_stiffness:
            text += f" (true 1/k_s = {1.0 / run.joint_stiffness:.4g})"
    if "gamma_inv_norm_end" in s:
        text += f", ‖Γ⁻¹‖(end) = {_fmt(s['gamma_inv_norm_end'], '{:.4g}')}"
    if "forgetting_end" in s:
        text += f", γ(end) = {_fmt(s['forgetting_end'], '{:.4g}')}"
    return text + "."


def _fig_key(number: str) -> tuple[int, ...]:
    return tuple(int(x) for x in number.split("."))


def metrics_table(runs: Sequence[FlexRun], spans: Sequence[tuple[float, float]] = WINDOWS
                  ) -> str:
    """A Markdown table, one row per (window, run), then one summary line per run."""
    header = "| run | window [s] | " + " | ".join(h for _, h, _, _ in TABLE_COLUMNS) + " |"
    lines = [header, "|" + "---|" * (len(TABLE_COLUMNS) + 2)]
    longest = max(runs, key=lambda r: r.time[-1] if len(r.time) else -1.0) if runs else None
    for a, b in windows(longest, spans) if longest is not None else []:
        for run in runs:
            if not len(run.time) or run.time[-1] < a:
                continue
            m = window_metrics(run, a, b)
            lines.append(f"| {run.label} | {a:g}–{b:.3g} | " + " | ".join(_cells(m)) + " |")
    lines += ["", TABLE_NOTE, ""]
    lines += [_summary_line(run) for run in runs]
    return "\n".join(lines) + "\n"
