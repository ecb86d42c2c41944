"""cr_reproduce's verdicts come from the numbers by their stated rules (synthetic sweep
tables, no Ray), and the report is one self-contained HTML file (figures inline)."""

from __future__ import annotations

import base64
import json
import math

import pytest

from cr_control.experiments import reproduce
from cr_control.experiments.sweep import SweepResult

PNG = base64.b64decode("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8z8BQDwAEhQGA"
                       "hKmMIQAAAABJRU5ErkJggg==")


def ch3(error_late: float, contact_lost: float) -> SweepResult:
    rows = [{"plant.stiffness": k, "status": "ok", "pos_err_rms_last_half_m": error_late,
             "pos_err_rms_m": 0.02, "f_err_x_max_N": 5.0, "f_err_x_min_N": -2.8,
             "contact_lost_s": contact_lost} for k in (15.0, 150.0, 1500.0)]
    return SweepResult([], rows, 3, 0)


def ch5(threshold: float) -> SweepResult:
    rows = [{"plant.disturbance_magnitude": m, "plant.disturbance_duration": d, "status": "ok",
             "separated_s": 0.05 if m >= threshold else 0.0, "f_m_min_after_N": 1.0}
            for m in (2.0, 6.3, 8.0) for d in (0.06, 0.2)]
    return SweepResult([], rows, 6, 0)


def extras(normalised_status: str = "diverged") -> dict[str, SweepResult]:
    """Synthetic tables of the studies of reproduce.MODULES (the case 5 gradient runs, the
    Panda map)."""
    gradient = [{"mrac_force.gamma_f": 0.8, "mrac_force.normalised_gradient": n,
                 "status": "ok" if n and normalised_status == "ok" else "diverged",
                 "reason": "" if n and normalised_status == "ok" else
                 "joint position norm 100 beyond max_joint_position 100 at t = 51.261 s",
                 "f_err_x_rms_N": 0.2 if n and normalised_status == "ok" else 570.0,
                 "f_x_max_N": 2.0} for n in (False, True)]
    panda = [{"plant.stiffness": k, "plant.tool_mass": m, "status": "ok",
              "normal_force_err_rms_last_half_N": 0.05, "path_err_rms_last_half_m": 0.02,
              "contact_lost_s": 0.0, "command_at_limit_s": 0.0}
             for k in (5000.0, 50000.0) for m in (0.7, 1.4)]
    return {"ch4_normalised_gradient": SweepResult([], gradient, 2, 0),
            "panda_wiping_map": SweepResult([], panda, 4, 0)}


@pytest.mark.parametrize("fixed_at, fuzzy_at, verdicts", [
    (6.3, 8.0, ["not reproduced", "reproduced", "reproduced"]),
    (8.0, 8.0, ["not reproduced", "reproduced", "not reproduced"]),
    (2.0, 6.3, ["reproduced", "reproduced", "reproduced"]),
    (2.0, 2.0, ["reproduced", "not reproduced", "not reproduced"]),
])
def test_chapter5_verdicts_follow_the_rules(fixed_at, fuzzy_at, verdicts):
    results = {f"ch3_{s}": ch3(0.0126, 0.0) for s in reproduce.CH3}
    results |= {"ch5_impedance": ch5(fixed_at), "ch5_fuzzy_unidirectional": ch5(fuzzy_at)}
    items = reproduce.claims(results | chapters_246c() | extras())
    assert [c["verdict"] for c in items if c["chapter"] == "5"] == verdicts
    assert all(c["verdict"] == "reproduced" for c in items if c["chapter"] == "3")


def test_chapter3_verdict_needs_contact_and_a_decreasing_error():
    base = {"ch5_impedance": ch5(8.0), "ch5_fuzzy_unidirectional": ch5(8.0), **chapters_246c(),
            **extras()}
    lost = reproduce.claims({**base, **{f"ch3_{s}": ch3(0.0126, 0.2) for s in reproduce.CH3}})
    grows = reproduce.claims({**base, **{f"ch3_{s}": ch3(0.03, 0.0) for s in reproduce.CH3}})
    for items in (lost, grows):
        assert all(c["verdict"] == "not reproduced" for c in items if c["chapter"] == "3")
    assert lost[0]["measured"]["pos_err_rms_5_10s_mm"] == pytest.approx(12.6)


