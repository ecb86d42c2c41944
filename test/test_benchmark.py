"""cr_benchmark's pure functions on synthetic input, and the echo pair for ~1 s.

No timing is asserted: only that the figures are parsed, combined and produced.
"""

import argparse
import io
import math
import subprocess
import sys
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control import robots
from cr_control.core import topics
from cr_control.core.ros_env import DOMAIN_SPAN, FIRST_DOMAIN
from cr_control.tools import benchmark as bm
from cr_control.tools import echo_pair
from cr_control.tools.echo_pair import parse_result

#: The Panda layout's echo pair messages (9 joints, 7 commanded).
PANDA_ECHO_ARGS = next(lay for lay in bm.LAYOUTS if lay.name == "panda").echo_args

# /proc/<pid>/stat of a process whose name holds a space and a parenthesis.
STAT = ("4242 (python (x) 3) S 1 4242 4242 0 -1 4194560 5000 0 0 0 "
        "250 75 0 0 20 0 5 0 12345 100000000 5000 18446744073709551615")


def test_proc_stat_utime_plus_stime():
    assert bm.parse_proc_stat(STAT) == 250 + 75


def test_cpu_of_this_process_is_readable():
    assert bm.read_cpu_ticks("self") >= 0
    assert bm.read_cpu_ticks(2**31 - 1) is None  # no such process


def test_cpu_percent_and_samples():
    assert bm.cpu_percent(100, 150, 1.0, clk_tck=100) == 50.0
    assert math.isnan(bm.cpu_percent(0, 10, 0.0))
    samples = [
        (0.0, {"plant": 100, "ctrl": 50}),
        (1.0, {"plant": 130, "ctrl": None}),
        (2.0, {"plant": 180, "ctrl": 90, "late": 7}),
    ]
    cpu = bm.cpu_from_samples(samples)
    assert math.isclose(cpu["plant"], 100.0 * 80 / bm.CLOCK_TICKS / 2.0)
    assert math.isclose(cpu["ctrl"], 100.0 * 40 / bm.CLOCK_TICKS / 2.0)
    assert "late" not in cpu  # a single sample gives no rate


def test_machine_stat_busy_ticks():
    text = "cpu  100 5 50 9000 40 3 2 1 0 0\ncpu0 50 2 25 4500 20 1 1 0 0 0\nintr 1 2\n"
    assert bm.parse_machine_stat(text) == 100 + 5 + 50 + 3 + 2   # steal (1) is not our machine's
    assert bm.parse_machine_stat(text, steal=True) == 1
    assert bm.parse_machine_stat("cpu  100 5 50 9000 40 3 2\n", steal=True) == 0  # old kernels
    assert bm.read_machine_ticks() is None or bm.read_machine_ticks() >= 0
    assert bm.disturbed({"cpu_others_pct": 12.0, "cpu_steal_pct": 9.0})   # together over 20 %
    assert not bm.disturbed({"cpu_others_pct": 12.0, "cpu_steal_pct": None})


def test_done_line():
    log = ("[INFO] [1.0] [plant]: t=1.0 s rate=1000 Hz\n"
           "[INFO] [2.0] [plant]: done: 10.000 s simulated in 4.125 s wall, 10000 cycles, "
           "0 commands refused\n")
    assert bm.parse_done_line(log) == (10.0, 4.125, 10000)
    assert bm.parse_done_line("nothing here") is None


def test_timing_dict_and_loop_figures():
    values = [float(i) for i in range(len(topics.PLANT_TIMING_FIELDS))]
    timing = bm.timing_dict(topics.layout_label(topics.PLANT_TIMING_FIELDS), values)
    assert timing["total_age_p99_ms"] == topics.PLANT_TIMING_FIELDS.index("total_age_p99_ms")
    fig = bm.loop_figures(dict(timing, total_fresh_share=0.995), (10.0, 10.01, 9990))
    assert fig["cycles"] == 9990
    assert math.isclose(fig["rate_hz"], 9990 / 10.01)
    assert math.isclose(fig["fresh_pct"], 99.5)
    assert fig["rt_p99_ms"] == timing["total_age_p99_ms"]
    assert bm.loop_figures(None, None) == {}
    silent = bm.loop_figures(dict(timing, total_age_p50_ms=0.0, total_age_p99_ms=0.0,
                                  total_age_max_ms=0.0, total_fresh_share=0.0), None)
    assert silent["rt_p99_ms"] is None and silent["fresh_pct"] == 0.0  # no command came back


