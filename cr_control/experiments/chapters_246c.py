"""``cr_reproduce``'s chapters 2, 4, 6 and appendix C: their studies (sweeps) and claims.

Studies (each a :func:`cr_control.experiments.sweep.sweep`, figures from the sweep; the
per-point figures are those of :mod:`.chapter_metrics`):

- ch. 2 (20 s, thesis gains): ``moving_object_adaptive`` (2.27, 2.35) and
  ``moving_object_nn`` (2.74, 2.79-2.81) at lambda_d = 2 N (the full run adds 1 and 4 N);
- ch. 4: ``backstepping_force`` over the outer-layer stiffnesses (k_o, k_s) of the dynamic
  constraint (plant parameters; cases 1-3 are its diagonal 20/50/80 N/m), the robustness map
  of settling time and error; ``backstepping_force`` with and without each adaptation
  (gamma x Gamma, case 4 = both off); ``mrac_force`` (case 5) from 0.65 x theta_f (thesis)
  and from the true theta_f;
- appendix C: ``cmmsd_backstepping`` for n = 1, 2, 3 masses (q_1(0) = 0.1 m; the full run
  adds 0.02 and 0.05 m);
- ch. 6 (20 s): ``fjr_robust_adaptive`` against the plant's K_s (cases 1, 2 and the thesis's
  "divergent" 100 N m/rad), ``fjr_singular_perturbation`` against the plant's K_s (the scheme
  assumes 300) with and without tau_s (slow_control).

``--quick`` drops: the chapter 4 runs last 40 s (MRAC 60 s, past its divergence near 50 s)
instead of 100 s (too short for case 1's estimates to settle: that claim's verdict differs)
and the (k_o, k_s) map is 3 x 3 instead of 5 x 5; the appendix C runs last 30 s instead of
60 s; one q_1(0) and one lambda_d instead of three; the chapter 6 K_s grids have 3 values
instead of 6.

Claims (:func:`claims`): each with the numbers measured, a stated rule, and the verdict
computed by the rule (the claim() helper of :mod:`.reproduce`). Where the run needs one of
the corrections of the thesis (docs/thesis.md) to hold, the claim names it (equation numbers) and the
verdict is "reproduced with correction".
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from cr_control.experiments.study import Study, row
from cr_control.experiments.sweep import SweepResult
from cr_control.schemes.force.backstepping_force import PARAMETERS as BS
from cr_control.schemes.force.mrac_force import TRUE_THETA_F_CASE1

#: Studies by mode: chapter 4 durations (s) and grids.
CH4_SECONDS = {"quick": 40.0, "full": 100.0}
MRAC_SECONDS = {"quick": 60.0, "full": 100.0}
CH4_STIFFNESS = {"quick": [20.0, 50.0, 80.0], "full": [20.0, 35.0, 50.0, 65.0, 80.0]}
CHAIN_SECONDS = {"quick": 30.0, "full": 60.0}
CHAIN_Q0 = {"quick": [[0.1]], "full": [[0.02], [0.05], [0.1]]}
CH2_LAMBDA = {"quick": [2.0], "full": [1.0, 2.0, 4.0]}
CH2_SECONDS = 20.0
CH6_SECONDS = 20.0
CH6_ROBUST_KS = {"quick": [10.0, 50.0, 100.0], "full": [5.0, 10.0, 20.0, 50.0, 100.0, 200.0]}
CH6_SP_KS = {"quick": [100.0, 300.0, 1000.0], "full": [100.0, 200.0, 300.0, 500.0, 1000.0, 2000.0]}

#: Rules' thresholds (stated in each claim's rule).
#: Converged: late RMS error below this share of the first second's (robust K_s = 50: 0.008).
CONVERGED_SHARE = 0.02
#: e^1 -> 0 in chapter 2 (measured shares 0.06 adaptive, 0.04 network at 20 s).
E1_SHARE = 0.1
#: f -> f_d: |mean(f) - f_d| over the last 10 s below this share of f_d (the settling band).
FORCE_SHARE = 0.02
#: An estimate's norm "does not converge": relative RMS error of the norm above this.
NOT_CONVERGED_REL = 0.25
#: The MRAC follows its reference model: max |f - f_m| over the last 10 s below (N)
#: (measured 0.014 N from the true theta_f).
MODEL_ERR_N = 0.05
#: Chattering "big" in cases 2, 3: chatter of delta_c above this multiple of case 1's.
CHATTER_RATIO = 2.0
#: Chapter 4's estimates "convergent": relative drift over the last 10 s below this (case 1:
#: 0.053 at 100 s, 0.17 at 40 s); "different from the true values": relative error above it.
DRIFT_REL = 0.1
#: Appendix C: q_1 -> 0 when max |q_1| over the last 10 s is below this share of q_1(0).
CHAIN_SHARE = 1e-3
#: A chapter 6 run diverged: |e_q| beyond this (rad) (chapter6_runs.DIVERGENCE_RAD).
DIVERGED_RAD = 1.0
#: The singular-perturbation force "at lambda_d": |mean lambda - lambda_d| late below (N).
FORCE_AT_DESIRED_N = 0.1

#: The corrections of the thesis (docs/thesis.md) the runs need, with its equation numbers.
CORRECTION = {
    "moving_object_adaptive": "docs/thesis.md ch. 2: L^-T in (2.27) is a right inverse of L^T; "
    "psi_11 of the regressor of (2.35) is qddot_r1 (printed thetaddot_1); x and y swapped "
    "back in (2.100); p2 = 0.0045 (printed 0.04)",
    "moving_object_nn": "docs/thesis.md ch. 2: L^-T in (2.74) is a right inverse of L^T; x and y "
    "swapped back in (2.100)",
    "backstepping_force": "docs/thesis.md ch. 4: the coefficients d_0..d_3, l_0..l_2 of (4.4) "
    "corrected (b_c b_c, missing 1/b_s); plant (4.2)-(4.3) with (4.5)",
    "mrac_force": "docs/thesis.md ch. 4: r_2, r_1, r_0 of the MRAC (4.72) corrected "
    "(r_3 = r + b_2/b_3, r_2 = (r b_2 + b_1)/b_3, r_1 = (r b_1 + b_0)/b_3, r_0 = r b_0/b_3); "
    "(4.4) coefficients corrected",
    "fjr": "docs/thesis.md ch. 6: the surface x - y + 0.35 = 0 (printed x - y + 0.25 = 0), "
    "q_l(0) = [2.85, -2.1202], L of (6.118) = [1; -1 - d1(s1+c1)/(d2(s12+c12))]",
}

Claim = Callable[..., None]


def studies(mode: str) -> list[Study]:
    """The chapter 2, 4, 6 and appendix C sweeps of ``mode`` (quick / full)."""
    gamma_thesis = next(p.default for p in BS if p.name == "Gamma")
    theta_f = [float(x) for x in TRUE_THETA_F_CASE1]
    out = []
    ch2_metrics = ["e1_rms_first_s_rad", "e1_rms_late_rad", "lambda_err_rms_first_s_N",
                   "lambda_err_rms_late_N", "lambda_err_max_late_N"]
    for scheme, eqs, extra in (
            ("moving_object_adaptive", "2.27, 2.35", []),
            ("moving_object_nn", "2.74, 2.79-2.81",
             ["M1_norm_rel_err_late", "C1_norm_rel_err_late", "G1_norm_rel_err_early",
              "G1_norm_rel_err_late"])):
        out.append(Study(f"ch2_{scheme}", "2", f"{scheme} ({eqs}): joint error e^1, force "
                          "error and (network) the norms' approximation against lambda_d "
                          "(thesis 2 N), 20 s",
                          {"scheme": scheme, "duration": CH2_SECONDS,
                           "vary": {f"{scheme}.lambda_d": CH2_LAMBDA[mode]},
                           "metrics": ch2_metrics + extra}))
    seconds = CH4_SECONDS[mode]
    out.append(Study("ch4_backstepping_map", "4", "backstepping_force (4.56): settling time, "
                      "steady-state error, overshoot and chattering of delta_c against the "
                      f"outer-layer stiffnesses k_o, k_s (N/m; cases 1-3: 20/50/80), {seconds:g} s",
                      {"scheme": "backstepping_force", "duration": seconds,
                       "vary": {"plant.k_o": CH4_STIFFNESS[mode],
                                "plant.k_s": CH4_STIFFNESS[mode]},
                       "metrics": ["settling_s", "ss_error_N", "overshoot_N", "chatter_m",
                                   "estimates_drift_tail_rel", "estimates_err_end_rel"]}))
    out.append(Study("ch4_adaptation", "4", "backstepping_force with and without adaptation "
                      "(gamma of d_hat x Gamma of theta_hat; case 4: both 0), case 1 plant, "
                      f"{seconds:g} s",
                      {"scheme": "backstepping_force", "duration": seconds,
                       "vary": {"backstepping_force.gamma": [0.0, 0.01],
                                "backstepping_force.Gamma": [0.0, list(gamma_thesis)]},
                       "metrics": ["settling_s", "ss_error_N", "f_max_N", "held_from_s"]}))
    out.append(Study("ch4_mrac", "4", "mrac_force (4.72, 4.76-4.77), case 5: from 0.65 x "
                      f"theta_f (thesis) and from the true theta_f, {MRAC_SECONDS[mode]:g} s",
                      {"scheme": "mrac_force", "duration": MRAC_SECONDS[mode],
                       "vary": {"mrac_force.theta_f_hat_0": [[0.65 * x for x in theta_f],
                                                             theta_f]},
                       "metrics": ["settling_s", "ss_error_N", "model_err_max_tail_N",
                                   "held_from_s"]}))
    for n in (1, 2, 3):
        out.append(Study(f"appC_n{n}", "C", f"cmmsd_backstepping (C.50), n = {n} masses: "
                          "q_1 regulation against the initial displacement (every mass), "
                          f"{CHAIN_SECONDS[mode]:g} s",
                          {"scheme": "cmmsd_backstepping", "duration": CHAIN_SECONDS[mode],
                           "set": {"plant.masses": n,
                                   "cmmsd_backstepping.joint_names":
                                       [f"q{i + 1}" for i in range(n)]},
                           "vary": {"plant.initial_position": CHAIN_Q0[mode]},
                           "metrics": ["q1_max_tail_m", "u_peak_N", "q_max_m"]}))
    ch6 = ["e_q_rms_first_s_rad", "e_q_rms_late_rad", "e_q_max_late_rad",
           "lambda_err_rms_late_N", "lambda_err_max_late_N"]
    out.append(Study("ch6_fjr_robust_adaptive", "6", "fjr_robust_adaptive (6.58): link and "
                      "force errors against the joint stiffness K_s (N m/rad; cases 1, 2: "
                      f"10, 50), {CH6_SECONDS:g} s",
                      {"scheme": "fjr_robust_adaptive", "duration": CH6_SECONDS,
                       "vary": {"plant.joint_stiffness": CH6_ROBUST_KS[mode]},
                       "metrics": [*ch6, "lambda_std_late_N", "tau_peak_after_1s_Nm"]}))
    out.append(Study("ch6_fjr_singular_perturbation", "6", "fjr_singular_perturbation (6.78 + "
                      "6.102): link and force errors against the plant's K_s (the scheme "
                      f"assumes 300 N m/rad), with and without tau_s, {CH6_SECONDS:g} s",
                      {"scheme": "fjr_singular_perturbation", "duration": CH6_SECONDS,
                       "vary": {"plant.joint_stiffness": CH6_SP_KS[mode],
                                "fjr_singular_perturbation.slow_control": [True, False]},
                       "metrics": [*ch6, "lambda_mean_late_N", "p_err_start", "p_err_end"]}))
    return out


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def _json_value(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return "n/a" if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def _ok(r: dict[str, Any]) -> bool:
    return r["status"] == "ok"


def claims(results: dict[str, SweepResult], add: Claim) -> None:
    """The claims of chapters 2, 4, 6 and appendix C, through ``add`` (reproduce's claim())."""
    def strict(chapter: str, text: str, measured: dict[str, Any], *rest: Any) -> None:
        # claims.json is strict JSON: a figure that does not exist (NaN: never settled,
        # never held) is written "n/a", an infinite one "inf"
        add(chapter, text, {k: _json_value(v) for k, v in measured.items()}, *rest)

    for chapter in (_chapter2, _chapter4, _appendix_c, _chapter6):
        chapter(results, strict, row)


def _chapter2(results: dict[str, SweepResult], claim: Claim, row: Callable) -> None:
    lambda_d = 2.0
    runs = {s: row(results[f"ch2_{s}"], **{f"{s}__lambda_d": lambda_d})
            for s in ("moving_object_adaptive", "moving_object_nn")}
    for scheme, r in runs.items():
        section = "2.4, Theorem 2.3.1" if scheme.endswith("adaptive") else "2.4, Theorem 2.3.2"
        claim("2", f"{section}: {scheme}: \"e^1 -> 0\" (thesis gains, 20 s)",
              {"e1_rms_0_1s_mrad": 1e3 * r["e1_rms_first_s_rad"],
               "e1_rms_last_quarter_mrad": 1e3 * r["e1_rms_late_rad"], "status": r["status"]},
              f"status ok and RMS |e^1| over the last quarter below {E1_SHARE:g} x that of the "
              "first second",
              lambda r=r: _ok(r) and r["e1_rms_late_rad"] < E1_SHARE * r["e1_rms_first_s_rad"],
              CORRECTION[scheme])
        claim("2", f"{section}: {scheme}: \"e_lambda is bounded\" (lambda_d = 2 N)",
              {"lambda_err_rms_0_1s_N": r["lambda_err_rms_first_s_N"],
               "lambda_err_rms_last_quarter_N": r["lambda_err_rms_late_N"],
               "lambda_err_max_last_quarter_N": r["lambda_err_max_late_N"]},
              "status ok and max |lambda_d - lambda| over the last quarter below lambda_d "
              "(2 N), its RMS below that of the first second",
              lambda r=r: _ok(r) and r["lambda_err_max_late_N"] < lambda_d
              and r["lambda_err_rms_late_N"] < r["lambda_err_rms_first_s_N"],
              CORRECTION[scheme])
    a, n = runs["moving_object_adaptive"], runs["moving_object_nn"]
    claim("2", "2.4: \"the magnitudes of the fluctuations of the force signals are bigger "
          "under neural network based adaptive control ... especially at the initial stage\"",
          {"lambda_err_rms_0_1s_adaptive_N": a["lambda_err_rms_first_s_N"],
           "lambda_err_rms_0_1s_network_N": n["lambda_err_rms_first_s_N"]},
          "RMS lambda error over the first second larger for the network scheme",
          lambda: n["lambda_err_rms_first_s_N"] > a["lambda_err_rms_first_s_N"])
    claim("2", "2.4 (fig. 2.12): \"G_hat_nn almost converge to its true value\"",
          {"G1_norm_rel_err_1_5s": n["G1_norm_rel_err_early"],
           "G1_norm_rel_err_last_quarter": n["G1_norm_rel_err_late"]},
          "relative RMS error of |G_hat| against |G^1| over the last quarter below half that "
          "over 1-5 s", lambda: n["G1_norm_rel_err_late"] < 0.5 * n["G1_norm_rel_err_early"])
    for name, fig in (("M1", "2.10"), ("C1", "2.11")):
        claim("2", f"2.4 (fig. {fig}): \"{name[0]}_hat_nn do[es] not converge to {name[0]}\"",
              {f"{name}_norm_rel_err_last_quarter": n[f"{name}_norm_rel_err_late"]},
              f"relative RMS error of |{name[0]}_hat| against |{name}| over the last quarter "
              f"above {NOT_CONVERGED_REL:g}",
              lambda name=name: n[f"{name}_norm_rel_err_late"] > NOT_CONVERGED_REL)


def _chapter4(results: dict[str, SweepResult], claim: Claim, row: Callable) -> None:
    grid = results["ch4_backstepping_map"]
    cases = {k: row(grid, plant__k_o=k, plant__k_s=k) for k in (20.0, 50.0, 80.0)}
    f_d = 1.0

    def converged(r: dict[str, Any]) -> bool:
        return _ok(r) and _finite(r["settling_s"]) and abs(r["ss_error_N"]) < FORCE_SHARE * f_d

    claim("4", "4.3 (figs. 4.2, 4.3): cases 1-3: \"the constraint force is convergent in each "
          "case though the stiffness of the constraint surface varies\" (f_d = 1 N)",
          {**{f"settling_case{i}_s": r["settling_s"] for i, r in enumerate(cases.values(), 1)},
           **{f"ss_error_case{i}_N": r["ss_error_N"] for i, r in enumerate(cases.values(), 1)}},
          f"in each case: status ok, settled in the 2 % band, |mean f - f_d| over the last "
          f"10 s below {FORCE_SHARE * f_d:g} N", lambda: all(map(converged, cases.values())),
          CORRECTION["backstepping_force"])
    c1, c2, c3 = cases.values()
    claim("4", "4.3: \"some fast and big chattering of the force and command displacement "
          "appear in Cases 2 and 3 where the stiffness of the constraint is big\"",
          {f"chatter_delta_c_case{i}_mm": 1e3 * r["chatter_m"]
           for i, r in enumerate(cases.values(), 1)},
          f"delta_c chattering (RMS about its 1 s mean) of cases 2 and 3 above {CHATTER_RATIO:g}"
          " x case 1's", lambda: min(c2["chatter_m"], c3["chatter_m"])
          > CHATTER_RATIO * c1["chatter_m"])
    claim("4", "4.3 (figs. 4.4-4.6): case 1: \"the parameters are convergent but are different "
          "from their true values\"",
          {"estimates_drift_last_10s_rel": c1["estimates_drift_tail_rel"],
           "estimates_err_end_rel": c1["estimates_err_end_rel"]},
          f"largest peak-to-peak of an estimate over the last 10 s below {DRIFT_REL:g} x its "
          f"final value, and |theta_hat - theta| / |theta| at the end above {DRIFT_REL:g}",
          lambda: c1["estimates_drift_tail_rel"] < DRIFT_REL
          and c1["estimates_err_end_rel"] > DRIFT_REL)
    off = row(results["ch4_adaptation"], backstepping_force__gamma=0.0,
              backstepping_force__Gamma=0.0)
    claim("4", "4.3 (figs. 4.7, 4.8): case 4, adaptation stopped: \"the force response cannot "
          "be converged to the desired value\"",
          {"settling_s": off["settling_s"], "ss_error_N": off["ss_error_N"],
           "status": off["status"]},
          "not settled, or |mean f - f_d| over the last 10 s at least "
          f"{FORCE_SHARE * f_d:g} N", lambda: not converged(off))
    claim("4", "4.3 (fig. 4.7): case 4 stays a bounded response with a steady-state error "
          "(not a divergence)",
          {"f_max_N": off["f_max_N"], "held_from_s": off["held_from_s"],
           "status": off["status"], "reason": off["reason"]},
          "status ok (no divergence) and max f below 10 f_d",
          lambda: _ok(off) and off["f_max_N"] < 10.0 * f_d)
    mrac = results["ch4_mrac"]
    thesis, true = mrac.rows[0], mrac.rows[1]
    claim("4", "4.3 (figs. 4.9-4.11): case 5, MRAC from 0.65 x theta_f: \"the output force f "
          "converged to its desired values f_d = 1\"",
          {"settling_s": thesis["settling_s"], "ss_error_N": thesis["ss_error_N"],
           "status": thesis["status"], "reason": thesis["reason"]},
          f"status ok, settled, |mean f - f_d| over the last 10 s below {FORCE_SHARE * f_d:g} N",
          lambda: converged(thesis))
    claim("4", "4.2.2, Theorem 4.2.2: under (4.72), (4.76)-(4.77) \"f -> f_m\" (run from the "
          "true theta_f)",
          {"model_err_max_last_10s_N": true["model_err_max_tail_N"],
           "ss_error_N": true["ss_error_N"], "status": true["status"]},
          f"status ok and max |f - f_m| over the last 10 s below {MODEL_ERR_N:g} N",
          lambda: _ok(true) and true["model_err_max_tail_N"] < MODEL_ERR_N,
          CORRECTION["mrac_force"])


def _appendix_c(results: dict[str, SweepResult], claim: Claim, row: Callable) -> None:
    q0 = [0.1]
    chains = {n: row(results[f"appC_n{n}"], plant__initial_position=q0) for n in (1, 2, 3)}
    for n, r in chains.items():
        text = ("C.2 (C.50): \"z -> 0 ... y_1 -> 0\" for the chain of n masses" if n < 3 else
                "C.2: the design holds for any n (\"a chain of multiple mass-spring-damper "
                "units\")")
        claim("C", f"{text}: n = {n}, q_1(0) = 0.1 m",
              {"q1_max_last_10s_m": r["q1_max_tail_m"], "u_peak_N": r["u_peak_N"],
               "status": r["status"], "reason": r["reason"]},
              f"status ok and max |q_1| over the last 10 s below {CHAIN_SHARE:g} x q_1(0)",
              lambda r=r: _ok(r) and r["q1_max_tail_m"] < CHAIN_SHARE * q0[0])


def _chapter6(results: dict[str, SweepResult], claim: Claim, row: Callable) -> None:
    lambda_d = 2.0

    def converged(r: dict[str, Any]) -> bool:
        return (_ok(r) and r["e_q_rms_late_rad"] < CONVERGED_SHARE * r["e_q_rms_first_s_rad"]
                and r["lambda_err_max_late_N"] < lambda_d)

    rule = (f"status ok, RMS |e_q| over the last quarter below {CONVERGED_SHARE:g} x that of "
            f"the first second, max |lambda_d - lambda| over the last quarter below lambda_d "
            f"({lambda_d:g} N)")

    def numbers(r: dict[str, Any]) -> dict[str, Any]:
        return {"e_q_rms_0_1s_mrad": 1e3 * r["e_q_rms_first_s_rad"],
                "e_q_rms_last_quarter_mrad": 1e3 * r["e_q_rms_late_rad"],
                "lambda_err_max_last_quarter_N": r["lambda_err_max_late_N"],
                "status": r["status"]}

    robust = results["ch6_fjr_robust_adaptive"]
    case = {ks: row(robust, plant__joint_stiffness=ks) for ks in (10.0, 50.0, 100.0)}
    for ks, number, figs in ((10.0, 1, "6.2-6.6"), (50.0, 2, "6.7-6.11")):
        claim("6", f"6.3.1 case {number} (K_s = {ks:g}, figs. {figs}): \"the link positions of "
              "the robot converge to their desired values and the force tracking error is "
              "bounded\"", numbers(case[ks]), rule, lambda r=case[ks]: converged(r),
              CORRECTION["fjr"])
    c1, c2 = case[10.0], case[50.0]
    claim("6", "6.3.1 case 2: \"the responses of the constraint force ... demonstrate bigger "
          "fluctuations\" than case 1",
          {"lambda_std_last_quarter_case1_N": c1["lambda_std_late_N"],
           "lambda_std_last_quarter_case2_N": c2["lambda_std_late_N"]},
          "standard deviation of lambda over the last quarter larger for K_s = 50 than 10",
          lambda: c2["lambda_std_late_N"] > c1["lambda_std_late_N"])
    big = case[100.0]
    claim("6", "6.3.1: \"once K_s becomes very big (e.g. K_s = diag[100.0]) ... the responses "
          "of the control system become divergent\"",
          {"e_q_max_last_quarter_mrad": 1e3 * big["e_q_max_late_rad"],
           "lambda_err_max_last_quarter_N": big["lambda_err_max_late_N"],
           "status": big["status"]},
          f"status diverged, or max |e_q| over the last quarter above {DIVERGED_RAD:g} rad",
          lambda: big["status"] == "diverged" or not big["e_q_max_late_rad"] < DIVERGED_RAD)
    sp = results["ch6_fjr_singular_perturbation"]
    with_s = row(sp, plant__joint_stiffness=300.0, fjr_singular_perturbation__slow_control=True)
    without = row(sp, plant__joint_stiffness=300.0,
                  fjr_singular_perturbation__slow_control=False)
    claim("6", "6.3.2 (figs. 6.12-6.15): \"the link positions of the robot converge to their "
          "desired values and the force tracking error is bounded\"", numbers(with_s), rule,
          lambda: converged(with_s), CORRECTION["fjr"])
    claim("6", "6.3.2 (fig. 6.15): \"the parameter estimation are also stabilized and bounded\"",
          {"p_err_start": with_s["p_err_start"], "p_err_end": with_s["p_err_end"]},
          "|p_hat - p| at the end finite and no larger than at the start",
          lambda: _finite(with_s["p_err_end"]) and with_s["p_err_end"] <= with_s["p_err_start"])
    claim("6", "6.3.2 (fig. 6.13): lambda follows lambda_d = 2 N",
          {"lambda_mean_last_quarter_N": with_s["lambda_mean_late_N"]},
          f"|mean lambda - lambda_d| over the last quarter below {FORCE_AT_DESIRED_N:g} N",
          lambda: abs(with_s["lambda_mean_late_N"] - lambda_d) < FORCE_AT_DESIRED_N)
    claim("6", "6.3.2 (figs. 6.16-6.18), without tau_s: \"the link position cannot converge to "
          "its desired trajectory and the constraint force shows bigger tracking errors\"",
          {"e_q_rms_last_quarter_with_mrad": 1e3 * with_s["e_q_rms_late_rad"],
           "e_q_rms_last_quarter_without_mrad": 1e3 * without["e_q_rms_late_rad"],
           "lambda_err_rms_last_quarter_with_N": with_s["lambda_err_rms_late_N"],
           "lambda_err_rms_last_quarter_without_N": without["lambda_err_rms_late_N"]},
          "without tau_s: RMS |e_q| over the last quarter above 10 x that with tau_s, and a "
          "larger RMS lambda error",
          lambda: without["e_q_rms_late_rad"] > 10.0 * with_s["e_q_rms_late_rad"]
          and without["lambda_err_rms_late_N"] > with_s["lambda_err_rms_late_N"])
