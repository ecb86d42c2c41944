"""Chapter 6 analysis (cr_control.analysis.chapter6): metrics on synthetic runs with known
numbers, the field sets of both schemes, divergence handling, and figures, tables and the
cr_analyze hooks on short offline runs of fjr_robust_adaptive and fjr_singular_perturbation
(skipped, with the reason, while a scheme is not registered)."""

import math
from pathlib import Path

import numpy as np
import pytest

from cr_control.analysis import analyze, chapter6
from cr_control.core.topics import STATUS_FIELDS
from cr_control.schemes.flexible_joint import flexible_joint_scheme

PNG = b"\x89PNG\r\n\x1a\n"
COMMON = [*STATUS_FIELDS, *flexible_joint_scheme.STATUS]


def assert_png(path: Path) -> None:
    assert path.exists() and path.stat().st_size > 0 and path.read_bytes()[:8] == PNG, path


def synthetic(kind: str = chapter6.ROBUST, duration: float = 6.0, label: str = "synthetic",
              dt: float = 1e-3) -> chapter6.FlexRun:
    """e_q = (0.1 sin 2πt, 0), λ = 2 + 0.5 sin 2πt (λ_d = 2), τ_m = (3 sin 2πt, −1), p̂
    constant (norm known), k̂_s⁻¹ = 0.1 (robust) or ‖Γ⁻¹‖ = 1/60, γ = 1 (SP)."""
    t = np.arange(0.0, duration, dt)
    s = np.sin(2 * np.pi * t)
    n = len(t)
    e_q = np.column_stack([0.1 * s, np.zeros(n)])
    q_ld = np.column_stack([2.85 + 0.1 * np.cos(2 * t), -2.12 + 0.1 * np.sin(2 * t)])
    lam = 2.0 + 0.5 * s
    tau = np.column_stack([3.0 * s, -np.ones(n)])
    if kind == chapter6.ROBUST:
        extras = {f"p_hat_{i}": np.full(n, 1.0) for i in range(1, 11)}
        extras |= {"ks_inv_hat_1": np.full(n, 0.1), "ks_inv_hat_2": np.full(n, 0.1),
                   "qddot_m_1": s + 0.1 * np.cos(400 * t), "qddot_m_2": -s,
                   "qddot_m_filtered_1": s, "qddot_m_filtered_2": -s}
    else:
        extras = {f"p_hat_{i}": np.full(n, 2.0) for i in range(1, 6)}
        extras |= {"gamma_inv_norm": np.full(n, 1 / 60), "forgetting": np.ones(n),
                   "tau_s_1": 0.2 * s, "tau_s_2": 0.1 * s}
    return chapter6.FlexRun(label, kind, t, q_ld, e_q, lam, np.full(n, 2.0), tau,
                            np.zeros(n), np.zeros(n, dtype=bool), extras)


