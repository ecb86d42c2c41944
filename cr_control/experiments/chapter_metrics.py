"""Per-point figures of the chapter 2, 4, 6 and appendix C runs, for sweeps and ``cr_reproduce``.

:func:`chapter_metrics` adds to a point's ``cr_analyze`` metrics the numbers the chapter's
own analysis gives (:mod:`cr_control.analysis.chapter2`, ``chapter4``, ``chapter6_metrics``),
flat and named with their unit, so that a sweep's table carries what docs/results.md reports
and the claims of :mod:`cr_control.experiments.chapters_246c` are computed from it:

- chapter 2 (``moving_object_*``): ``e1_rms_first_s_rad`` (window [0, 1) s) and
  ``e1_rms_late_rad`` (the last quarter of the run), ``lambda_{min,max}_after_1s_N``,
  ``lambda_err_rms_first_s_N`` / ``_late_N``, ``lambda_err_max_late_N``,
  ``lambda_negative_s`` (time with lambda < 0), ``x_o_err_rms_late_m``; the adaptive scheme
  ``P_err_start``/``P_err_end`` (|P_hat - P|),
  the network scheme ``{M1,C1,G1}_norm_rel_err_{early,late}`` (RMS of |X| - |X_hat| over RMS
  |X|, early = [1, 5) s, late = the last quarter);
- chapter 4 (``backstepping_force``, ``mrac_force``): :func:`chapter4.force_metrics`
  (``settling_s``, ``ss_error_N``, ``chatter_m``, ``no_contact_s``... over the last 10 s), the
  estimates' ``estimates_drift_tail_rel`` (largest peak-to-peak of an estimate over the last
  10 s relative to its final value) and ``estimates_err_end_rel`` (|theta_hat - theta| / |theta|
  at the end, over the estimates with a true value) and, for the MRAC,
  ``model_err_max_tail_N`` = max |f - f_m| over the last 10 s;
- appendix C (``cmmsd_backstepping``): :func:`chapter4.chain_metrics` (``q1_max_tail_m``,
  ``u_peak_N``, ``q_max_m``...) and ``q1_initial_m``;
- chapter 6 (``fjr_*``): ``e_q_rms_first_s_rad``, ``e_q_rms_late_rad``, ``e_q_max_late_rad``,
  ``lambda_{min,max}_after_1s_N``, ``lambda_err_max_after_1s_N``, ``lambda_{mean,std}_late_N``,
  ``lambda_err_{rms,max}_late_N``, ``tau_peak_after_1s_Nm``, ``diverged_at_s`` (NaN: never, by
  :func:`chapter6_runs.divergence`), the estimates at the end (``p_err_start``/``p_err_end``
  where the truth is known, ``ks_inv_hat_{1,2}_end``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cr_control.analysis import chapter2 as ch2
from cr_control.analysis import chapter4 as ch4
from cr_control.analysis import chapter6_metrics as m6
from cr_control.analysis import chapter6_runs as r6

#: Start-up left out of the "after 1 s" figures (s).
STARTUP_S = 1.0
#: The "late" window: the last quarter of the run.
LATE_FRACTION = 0.25
#: The chapter 2 network's "early" window [1, 5) s.
EARLY_S = (1.0, 5.0)


def _rms(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else math.nan


def _reduce(fn: Any, x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(fn(x)) if len(x) else math.nan


def _late(t: np.ndarray) -> np.ndarray:
    return t >= t[-1] * (1.0 - LATE_FRACTION)


def chapter2(run: Any, scheme: str) -> dict[str, float]:
    """The chapter 2 figures of an offline run (module docstring)."""
    r = ch2.from_offline(run, scheme)
    t = r.time
    first, late, after = t < STARTUP_S, _late(t), t >= STARTUP_S
    e1 = np.hypot(r.e1[:, 0], r.e1[:, 1])
    err = r.lam_d - r.lam
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    out = {"e1_rms_first_s_rad": _rms(e1[first]), "e1_rms_late_rad": _rms(e1[late]),
           "lambda_min_after_1s_N": _reduce(np.min, r.lam[after]),
           "lambda_max_after_1s_N": _reduce(np.max, r.lam[after]),
           "lambda_err_rms_first_s_N": _rms(err[first]), "lambda_err_rms_late_N": _rms(err[late]),
           "lambda_err_max_late_N": _reduce(np.max, np.abs(err[late])),
           "lambda_negative_s": float(np.count_nonzero(r.lam < 0.0) * dt),
           "x_o_err_rms_late_m": _rms((r.x_o_d - r.x_o)[late])}
    summary = ch2.run_summary(r)
    for key in ("P_err_start", "P_err_end"):
        if key in summary:
            out[key] = float(summary[key])
    early = (t >= EARLY_S[0]) & (t < EARLY_S[1])
    for true, est, name, _ in ch2.NORM_PAIRS:
        if true in r.norms and est in r.norms:
            for label, w in (("early", early), ("late", late)):
                a, b = r.norms[true][w], r.norms[est][w]
                out[f"{name}_norm_rel_err_{label}"] = _rms(a - b) / max(_rms(a), 1e-12)
    return out


def chapter4(run: Any, plant: dict[str, Any], controller: dict[str, Any]) -> dict[str, float]:
    """The chapter 4 force figures of an offline run (module docstring)."""
    r = ch4.force_from_offline(run, "run", plant, controller)
    out = {k: float(v) for k, v in ch4.force_metrics(r).items()}
    names = [n for n in r.estimates if n in r.true]
    if names:
        tail = r.time >= r.time[-1] - ch4.TAIL_S
        end = np.array([r.estimates[n][-1] for n in names])
        truth = np.array([r.true[n] for n in names])
        drift = [np.ptp(r.estimates[n][tail]) / max(abs(r.estimates[n][-1]), 1e-9) for n in names]
        out["estimates_drift_tail_rel"] = _reduce(np.max, np.array(drift))
        out["estimates_err_end_rel"] = float(np.linalg.norm(end - truth) / np.linalg.norm(truth))
    if r.f_m is not None:
        tail = r.time >= r.time[-1] - ch4.TAIL_S
        out["model_err_max_tail_N"] = _reduce(np.max, np.abs(r.f - r.f_m)[tail])
    return out


def appendix_c(run: Any, plant: dict[str, Any]) -> dict[str, float]:
    """The appendix C chain figures of an offline run (module docstring)."""
    r = ch4.chain_from_offline(run, "run", plant)
    out = {k: float(v) for k, v in ch4.chain_metrics(r).items()}
    out["q1_initial_m"] = float(r.q[0, 0])
    return out


def chapter6(run: Any, scheme: str, plant: dict[str, Any], controller: dict[str, Any]
             ) -> dict[str, float]:
    """The chapter 6 figures of an offline run (module docstring)."""
    r = r6.from_offline(run, scheme, plant, controller)
    t = r.time
    first, late, after = t < STARTUP_S, _late(t), t >= STARTUP_S
    e = r.e_q_norm
    err = r.lam_d - r.lam
    div = r6.divergence(r)
    out = {"e_q_rms_first_s_rad": _rms(e[first]), "e_q_rms_late_rad": _rms(e[late]),
           "e_q_max_late_rad": _reduce(np.max, e[late]),
           "lambda_min_after_1s_N": _reduce(np.min, r.lam[after]),
           "lambda_max_after_1s_N": _reduce(np.max, r.lam[after]),
           "lambda_err_max_after_1s_N": _reduce(np.max, np.abs(err[after])),
           "lambda_mean_late_N": _reduce(np.mean, r.lam[late]),
           "lambda_std_late_N": _reduce(np.std, r.lam[late]),
           "lambda_err_rms_late_N": _rms(err[late]),
           "lambda_err_max_late_N": _reduce(np.max, np.abs(err[late])),
           "tau_peak_after_1s_Nm": _reduce(np.max, np.abs(r.tau[after])),
           "diverged_at_s": div.time if div is not None else math.nan}
    summary = m6.run_summary(r)
    for key in ("p_err_start", "p_err_end", "ks_inv_hat_1_end", "ks_inv_hat_2_end"):
        if key in summary:
            out[key] = float(summary[key])
    return out


def chapter_metrics(run: Any, scheme: str, plant: dict[str, Any], controller: dict[str, Any]
                    ) -> dict[str, float]:
    """The chapter figures of ``run`` of ``scheme`` (none for other schemes); ``plant``: the
    plant's parameter values (defaults and overrides), ``controller``: the controller's."""
    if scheme.startswith("moving_object_"):
        return chapter2(run, scheme)
    if scheme in ("backstepping_force", "mrac_force"):
        return chapter4(run, plant, controller)
    if scheme == "cmmsd_backstepping":
        return appendix_c(run, plant)
    if scheme.startswith("fjr_"):
        return chapter6(run, scheme, plant, controller)
    return {}