def test_last_double_reads_raw_cdr():
    fields = topics.STATUS_FIELDS
    msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension, fields)
    msg.data = [float(i) + 0.25 for i in range(len(fields))]
    buf = serialize_message(msg)
    i = fields.index("compute_time_us")
    assert bm.last_double(buf, len(fields) - i) == msg.data[i]


def test_ratios_to_baseline():
    run = {"fresh_pct": 99.0, "rt_p99_ms": 0.9, "cpu_total_pct": 60.0}
    base = {"fresh_pct": 99.9, "rt_p99_ms": 0.3, "cpu_total_pct": 30.0}
    r = bm.ratios(run, base)
    assert math.isclose(r["fresh_diff_pp"], -0.9)
    assert math.isclose(r["p99_ratio"], 3.0)
    assert math.isclose(r["cpu_ratio"], 2.0)
    assert all(math.isnan(v) for v in bm.ratios({}, base).values())
    assert math.isnan(bm.ratios(run, dict(base, rt_p99_ms=0.0))["p99_ratio"])


def test_tables_format_missing_and_failed():
    assert bm.fmt(None) == "-" and bm.fmt(math.nan) == "-" and bm.fmt(1.234, ".2f", "x") == "1.23x"
    runs = [("session processes", {"rate_hz": 999.5, "rt_p99_ms": 0.8, "p99_ratio": 2.5,
                                   "fresh_diff_pp": -0.4, "compute_p50_us": 120.0}),
            ("echo processes", {"error": "boom"})]
    table = bm.format_realtime_table(runs)
    lines = table.splitlines()
    assert len(lines) == 1 + len(bm.REALTIME_ROWS)
    assert "session processes" in lines[0] and "echo processes" in lines[0]
    rate = next(ln for ln in lines if ln.startswith("achieved rate"))
    assert "999.5" in rate and "failed" in rate
    assert "2.50x" in table and "-0.40" in table
    speed = bm.format_speed_table([("offline loop (no ROS)", {"simulated_s": 10.0, "wall_s": 0.8,
                                                              "speed": 12.5, "rate_hz": 12500.0}),
                                   ("lockstep composed", {"error": "x"})])
    assert "12.50x" in speed and "failed" in speed


def test_json_safe_and_domain_ids():
    assert bm.json_safe({"a": math.nan, "b": [1.0, math.inf], "c": (1, "x")}) == \
        {"a": None, "b": [1.0, None], "c": [1, "x"]}
    ids = bm.domain_ids(FIRST_DOMAIN + DOMAIN_SPAN - 2, 4)
    assert ids == [FIRST_DOMAIN + DOMAIN_SPAN - 2, FIRST_DOMAIN + DOMAIN_SPAN - 1, FIRST_DOMAIN,
                   FIRST_DOMAIN + 1]