def test_the_thesis_point_is_picked_from_a_map_with_link_mass():
    rows = [{"plant.stiffness": 150.0, "plant.link_mass": m, "status": "ok",
             "pos_err_rms_last_half_m": e, "pos_err_rms_m": 0.02, "f_err_x_max_N": 5.0,
             "f_err_x_min_N": -2.8, "contact_lost_s": 0.0}
            for m, e in (([0.05, 0.05], 0.0115), ([0.1, 0.1], 0.0126), ([0.15, 0.15], 0.0137))]
    results = {f"ch3_{s}": SweepResult([], rows, 3, 0) for s in reproduce.CH3}
    results |= {"ch5_impedance": ch5(8.0), "ch5_fuzzy_unidirectional": ch5(8.0)}
    first = reproduce.claims(results | chapters_246c() | extras())[0]
    assert first["measured"]["pos_err_rms_5_10s_mm"] == pytest.approx(12.6)


def test_report_is_self_contained(tmp_path):
    figure = tmp_path / "f.png"
    figure.write_bytes(PNG)
    results = all_results()
    for r in results.values():
        r.figures = [figure]
    items = reproduce.claims(results)
    json.dumps(items, allow_nan=False)                  # claims.json is strict JSON
    page = reproduce.report(tmp_path, "quick", results, items, reproduce.studies("quick"), 1.0)
    text = page.read_text()
    assert text.count("data:image/png;base64,") == len(results) and "src=\"http" not in text
    for chapter in ("2", "3", "4", "5", "6"):
        assert f"<h2>Chapter {chapter}</h2>" in text
    assert "<h2>Appendix C</h2>" in text
    assert "r_2, r_1, r_0 of the MRAC (4.72) corrected" in text   # a claim's correction
    assert "3.48 prints" in text                         # the defects, from docs/thesis.md


# -- chapters 2, 4, 6 and appendix C (cr_control/experiments/chapters_246c.py) ----------------
#: The figures measured by ``cr_reproduce`` (rounded), at the studies' thesis points.
CH2 = {"e1_rms_first_s_rad": 2.4e-3, "e1_rms_late_rad": 1.0e-4, "lambda_err_rms_first_s_N": 0.98,
       "lambda_err_rms_late_N": 0.17, "lambda_err_max_late_N": 0.27}
CH2_NN = {**CH2, "e1_rms_first_s_rad": 1.8e-3, "e1_rms_late_rad": 3.7e-5,
          "lambda_err_rms_first_s_N": 0.78, "M1_norm_rel_err_late": 0.016,
          "C1_norm_rel_err_late": 0.50, "G1_norm_rel_err_early": 1.99, "G1_norm_rel_err_late": 0.34}
CASE = {"settling_s": 20.1, "ss_error_N": -3e-4, "overshoot_N": 0.15, "chatter_m": 1.7e-4,
        "f_max_N": 1.5, "held_from_s": math.nan, "model_err_max_tail_N": 0.014,
        "estimates_drift_tail_rel": 0.053, "estimates_err_end_rel": 0.39}
DIVERGED = {"status": "diverged", "reason": "joint position norm 100 beyond 100",
            "settling_s": math.nan, "ss_error_N": 266.0, "f_max_N": 3683.0, "chatter_m": 2.2,
            "held_from_s": 20.8, "model_err_max_tail_N": 797.0, "q1_max_tail_m": 1761.0,
            "u_peak_N": 6e45}
FJR = {"e_q_rms_first_s_rad": 0.142, "e_q_rms_late_rad": 7.0e-4, "e_q_max_late_rad": 1.4e-3,
       "lambda_err_rms_late_N": 0.054, "lambda_err_max_late_N": 0.12, "lambda_std_late_N": 0.054,
       "lambda_mean_late_N": 1.99, "p_err_start": 0.70, "p_err_end": 0.045}


def table(rows: list[dict]) -> SweepResult:
    return SweepResult([], [{"status": "ok", "reason": "", **r} for r in rows], len(rows), 0)


