"""Chapter 2 and chapter 4 / appendix C analysis (cr_control.analysis.chapter2, .chapter4):
figures written as PNG, tables with the right rows, metrics on synthetic data, and the
cr_analyze hooks on sessions built from short offline runs."""

from pathlib import Path

import numpy as np
import pytest

from cr_control.analysis import analyze, chapter2, chapter4
from cr_control.offline import run_scheme

PNG = b"\x89PNG\r\n\x1a\n"


def assert_png(path: Path) -> None:
    assert path.exists() and path.read_bytes()[:8] == PNG, path


def as_session(run, controller: str, name: str, parameters=None) -> analyze.Session:
    """A loaded-session stand-in holding an offline run's status and reference columns."""
    status = {"stamp": run.time, **{n: run.column(n) for n in run.status_fields[1:]}}
    reference = {"stamp": run.time, **{n: run.column(n) for n in run.reference_fields[1:]}}
    return analyze.Session(Path(f"{name}.mcap"), controller=controller, status=status,
                           reference=reference, parameters=parameters or {})


@pytest.fixture(scope="module")
def ch2_runs():
    return {s: run_scheme(s, 0.6) for s in chapter2.SCHEMES}


@pytest.fixture(scope="module")
def ch4_runs():
    return {"backstepping_force": run_scheme("backstepping_force", 1.0),
            "mrac_force": run_scheme("mrac_force", 1.0),
            "chain1": run_scheme("cmmsd_backstepping", 1.0, {"joint_names": ["q1"]},
                                 {"masses": 1}),
            "chain2": run_scheme("cmmsd_backstepping", 1.0)}


# -- chapter 2 ---------------------------------------------------------------------------
def test_chapter2_figures_and_table(ch2_runs, tmp_path):
    runs = [chapter2.from_offline(ch2_runs[s], chapter2.SHORT[s]) for s in chapter2.SCHEMES]
    adaptive, network = runs
    assert adaptive.estimates and not adaptive.norms and adaptive.true_p is not None
    assert network.norms and not network.estimates
    # the desired values are rebuilt from the errors
    np.testing.assert_allclose(adaptive.x_o_d, ch2_runs["moving_object_adaptive"].column("x_o_d"),
                               atol=1e-12)
    np.testing.assert_allclose(adaptive.lam_d, 2.0, atol=1e-12)

    names = {p.name for p in chapter2.plot_chapter2(adaptive, tmp_path / "a")}
    assert names == {"ch2_position.png", "ch2_force.png", "ch2_torques.png", "ch2_estimates.png"}
    written = chapter2.plot_chapter2(network, tmp_path / "n")
    assert {p.name for p in written} == {"ch2_position.png", "ch2_force.png", "ch2_torques.png",
                                         "ch2_network.png"}
    for path in written:
        assert_png(path)

    spans = [(0.0, 0.2), (0.2, 0.6), (0.6, 1.0)]       # the last lies past the run's end
    png, md = chapter2.compare_chapter2(runs, tmp_path, spans)
    assert_png(png)
    text = md.read_text()
    rows = [line for line in text.splitlines() if line.startswith("| ") and "---" not in line]
    assert len(rows) == 1 + 2 * 2                       # header + 2 windows x 2 schemes
    assert sum(line.startswith(f"| {network.label} | 0.2–0.6") for line in rows) == 1
    assert "λ < 0 in" in text and "‖P̂ − P‖" in text and "G1" in text


def test_chapter2_windows_and_metrics_on_synthetic_data():
    t = np.arange(0.0, 2.0, 1e-3)
    zero = np.zeros_like(t)
    lam = 2.0 + np.where(t < 0.5, -3.0, 0.1)           # negative for the first 0.5 s
    run = chapter2.ObjectRun("synthetic", t, zero, zero + 0.001, zero, zero,
                             np.column_stack([zero + 0.003, zero + 0.004]), lam, zero + 2.0,
                             np.column_stack([zero + 1.0, zero - 2.0, zero + 0.5]))
    assert chapter2.windows(run, [(0, 1), (1, 5), (5, 10)]) == [(0, 1), (1, pytest.approx(2.0))]
    m = chapter2.object_metrics(run, 1.0, 2.0)
    assert m["e1_rms_rad"] == pytest.approx(0.005)
    assert m["x_o_err_max_m"] == pytest.approx(0.001)
    assert m["lambda_err_rms_N"] == pytest.approx(0.1)
    assert m["tau1_peak_Nm"] == 2.0 and m["tau2_peak_N"] == 0.5
    s = chapter2.run_summary(run)
    assert len(s["lambda_negative"]) == 1
    assert s["lambda_negative"][0][0] == 0.0 and s["lambda_negative"][0][1] == pytest.approx(0.499)
    assert chapter2.running_rms(t, zero + 3.0) == pytest.approx(3.0)


