"""Analysis of recorded sessions on synthetic MCAP files with known errors."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control.analysis import analyze as analysis
from cr_control.core import topics
from cr_control.recording.recorder import McapBagWriter

REPO = Path(__file__).resolve().parents[1]
DT = 0.01
DURATION = 10.0
T_START = 100.0  # stamps start here; figures and metrics use time from the first sample
EXTRA_STATUS = ["A_hat_11", "A_hat_22", "B_hat_11", "c_hat_x", "s_x", "s_y",
                "M_r_norm", "M_r_hat_norm", "C_r_norm", "C_r_hat_norm", "G_r_norm",
                "G_r_hat_norm"]
STATUS_FIELDS = topics.STATUS_FIELDS + EXTRA_STATUS
JOINTS = ["joint1", "joint2"]
TIMING = {"rate_hz": 998.0, "total_cycles": 10_000.0, "total_fresh_share": 0.97,
          "total_missed_cycles": 3.0, "total_age_p50_ms": 0.4, "total_age_p99_ms": 1.2,
          "total_age_max_ms": 2.5}


def signals(scale: float = 1.0) -> dict[str, np.ndarray]:
    """The synthetic run: ||e|| = 0.01 exp(-t) (scaled), known force errors and torques."""
    t = np.arange(0.0, DURATION + DT / 2, DT)
    e = scale * 0.01 * np.exp(-t)
    theta = 0.6
    s = {"t": t, "e_x": e * np.cos(theta), "e_y": e * np.sin(theta),
         "r_d_x": -0.05 + 0.01 * t, "r_d_y": 0.3 + 0.0 * t,
         "f_err_x": 0.5 * np.sin(t), "f_err_y": -0.2 + 0.1 * np.cos(t),
         "f_d_x": 2.0 + 0.0 * t, "f_d_y": -2.0 + 0.0 * t,
         "tau_1": 2.0 * np.sin(t), "tau_2": -3.0 * np.cos(t),
         "compute_time_us": 50.0 + np.arange(len(t)) % 100}
    s["r_x"], s["r_y"] = s["r_d_x"] + s["e_x"], s["r_d_y"] + s["e_y"]
    s["f_x"], s["f_y"] = s["f_d_x"] + s["f_err_x"], s["f_d_y"] + s["f_err_y"]
    return s


def labelled(fields: list[str], values: list[float]) -> bytes:
    msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension, fields)
    msg.data = [float(v) for v in values]
    return serialize_message(msg)


def stamped(msg, t: float):
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))
    return msg


def write_session(path: Path, controller: str = "synth_ctrl", scale: float = 1.0,
                  chunk_size: int = 1 << 20) -> dict[str, np.ndarray]:
    """A recording as the recorder writes it; returns the signals it holds."""
    s = signals(scale)
    writer = McapBagWriter(path, chunk_size=chunk_size)
    status = writer.add_topic(topics.status_topic(controller), "std_msgs/msg/Float64MultiArray")
    reference = writer.add_topic(topics.reference_topic(controller),
                                 "std_msgs/msg/Float64MultiArray")
    timing = writer.add_topic(topics.PLANT_TIMING, "std_msgs/msg/Float64MultiArray")
    commands = writer.add_topic(topics.JOINT_COMMANDS, "sensor_msgs/msg/JointState",
                                has_header=True)
    states = writer.add_topic(topics.JOINT_STATES, "sensor_msgs/msg/JointState",
                              has_header=True)
    wrench = writer.add_topic(topics.WRENCH, "geometry_msgs/msg/WrenchStamped", has_header=True)
    log = 1_700_000_000_000_000_000
    for i, t in enumerate(s["t"]):
        stamp = T_START + t
        log_ns = log + int(t * 1e9)
        extra = [1.0 + t, 2.0, 3.0 - t, 0.1 * t, s["e_x"][i] * 10, s["e_y"][i] * 10,
                 1.0, 1.1 - 0.1 * math.exp(-t), 2.0, 2.0, 3.0, 2.9]
        values = {name: s[name][i] for name in s if name != "t"}
        row = [stamp] + [values.get(name, 0.0) for name in topics.STATUS_FIELDS[1:]] + extra
        writer.write(status, labelled(STATUS_FIELDS, row), log_ns)
        writer.write(reference, labelled(topics.REFERENCE_FIELDS, [stamp] + [
            values.get(name, 0.0) for name in topics.REFERENCE_FIELDS[1:]]), log_ns)
        command = stamped(JointState(name=JOINTS, effort=[s["tau_1"][i], s["tau_2"][i]]), stamp)
        writer.write(commands, serialize_message(command), log_ns)
        state = stamped(JointState(name=JOINTS, position=[0.1 * t, -0.2 * t],
                                   velocity=[0.1, -0.2], effort=[s["tau_1"][i], 0.0]), stamp)
        writer.write(states, serialize_message(state), log_ns)
        measured = stamped(WrenchStamped(), stamp)
        measured.wrench.force.x, measured.wrench.force.y = s["f_x"][i], s["f_y"][i]
        writer.write(wrench, serialize_message(measured), log_ns)
        if i % 100 == 99:  # per-second plant timing; the last one carries TIMING
            last = i + 100 >= len(s["t"])
            fields = dict.fromkeys(topics.PLANT_TIMING_FIELDS, 0.0)
            fields.update(TIMING if last else {"rate_hz": 1000.0})
            fields["stamp"] = stamp
            writer.write(timing, labelled(topics.PLANT_TIMING_FIELDS, list(fields.values())),
                         log_ns)
    writer.add_metadata("parameters/synth_ctrl", {"K_e": "150.0", "gains": "[1.0, 2.0]"})
    writer.close()
    return s


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, dict[str, np.ndarray]]:
    path = tmp_path_factory.mktemp("sessions") / "synth.mcap"
    return path, write_session(path)


def test_load_session_reads_every_part(recorded):
    path, s = recorded
    session = analysis.load_session(path)
    assert session.controller == "synth_ctrl" and session.name == "synth_ctrl"
    assert not session.warnings
    np.testing.assert_allclose(session.status["stamp"], T_START + s["t"])
    np.testing.assert_allclose(session.status["e_x"], s["e_x"])
    np.testing.assert_allclose(session.reference["r_d_x"], s["r_d_x"])
    assert session.t0 == pytest.approx(T_START)
    assert session.timing["rate_hz"][-1] == TIMING["rate_hz"]
    assert session.joint_commands.names == JOINTS
    np.testing.assert_allclose(session.joint_commands.effort[:, 1], s["tau_2"])
    assert np.isnan(session.joint_commands.position).all()
    np.testing.assert_allclose(session.joint_states.position[:, 0], 0.1 * s["t"], atol=1e-12)
    np.testing.assert_allclose(session.wrench.force[:, 0], s["f_x"])
    np.testing.assert_allclose(session.wrench.time, T_START + s["t"], atol=1e-6)
    assert session.parameters == {"synth_ctrl": {"K_e": 150.0, "gains": [1.0, 2.0]}}


def test_metrics_match_numpy_and_analytic_values(recorded):
    path, s = recorded
    m = analysis.metrics(analysis.load_session(path))
    t, e = s["t"], np.hypot(s["e_x"], s["e_y"])
    last = t >= DURATION / 2
    assert m["controller"] == "synth_ctrl"
    assert m["duration_s"] == pytest.approx(DURATION)
    assert m["pos_err_rms_m"] == pytest.approx(np.sqrt(np.mean(e**2)))
    assert m["pos_err_max_m"] == pytest.approx(0.01)
    assert m["pos_err_rms_last_half_m"] == pytest.approx(np.sqrt(np.mean(e[last] ** 2)))
    # Analytic: sqrt(mean of (0.01 e^-t)^2 over [5, 10]); sampling changes it by < 3 %.
    analytic = 0.01 * math.sqrt((math.exp(-10) - math.exp(-20)) / (2 * 5))
    assert m["pos_err_rms_last_half_m"] == pytest.approx(analytic, rel=0.03)
    assert m["pos_err_max_last_half_m"] == pytest.approx(0.01 * math.exp(-5))
    # ||e|| falls below the 1 mm band at t = ln 10.
    assert m["settling_time_s"] == pytest.approx(math.log(10), abs=DT)
    for axis in ("x", "y"):
        err = s[f"f_err_{axis}"]
        assert m[f"f_err_{axis}_rms_N"] == pytest.approx(np.sqrt(np.mean(err**2)))
        assert m[f"f_err_{axis}_max_N"] == pytest.approx(err.max())
        assert m[f"f_err_{axis}_min_N"] == pytest.approx(err.min())
        assert m[f"f_{axis}_max_N"] == pytest.approx(s[f"f_{axis}"].max())
    assert m["tau_peak_joint1_Nm"] == pytest.approx(np.abs(s["tau_1"]).max())
    assert m["tau_peak_joint2_Nm"] == pytest.approx(3.0)
    p50, p99 = np.percentile(s["compute_time_us"], [50, 99])
    assert (m["compute_time_p50_us"], m["compute_time_p99_us"], m["compute_time_max_us"]) == (
        pytest.approx(p50), pytest.approx(p99), 149.0)
    assert m["loop_rate_hz"] == TIMING["rate_hz"]
    assert m["loop_rate_mean_hz"] == pytest.approx((9 * 1000.0 + 998.0) / 10)
    assert m["loop_fresh_share"] == TIMING["total_fresh_share"]
    assert m["loop_missed_cycles"] == 3 and m["loop_cycles"] == 10_000
    assert (m["loop_age_p50_ms"], m["loop_age_p99_ms"], m["loop_age_max_ms"]) == (0.4, 1.2, 2.5)


def test_settling_time_definition():
    t = np.arange(0.0, 1.0, 0.1)
    assert analysis.settling_time(t, np.full(10, 1e-4)) == 0.0  # never outside 1 mm
    assert math.isnan(analysis.settling_time(t, np.full(10, 0.1)))  # never settles
    e = np.array([0.1, 0.05, 0.01, 0.0005, 0.003, 0.0009, 0.0, 0.0, 0.0, 0.0])
    assert analysis.settling_time(t, e) == pytest.approx(0.5)  # after the last excursion


def png_ok(path: Path) -> bool:
    return path.is_file() and path.stat().st_size > 2000 and path.read_bytes()[:4] == b"\x89PNG"


def test_plot_session_writes_thesis_figures(recorded, tmp_path):
    path, _ = recorded
    written = analysis.plot_session(analysis.load_session(path), tmp_path / "plots")
    assert {p.name for p in written} == {
        "position.png", "errors.png", "force.png", "torques.png", "estimates.png",
        "sliding.png", "network_norms.png", "loop_timing.png"}
    assert all(png_ok(p) for p in written)


def test_compare_and_format_metrics(recorded, tmp_path):
    path, _ = recorded
    other = tmp_path / "other.mcap"
    write_session(other, controller="other_ctrl", scale=2.0)
    sessions = [analysis.load_session(path), analysis.load_session(other)]
    written = analysis.compare(sessions, tmp_path / "cmp")
    names = {p.name for p in written}
    assert {"compare_position.png", "compare_force.png", "compare_torques.png",
            "compare_loop_timing.png", "comparison.txt", "comparison.csv"} <= names
    assert all(png_ok(p) for p in written if p.suffix == ".png")
    table = (tmp_path / "cmp" / "comparison.txt").read_text()
    header, rule, *rows = table.splitlines()
    assert header.split()[1:] == ["synth_ctrl", "other_ctrl"]
    rms = next(r for r in rows if r.startswith("pos_err_rms_m")).split()
    m1, m2 = (analysis.metrics(s) for s in sessions)
    assert [float(v) for v in rms[1:]] == pytest.approx(
        [m1["pos_err_rms_m"], m2["pos_err_rms_m"]], rel=1e-3)
    assert float(rms[2]) == pytest.approx(2 * float(rms[1]), rel=1e-3)
    # Aligned: each value column ends at the same character position as its header.
    ends = [len(header)] + [len(r) for r in rows if not r.startswith("controller")]
    assert len(set(ends)) == 1
    assert len(rule) == len(header)


def test_same_controller_sessions_get_distinct_labels(recorded, tmp_path):
    path, _ = recorded
    copy = tmp_path / "again.mcap"
    copy.write_bytes(path.read_bytes())
    labels = analysis.session_labels([analysis.load_session(path), analysis.load_session(copy)])
    assert labels == ["synth_ctrl (synth)", "synth_ctrl (again)"]


def test_recording_cut_short_is_read_up_to_the_cut(tmp_path):
    full = tmp_path / "full.mcap"
    write_session(full, chunk_size=16 * 1024)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    session = analysis.load_session(cut)
    assert session.warnings and "ends early" in session.warnings[0]
    n = len(session.status["stamp"])
    assert 0 < n < len(signals()["t"])
    assert analysis.metrics(session)["samples"] == n


def test_partial_recording_has_partial_metrics(tmp_path):
    path = tmp_path / "states_only.mcap"
    writer = McapBagWriter(path)
    channel = writer.add_topic(topics.JOINT_STATES, "sensor_msgs/msg/JointState", has_header=True)
    for i in range(5):
        state = stamped(JointState(name=JOINTS, position=[0.1 * i, 0.0]), 1.0 + 0.001 * i)
        writer.write(channel, serialize_message(state), 1_000 + i)
    writer.close()
    session = analysis.load_session(path)
    assert session.controller is None and session.name == "states_only"
    assert analysis.metrics(session) == {"controller": "-", "stamps_backwards_joint_states": 0,
                                         "stamps_repeated_joint_states": 0, "data_warnings": 0}
    assert analysis.plot_session(session, tmp_path / "plots") == []


def test_file_without_package_topics_is_refused(tmp_path):
    path = tmp_path / "foreign.mcap"
    writer = McapBagWriter(path)
    writer.add_topic("/chatter", "std_msgs/msg/String")
    writer.close()
    with pytest.raises(analysis.SessionError, match="none of cr_control's topics"):
        analysis.load_session(path)


def test_cli_prints_metrics_and_writes_plots(recorded, tmp_path, capsys):
    path, _ = recorded
    assert analysis.main([str(path), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "pos_err_rms_m" in out and "synth_ctrl" in out
    assert f"to {tmp_path / 'out'}" in out
    assert png_ok(tmp_path / "out" / "position.png")


def test_cli_json_and_several_files(recorded, tmp_path, capsys):
    path, _ = recorded
    other = tmp_path / "other.mcap"
    write_session(other, controller="other_ctrl", scale=2.0)
    assert analysis.main([str(path), str(other), "--json", "--out", str(tmp_path / "o")]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert set(data) == {"synth_ctrl", "other_ctrl"}
    assert data["other_ctrl"]["pos_err_max_m"] == pytest.approx(0.02)
    assert (tmp_path / "o" / "comparison.txt").is_file()
    assert png_ok(tmp_path / "o" / "other_ctrl" / "position.png")  # a folder per session label


def test_cli_default_plot_dir_is_next_to_the_file(tmp_path, capsys):
    path = tmp_path / "run1.mcap"
    write_session(path)
    assert analysis.main([str(path)]) == 0
    assert png_ok(tmp_path / "run1_plots" / "force.png")


def test_cli_user_errors_exit_2_with_a_clear_message(tmp_path, capsys):
    missing = tmp_path / "nope.mcap"
    assert analysis.main([str(missing), "--no-plots"]) == 2
    assert capsys.readouterr().err.strip() == f"cr_analyze: error: {missing}: no such file"
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n")
    assert analysis.main([str(text)]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
    assert analysis.main([str(tmp_path), "--no-plots"]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_cli_process_exit_code_without_traceback(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "cr_control.analysis.analyze", str(tmp_path / "missing.mcap")],
        capture_output=True, text=True, timeout=120, cwd=REPO)
    assert result.returncode == 2
    assert "no such file" in result.stderr and "Traceback" not in result.stderr


def test_stamps_on_another_clock_are_plotted_as_they_are(tmp_path):
    session = analysis.Session(tmp_path / "x.mcap",
                               status={"stamp": np.array([1.7e9, 1.7e9 + 1.0])},
                               timing={"stamp": np.array([1.0, 2.0])})
    np.testing.assert_allclose(session.relative_time(session.status["stamp"]), [0.0, 1.0])
    np.testing.assert_allclose(session.relative_time(session.timing["stamp"]), [1.0, 2.0])


def test_loop_summary_warns_plainly_when_a_real_time_loop_fell_behind():
    good = {"loop_fresh_share": 0.998, "loop_rate_mean_hz": 999.2, "loop_age_p50_ms": 0.2,
            "loop_age_p99_ms": 0.6}
    lines = analysis.loop_summary(good)
    assert len(lines) == 1 and "999.2 Hz" in lines[0] and "99.80 %" in lines[0]
    behind = dict(good, loop_fresh_share=0.40)
    assert "WARNING" in analysis.loop_summary(behind)[-1]
    assert "WARNING" in analysis.loop_summary(dict(good, loop_rate_mean_hz=660.0))[-1]
    assert len(analysis.loop_summary(behind, realtime=False)) == 1  # lockstep: no deadline
    assert analysis.loop_summary({}) == []


def _two_controllers(path: Path, first: range, second: range) -> None:
    """Statuses and commands of controllers "a" (every status field 1) then "b" (2) at the
    stamps 100 + i/1000 of the given ranges, recorded in that order; "a" sends the command
    of i = 50 twice (a repeated stamp that no switch explains)."""
    writer = McapBagWriter(path)
    commands = writer.add_topic(topics.JOINT_COMMANDS, "sensor_msgs/msg/JointState",
                                has_header=True)
    log = 1_700_000_000
    for name, indices, value in (("a", first, 1.0), ("b", second, 2.0)):
        topic = writer.add_topic(topics.status_topic(name), "std_msgs/msg/Float64MultiArray")
        for i in indices:
            row = [T_START + i * 1e-3] + [value] * (len(topics.STATUS_FIELDS) - 1)
            writer.write(topic, labelled(topics.STATUS_FIELDS, row), log)
            for _ in range(2 if (name, i) == ("a", 50) else 1):
                command = stamped(JointState(name=JOINTS, effort=[value, value]),
                                  T_START + i * 1e-3)
                writer.write(commands, serialize_message(command), log)
            log += 1
    writer.close()


@pytest.mark.parametrize("overlap", [0, 1, 5])
def test_a_live_switch_is_joined_with_the_first_answers(tmp_path, overlap):
    """The second controller's first statuses at or before the first's last (both answered
    the states the second held or had queued when activated): a switch, each stamp once, the
    first's rows kept; the commands' stamps in the overlap not counted as going backwards or
    repeating, the one repeated elsewhere counted."""
    path = tmp_path / "switch.mcap"
    _two_controllers(path, range(0, 101), range(101 - overlap, 200))
    session = analysis.load_session(path)
    assert session.controllers == ["a", "b"] and not session.warnings
    assert session.switches == [(pytest.approx(T_START + (101 - overlap) * 1e-3), "b")]
    stamps = session.status["stamp"]
    assert len(stamps) == 200 and np.all(np.diff(stamps) > 0)
    values = session.status[topics.STATUS_FIELDS[1]]
    assert np.all(values[:101] == 1.0) and np.all(values[101:] == 2.0)
    commands = session.joint_commands
    assert (commands.stamps_backwards, commands.stamps_repeated) == (0, 1)


def test_two_controllers_at_once_are_not_a_switch(tmp_path):
    """An overlap longer than a switch leaves (0.2 s): a second controller at once."""
    path = tmp_path / "rogue.mcap"
    _two_controllers(path, range(0, 301), range(100, 400))
    session = analysis.load_session(path)
    assert session.controllers == ["a"] and len(session.status["stamp"]) == 301
    assert session.warnings == ["several controllers ['a', 'b']; analysing a"]
    assert session.joint_commands.stamps_backwards == 1
