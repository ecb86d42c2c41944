"""cr_sweep on a Ray cluster as a cluster runs: a head and a second node started as separate
``ray start`` processes (on 127.0.0.2 and 127.0.0.3: the loopback settings of docs/experiments.md, token
auth off for this local test cluster), the sweep joining through ``--address``. Checked: the
table equals the local run's bit for bit, the second node killed mid-sweep loses no point
(tasks are retried on the head), and ``ss`` sees no connection of any Ray process of the
test through an address other than loopback.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from ray_net import non_loopback, tree, with_cmdline

from cr_control.experiments import engine, table
from cr_control.experiments.points import points
from cr_control.experiments.spec import parse_spec
from cr_control.experiments.sweep import jobs_of

ROOT = Path(__file__).resolve().parents[1]
RAY = str(Path(sys.executable).with_name("ray"))
HEAD, NODE = "127.0.0.2", "127.0.0.3"
SPEC = {"scheme": "adaptive_impedance", "duration": 1.5,
        "vary": {"plant.stiffness": [50.0, 75.0, 150.0, 300.0, 600.0, 900.0],
                 "adaptive_impedance.Q_c": [5, 50]},
        "metrics": ["pos_err_rms_last_half_m", "f_err_x_rms_N"]}

pytestmark = [pytest.mark.ros, pytest.mark.skipif(shutil.which("ss") is None, reason="needs ss (iproute2)")]


def _env() -> dict[str, str]:
    env = dict(os.environ, RAY_AUTH_MODE="disabled", RAY_USAGE_STATS_ENABLED="0")
    env.pop("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", None)     # =0 refuses a second node
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return env


def _free_port(host: str) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _kill(pids: set[int], grace: float) -> None:
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 0.0)):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        time.sleep(wait)


@pytest.fixture
def cluster():
    """A head on HEAD and a second node on NODE (1 CPU each); every process of it is found
    by the cluster's own temp dir and killed by pid afterwards."""
    temp = tempfile.mkdtemp(prefix="rt", dir="/tmp")      # short: Ray's socket paths
    port = _free_port(HEAD)
    common = ["--num-cpus=1", "--disable-usage-stats"]
    try:
        subprocess.run([RAY, "start", "--head", f"--node-ip-address={HEAD}", f"--port={port}",
                        "--include-dashboard=false", f"--temp-dir={temp}", *common],
                       env=_env(), check=True, capture_output=True, timeout=180)
        subprocess.run([RAY, "start", f"--address={HEAD}:{port}", f"--node-ip-address={NODE}",
                        *common], env=_env(), check=True, capture_output=True, timeout=180)
        yield f"{HEAD}:{port}", temp
    finally:
        _kill(tree(with_cmdline(temp)), 3.0)
        shutil.rmtree(temp, ignore_errors=True)


def test_sweep_through_a_cluster_equals_the_local_run_and_survives_a_node_kill(cluster, tmp_path):
    address, temp = cluster
    spec_file = tmp_path / "spec.yaml"
    spec_file.write_text(json.dumps(SPEC))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "cr_control.experiments.sweep", str(spec_file),
                             "--out", str(out), "--address", address, "--quiet", "--no-plots"],
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    bad: list[str] = []
    wildcard = 0
    killed_after = None
    deadline = time.monotonic() + 240
    checked = 0.0
    while proc.poll() is None and time.monotonic() < deadline:
        if time.monotonic() - checked > 1.0:         # ss: about once a second
            found, listeners = non_loopback(tree(with_cmdline(temp) + [proc.pid]))
            bad += found
            wildcard = max(wildcard, listeners)
            checked = time.monotonic()
        done = out / "points.jsonl"
        lines = done.read_text().count("\n") if done.exists() else 0
        if killed_after is None and lines:
            node = [p for p in with_cmdline(f"--node_ip_address={NODE}")
                    if "raylet" in Path(f"/proc/{p}/cmdline").read_bytes().decode(errors="replace")]
            _kill(tree(node), 0.0)          # the second node dies with its workers
            killed_after = lines
        time.sleep(0.1)
    output = proc.communicate(timeout=30)[0] if proc.poll() is not None else ""
    if proc.returncode is None:
        proc.kill()
        pytest.fail("the sweep did not finish in 240 s")
    assert proc.returncode == 0, output
    assert killed_after is not None and killed_after < 12, killed_after
    # every point, and the same table as the local run (the offline loop in this process)
    spec, targets = parse_spec(SPEC)
    local = engine.run_chunk(spec.scheme, None, spec.duration,
                             jobs_of(spec, targets, points(spec, targets)))
    table.write(tmp_path, local, list(spec.vary), spec.metrics)
    assert (out / "results.csv").read_bytes() == (tmp_path / "results.csv").read_bytes()
    assert not bad, bad
    print(f"cluster sweep: second node killed after {killed_after} of 12 points, none lost; "
          f"0 connections off loopback; {wildcard} wildcard listeners of the test cluster "
          "(gcs_server/raylet bind all interfaces unless the node IP is 127.0.0.1)")
