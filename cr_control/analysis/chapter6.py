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
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cr_control.analysis.chapter6_figures import (
    compare_chapter6,
    compare_sessions,
    plot_chapter6,
    session_figures,
)
from cr_control.analysis.chapter6_metrics import metrics_table, window_metrics
from cr_control.analysis.chapter6_runs import (
    ROBUST,
    ROBUST_EXTRAS,
    ROBUST_SCHEME,
    SP,
    SP_EXTRAS,
    SP_SCHEME,
    FlexRun,
    divergence,
    from_offline,
    from_session,
    is_chapter6,
    scheme_kind,
    thesis_case,
)
from cr_control.core.parameters import resolve

#: Names other modules and the tests import from here (their code lives in the modules above).
__all__ = [
    "FlexRun", "ROBUST", "ROBUST_EXTRAS", "ROBUST_SCHEME", "SP", "SP_EXTRAS", "SP_SCHEME",
    "compare_chapter6", "compare_sessions", "divergence", "from_offline", "from_session", "is_chapter6",
    "metrics_table", "plot_chapter6", "scheme_kind", "session_figures", "thesis_case", "window_metrics",
]

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
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_control.offline import run_scheme, scheme_plant_overrides
    from cr_control.schemes.registry import controller_class
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
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
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
