"""cr_reproduce's verdicts come from the numbers by their stated rules (synthetic sweep
tables, no Ray), and the report is one self-contained HTML file (figures inline)."""

from __future__ import annotations

import base64
import json

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
    results |= extras()
    items = reproduce.claims(results)
    assert [c["verdict"] for c in items if c["chapter"] == "5"] == verdicts
    assert all(c["verdict"] == "reproduced" for c in items if c["chapter"] == "3")


def test_chapter3_verdict_needs_contact_and_a_decreasing_error():
    base = {"ch5_impedance": ch5(8.0), "ch5_fuzzy_unidirectional": ch5(8.0), **extras()}
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
    results |= extras()
    assert reproduce.claims(results)[0]["measured"]["pos_err_rms_5_10s_mm"] == pytest.approx(12.6)


def test_report_is_self_contained(tmp_path):
    figure = tmp_path / "f.png"
    figure.write_bytes(PNG)
    results = {f"ch3_{s}": ch3(0.0126, 0.0) for s in reproduce.CH3}
    results |= {"ch5_impedance": ch5(6.3), "ch5_fuzzy_unidirectional": ch5(8.0)}
    results |= extras()
    for r in results.values():
        r.figures = [figure]
    items = reproduce.claims(results)
    json.dumps(items, allow_nan=False)                  # claims.json is strict JSON
    page = reproduce.report(tmp_path, "quick", results, items, reproduce.studies("quick"), 1.0)
    text = page.read_text()
    assert text.count("data:image/png;base64,") == len(results) and "src=\"http" not in text
    assert "<h2>Chapter 3</h2>" in text and "<h2>Chapter 5</h2>" in text
    assert "3.48 prints" in text                         # the defects, from docs/thesis.md


@pytest.mark.parametrize("normalised, verdict", [("diverged", "not reproduced"),
                                                 ("ok", "reproduced")])
def test_normalised_gradient_verdict_follows_its_rule(normalised, verdict):
    results = {f"ch3_{s}": ch3(0.0126, 0.0) for s in reproduce.CH3}
    results |= {"ch5_impedance": ch5(6.3), "ch5_fuzzy_unidirectional": ch5(8.0)}
    results |= extras(normalised)
    (item,) = [c for c in reproduce.claims(results) if c["chapter"] == "4"]
    assert item["verdict"] == verdict
    assert item["measured"]["plain_diverged_at_s"] == pytest.approx(51.261)
    assert item["measured"]["normalised_diverged_at_s"] == \
        (None if normalised == "ok" else pytest.approx(51.261))
