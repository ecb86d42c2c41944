"""Analysis of a robot session (cr_control.analysis.robot): a Panda wiping a table with the
impedance scheme, recorded in lockstep over ROS for 1.5 s; its metrics against the same
quantities computed directly from the offline loop's columns (lockstep reproduces it bit
for bit), its figures, and cr_analyze on it, alone and beside a thesis session. The robot
scenario's sensor is a wrist sensor: the normal-force metrics judge the plant's
true contact force (/plant/contact_wrench, the offline loop's ``true_force``), the 2-D
force metrics what the law was given (the compensated force of the status). The sensor runs
without noise here: with it the laws' torque steps exceed the plant node's torque-rate
limit, which the offline loop does not have (test_robots.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from ros_probe import next_domain
from test_analysis import png_ok, write_session

from cr_control import robots
from cr_control.analysis import analyze, robot
from cr_control.offline import run_scheme

SCHEME, ROBOT, DURATION = "impedance", "panda_ft", 1.5
ROBOT_METRICS = ("normal_force_mean_last_half_N", "normal_force_err_rms_last_half_N",
                 "path_err_rms_last_half_m", "path_err_max_last_half_m", "contact_lost_s",
                 "orientation_err_max_deg", "posture_err_max_rad", "singularity_damping_max")
ROBOT_FIGURES = {"path_3d.png", "path_top.png", "normal_force.png", "orientation.png"}


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    from cr_control.tools.session import Session, SessionConfig

    cfg = SessionConfig(scheme=SCHEME, duration=DURATION, mode="lockstep",
                        out=tmp_path_factory.mktemp("robot"), domain_id=next_domain(),
                        name="run", robot=ROBOT, overrides=[
                            "plant.ft_noise_std=[0.0, 0.0]"])
    return Session(cfg, progress=lambda _: None).run().mcap


@pytest.fixture(scope="module")
def session(recording) -> analyze.Session:
    return analyze.load_session(recording)


def expected_metrics(rows: np.ndarray) -> dict[str, float]:
    """The metrics' definitions, computed from the offline run's columns at ``rows``."""
    run = run_scheme(SCHEME, DURATION, robot=ROBOT, plant_overrides={"ft_noise_std": [0.0, 0.0]})
    col = lambda name: run.column(name)[rows]  # noqa: E731
    t = run.time[rows]
    last = t >= t[0] + 0.5 * (t[-1] - t[0])
    rms = lambda x: math.sqrt(np.mean(np.square(x)))  # noqa: E731
    f_z = run.true_force[rows, 2]          # the true contact force
    f_law = col("f_z")                          # the compensated sensor force
    path = np.hypot(col("e_x"), col("e_y"))
    e = np.sqrt(col("e_x") ** 2 + col("e_y") ** 2 + col("e_z") ** 2)
    rot = np.sqrt(sum(col(f"e_rot_{a}") ** 2 for a in "xyz"))
    out = {"normal_force_mean_last_half_N": np.mean(f_z[last]),
           "normal_force_err_rms_last_half_N": rms(f_z[last] - col("f_d_z")[last]),
           "path_err_rms_last_half_m": rms(path[last]), "path_err_max_last_half_m": path[last].max(),
           "contact_lost_s": 1e-3 * np.count_nonzero((f_z <= 0.0) & (t >= t[0] + 0.05)),
           "orientation_err_max_deg": math.degrees(rot.max()),
           "posture_err_max_rad": col("posture_error").max(),
           "singularity_damping_max": col("singularity_damping").max(),
           "pos_err_rms_m": rms(e), "pos_err_max_m": e.max(), "pos_err_rms_last_half_m": rms(e[last]),
           "f_z_min_N": f_law.min(), "f_z_max_N": f_law.max()}
    for a in "xyz":
        err = col(f"f_err_{a}")
        out |= {f"f_err_{a}_rms_N": rms(err), f"f_err_{a}_max_N": err.max(),
                f"f_err_{a}_min_N": err.min()}
    return out


@pytest.mark.ros
def test_metrics_match_the_offline_run(session):
    rows = np.rint(session.status["stamp"] * 1e3).astype(int)
    assert len(rows) > 0.9 * DURATION * 1000 and robot.is_robot(session.status)
    m = analyze.metrics(session)
    for name, value in expected_metrics(rows).items():
        assert m[name] == pytest.approx(value, rel=1e-6, abs=1e-9), name
    # the task as the robots module sets it: 10 N along +z, reached at the end of the ramp
    # (the true force; the law's reading has the sensor's 0.2 N noise)
    assert m["force_source"] == "contact_wrench"
    assert 9.5 < session.contact_wrench.force[-1, 2] < robots.WIPE_FORCE
    assert m["path_err_rms_last_half_m"] < 1e-3 and m["orientation_err_max_deg"] < 1.0
    assert m["contact_lost_s"] == 0.0 and m["singularity_damping_max"] == 0.0
    # the 2-D metrics still there, the joints by name
    assert "tau_peak_panda_joint7_Nm" in m and "f_err_x_rms_N" in m


def synthetic(n_axis: np.ndarray, lost: tuple[float, float], wrench: bool) -> analyze.Session:
    """A robot status at 500 Hz on a plane of normal ``n_axis`` (in n_*): 8 N along the
    normal, off over ``lost`` (also in a 1 kHz wrench topic if ``wrench``); the error 1 mm
    along the normal plus 3 mm, 4 mm in the plane; the desired force 10 N at 250 Hz."""
    k = np.arange(1000)
    t = 100.0 + 0.002 * k
    n = n_axis / np.linalg.norm(n_axis)
    a, b = robot.plane_basis(n)
    force = np.where((k >= round(lost[0] / 0.002)) & (k < round(lost[1] / 0.002)), -0.5, 8.0)
    e = 1e-3 * (n + 3.0 * a + 4.0 * b)
    status = {"stamp": t, "e_rot_x": 0.01 * np.cos(2 * np.pi * k / 1000), "e_rot_y": np.full_like(t, 0.02),
              "singularity_damping": np.zeros_like(t)}
    for i, axis in enumerate("xyz"):
        status |= {f"r_{axis}": 0.1 * t, f"e_{axis}": np.full_like(t, e[i]),
                   f"f_{axis}": force * n[i], f"n_{axis}": np.full_like(t, 2.0 * n[i])}
    reference = {"stamp": t[::2], **{f"f_d_{ax}": np.full(len(t[::2]), 10.0 * n[i])
                                     for i, ax in enumerate("xyz")}}
    s = analyze.Session(Path("synthetic.mcap"), "synth", status, reference)
    if wrench:
        t_w = 100.0 + 0.001 * np.arange(2000)
        f_w = np.where((t_w >= t[round(lost[0] / 0.002)]) & (t_w < t[round(lost[1] / 0.002)]),
                       -0.5, 8.0)
        s.wrench = analyze.WrenchSeries(t_w, f_w[:, None] * n, np.zeros((len(t_w), 3)))
    return s


@pytest.mark.parametrize("wrench", [False, True], ids=["status", "wrench"])
@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (0.0, 0.6, 0.8)], ids=["flat", "tilted"])
def test_metric_definitions_on_a_tilted_table(normal, wrench):
    s = synthetic(np.array(normal), lost=(0.5, 0.7), wrench=wrench)
    m = robot.robot_metrics(s)
    assert m["normal_force_mean_last_half_N"] == pytest.approx(8.0)
    assert m["normal_force_err_rms_last_half_N"] == pytest.approx(2.0)
    assert m["path_err_rms_last_half_m"] == pytest.approx(5e-3)   # 1 mm along n left out
    assert m["contact_lost_s"] == pytest.approx(0.2)
    assert m["orientation_err_max_deg"] == pytest.approx(math.degrees(math.hypot(0.01, 0.02)))
    assert "posture_err_max_rad" not in m and m["singularity_damping_max"] == 0.0
    assert analyze.metrics(s)["pos_err_max_m"] == pytest.approx(math.sqrt(26) * 1e-3)


def test_contact_lost_intervals():
    t = np.arange(10) * 0.01
    f = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, -1.0, -1.0, 0.0])
    # before 50 ms not judged; each sample holds until the next, the last for one period
    np.testing.assert_allclose(robot.contact_lost_intervals(t, f), [(0.05, 0.06), (0.07, 0.10)])
    assert robot.contact_lost_intervals(t, f + 2.0) == []
    assert robot.contact_lost_intervals(t[:0], f[:0]) == []


@pytest.mark.ros
def test_plots_of_a_robot_session(session, tmp_path):
    written = analyze.plot_session(session, tmp_path)
    names = {p.name for p in written}
    assert ROBOT_FIGURES | {"position.png", "errors.png", "force.png", "torques.png"} <= names
    for path in written:
        assert png_ok(path) and path.stat().st_size > 20_000, path.name


@pytest.mark.ros
def test_cr_analyze_prints_the_robot_metrics(recording, session, capsys):
    assert analyze.main([str(recording), "--no-plots"]) == 0
    text = capsys.readouterr().out
    for name in (*ROBOT_METRICS, "f_err_z_rms_N", "f_z_max_N", "pos_err_rms_m"):
        assert f"\n{name} " in text, name
    assert analyze.main([str(recording), "--no-plots", "--json"]) == 0
    values = json.loads(capsys.readouterr().out)[SCHEME]
    expected = analyze.metrics(session)
    assert values.keys() == expected.keys()
    for name in ROBOT_METRICS:
        assert values[name] == pytest.approx(expected[name], rel=1e-12), name


@pytest.mark.ros
def test_cr_analyze_side_by_side_with_a_thesis_session(recording, tmp_path, capsys):
    thesis = tmp_path / "thesis.mcap"
    write_session(thesis)
    out = tmp_path / "cmp"
    assert analyze.main([str(recording), str(thesis), "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    row = {line.split()[0]: line.split()[1:] for line in lines[2:] if line.strip()}
    assert row["controller"] == [SCHEME, "synth_ctrl"]
    for name in ROBOT_METRICS:
        assert row[name][1] == "-" and row[name][0] != "-", name   # robot metrics: robot only
    assert row["f_err_x_rms_N"][1] != "-" and row["f_err_z_rms_N"][1] == "-"
    for name in ("compare_robot.png", "compare_position.png", "compare_force.png"):
        assert png_ok(out / name), name
    assert all(png_ok(out / SCHEME / name) for name in ROBOT_FIGURES)
    assert not any((out / "synth_ctrl" / name).exists() for name in ROBOT_FIGURES)
    assert png_ok(out / "synth_ctrl" / "position.png")