# -- synthetic data ----------------------------------------------------------------------
def test_window_metrics_on_synthetic_data():
    run = synthetic()
    m = chapter6.window_metrics(run, 1.0, 5.0)           # four whole periods
    assert m["e_q_rms_rad"] == pytest.approx(0.1 / math.sqrt(2), rel=1e-6)   # 0.0707...
    assert m["e_q_max_rad"] == pytest.approx(0.1, rel=1e-6)
    assert m["lambda_min_N"] == pytest.approx(1.5, abs=1e-6)
    assert m["lambda_max_N"] == pytest.approx(2.5, abs=1e-6)
    assert m["lambda_err_rms_N"] == pytest.approx(0.5 / math.sqrt(2), rel=1e-6)
    assert m["lambda_err_max_N"] == pytest.approx(0.5, abs=1e-6)
    assert m["tau1_peak_Nm"] == pytest.approx(3.0, abs=1e-6)
    assert m["tau1_rms_Nm"] == pytest.approx(3.0 / math.sqrt(2), rel=1e-6)
    assert m["tau2_peak_Nm"] == pytest.approx(1.0) and m["tau2_rms_Nm"] == pytest.approx(1.0)
    assert m["p_hat_norm_end"] == pytest.approx(math.sqrt(10))
    assert m["ks_inv_hat_1_end"] == pytest.approx(0.1) and m["held_fraction"] == 0.0
    assert "gamma_inv_norm_end" not in m
    np.testing.assert_allclose(run.q_l, run.q_ld - run.e_q)

    sp = chapter6.window_metrics(synthetic(chapter6.SP), 0.0, 1.0)
    assert sp["p_hat_norm_end"] == pytest.approx(2.0 * math.sqrt(5))
    assert sp["gamma_inv_norm_end"] == pytest.approx(1 / 60) and "ks_inv_hat_1_end" not in sp

    # windows cut to the run; one row per (window, run); '—' for what a scheme lacks
    table = chapter6.metrics_table([run, synthetic(chapter6.SP, label="sp")])
    rows = [line for line in table.splitlines() if line.startswith("| synthetic |")]
    assert [r.split(" | ")[1] for r in rows] == ["0–1", "1–5", "5–6"]
    assert len([line for line in table.splitlines() if line.startswith("| sp |")]) == 3
    assert "| 70.7 | 100 | 1.500 | 2.500 |" in rows[1]
    assert "0.1, 0.1 | — |" in rows[1]
    assert "no divergence" in table and "clip" not in table
    run.max_effort = 1.0                                   # τ_m2 = −1 sits at the clip
    assert "τ_m at the ±1 N m clip (max_effort) in 100.0 % of the cycles" in \
        chapter6.metrics_table([run])


def test_is_chapter6_on_both_field_sets():
    robust = [*COMMON, *chapter6.ROBUST_EXTRAS]
    sp = [*COMMON, *chapter6.SP_EXTRAS]
    assert chapter6.is_chapter6(robust) and chapter6.scheme_kind(robust) == chapter6.ROBUST
    assert chapter6.is_chapter6(sp) and chapter6.scheme_kind(sp) == chapter6.SP
    assert not chapter6.is_chapter6(COMMON)                        # no scheme's own fields
    assert not chapter6.is_chapter6([f for f in robust if f != "e_q_2"])
    assert not chapter6.is_chapter6(["lambda", "lambda_err", "x_o", "tau_1", "tau_2"])


def test_thesis_case_and_figure_names(tmp_path):
    run = synthetic()
    assert chapter6.thesis_case(run) is None                       # K_s unknown
    run.joint_stiffness = 10.0
    assert chapter6.thesis_case(run) == "case 1"
    run.joint_stiffness = None
    run.label = "robust K_s = 50"
    assert chapter6.thesis_case(run) == "case 2"
    names = {p.name for p in chapter6.plot_chapter6(run, tmp_path / "r")}
    assert names == {"fig6_7_positions.png", "fig6_8_force.png", "fig6_9_torques.png",
                     "fig6_10_p_hat.png", "fig6_11_ks_inv_hat.png", "ch6_qddot_m_filter.png"}
    sp = synthetic(chapter6.SP)
    assert chapter6.thesis_case(sp) == "sp"                        # τ_s non-zero
    sp.extras["tau_s_1"] = sp.extras["tau_s_2"] = np.zeros(len(sp.time))
    assert chapter6.thesis_case(sp) == "sp without tau_s"
    sp.slow_control = True
    assert chapter6.thesis_case(sp) == "sp"
    sp.joint_stiffness = 100.0
    assert chapter6.thesis_case(sp) is None
    written = chapter6.plot_chapter6(sp, tmp_path / "s", case="sp without tau_s")
    assert {p.name for p in written} == {"fig6_16_positions.png", "fig6_17_force.png",
                                         "fig6_18_torques.png", "ch6_estimates.png"}
    for path in written:
        assert_png(path)


