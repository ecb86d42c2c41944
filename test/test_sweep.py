"""cr_sweep (cr_control.experiments): SPEC errors as one line, the same table bit for bit on
1 and 2 workers and as plain in-process evaluation, resuming after a kill (only the missing
points computed), every socket of the local Ray instance on loopback (ss).

The local Ray instance is started once for the module (2 CPUs, loopback only: see
cr_control.experiments.engine); the points are 0.3 s of the chapter 3 plane.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from ray_net import non_loopback, tree

from cr_control.experiments import engine, store
from cr_control.experiments.points import points
from cr_control.experiments.spec import SpecError, parse_spec
from cr_control.experiments.sweep import jobs_of, main, sweep

SPEC = {"scheme": "adaptive_impedance", "duration": 0.3,
        "vary": {"plant.stiffness": [75.0, 150.0, 600.0], "adaptive_impedance.Q_c": [5, 50]},
        "metrics": ["pos_err_rms_last_half_m", "f_err_x_rms_N", "tau_peak_joint1_Nm"]}

@pytest.mark.parametrize("change, message", [
    ({"vary": {"adaptive_impedance.Q_zz": [1]}}, "unknown parameter 'Q_zz' of adaptive_impedance"),
    ({"vary": {"robot_arm.Q_c": [1]}}, "no node 'robot_arm'"),
    ({"vary": {"adaptive_impedance.Q_c": [5, -1]}}, "Q_c must be positive definite"),
    ({"vary": {"plant.stiffness": [1e9]}}, "plant: stiffness is out of bounds"),
    ({"vary": {"adaptive_impedance.Q_c": []}}, "the grid is empty"),
    ({"vary": {}}, "the grid is empty"),
    ({"vary": {"plant.stiffness": {"low": 1, "high": 10}}}, "samples is needed"),
    ({"vary": {"plant.stiffness": {"low": 0, "high": 10, "log": True}}, "samples": 3, "seed": 1},
     "a log range needs low > 0"),
    ({"duration": -1}, "duration must be in"),
    ({"scheme": "nope"}, "unknown scheme 'nope'"),
    ({"colour": "red"}, "unknown key 'colour'"),
])
def test_a_bad_spec_is_one_clear_error(change, message):
    with pytest.raises(SpecError, match=message) as info:
        parse_spec({**SPEC, **change})
    assert "\n" not in str(info.value)


def test_bad_spec_on_the_command_line(tmp_path, capsys):
    path = tmp_path / "s.yaml"
    path.write_text("scheme: adaptive_impedance\nduration: 1\nvary: {plant.stiffness: [1e9]}\n")
    assert main([str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("cr_sweep: error: plant: stiffness is out of bounds") and "\n" not in err
    assert main([str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "o")]) == 2


def test_unreachable_address_fails_fast(tmp_path, capsys):
    path = tmp_path / "s.yaml"
    path.write_text(json.dumps(SPEC))
    start = time.monotonic()
    assert main([str(path), "--out", str(tmp_path / "out"), "--address", "127.0.0.9:1",
                 "--quiet"]) == 1
    elapsed = time.monotonic() - start
    err = capsys.readouterr().err.strip()
    assert "cannot reach a Ray head" in err and "\n" not in err
    print(f"unreachable --address: exit after {elapsed:.1f} s")
    assert elapsed < engine.CONNECT_TIMEOUT_S + 30      # imports on a loaded machine; no hang


def test_random_points_are_seeded():
    spec, targets = parse_spec({"scheme": "adaptive_impedance", "duration": 1.0,
                                "vary": {"plant.stiffness": {"low": 15, "high": 1500, "log": True},
                                         "adaptive_impedance.Q_c": [5, 50]},
                                "samples": 20, "seed": 3})
    a, b = points(spec, targets), points(spec, targets)
    assert a == b and len(a) == 20
    k = [p["plant.stiffness"] for _, p in a]
    assert all(15 <= x <= 1500 for x in k) and min(k) < 150 < max(k)
    assert {p["adaptive_impedance.Q_c"] for _, p in a} == {5, 50}
    other = parse_spec({**spec.canonical(), "set": {}, "seed": 4, "metrics": None})[0]
    assert points(other, targets) != a


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same sweep: in this process without Ray, then on Ray with one task in flight
    (1 point per task) and with two (3 points per task), then resumed after a 'kill'."""
    root = tmp_path_factory.mktemp("sweeps")
    spec, targets = parse_spec(SPEC)
    out = {}
    t0 = time.perf_counter()
    serial = engine.run_chunk(spec.scheme, None, spec.duration,
                              jobs_of(spec, targets, points(spec, targets)))
    out["serial_s"] = time.perf_counter() - t0
    out["serial"] = serial
    engine.start(None, 2)
    try:
        for name, workers, chunk in (("one", 1, 1), ("two", 2, 3)):
            t0 = time.perf_counter()
            out[name] = sweep(spec, targets, root / name, workers=workers, chunk=chunk,
                              show_progress=False)
            out[f"{name}_s"] = time.perf_counter() - t0
        # a killed sweep: 2 points on disk and a line cut short by the kill
        killed = root / "killed"
        killed.mkdir()
        (killed / store.SPEC_FILE).write_text((root / "two" / store.SPEC_FILE).read_text())
        lines = (root / "two" / store.POINTS_FILE).read_text().splitlines(keepends=True)
        (killed / store.POINTS_FILE).write_text("".join(lines[:2]) + lines[2][:40])
        out["resumed"] = sweep(spec, targets, killed, workers=2, show_progress=False)
        out["net"] = non_loopback(tree([os.getpid()]))     # Ray's processes are our children
    finally:
        engine.stop()
    out["root"] = root
    return out


