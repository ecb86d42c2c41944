"""Chapter 6 analysis: constrained flexible-joint robots (thesis figs. 6.2-6.18).

Works on a recorded session (:func:`from_session`) or an offline run (:func:`from_offline`)
of ``fjr_robust_adaptive`` (Theorem 6.2.1) or ``fjr_singular_perturbation`` (section 6.2.1).
Both publish (:mod:`cr_control.schemes.flexible_joint.flexible_joint_scheme`) the task-space fields, the
motor torques tau_1, tau_2 (= tau_m1, tau_m2), ``held``, then lambda, e_lambda =
lambda_d - lambda, e_q = q_ld - q_l and Phi(q_l); the reference carries q_ld. The robust
scheme adds p_hat_1..10 (the two per-joint blocks p_1, p_2 of Property 6.5, five each),
ks_inv_hat_1..2, k_tau, the measured and filtered motor accelerations qddot_m(_filtered)_1..2
and its internals; the singular-perturbation scheme p_hat_1..5, |Gamma^-1|, the forgetting
factor gamma(t), the slow control tau_s_1..2 and its internals.

:func:`window_metrics` gives, per time window, RMS/max of |e_q|, the lambda range and
error, peak/RMS motor torques and the estimates at the window's end; :func:`metrics_table`
puts several runs side by side. :func:`divergence` finds where a run blew up (|e_q| above
1 rad, non-finite values, or the controller holding its command): the thesis says the
robust scheme diverges for K_s = 100.
:func:`plot_chapter6` draws one run under the thesis's figure numbers (robust K_s = 10:
6.2-6.6, K_s = 50: 6.7-6.11; singular perturbation: 6.12-6.15, without tau_s: 6.16-6.18;
``ch6_*`` names for runs the thesis does not show) plus, for the robust scheme, measured vs
filtered q_m''; :func:`compare_chapter6` overlays the K_s cases and SP with vs without
tau_s and writes the table.

``python -m cr_control.analysis.chapter6 OUT_DIR [DURATION]`` runs the five cases offline
(default 20 s each) and writes all of it there.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cr_control.analysis.chapter2 import RMS_WINDOW_S, robust_ylim, running_rms, windows
from cr_control.analysis.figures import column_figure
from cr_control.analysis.figures import save_figure as save

ROBUST_SCHEME = "fjr_robust_adaptive"
SP_SCHEME = "fjr_singular_perturbation"
#: Status fields of both chapter 6 schemes (flexible_joint_scheme.STATUS and the torques).
REQUIRED = ("lambda", "e_lambda", "e_q_1", "e_q_2", "phi", "tau_1", "tau_2")
#: The schemes' own status fields (as published).
ROBUST_EXTRAS = (*(f"p_hat_{i}" for i in range(1, 11)), "ks_inv_hat_1", "ks_inv_hat_2",
                 "mu_1", "mu_2", "sigma_1", "sigma_2", "theta_d_1", "theta_d_2", "z_1", "z_2",
                 "s_1", "s_2", "k_tau", "qddot_m_1", "qddot_m_2", "qddot_m_filtered_1",
                 "qddot_m_filtered_2")
SP_EXTRAS = (*(f"p_hat_{i}" for i in range(1, 6)), "gamma_inv_norm", "forgetting", "tau_s_1",
             "tau_s_2", "z_tilde_1", "z_tilde_2", "q_md_hat_1", "q_md_hat_2", "e_m_hat_1",
             "e_m_hat_2")
#: Fields that tell the two schemes apart.
ROBUST_MARK = ("p_hat_10", "ks_inv_hat_1", "ks_inv_hat_2")
SP_MARK = ("gamma_inv_norm", "tau_s_1", "tau_s_2")
ROBUST, SP = "robust", "sp"
#: Windows (s) of the side-by-side table (cut to the run's length).
WINDOWS = ((0.0, 1.0), (1.0, 5.0), (5.0, 10.0), (10.0, 15.0), (15.0, 20.0))
#: |e_q| (rad) above which a run counts as diverged.
DIVERGENCE_RAD = 1.0
#: Thesis figure numbers of each case (section 6.3).
FIGURES: dict[str, dict[str, str]] = {
    "case 1": {"positions": "6.2", "force": "6.3", "torques": "6.4", "p_hat": "6.5",
               "ks_inv_hat": "6.6"},
    "case 2": {"positions": "6.7", "force": "6.8", "torques": "6.9", "p_hat": "6.10",
               "ks_inv_hat": "6.11"},
    "sp": {"positions": "6.12", "force": "6.13", "torques": "6.14", "estimates": "6.15"},
    "sp without tau_s": {"positions": "6.16", "force": "6.17", "torques": "6.18"},
}
#: Plant K_s of each thesis case (all joints alike).
CASE_STIFFNESS = {"case 1": 10.0, "case 2": 50.0, "sp": 300.0, "sp without tau_s": 300.0}
#: Sentinel of :func:`plot_chapter6`: take the case from the run.
AUTO = "auto"


@dataclass
class FlexRun:
    """Time series of one chapter 6 run, on a time axis starting at 0."""

    label: str
    kind: str                  #: ROBUST or SP
    time: np.ndarray
    q_ld: np.ndarray           #: (k, 2) desired link positions (rad); NaN where unknown
    e_q: np.ndarray            #: (k, 2) q_ld - q_l (rad)
    lam: np.ndarray            #: constraint force lambda (N)
    lam_d: np.ndarray
    tau: np.ndarray            #: (k, 2) motor torques tau_m (N m)
    phi: np.ndarray            #: Phi(q_l) (m)
    held: np.ndarray           #: (k,) bool: the controller held its last command
    #: The scheme's own status fields present (ROBUST_EXTRAS or SP_EXTRAS).
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    #: Plant K_s (N m/rad) where known and alike for both joints.
    joint_stiffness: float | None = None
    #: The SP scheme's slow_control parameter where known.
    slow_control: bool | None = None
    #: The controller's max_effort (N m: commands are clipped there) where known.
    max_effort: float | None = None
    #: The robust scheme's motor_acceleration parameter (q_m'' in tau_m: "measured" or
    #: "filtered") where known.
    motor_acceleration: str | None = None

    @property
    def q_l(self) -> np.ndarray:
        """Link positions q_l = q_ld - e_q (rad)."""
        return self.q_ld - self.e_q

    @property
    def e_q_norm(self) -> np.ndarray:
        return np.hypot(self.e_q[:, 0], self.e_q[:, 1])

    def p_hat(self) -> np.ndarray | None:
        """(k, l) the p_hat estimates, or None."""
        names = [n for n in self.extras if re.fullmatch(r"p_hat_\d+", n)]
        if not names:
            return None
        names.sort(key=lambda n: int(n.rsplit("_", 1)[1]))
        return np.column_stack([self.extras[n] for n in names])


def scheme_kind(status: dict[str, np.ndarray] | Sequence[str]) -> str | None:
    """ROBUST, SP, or None from the status field names."""
    if all(n in status for n in ROBUST_MARK):
        return ROBUST
    if all(n in status for n in SP_MARK):
        return SP
    return None


def is_chapter6(status: dict[str, np.ndarray] | Sequence[str]) -> bool:
    """True if the status carries the fields of one of the chapter 6 schemes."""
    return all(n in status for n in REQUIRED) and scheme_kind(status) is not None


def _clean(x: Any) -> np.ndarray:
    """Float array with inf as NaN (plots and limits cannot take inf)."""
    a = np.array(x, dtype=float)
    a[~np.isfinite(a)] = np.nan
    return a


def _stiffness(plant: dict[str, Any] | None) -> float | None:
    ks = (plant or {}).get("joint_stiffness")
    if ks is None:
        return None
    values = np.atleast_1d(np.asarray(ks, dtype=float))
    return float(values[0]) if len(values) and np.all(values == values[0]) else None


def _slow(controller: dict[str, Any] | None) -> bool | None:
    value = (controller or {}).get("slow_control")
    return None if value is None else bool(value)


def _max_effort(controller: dict[str, Any] | None) -> float | None:
    value = (controller or {}).get("max_effort")
    try:
        return float(value) if value is not None else None
    except (TypeError, ValueError):
        return None


def _build(label: str, t: np.ndarray, col: Callable[[str], np.ndarray], names: Any,
           q_ld: np.ndarray) -> FlexRun:
    kind = scheme_kind(names)
    if kind is None or not all(n in names for n in REQUIRED):
        raise ValueError(f"{label}: not a chapter 6 run (status lacks the fields of "
                         f"{ROBUST_SCHEME} and {SP_SCHEME})")
    lam = _clean(col("lambda"))
    held = (np.asarray(col("held"), dtype=float) > 0.5) if "held" in names \
        else np.zeros(len(t), dtype=bool)
    extras = ROBUST_EXTRAS if kind == ROBUST else SP_EXTRAS
    return FlexRun(label, kind, _clean(t), _clean(q_ld),
                   _clean(np.column_stack([col("e_q_1"), col("e_q_2")])), lam,
                   lam + _clean(col("e_lambda")),
                   _clean(np.column_stack([col("tau_1"), col("tau_2")])), _clean(col("phi")),
                   held, {n: _clean(col(n)) for n in extras if n in names})


def from_offline(run: Any, label: str, plant: dict[str, Any] | None = None,
                 controller: dict[str, Any] | None = None) -> FlexRun:
    """A FlexRun from :class:`cr_control.tools.offline.OfflineRun`; ``plant`` and
    ``controller`` (parameter values, where known) give K_s and slow_control."""
    names = set(run.status_fields)
    q_ld = (np.column_stack([run.column("q_ld_1"), run.column("q_ld_2")])
            if "q_ld_1" in run.reference_fields else np.full((len(run.time), 2), np.nan))
    out = _build(label, run.time - run.time[0], run.column, names, q_ld)
    out.joint_stiffness, out.slow_control = _stiffness(plant), _slow(controller)
    out.max_effort = _max_effort(controller)
    out.motor_acceleration = (controller or {}).get("motor_acceleration")
    return out


def _on_stamps(reference: dict[str, np.ndarray], name: str, stamps: np.ndarray) -> np.ndarray:
    """Reference column ``name`` at the status stamps (NaN where missing)."""
    if name not in reference or "stamp" not in reference or not len(reference["stamp"]):
        return np.full(len(stamps), np.nan)
    ref_t, values = np.asarray(reference["stamp"], float), np.asarray(reference[name], float)
    if len(ref_t) == len(stamps) and np.array_equal(ref_t, stamps):
        return values
    order = np.argsort(ref_t, kind="stable")
    return np.interp(stamps, ref_t[order], values[order], left=np.nan, right=np.nan)


def from_session(session: Any) -> FlexRun:
    """A FlexRun from a loaded session (:func:`cr_control.analysis.analyze.load_session`)."""
    s = session.status
    stamps = np.asarray(s["stamp"], dtype=float)
    q_ld = np.column_stack([_on_stamps(session.reference, f"q_ld_{i}", stamps) for i in (1, 2)])
    out = _build(session.name, session.relative_time(stamps), s.__getitem__, s, q_ld)
    out.joint_stiffness = _stiffness(session.parameters.get("plant"))
    controller = session.parameters.get(session.controller or "", {})
    out.slow_control, out.max_effort = _slow(controller), _max_effort(controller)
    out.motor_acceleration = controller.get("motor_acceleration")
    return out


def _label_stiffness(label: str) -> float | None:
    m = re.search(r"K_?s\s*=\s*([0-9]+(?:\.[0-9]*)?)", label)
    return float(m.group(1)) if m else None


def true_p(run: FlexRun) -> np.ndarray | None:
    """What p_hat estimates for the section 6.3 links (flexible_joint_model.TRUE_P = p):
    p itself (singular perturbation, K_s known), Lambda^-1 p = [p / k_s1; p / k_s2] (robust,
    Property 6.5; only where the plant's K_s is known). None otherwise."""
    from cr_control.schemes.flexible_joint.flexible_joint_model import TRUE_P  # analysis -> schemes (one way)

    p = run.p_hat()
    if p is None:
        return None
    if run.kind == SP and p.shape[1] == len(TRUE_P):
        return np.asarray(TRUE_P, dtype=float)
    if run.kind == ROBUST and run.joint_stiffness and p.shape[1] == 2 * len(TRUE_P):
        return np.concatenate([TRUE_P, TRUE_P]) / run.joint_stiffness
    return None


def thesis_case(run: FlexRun) -> str | None:
    """The section 6.3 case the run reproduces (a key of FIGURES), or None: robust with
    K_s = 10 / 50 (from the plant parameters, else the label), singular perturbation with
    K_s = 300 (or unknown) with / without tau_s (slow_control, else whether tau_s is ever
    non-zero)."""
    ks = run.joint_stiffness if run.joint_stiffness is not None else _label_stiffness(run.label)
    if run.kind == ROBUST:
        return next((c for c in ("case 1", "case 2") if ks == CASE_STIFFNESS[c]), None)
    if ks is not None and ks != CASE_STIFFNESS["sp"]:
        return None
    slow = run.slow_control
    if slow is None and "tau_s_1" in run.extras and "tau_s_2" in run.extras:
        tau_s = np.abs(np.column_stack([run.extras["tau_s_1"], run.extras["tau_s_2"]]))
        slow = bool(np.nanmax(tau_s, initial=0.0) > 0.0)
    if slow is None:
        return None
    return "sp" if slow else "sp without tau_s"


# -- divergence --------------------------------------------------------------------------
@dataclass
class Divergence:
    """Where a run blew up."""

    time: float     #: s
    reason: str


def divergence(run: FlexRun, limit: float = DIVERGENCE_RAD) -> Divergence | None:
    """The first time |e_q| exceeds ``limit`` rad, a tracked value (e_q, lambda, tau_m) is
    not finite, or the controller holds its command; None if none of it happens."""
    t = run.time
    found: list[tuple[int, str]] = []
    e = run.e_q_norm
    above = np.flatnonzero(e > limit)
    if len(above):
        found.append((int(above[0]), f"|e_q| > {limit:g} rad"))
    bad = ~np.isfinite(np.column_stack([run.e_q, run.lam, run.tau])).all(axis=1)
    if bad.any():
        found.append((int(np.argmax(bad)), "non-finite values"))
    if run.held.any():
        found.append((int(np.argmax(run.held)), "controller holding its command"))
    if not found:
        return None
    k, reason = min(found)
    return Divergence(float(t[k]), reason)


def _before(run: FlexRun, div: Divergence | None = None) -> np.ndarray:
    """Mask of the samples before the divergence (all if none; at least the first)."""
    div = divergence(run) if div is None else div
    if div is None:
        return np.ones(len(run.time), dtype=bool)
    mask = run.time < div.time
    mask[:1] = True
    return mask


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
        t, keep = run.time, _before(run)
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
    keep = _before(run, div)
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
    keep = _before(run, div)
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
        keep = _before(run, div)
        for ax, _, get in panels:
            ax.plot(run.time, np.where(keep, get(run), np.nan), color=colour, lw=1.0,
                    label=run.label)
        if div is not None:
            for ax in axes:
                ax.axvline(div.time, color=colour, ls=":", lw=1.0)
    for ax, ylabel, get in panels:
        ax.set_ylabel(ylabel)
        robust_ylim(ax, [(r.time[_before(r)], get(r)[_before(r)]) for r in good],
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


# -- offline reproduction ----------------------------------------------------------------
ROBUST_PLANT = {"motor_inertia": [0.5, 0.5]}
SP_PLANT = {"joint_stiffness": [300.0, 300.0], "motor_inertia": [1.0, 1.0]}
#: The runs of section 6.3: (folder, label, scheme, controller overrides, plant overrides).
CASES: list[tuple[str, str, str, dict[str, Any], dict[str, Any]]] = [
    ("robust_ks10", "robust K_s = 10 (case 1)", ROBUST_SCHEME, {},
     {"joint_stiffness": [10.0, 10.0], **ROBUST_PLANT}),
    ("robust_ks50", "robust K_s = 50 (case 2)", ROBUST_SCHEME, {},
     {"joint_stiffness": [50.0, 50.0], **ROBUST_PLANT}),
    ("robust_ks100", "robust K_s = 100 (thesis: diverges)", ROBUST_SCHEME, {},
     {"joint_stiffness": [100.0, 100.0], **ROBUST_PLANT}),
    ("sp", "SP with τ_s", SP_SCHEME, {}, dict(SP_PLANT)),
    ("sp_no_slow", "SP without τ_s", SP_SCHEME, {"slow_control": False}, dict(SP_PLANT)),
]


def offline_run(scheme: str, duration: float = 20.0, controller: dict[str, Any] | None = None,
                plant: dict[str, Any] | None = None, label: str | None = None) -> FlexRun:
    """Run ``scheme`` offline on its thesis plant (with ``plant`` overrides) and return its
    FlexRun, K_s and slow_control taken from the resolved parameters."""
    from cr_control.core.parameters import resolve
    from cr_control.schemes.registry import controller_class
    from cr_control.tools.offline import run_scheme, scheme_plant_overrides
    from cr_sim.plants import flexible_joint_surface

    result = run_scheme(scheme, duration, controller_overrides=controller, plant_overrides=plant)
    plant_values = resolve(flexible_joint_surface.PARAMETERS, scheme_plant_overrides(scheme, plant))
    controller_values = resolve(controller_class(scheme).parameters(), controller)
    return from_offline(result, label or scheme, plant_values, controller_values)


def _error(message: str) -> int:
    import sys

    print(f"chapter6: error: {message}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m cr_control.analysis.chapter6 OUT_DIR [DURATION]``: the five runs of
    section 6.3 offline (default 20 s each): robust K_s = 10, 50 and 100, singular
    perturbation with and without τ_s; each run's figures in OUT_DIR/<run>/, the overlays
    and the table (ch6_comparison.md) in OUT_DIR; prints the table. A run that diverges is
    reported (with the time) and drawn; one that fails is reported and left out (exit 1)."""
    import sys
    import time

    args = sys.argv[1:] if argv is None else list(argv)
    if args and args[0] in ("-h", "--help"):
        print(main.__doc__)
        return 0
    if not args:
        return _error("missing OUT_DIR (usage: python -m cr_control.analysis.chapter6 "
                      "OUT_DIR [DURATION])")
    if len(args) > 2:
        return _error(f"too many arguments {args[2:]} (usage: OUT_DIR [DURATION])")
    if args[0].startswith("-"):
        return _error(f"unknown option {args[0]!r} (usage: OUT_DIR [DURATION])")
    out = Path(args[0])
    if out.exists() and not out.is_dir():
        return _error(f"OUT_DIR {str(out)!r} exists and is not a directory")
    duration = 20.0
    if len(args) > 1:
        try:
            duration = float(args[1])
        except ValueError:
            duration = math.nan
        if not (math.isfinite(duration) and duration > 0.0):
            return _error(f"DURATION must be a positive number of seconds, got {args[1]!r}")
    from cr_control.schemes.registry import controller_class

    for scheme in (ROBUST_SCHEME, SP_SCHEME):
        try:
            controller_class(scheme)
        except ValueError:
            print(f"chapter6: error: scheme {scheme!r} is not registered", file=sys.stderr)
            return 1
    runs, failed = [], 0
    begin = time.perf_counter()
    for folder, label, scheme, controller, plant in CASES:
        start = time.perf_counter()
        print(f"chapter 6: {label} ({scheme}), {duration:g} s simulated ...", flush=True)
        try:
            run = offline_run(scheme, duration, controller, plant, label)
            paths = plot_chapter6(run, out / folder)
        except Exception as exc:  # a run that cannot finish is reported, the rest goes on
            failed += 1
            print(f"  FAILED after {time.perf_counter() - start:.1f} s wall: "
                  f"{type(exc).__name__}: {exc}", flush=True)
            continue
        runs.append(run)
        div = divergence(run)
        state = (f"diverged at t = {div.time:.3f} s ({div.reason})" if div
                 else "no divergence")
        print(f"  done in {time.perf_counter() - start:.1f} s wall; {state}; {len(paths)} "
              f"figures in {out / folder}", flush=True)
    if runs:
        written = compare_chapter6(runs, out)
        print(written[-1].read_text())
        for path in written:
            print(path)
    print(f"chapter 6: {len(runs)} runs in {time.perf_counter() - begin:.1f} s wall"
          + (f", {failed} failed" if failed else ""), flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