def chapters_246c(**change: dict) -> dict[str, SweepResult]:
    """Synthetic tables of the chapter 2, 4, 6, C studies as measured; ``change``: figures
    that replace the measured ones at a study's thesis point (study name -> figures)."""
    from cr_control.schemes.force.backstepping_force import PARAMETERS

    thesis_gamma = next(p.default for p in PARAMETERS if p.name == "Gamma")
    ch = {k: dict(v) for k, v in change.items()}
    out = {
        "ch2_moving_object_adaptive": table([{"moving_object_adaptive.lambda_d": 2.0, **CH2,
                                              **ch.get("ch2_adaptive", {})}]),
        "ch2_moving_object_nn": table([{"moving_object_nn.lambda_d": 2.0, **CH2_NN,
                                        **ch.get("ch2_nn", {})}]),
        "ch4_backstepping_map": table([{"plant.k_o": a, "plant.k_s": b, **CASE,
                                        **(ch.get(f"case{a:g}", {}) if a == b else {})}
                                       for a in (20.0, 50.0, 80.0) for b in (20.0, 50.0, 80.0)]),
        "ch4_adaptation": table([{"backstepping_force.gamma": g, "backstepping_force.Gamma": G,
                                  **(CASE if g else {**DIVERGED, **ch.get("case4", {})})}
                                 for g in (0.0, 0.01) for G in (0.0, thesis_gamma)]),
        "ch4_mrac": table([{"mrac_force.theta_f_hat_0": [0.65], **DIVERGED,
                            **ch.get("case5", {})},
                           {"mrac_force.theta_f_hat_0": [1.0], **CASE}]),
        "ch6_fjr_robust_adaptive": table([
            {"plant.joint_stiffness": 10.0, **FJR},
            {"plant.joint_stiffness": 50.0, **FJR, "e_q_rms_late_rad": 1.1e-3,
             "lambda_std_late_N": 0.131, **ch.get("ks50", {})},
            {"plant.joint_stiffness": 100.0, **FJR, "e_q_max_late_rad": 5.1e-3,
             **ch.get("ks100", {})}]),
        "ch6_fjr_singular_perturbation": table([
            {"plant.joint_stiffness": 300.0, "fjr_singular_perturbation.slow_control": True,
             **FJR, "lambda_mean_late_N": 1.12, "lambda_err_rms_late_N": 0.88,
             "lambda_err_max_late_N": 0.93, "e_q_rms_late_rad": 2.0e-4},
            {"plant.joint_stiffness": 300.0, "fjr_singular_perturbation.slow_control": False,
             **FJR, "lambda_mean_late_N": 1.36, "lambda_err_rms_late_N": 0.95,
             "e_q_rms_late_rad": 6.95e-3, "p_err_end": 0.70, **ch.get("sp_without", {})}]),
    }
    for n, q1 in ((1, 8e-8), (2, 2.8e-5), (3, None)):
        r = {"plant.initial_position": [0.1], "q1_max_tail_m": q1, "u_peak_N": 0.6,
             "q_max_m": 0.15, **(DIVERGED if q1 is None else {}), **ch.get(f"n{n}", {})}
        out[f"appC_n{n}"] = table([r])
    return out


def all_results(**change: dict) -> dict[str, SweepResult]:
    results = {f"ch3_{s}": ch3(0.0126, 0.0) for s in reproduce.CH3}
    results |= {"ch5_impedance": ch5(6.3), "ch5_fuzzy_unidirectional": ch5(8.0)}
    return results | chapters_246c(**change) | extras()


WITH, NOT, YES = "reproduced with correction", "not reproduced", "reproduced"
#: The verdicts of the full run, in claims.json order, per chapter (the quick run's 40 s leave
#: the chapter 4 estimates drifting: its third chapter 4 claim is not reproduced). The last
#: chapter 4 claim is the normalised-gradient conjecture's (normalised_gradient.py: refuted).
MEASURED = {"2": [WITH, WITH, WITH, WITH, NOT, YES, NOT, YES],
            "4": [WITH, NOT, YES, YES, NOT, NOT, WITH, NOT],
            "C": [YES, YES, NOT],
            "6": [WITH, WITH, YES, NOT, WITH, YES, NOT, YES]}


def verdicts(items: list[dict], chapter: str) -> list[str]:
    return [c["verdict"] for c in items if c["chapter"] == chapter]


def test_chapters_246c_verdicts_of_the_measured_numbers():
    items = reproduce.claims(all_results())
    for chapter, expected in MEASURED.items():
        assert verdicts(items, chapter) == expected, chapter
    for c in (c for c in items if c["chapter"] in MEASURED):
        assert c["rule"] and c["claim"][0].isdigit() or c["claim"].startswith("C.")
        assert any(isinstance(v, float) for v in c["measured"].values()), c["claim"]
        if c["verdict"] == WITH:                      # a correction names its equations
            assert c["correction"].startswith("docs/thesis.md ch. ") and "(" in c["correction"]
        else:
            assert "correction" not in c