# -- chapter 4 ---------------------------------------------------------------------------
def test_chapter4_force_figures_and_table(ch4_runs, tmp_path):
    bs = chapter4.force_from_offline(ch4_runs["backstepping_force"], "case 1")
    mrac = chapter4.force_from_offline(ch4_runs["mrac_force"], "case 5")
    assert bs.scheme == "backstepping_force" and mrac.scheme == "mrac_force"
    assert bs.true["b3_hat"] == pytest.approx(20.0) and bs.true["a3_hat"] == pytest.approx(2.4005)
    assert mrac.true["r3p_hat"] == pytest.approx(-9.325, abs=1e-3)
    assert mrac.f_m is not None and np.all(bs.f_d == 1.0)
    for run, folder in ((bs, "bs"), (mrac, "mrac")):
        written = chapter4.plot_force_run(run, tmp_path / folder)
        assert {p.name for p in written} == {"ch4_force.png", "ch4_command.png",
                                             "ch4_estimates.png"}
        for path in written:
            assert_png(path)
    png, md = chapter4.compare_force([bs, mrac], tmp_path, "cmp", "test")
    assert_png(png)
    rows = [line for line in md.read_text().splitlines() if line.startswith("| case")]
    assert [r.split(" | ")[0] for r in rows] == ["| case 1", "| case 5"]


def test_chapter4_diverged_run_is_drawn_and_flagged(ch4_runs, tmp_path):
    good = chapter4.force_from_offline(ch4_runs["backstepping_force"], "good")
    bad = chapter4.force_from_offline(ch4_runs["backstepping_force"], "diverged")
    k = len(bad.time) // 2
    bad.f = bad.f.copy()
    bad.f[k:] = 5e3
    bad.held = bad.held.copy()
    bad.held[k:] = True
    m = chapter4.force_metrics(bad)
    assert m["held_from_s"] == pytest.approx(bad.time[k]) and np.isnan(m["settling_s"])
    assert np.isnan(chapter4.force_metrics(good)["held_from_s"])
    png, md = chapter4.compare_force([good, bad], tmp_path)
    assert_png(png)
    lines = md.read_text().splitlines()
    assert any(line.startswith("| good |") and line.endswith("| – |") for line in lines)
    assert any(line.startswith("| diverged |") and "n/a" in line for line in lines)


def test_force_metrics_on_synthetic_data():
    t = np.arange(0.0, 40.0, 1e-3)
    f = 1.0 + 0.5 * np.exp(-t)                          # 1.5 N -> 1 N, no overshoot
    run = chapter4.ForceRun("x", "backstepping_force", t, f, np.ones_like(t), f * 0.2,
                            0.2 + 1e-3 * np.sin(2 * np.pi * 20 * t), np.zeros(len(t), bool))
    m = chapter4.force_metrics(run)
    assert m["settling_s"] == pytest.approx(np.log(25.0), abs=2e-3)   # 0.5 e^-t = 0.02
    assert abs(m["ss_error_N"]) < 1e-9 and m["p2p_tail_N"] < 1e-9
    assert m["chatter_m"] == pytest.approx(1e-3 / np.sqrt(2), rel=1e-2)
    assert m["no_contact_s"] == 0.0


def test_appendix_c_chain_figure_and_table(ch4_runs, tmp_path):
    chains = [chapter4.chain_from_offline(ch4_runs["chain1"], "n = 1", {"masses": 1}),
              chapter4.chain_from_offline(ch4_runs["chain2"], "n = 2", {"masses": 2})]
    assert [c.n for c in chains] == [1, 2] and chains[1].q.shape[1] == 2
    assert chains[0].true_d is not None and chains[0].true_theta_norm is not None
    png, md = chapter4.plot_chains(chains, tmp_path)
    assert_png(png)
    rows = [line for line in md.read_text().splitlines() if line.startswith("| n = ")]
    assert len(rows) == 2


# -- cr_analyze hooks --------------------------------------------------------------------
def test_cr_analyze_draws_the_chapter_figures(ch2_runs, ch4_runs, tmp_path):
    ch2 = [as_session(ch2_runs[s], s, s) for s in chapter2.SCHEMES]
    bs = as_session(ch4_runs["backstepping_force"], "backstepping_force", "bs",
                    {"plant": {"scenario": "dynamic_constraint", "k_o": 50.0, "k_s": 50.0}})
    mrac = as_session(ch4_runs["mrac_force"], "mrac_force", "mrac")
    chain = as_session(ch4_runs["chain2"], "cmmsd_backstepping", "chain")
    assert chapter2.is_chapter2(ch2[0].status) and not chapter4.is_force_run(ch2[0].status)
    assert chapter4.is_force_run(bs.status) and chapter4.is_chain_run(chain.status)
    assert not chapter4.is_chain_run(bs.status) and not chapter2.is_chapter2(bs.status)
    assert chapter4.force_from_session(bs).true["b3_hat"] == pytest.approx(50.0)   # case 2

    names = {p.name for p in analyze.plot_session(ch2[1], tmp_path / "nn")}
    assert {"ch2_position.png", "ch2_network.png"} <= names
    names = {p.name for p in analyze.plot_session(bs, tmp_path / "bs")}
    assert {"ch4_force.png", "ch4_command.png", "ch4_estimates.png"} <= names
    assert "appC_chain.png" in {p.name for p in analyze.plot_session(chain, tmp_path / "c")}

    written = analyze.compare([*ch2, bs, mrac], tmp_path / "cmp")
    names = {p.name for p in written}
    assert {"ch2_comparison.png", "ch2_comparison.md", "ch4_comparison.png",
            "ch4_comparison.md"} <= names
    md = (tmp_path / "cmp" / "ch4_comparison.md").read_text()
    assert "| backstepping_force |" in md and "| mrac_force |" in md
    for path in written:
        if path.suffix == ".png":
            assert_png(path)
