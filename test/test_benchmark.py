"""cr_benchmark's pure functions on synthetic input, and the echo pair for ~1 s.

No timing is asserted: only that the figures are parsed, combined and produced.
"""

import math
import subprocess
import sys

from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from cr_control.core import topics
from cr_control.core.ros_env import DOMAIN_SPAN, FIRST_DOMAIN
from cr_control.tools import benchmark as bm
from cr_control.tools.echo_pair import parse_result

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
    assert bm.parse_machine_stat(text) == 100 + 5 + 50 + 3 + 2 + 1
    assert bm.read_machine_ticks() is None or bm.read_machine_ticks() >= 0


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


def test_percentile():
    assert bm.percentile([3.0, 1.0, 2.0], 50) == 2.0
    assert bm.percentile([0.0, 10.0], 99) == 9.9
    assert math.isnan(bm.percentile([], 50))


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


def test_echo_pair_one_process_produces_cycles(ros_env):
    proc = subprocess.run([sys.executable, "-m", "cr_control.tools.echo_pair", "both", "--duration", "1"],
                          env=ros_env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = parse_result(proc.stdout)
    assert result is not None, proc.stdout + proc.stderr
    assert result["total_cycles"] > 0
    assert all(math.isfinite(v) for v in result.values())
    assert set(topics.PLANT_TIMING_FIELDS) <= set(result)
    assert bm.parse_done_line(proc.stdout + proc.stderr) is not None