@pytest.mark.parametrize("change, chapter, index, verdict", [
    ({"ch2_adaptive": {"e1_rms_late_rad": 3e-4}}, "2", 0, NOT),      # e1 not down 10x
    ({"ch2_nn": {"lambda_err_max_late_N": 2.5}}, "2", 3, NOT),        # lambda error > lambda_d
    ({"ch2_nn": {"lambda_err_rms_first_s_N": 1.2}}, "2", 4, YES),     # network fluctuates more
    ({"ch2_nn": {"M1_norm_rel_err_late": 0.3}}, "2", 6, YES),         # M_hat does not converge
    ({"ch2_nn": {"G1_norm_rel_err_late": 1.2}}, "2", 5, NOT),
    ({"case80": {"ss_error_N": 0.03}}, "4", 0, NOT),                  # case 3 off by 3 %
    ({"case50": {"chatter_m": 5e-4}, "case80": {"chatter_m": 5e-4}}, "4", 1, YES),
    ({"case20": {"estimates_drift_tail_rel": 0.17}}, "4", 2, NOT),   # still drifting
    ({"case20": {"estimates_err_end_rel": 0.05}}, "4", 2, NOT),      # at the true values
    ({"case4": {**CASE, "status": "ok", "ss_error_N": 0.3}}, "4", 4, YES),  # bounded offset
    ({"case4": {**CASE, "status": "ok", "reason": ""}}, "4", 3, NOT),  # case 4 converges
    ({"case5": {**CASE, "status": "ok", "reason": ""}}, "4", 5, YES),
    ({"n3": {"status": "ok", "reason": "", "q1_max_tail_m": 5e-5}}, "C", 2, YES),
    ({"n2": {"q1_max_tail_m": 2e-4}}, "C", 1, NOT),                   # above 1e-3 x q1(0)
    ({"ks50": {"e_q_rms_late_rad": 3e-3}}, "6", 1, NOT),              # not down 50x
    ({"ks50": {"lambda_std_late_N": 0.05}}, "6", 2, NOT),
    ({"ks100": {"status": "diverged"}}, "6", 3, YES),
    ({"ks100": {"e_q_max_late_rad": 2.0}}, "6", 3, YES),
    ({"sp_without": {"e_q_rms_late_rad": 1e-3}}, "6", 7, NOT),
])
def test_chapters_246c_verdicts_follow_the_rules(change, chapter, index, verdict):
    items = reproduce.claims(all_results(**change))
    assert verdicts(items, chapter)[index] == verdict
    assert verdicts(reproduce.claims(all_results()), chapter)[index] != verdict


@pytest.mark.parametrize("mode", ["quick", "full"])
def test_chapters_246c_specs_are_valid(mode):
    from cr_control.experiments import chapters_246c
    from cr_control.experiments.points import points
    from cr_control.experiments.spec import parse_spec

    sizes = {}
    for study in chapters_246c.studies(mode):
        spec, targets = parse_spec(study.spec, study.name)      # SpecError if a name is wrong
        sizes[study.name] = len(points(spec, targets))
        assert study.chapter in ("2", "4", "6", "C") and study.name.startswith(
            {"2": "ch2_", "4": "ch4_", "6": "ch6_", "C": "appC_"}[study.chapter])
    assert sizes["ch4_backstepping_map"] == (9 if mode == "quick" else 25)
    assert sizes["ch6_fjr_singular_perturbation"] == (6 if mode == "quick" else 12)
    assert sum(sizes.values()) == (29 if mode == "quick" else 64)


def test_chapters_246c_points_give_the_metrics_their_claims_read():
    """The first point of every quick study, run 1 s offline: every metric its SPEC lists
    is among the point's figures (a typo would leave a claim with NaN)."""
    from cr_control.experiments import chapters_246c, evaluate
    from cr_control.experiments.points import points
    from cr_control.experiments.spec import parse_spec

    for study in chapters_246c.studies("quick"):
        spec, targets = parse_spec(study.spec, study.name)
        _, inputs = points(spec, targets)[0]
        controller, plant = targets.split({**spec.fixed, **inputs})
        result = evaluate.run_point(spec.scheme, None, 1.0, controller, plant)
        assert result["status"] != "failed", (study.name, result["reason"])
        assert set(spec.metrics) <= set(result), (study.name, set(spec.metrics) - set(result))


@pytest.mark.parametrize("normalised, verdict", [("diverged", "not reproduced"),
                                                 ("ok", "reproduced")])
def test_normalised_gradient_verdict_follows_its_rule(normalised, verdict):
    results = all_results() | extras(normalised)
    (item,) = [c for c in reproduce.claims(results) if "plain_diverged_at_s" in c["measured"]]
    assert item["verdict"] == verdict
    assert item["measured"]["plain_diverged_at_s"] == pytest.approx(51.261)
    assert item["measured"]["normalised_diverged_at_s"] == \
        (None if normalised == "ok" else pytest.approx(51.261))