def test_diverged_run_is_reported_drawn_and_tabled(tmp_path):
    good = synthetic(label="good")
    bad = synthetic(label="K_s = 100")
    k = 2500                                                      # t = 2.5 s
    bad.e_q[k:, 1] = np.linspace(0.0, 50.0, len(bad.time) - k)     # grows past 1 rad
    j = 4000                                                      # then NaN, and held
    bad.e_q[j:] = np.nan
    bad.lam[j:] = np.inf
    bad.tau[j:] = np.nan
    bad.extras["p_hat_3"][j:] = np.nan
    assert chapter6.divergence(good) is None
    div = chapter6.divergence(bad)
    first = bad.time[k + np.argmax(np.hypot(bad.e_q[k:j, 0], bad.e_q[k:j, 1]) > 1.0)]
    assert div.time == pytest.approx(first) and "e_q" in div.reason
    assert 2.5 < div.time < 4.0

    nan_only = synthetic(label="nan")
    nan_only.lam[3000:] = np.nan
    assert chapter6.divergence(nan_only).time == pytest.approx(3.0)
    assert chapter6.divergence(nan_only).reason == "non-finite values"
    held = synthetic(label="held")
    held.held[1234:] = True
    assert chapter6.divergence(held).time == pytest.approx(1.234)

    m = chapter6.window_metrics(bad, 5.0, 6.0)                     # all NaN: no crash
    assert math.isnan(m["e_q_rms_rad"]) and math.isnan(m["p_hat_norm_end"])
    written = chapter6.plot_chapter6(bad, tmp_path / "bad")
    written += chapter6.compare_chapter6([good, bad, held], tmp_path)
    for path in written[:-1]:
        assert_png(path)
    assert (tmp_path / "ch6_robust_ks.png").exists()
    table = written[-1].read_text()
    assert f"diverged at t = {div.time:.3f} s" in table
    assert "| K_s = 100 | 5–6 | n/a | n/a |" in table


# -- offline runs of the schemes ---------------------------------------------------------
def _require(scheme: str) -> None:
    from cr_control.schemes.registry import controller_class

    try:
        controller_class(scheme)
    except ValueError:
        pytest.skip(f"scheme {scheme} is not registered (cr_control.schemes.registry)")


@pytest.fixture(scope="module")
def robust_run():
    _require(chapter6.ROBUST_SCHEME)
    from cr_control.offline import run_scheme

    plant = {"joint_stiffness": [10.0, 10.0], "motor_inertia": [0.5, 0.5]}
    return run_scheme(chapter6.ROBUST_SCHEME, 1.5, plant_overrides=plant), plant


@pytest.fixture(scope="module")
def sp_runs():
    _require(chapter6.SP_SCHEME)
    from cr_control.offline import run_scheme

    plant = {"joint_stiffness": [300.0, 300.0], "motor_inertia": [1.0, 1.0]}
    return (run_scheme(chapter6.SP_SCHEME, 1.5, plant_overrides=plant),
            run_scheme(chapter6.SP_SCHEME, 1.5, {"slow_control": False}, plant), plant)


def as_session(run, controller: str, name: str, parameters=None) -> analyze.Session:
    """A loaded-session stand-in holding an offline run's status and reference columns."""
    status = {"stamp": run.time, **{n: run.column(n) for n in run.status_fields[1:]}}
    reference = {"stamp": run.time, **{n: run.column(n) for n in run.reference_fields[1:]}}
    return analyze.Session(Path(f"{name}.mcap"), controller=controller, status=status,
                           reference=reference, parameters=parameters or {})


def test_robust_scheme_figures(robust_run, tmp_path):
    result, plant = robust_run
    assert chapter6.is_chapter6(result.status_fields)
    run = chapter6.from_offline(result, "robust", plant)
    assert run.kind == chapter6.ROBUST and chapter6.thesis_case(run) == "case 1"
    np.testing.assert_allclose(run.q_ld[:, 0], result.column("q_ld_1"))
    np.testing.assert_allclose(run.lam_d, 2.0, atol=1e-12)
    assert run.p_hat().shape == (len(run.time), 10)
    written = chapter6.plot_chapter6(run, tmp_path)
    assert {p.name for p in written} == {
        "fig6_2_positions.png", "fig6_3_force.png", "fig6_4_torques.png", "fig6_5_p_hat.png",
        "fig6_6_ks_inv_hat.png", "ch6_qddot_m_filter.png"}
    for path in written:
        assert_png(path)


