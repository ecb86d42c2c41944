"""cr_fuzz's inputs suite in CI: every hostile robot description, file and command line of
:mod:`cr_control.tools.fuzz_inputs`, its tool run as a process of its own under resource
limits (no ROS session): exit code, one line, no traceback, peak memory below
PEAK_MEMORY_MB. The messages' details are the in-process tests' (test_robot_descriptions,
test_hostile_files); these show what a user meets at the command line.

Before, of these inputs: a 4000-link chain or tree crashed cr_session with SIGSEGV; a
1e300 m origin, zero, negative or NaN masses and limits started a session; a params file
was read whole whatever its size, and a named pipe as a params file hung cr_session; a
flipped bit inside an MCAP chunk was decoded as a value (0.1 rad/s read as 1.8e307 rad/s).
"""

from __future__ import annotations

import math
import struct
import sys
import time
from pathlib import Path

import pytest
from robot_data import example_robot_data_installed

from cr_control.analysis.session_file import load_session
from cr_control.tools import fuzz_inputs as fi

CASES = {case.name: case for case in fi.INPUT_CASES}


@pytest.mark.parametrize("name", fi.INPUT_CASE_NAMES)
def test_every_hostile_input_is_refused_in_one_line(tmp_path, name):
    case = CASES[name]
    if case.kind == "description" and not example_robot_data_installed():
        pytest.skip("example-robot-data not installed")
    row = fi.run_input(case, tmp_path)
    print(f"\n{name}: exit {row.exit_code} in {row.seconds:.1f} s, peak {row.peak_mb:.0f} MiB: "
          f"{row.line}")
    assert row.verdict == "refused", (row.verdict, row.line)
    assert row.exit_code == case.exit_code and row.error_lines == 1 and not row.traceback
    assert row.peak_mb < fi.PEAK_MEMORY_MB


def test_the_suite_covers_each_kind_and_every_name_once():
    kinds = {case.kind for case in fi.INPUT_CASES}
    assert kinds == {"description", "file", "command line"}
    assert len(set(fi.INPUT_CASE_NAMES)) == len(fi.INPUT_CASE_NAMES) >= 30


ROW = dict(case="x", kind="file", exit_code=2, seconds=1.0, peak_mb=100.0,
           line="cr_analyze: error: x: not a regular file", error_lines=1, traceback=False)
CASE = fi.InputCase("x", "file", "x", lambda folder: [], "not a regular file", 2)


@pytest.mark.parametrize("changes, reason", [
    ({}, None),
    ({"hung": True, "exit_code": -9}, "still running after 60 s"),
    ({"exit_code": -11}, "killed by signal 11"),
    ({"traceback": True, "error_lines": 5}, "a traceback"),
    ({"exit_code": 1}, "exit 1, not 2"),
    ({"error_lines": 0, "line": ""}, "0 error lines, not 1"),
    ({"line": "cr_analyze: error: something else"}, "the line does not say"),
    ({"peak_mb": 6000.0}, "peak memory 6000 MiB"),
    ({"peak_mb": math.nan}, "peak memory nan MiB"),
])
def test_the_verdict_names_the_first_failure(changes, reason):
    got = fi.input_verdict(fi.InputRow(**{**ROW, **changes}), CASE)
    assert got == "refused" if reason is None else got.startswith(f"FAILED: {reason}"), got


def test_argparse_usage_lines_are_not_error_lines():
    stderr = ("usage: cr_param [-h] [--timeout S]\n                {get,set,list} ...\n"
              "cr_param: error: argument --timeout: must be a number\n")
    assert fi._error_lines(stderr) == ["cr_param: error: argument --timeout: must be a number"]
    assert len(fi._error_lines("Traceback (most recent call last):\n  File x\nKeyError: 1\n")) == 3


def test_a_flipped_bit_was_read_as_a_value_before_the_crc_check(tmp_path):
    """The damage the CRC check catches: without it, the mcap reader decodes the chunk and
    one velocity of 0.1 rad/s reads 1.8e307 rad/s."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    path = tmp_path / "flipped.mcap"
    fi.flipped_bit_in_chunk(path)
    with open(path, "rb") as f:
        velocities = [v for *_, msg in make_reader(f, decoder_factories=[DecoderFactory()])
                      .iter_decoded_messages() for v in msg.velocity]
    wrong = [v for v in velocities if v not in (0.1, 0.2)]
    flipped = struct.unpack("<d", struct.pack("<Q", 0x7FB999999999999A))[0]   # 0x3fb9...: 0.1
    assert len(velocities) == 2 * 400 and wrong == [flipped] and 1.79e307 < flipped < 1.8e307
    with pytest.raises(Exception, match="fails its CRC-32 check"):
        load_session(path)


def test_a_chunk_without_a_stored_crc_is_read(tmp_path):
    """A CRC of 0 means none was stored (the MCAP format): such a chunk is read unchecked."""
    path = tmp_path / "no_crc.mcap"
    fi.write_states(path, compression="none")
    data = bytearray(path.read_bytes())
    for index in fi.chunk_indexes(path):
        data[index.chunk_start_offset + 33:index.chunk_start_offset + 37] = struct.pack("<I", 0)
    path.write_bytes(bytes(data))
    session = load_session(path)
    assert len(session.joint_states.time) == 400 and not session.warnings


def test_a_hanging_tool_is_killed_with_its_children(tmp_path, monkeypatch):
    """A tool that never returns (and started a child that would outlive it) is killed as a
    process group after WALL_LIMIT_S: its row says so."""
    child = tmp_path / "child.pid"
    hang = ("import subprocess, sys, time; "
            "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)']); "
            f"open({str(child)!r}, 'w').write(str(p.pid)); time.sleep(60)")
    monkeypatch.setattr(fi, "command", lambda name: [sys.executable, "-c", hang])
    monkeypatch.setattr(fi, "WALL_LIMIT_S", 5.0)      # the child's pid written well before
    row = fi.run_input(fi.InputCase("hang", "file", "x", lambda folder: ["x"], "x", 2), tmp_path)
    assert row.hung and row.exit_code == -9 and row.verdict == "FAILED: still running after 5 s"
    assert not running(int(child.read_text()))     # the child went with it


def running(pid: int) -> bool:
    """Whether process ``pid`` still runs (a zombie, dead but not reaped, does not)."""
    stat = Path(f"/proc/{pid}/stat")
    for _ in range(100):                           # SIGKILL to a group is delivered at once
        if not stat.exists() or stat.read_text().rsplit(")", 1)[1].split()[0] in "ZX":
            return False
        time.sleep(0.05)
    return True