@pytest.mark.ros
@pytest.mark.parametrize("shape", [(), PANDA_ECHO_ARGS], ids=["2 joints", "panda"])
def test_echo_pair_one_process_produces_cycles(ros_env, shape):
    proc = subprocess.run([sys.executable, "-m", "cr_control.tools.echo_pair", "both", "--duration", "1",
                           *shape], env=ros_env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = parse_result(proc.stdout)
    assert result is not None, proc.stdout + proc.stderr
    assert result["total_cycles"] > 0
    core = ["rate_hz", "total_cycles", "total_fresh_share", "total_age_p50_ms", "total_age_p99_ms",
            "step_time_us", "wall_s", "achieved_rate_hz"]
    assert all(math.isfinite(result[k]) for k in core)
    assert set(topics.PLANT_TIMING_FIELDS) <= set(result)
    assert bm.parse_done_line(proc.stdout + proc.stderr) is not None


def test_cpu_per_cycle_between_first_and_last_readable_sample():
    samples = [{"plant": 100, "ctrl": None}, {"plant": 110, "ctrl": 40}, {"plant": 130, "ctrl": 60}]
    cycles = [0, 1000, 3000]
    per = bm.cpu_per_cycle(samples, cycles, clk_tck=100)
    assert math.isclose(per["plant"], 30 / 100 * 1e6 / 3000)  # 100 us per cycle
    assert math.isclose(per["ctrl"], 20 / 100 * 1e6 / 2000)
    assert bm.cpu_per_cycle([{"x": 1}, {"x": 5}], [10, 10]) == {}  # no cycles: no figure


def test_window_mean_weighted_and_absent_fields():
    reports = [{"step_time_us": 100.0, "window_cycles": 1000.0},
               {"step_time_us": 40.0, "window_cycles": 500.0},
               {"window_cycles": 10.0}]
    assert math.isclose(bm.window_mean(reports, "step_time_us"), (100e3 + 20e3) / 1500)
    assert bm.window_mean(reports, "publish_time_us") is None
    assert bm.window_mean([], "step_time_us") is None


def test_status_fields_read_by_name_from_raw_cdr():
    fields = topics.STATUS_FIELDS[:-1] + ["in_time_us", "out_time_us", "held", "estimate"]
    msg = topics.labelled_array(Float64MultiArray, MultiArrayDimension, fields)
    msg.data = [float(i) + 0.5 for i in range(len(fields))]
    buf = serialize_message(msg)
    offsets = bm.offsets_from_end(fields, bm.STATUS_TIME_FIELDS)
    assert set(offsets) == {"in_time_us", "compute_time_us", "out_time_us"}
    for name, k in offsets.items():
        assert bm.last_double(buf, k) == msg.data[fields.index(name)]
    # Before the controller publishes in/out times: only compute_time_us.
    assert set(bm.offsets_from_end(topics.STATUS_FIELDS, bm.STATUS_TIME_FIELDS)) == {"compute_time_us"}


def test_scaling_to_the_reference_machine():
    assert bm.scaled_cost(10.0, 30.0) == 100.0  # 10 us at 30 ns/iteration -> 100 us at 300
    assert bm.scaled_speed(20.0, 30.0) == 2.0   # 20x at 30 ns/iteration -> 2x at 300
    assert bm.scaled_cost(10.0, 300.0, reference_ns=300.0) == 10.0
    assert bm.scaled_cost(None, 30.0) is None and bm.scaled_speed(5.0, None) is None
    assert bm.scaled_cost(math.nan, 30.0) is None and bm.scaled_cost(1.0, 0.0) is None


def test_verdicts():
    assert bm.verdict(995.0, ">=", 990.0) == "PASS"
    assert bm.verdict(980.0, ">=", 990.0) == "FAIL"
    assert bm.verdict(1.2, "<=", 1.5) == "PASS" and bm.verdict(1.6, "<=", 1.5) == "FAIL"
    assert bm.verdict(None, "<=", 1.5) == "n/a" and bm.verdict(1.0, ">=", math.nan) == "n/a"


def test_realtime_targets_per_layout():
    session = {"fresh_diff_pp": -1.5, "rate_hz": 995.0, "p99_ratio": 1.7}
    echo = {"rate_hz": 990.0}
    t = {x.name: x for x in bm.realtime_targets("processes", session, echo)}
    assert [x.verdict for x in t.values()] == ["PASS", "PASS", "FAIL"]
    composed = bm.realtime_targets("composed", session, echo)
    assert [x.verdict for x in composed] == ["FAIL", "PASS"]  # within 1 pp; no p99 target
    recorded = bm.realtime_targets("recorder", dict(session, rate_hz=980.0), {"rate_hz": 985.0})
    rate = next(x for x in recorded if "rate" in x.name)
    assert rate.limit == 985.0 and rate.verdict == "FAIL"  # at least the echo pair + recorder's
    assert all(x.verdict == "n/a" for x in bm.realtime_targets("processes", {}, {}))


def test_cost_targets_use_scaled_figures():
    session = {"compute_p50_us": 9.0, "plant_step_us": 9.0}
    targets = bm.cost_targets(session, {"speed": 25.0}, {"speed": 60.0}, loop_ns=30.0)
    by_name = {t.name: t for t in targets}
    assert by_name["controller compute p50 in the node"].value == 90.0
    assert by_name["controller compute p50 in the node"].verdict == "PASS"
    assert by_name["plant step, mean"].verdict == "FAIL"  # 90 us scaled > 80
    assert by_name["offline loop speed"].value == 6.0 and by_name["offline loop speed"].verdict == "FAIL"
    assert by_name["lockstep composed speed"].value == 2.5
    table = bm.format_targets(targets)
    assert "PASS" in table and "FAIL" in table and "<= 100.0 us" in table
    assert all(t.as_dict()["verdict"] in ("PASS", "FAIL") for t in targets)
    assert {t.verdict for t in bm.cost_targets({}, {}, {}, None)} == {"n/a"}


def test_cost_targets_carried_by_the_issues_own_code():
    """With the reference run, our figures are carried to the issue's machine by the ratio of
    the issue's figures of its code to that code measured in this run; the loop-iteration
    scaling follows, marked."""
    before = bm.ISSUE_BEFORE
    reference = {"rev": "abc", "compute_p50_us": 2 * before["compute_p50_us"],   # machine 2x slower
                 "plant_step_us": before["plant_step_us"] / 2,                    # 2x faster
                 "offline_speed": before["offline_speed"] * 4, "lockstep_composed_speed": None}
    session = {"compute_p50_us": 150.0, "plant_step_us": 50.0}
    targets = bm.cost_targets(session, {"speed": 3.0}, {"speed": 30.0}, loop_ns=30.0, reference=reference)
    assert len(targets) == 8
    by_name = {t.name: t for t in targets}
    assert by_name["controller compute p50 in the node"].value == 75.0       # 150 x 1/2
    assert by_name["controller compute p50 in the node"].verdict == "PASS"
    assert by_name["plant step, mean"].value == 100.0                        # 50 x 2
    assert by_name["plant step, mean"].verdict == "FAIL"
    assert by_name["offline loop speed"].value == 7.5                        # 30 / 4
    assert by_name["lockstep composed speed"].verdict == "n/a"               # no reference figure
    assert by_name["controller compute p50 in the node [loop scaling]"].value == 1500.0
    assert "abc" in by_name["plant step, mean"].note
    failed = bm.cost_targets(session, {}, {}, 30.0, reference={"rev": "abc", "error": "no git"})
    assert [t.name for t in failed] == [name for name, *_ in bm.COST_TARGETS]   # loop scaling only
    assert "abc" in bm.format_reference(reference)
    assert "no git" in bm.format_reference({"error": "no git"})
    assert bm.reference_scaled(1.0, 0.0, 2.0) is None and bm.reference_scaled(None, 1.0, 2.0) is None


def test_reference_run_reports_a_missing_revision(tmp_path):
    args = argparse.Namespace(duration=1.0, lockstep_duration=1.0, skip_offline=True, skip_lockstep=True,
                              no_compute_time=True)
    progress = bm.Progress(stream=io.StringIO())
    result = bm.run_reference("0" * 40, tmp_path, args, progress)
    assert result["error"].startswith("no revision " + "0" * 40)


def test_bad_arguments_are_refused_in_one_line_before_any_run(capsys):
    assert bm.main(["--repeat", "0"]) == 2
    assert bm.main(["-p", "adaptive_impedance.no_such_gain=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("cr_benchmark: ") for line in err)
    assert "no_such_gain" in err[1]
    assert bm.build_parser().parse_args(["-p", "adaptive_impedance.diagnostics_every=1"]).set == [
        "adaptive_impedance.diagnostics_every=1"]


def test_median_of_repeats_keeps_each_repeat_and_errors():
    figs = [{"rate_hz": 990.0, "fresh_diff_pp": -3.0, "cpu_per_process_pct": {"plant": 40.0}, "logs": "a"},
            {"rate_hz": 995.0, "fresh_diff_pp": -1.0, "cpu_per_process_pct": {"plant": 50.0}, "logs": "b"},
            {"rate_hz": 980.0, "fresh_diff_pp": math.nan, "cpu_per_process_pct": {"plant": 45.0}, "logs": "c",
             "error": "no 'done:' line"}]
    merged = bm.median_figures(figs)
    assert merged["rate_hz"] == 990.0                       # median of three
    assert merged["fresh_diff_pp"] == -2.0                  # median of the two finite ones
    assert merged["cpu_per_process_pct"] == {"plant": 45.0}
    assert merged["logs"] == "a" and merged["error"] == "no 'done:' line"
    assert [r["rate_hz"] for r in merged["repeats"]] == [990.0, 995.0, 980.0]
    assert bm.median_figures(figs[:1]) == figs[0]           # one repeat: as measured
    assert "-3.00 pp" in bm.format_repeats([("session processes", merged)])


@pytest.mark.ros
def test_reference_run_measures_the_issues_own_code(tmp_path):
    """The code the "before" table measured comes out of this repository's history and runs its own
    benchmark (short runs here): the four figures the cost targets are carried by."""
    repo = Path(bm.__file__).resolve().parents[2]
    if subprocess.run(["git", "-C", str(repo), "cat-file", "-e", f"{bm.REFERENCE_REV}^{{commit}}"],
                      capture_output=True).returncode != 0:
        pytest.skip(f"no git history with {bm.REFERENCE_REV} here (a shallow or exported copy)")
    args = argparse.Namespace(duration=4.0, lockstep_duration=0.5, skip_offline=False, skip_lockstep=False,
                              no_compute_time=False)
    result = bm.run_reference(bm.REFERENCE_REV, tmp_path, args, bm.Progress(stream=io.StringIO()))
    assert "error" not in result, result.get("error")
    assert all(result[key] > 0 for key in bm.ISSUE_BEFORE), result
    assert (tmp_path / f"reference-{bm.REFERENCE_REV}" / "cr_control" / "benchmark.py").exists()  # its layout
    assert "reference" in bm.format_reference(result)


def test_recorder_window_cost_and_samples():
    log_times = [1_000 + 10 * i for i in range(100)]  # 100 messages, 10 ns apart
    cost = bm.recorder_window_cost(50, 60, 1_000, 1_500, log_times, clk_tck=100)
    assert cost["messages"] == 50  # (1000, 1500]
    assert math.isclose(cost["us_per_msg"], 0.1 * 1e6 / 50)
    assert math.isclose(cost["msgs_per_s"], 50 / 500e-9)
    samples = [(0, 1), (10, None), (20, 3), (30, 4), (40, 9)]
    assert bm.samples_between(samples, 5, 35) == ((20, 3), (30, 4))
    assert bm.samples_between(samples, 5, 25) is None


def test_cells_say_na_when_a_node_does_not_publish_a_field():
    assert bm.cell({"plant_publish_us": None}, "plant_publish_us", ".1f") == "n/a"
    assert bm.cell({}, "plant_publish_us", ".1f") == "-"
    assert bm.cell({"plant_publish_us": 12.34}, "plant_publish_us", ".1f") == "12.3"
    table = bm.format_realtime_table([("session processes", {"out_p50_us": None, "in_p50_us": 3.0})])
    assert "n/a" in next(ln for ln in table.splitlines() if ln.startswith("controller out p50"))


def test_recorder_load_table_and_published_line():
    assert bm.parse_published("[synthetic_load]: published: 15000 messages in 3.000 s") == 15000
    assert bm.parse_published("nothing") is None
    table = bm.format_recorder_load([("recorder, synthetic load", {
        "msgs_per_s": 5000.0, "cpu_pct": 12.5, "us_per_msg": 25.0, "published": 10, "recorded": 10,
        "lost": 0}), ("other", {"error": "x"})], loop_ns=30.0)
    assert "250.0" in table and "failed" in table  # 25 us at 30 ns -> 250 us at 300 ns


def test_calibration_figures_are_positive():
    assert bm.loop_ns_per_iteration(n=1000, repeats=2) > 0
    aba = bm.aba_us_per_call(n=10, repeats=1)
    assert aba is None or aba > 0
    steps = bm.step_us_hot_and_after_idle(cycles=20, idle_s=1e-4)
    assert steps["step_hot_us"] > 0 and steps["step_after_idle_us"] > 0


def test_mcap_log_times_from_message_indexes(tmp_path):
    from cr_control.recording.recorder import McapBagWriter

    path = tmp_path / "t.mcap"
    writer = McapBagWriter(path, chunk_size=2048)
    a = writer.add_topic("/a", "std_msgs/msg/Float64MultiArray")
    b = writer.add_topic("/b", "std_msgs/msg/Float64MultiArray")
    data = serialize_message(Float64MultiArray(data=[1.0, 2.0]))
    for i in range(300):
        writer.write(a if i % 2 else b, data, 5_000 + 3 * i)
    writer.close()
    assert bm.mcap_log_times(path) == [5_000 + 3 * i for i in range(300)]


def test_recorder_missed_from_its_exit_line():
    clean = "[INFO] ready\nrecorder: wrote 5266 messages to /tmp/x/session.mcap\n"
    lossy = ("recorder: wrote 53061 messages to /tmp/s.mcap; 6947 missed (gaps in the publishers' "
             "sequence numbers: /joint_states 1160, /clock 1155)\n")
    assert bm.parse_recorder_missed(clean) == 0
    assert bm.parse_recorder_missed(lossy) == 6947
    assert bm.parse_recorder_missed("Traceback ...") is None


def test_claimed_domains_one_held_at_a_time():
    from cr_control.core import ros_env

    domains = bm.claimed_domains(None)
    first, second = next(domains), next(domains)
    assert first != second
    assert all(FIRST_DOMAIN <= d < FIRST_DOMAIN + DOMAIN_SPAN for d in (first, second))
    assert second in ros_env._held and first not in ros_env._held
    domains.close()
    assert second not in ros_env._held


def test_pairs_stolen_by_the_hypervisor_are_run_again_at_most_retries_times():
    """ABBA order; a pair with a disturbed run (others + steal above DISTURBED_PCT) is
    discarded and run again until ``retries`` pairs were discarded; then pairs are kept."""
    order, steals = [], iter([0, 0, 50, 0, 30, 0, 0, 0, 90, 90])
    lines = []

    def run(kind):
        def fn(tag):
            order.append(kind + tag)
            steal = next(steals)
            return {"cpu_steal_pct": steal / 2, "cpu_others_pct": steal / 2,
                    "fresh_pct": 90.0 if kind == "s" else 95.0,
                    "rt_p99_ms": 1.0, "rate_hz": 999.0}
        return fn

    sessions, echoes, discarded = bm.run_pairs(run("s"), run("e"), repeat=3, retries=2,
                                               progress=lines.append)
    assert order == ["s #1", "e #1", "e #2", "s #2", "s #3", "e #3", "e #4", "s #4",
                     "s #5", "e #5"]
    assert [d["pair"] for d in discarded] == [2, 3]       # #2: 50 % (echo), #3: 30 % (session)
    assert discarded[0]["echo_steal_pct"] == 25 and discarded[1]["cpu_others_pct"] == 15
    assert len(sessions) == len(echoes) == 3             # #1, #4 and #5 (90 %: no retry left)
    assert [s["cpu_steal_pct"] for s in sessions] == [0, 0, 45]
    assert sessions[0]["fresh_diff_pp"] == pytest.approx(-5.0)
    assert len(lines) == 2 and "discarded, run again" in lines[0]
    text = bm.format_repeats([("session processes", {"discarded": discarded})])
    assert "pair #2 discarded" in text and "pair #3 discarded" in text


def test_a_single_pair_keeps_its_untagged_title_unless_run_again():
    tags = []

    def run(tag):
        tags.append(tag)
        return {"cpu_steal_pct": 0.0}

    bm.run_pairs(run, run, repeat=1, retries=0, progress=print)
    assert tags == ["", ""]


PANDA = next(lay for lay in bm.LAYOUTS if lay.name == "panda")


def test_layouts_selected_by_only_and_skip_in_their_order():
    names = [lay.name for lay in bm.LAYOUTS]
    assert names == ["processes", "composed", "recorder", "panda", "ur5", "ur5_position", "xarm7"]
    assert [lay.name for lay in bm.select_layouts()] == names
    assert bm.select_layouts(["panda"]) == [PANDA]
    assert [lay.name for lay in bm.select_layouts(["panda", "processes"])] == ["processes", "panda"]
    assert [lay.name for lay in bm.select_layouts(None, ["composed", "panda", "ur5"])] == [
        "processes", "recorder", "ur5_position", "xarm7"]
    assert bm.select_layouts(["panda"], ["panda"]) == []
    # The existing layouts keep their titles (README tables, the reference run's JSON keys).
    assert [(lay.session_title, lay.echo_title) for lay in bm.LAYOUTS[:3]] == [
        ("session processes", "echo processes"), ("session composed", "echo composed"),
        ("session + recorder", "echo + recorder")]
    assert PANDA.robot == "panda" and PANDA.record and not PANDA.composed
    assert PANDA.session_title.startswith("session")  # its repeats are printed (format_repeats)
    # the UR5 at ur_robot_driver's 500 Hz: its echo pair at the same rate and shape
    ur5 = next(lay for lay in bm.LAYOUTS if lay.name == "ur5")
    assert ur5.robot == "ur5" and ur5.record and "--rate" in ur5.echo_args
    assert float(ur5.echo_args[ur5.echo_args.index("--rate") + 1]) == robots.robot("ur5").rate_hz
    # the arms that take joint positions: each against an echo pair of its driver's rate and
    # its joints (the xArm's 150 Hz, 7 joints; the UR5's 500 Hz, 6)
    for name, joints in (("ur5_position", 6), ("xarm7", 7)):
        lay = next(lay for lay in bm.LAYOUTS if lay.name == name)
        assert lay.robot == name and lay.record and lay.rules == "recorder"
        args = lay.echo_args
        assert float(args[args.index("--rate") + 1]) == robots.robot(name).rate_hz
        assert int(args[args.index("--joints") + 1]) == joints


def test_panda_targets_are_the_recorders_plus_compute_p50():
    session = {"fresh_diff_pp": -1.5, "rate_hz": 992.0, "p99_ratio": 1.2, "compute_p50_us": 39.0}
    echo = {"rate_hz": 990.5}
    targets = bm.layout_targets(PANDA, session, echo)
    recorder = bm.realtime_targets("recorder", session, echo)
    assert [(t.op, t.limit, t.unit) for t in targets[:-1]] == [(t.op, t.limit, t.unit) for t in recorder]
    assert [t.name for t in targets] == ["panda: fresh command vs echo pair", "panda: achieved rate",
                                         "panda: round trip p99 vs echo pair",
                                         "panda: controller compute p50 in the node"]
    assert [t.verdict for t in targets] == ["PASS", "PASS", "PASS", "PASS"]
    compute = targets[-1]
    assert (compute.value, compute.op, compute.limit) == (39.0, "<=", 100.0)  # as measured, not scaled
    slow = bm.layout_targets(PANDA, dict(session, compute_p50_us=101.0, fresh_diff_pp=-2.5,
                                         rate_hz=990.0, p99_ratio=1.6), echo)
    assert [t.verdict for t in slow] == ["FAIL", "FAIL", "FAIL", "FAIL"]
    assert bm.layout_targets(PANDA, dict(session, compute_p50_us=None), echo)[-1].verdict == "n/a"
    # The other layouts: the real-time targets of their own name, no compute limit of their own.
    for lay in bm.LAYOUTS[:3]:
        assert bm.layout_targets(lay, session, echo) == bm.realtime_targets(lay.name, session, echo)
    table = bm.format_targets(targets)
    assert "panda: controller compute p50 in the node" in table and "<= 100.0 us" in table
    assert "<= 1.50x" in table and ">= 990.5 Hz" in table


def test_realtime_table_with_the_panda_columns():
    runs = [("session + recorder", {"rate_hz": 995.0}), ("echo + recorder", {"rate_hz": 994.0}),
            (PANDA.session_title, {"rate_hz": 981.25, "compute_p50_us": 39.0, "fresh_diff_pp": -0.5,
                                   "compute_p99_us": None}),
            (PANDA.echo_title, {"error": "boom"})]
    lines = bm.format_realtime_table(runs).splitlines()
    assert len(lines) == 1 + len(bm.REALTIME_ROWS)
    assert len({len(line) for line in lines}) == 1  # every column right-aligned to its own width
    head = lines[0]
    assert head.endswith("  " + PANDA.echo_title) and "  " + PANDA.session_title + "  " in head
    rate = next(ln for ln in lines if ln.startswith("achieved rate"))
    assert rate.split()[-4:] == ["995.0", "994.0", "981.2", "failed"]
    compute = next(ln for ln in lines if ln.startswith("controller compute p50 (us)"))
    assert compute.split()[-2:] == ["39.0", "-"]
    assert next(ln for ln in lines if ln.startswith("controller compute p99")).split()[-2] == "n/a"
    # Each column as wide as its title needs: the older ones are not widened by the Panda's.
    label_w = max(len(label) for label, *_ in bm.REALTIME_ROWS)
    assert head[label_w:label_w + 20] == "  session + recorder"


def test_echo_pair_messages_of_the_pandas_shape():
    args = echo_pair.build_parser().parse_args(["both", *PANDA.echo_args])
    state_names, command_names = echo_pair.message_names(args)
    state = echo_pair.joint_state(state_names)
    assert len(state.name) == len(state.position) == len(state.velocity) == len(state.effort) == 9
    assert state.name[0] == "panda_joint1" and state.name[-1] == "panda_joint9"
    command = echo_pair.joint_command(command_names)
    assert list(command.name) == list(state.name[:7]) and len(command.effort) == 7
    assert len(command.position) == len(command.velocity) == 0      # as the controller's: efforts only
    # Without options: the thesis arm's two joints, as before.
    default = echo_pair.message_names(echo_pair.build_parser().parse_args(["both"]))
    assert default == (echo_pair.JOINT_NAMES, echo_pair.JOINT_NAMES)
    assert list(echo_pair.joint_state(default[0]).position) == [0.1, 0.2]
    for bad in (["--command-joints", "10"], ["--command-joints", "0"], ["--joints", "0"]):
        with pytest.raises(ValueError, match="--command-joints"):
            echo_pair.message_names(echo_pair.build_parser().parse_args(["both", "--joints", "9", *bad]))


def test_panda_echo_shape_is_the_panda_plants():
    """The echo pair's 9/7 joints are what the Panda's plant publishes and is commanded."""
    from cr_control import robots
    from cr_control.models.urdf import package_share
    from cr_sim.plants.registry import make_plant

    try:
        package_share("example-robot-data")
    except ValueError:
        pytest.skip("example-robot-data not installed")
    values = robots.plant_values(robots.robot("panda"))
    plant = make_plant(values.pop("scenario"), values)
    args = echo_pair.build_parser().parse_args(["both", *PANDA.echo_args])
    state_names, command_names = echo_pair.message_names(args)
    assert len(state_names) == len(plant.joint_names) == 9
    assert len(command_names) == len(plant.command_joints) == 7
    assert all(name.startswith(args.joint_prefix) for name in plant.joint_names)


def test_layout_flags_refused_in_one_line_before_any_run(capsys):
    assert bm.main(["--only", "panda", "--only-recorder-load"]) == 2
    assert bm.main(["--only", "panda", "--skip-panda"]) == 2
    assert bm.main(["--only", "recorder", "--only", "panda", "--skip-recorder"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("cr_benchmark: ") for line in err)
    only = bm.build_parser().parse_args(["--only", "panda", "--only", "composed"]).only
    assert only == ["panda", "composed"]
    with pytest.raises(SystemExit):
        bm.build_parser().parse_args(["--only", "kuka"])