def test_sp_scheme_figures_and_comparison(sp_runs, tmp_path):
    with_slow, without, plant = sp_runs
    a = chapter6.from_offline(with_slow, "SP with τ_s", plant, {"slow_control": True})
    b = chapter6.from_offline(without, "SP without τ_s", plant, {"slow_control": False})
    assert a.kind == b.kind == chapter6.SP
    assert chapter6.thesis_case(a) == "sp" and chapter6.thesis_case(b) == "sp without tau_s"
    names = {p.name for p in chapter6.plot_chapter6(a, tmp_path / "a")}
    assert names == {"fig6_12_positions.png", "fig6_13_force.png", "fig6_14_torques.png",
                     "fig6_15_estimates.png"}
    written = chapter6.plot_chapter6(b, tmp_path / "b")
    assert {"fig6_16_positions.png", "fig6_17_force.png", "fig6_18_torques.png"} <= {
        p.name for p in written}
    written += chapter6.compare_chapter6([a, b], tmp_path)
    assert [p.name for p in written[-2:]] == ["ch6_sp_slow_control.png", "ch6_comparison.md"]
    for path in written[:-1]:
        assert_png(path)
    rows = [line for line in written[-1].read_text().splitlines() if line.startswith("| SP")]
    assert len(rows) == 4                                      # windows 0–1, 1–1.5 per run


def test_cr_analyze_draws_the_chapter6_figures(robust_run, sp_runs, tmp_path):
    result, plant = robust_run
    robust = as_session(result, chapter6.ROBUST_SCHEME, "robust", {"plant": plant})
    sp = as_session(sp_runs[0], chapter6.SP_SCHEME, "sp",
                    {"plant": sp_runs[2], chapter6.SP_SCHEME: {"slow_control": True}})
    run = chapter6.from_session(robust)
    assert run.joint_stiffness == 10.0 and chapter6.thesis_case(run) == "case 1"
    np.testing.assert_allclose(run.q_l[:, 1], result.column("q_ld_2") - result.column("e_q_2"))
    names = {p.name for p in chapter6.session_figures(robust, tmp_path / "r")}
    assert {"fig6_2_positions.png", "fig6_6_ks_inv_hat.png"} <= names
    names = {p.name for p in chapter6.session_figures(sp, tmp_path / "s")}
    assert "fig6_15_estimates.png" in names
    written = chapter6.compare_sessions([robust, sp], ["robust", "sp"], tmp_path / "cmp")
    md = written[-1].read_text()
    assert written[-1].name == "ch6_comparison.md" and "| robust |" in md and "| sp |" in md
    assert chapter6.compare_sessions([robust], ["robust"], tmp_path / "one") == []


def test_cli_refuses_bad_arguments(capsys, tmp_path):
    assert chapter6.main([]) == 2
    assert chapter6.main([str(tmp_path), "abc"]) == 2
    assert chapter6.main([str(tmp_path), "-3"]) == 2
    assert chapter6.main([str(tmp_path), "1", "2"]) == 2
    (tmp_path / "file").write_text("x")
    assert chapter6.main([str(tmp_path / "file")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 5 and all(line.startswith("chapter6: error: ") for line in err)


def test_cli_writes_runs_overlays_and_table(monkeypatch, capsys, tmp_path):
    _require(chapter6.ROBUST_SCHEME)
    _require(chapter6.SP_SCHEME)
    cases = [c for c in chapter6.CASES if c[0] in ("robust_ks10", "robust_ks50", "sp_no_slow")]
    monkeypatch.setattr(chapter6, "CASES", cases)
    assert chapter6.main([str(tmp_path), "0.3"]) == 0
    out = capsys.readouterr().out
    assert out.count("done in ") == 3 and "no divergence" in out and "runs in" in out
    assert (tmp_path / "robust_ks10" / "fig6_2_positions.png").exists()
    assert (tmp_path / "robust_ks50" / "fig6_11_ks_inv_hat.png").exists()
    assert (tmp_path / "sp_no_slow" / "fig6_18_torques.png").exists()
    assert_png(tmp_path / "ch6_robust_ks.png")
    assert not (tmp_path / "ch6_sp_slow_control.png").exists()      # one SP run only
    md = (tmp_path / "ch6_comparison.md").read_text()
    assert "| robust K_s = 50 (case 2) | 0–0.3 |" in md and md in out