@pytest.mark.ros
def test_same_table_on_any_number_of_workers(runs):
    root: Path = runs["root"]
    one = runs["one"]
    assert len(one.rows) == 6 and [r["point"] for r in one.rows] == list(range(6))
    assert all(r["status"] == "ok" for r in one.rows)
    assert (root / "one" / "results.csv").read_bytes() == (root / "two" / "results.csv").read_bytes()
    assert pq.read_table(root / "one" / "results.parquet").equals(
        pq.read_table(root / "two" / "results.parquet"))
    # and the same numbers as the offline loop in this process, without Ray
    serial = {r["point"]: r["result"] for r in runs["serial"]}
    for row in one.rows:
        for metric in SPEC["metrics"]:
            assert row[metric] == serial[row["point"]][metric], (row["point"], metric)
    # the inputs reach the run: a 10x faster c_hat adaptation cuts the error
    by = {(r["plant.stiffness"], r["adaptive_impedance.Q_c"]): r for r in one.rows}
    assert by[(150.0, 50)]["pos_err_rms_last_half_m"] < 0.5 * by[(150.0, 5)]["pos_err_rms_last_half_m"]
    assert {p.name for p in one.figures} == {f"{m}.png" for m in SPEC["metrics"]}
    header = (root / "one" / "results.csv").read_text().splitlines()[0].split(",")
    assert header == ["point", "plant.stiffness", "adaptive_impedance.Q_c", "status", "reason",
                      *SPEC["metrics"]]
    print(f"6 points of {SPEC['duration']} s: in process {runs['serial_s']:.1f} s, Ray 1 task in "
          f"flight {runs['one_s']:.1f} s, 2 in flight {runs['two_s']:.1f} s")


@pytest.mark.ros
def test_local_ray_listens_and_connects_on_loopback_only(runs):
    bad, wildcard = runs["net"]
    assert not bad and wildcard == 0, (bad, wildcard)


@pytest.mark.ros
def test_resume_computes_only_the_missing_points(runs):
    resumed, root = runs["resumed"], runs["root"]
    assert (resumed.computed, resumed.skipped) == (4, 2)
    assert (root / "killed" / "results.csv").read_bytes() == (root / "two" / "results.csv").read_bytes()
    # a rerun of a finished sweep computes nothing and needs no Ray
    spec, targets = parse_spec(SPEC)
    again = sweep(spec, targets, root / "killed", show_progress=False, plot=False)
    assert (again.computed, again.skipped) == (0, 6)


@pytest.mark.ros
def test_another_spec_in_the_same_directory_is_refused(runs):
    spec, targets = parse_spec({**SPEC, "duration": 0.4})
    with pytest.raises(SpecError, match="holds another sweep"):
        sweep(spec, targets, runs["root"] / "one", show_progress=False)

