"""Hostile or careless input to the tools that read files and command lines: one clear line
and a non-zero exit, never a traceback or a hang, in bounded memory. Every input is built
here in tmp_path; no test starts ROS.

- cr_analyze: an MCAP file with a corrupt chunk, /joint_states recorded with another schema
  (two types on the topic, or a schema of that name with other fields), a schema that does
  not parse, a named pipe;
- cr_sweep / cr_tune: a YAML alias bomb, deep nesting, a file over 1 MiB, a named pipe, a
  long value quoted in a message;
- the recorder's writer: the disk full while writing (the partial file still reads);
- cr_identify_tool: a --node that is no node name (injected YAML), the params file's text;
  --timeout NaN, infinite, <= 0 or over an hour (cr_param and cr_lifecycle too).
"""

from __future__ import annotations

import errno
import io
import os
import struct
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from cr_control.analysis import analyze
from cr_control.analysis.session_file import load_session
from cr_control.core import ros_yaml, topics
from cr_control.experiments import sweep, tune
from cr_control.experiments.spec import SpecError, read_yaml
from cr_control.recording import mcap_writer, recorder
from cr_control.recording.mcap_writer import McapBagWriter
from cr_control.tools import identify_tool, lifecycle_tool, param_tool
from cr_control.tools.fuzz_inputs import (
    alias_bomb,
    corrupt_zstd_chunk,
    flipped_bit_in_chunk,
    foreign_schema,
    joint_state,
    two_types,
    write_states,
)
from cr_control.tools.fuzz_inputs import chunk_indexes as chunks

MESSAGES = 400


def one_error_line(capsys, prefix: str) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.count("\n") == 1 and err.startswith(prefix), err
    return err.strip()


# -- cr_analyze ---------------------------------------------------------------------------

def test_a_corrupt_compressed_chunk_is_one_line(tmp_path, capsys):
    path = tmp_path / "corrupt.mcap"
    corrupt_zstd_chunk(path)
    assert len(chunks(path)) >= 3
    assert analyze.main([str(path), "--no-plots"]) == 2
    line = one_error_line(capsys, f"cr_analyze: error: {path}: damaged MCAP file")
    assert "corrupt record" in line


def test_a_chunk_naming_an_unknown_channel_is_one_line(tmp_path, capsys):
    """An uncompressed chunk whose message names a channel the file does not have (what a
    flipped byte does to it), its CRC stored as 0 (none: unchecked, else the CRC check
    refuses it first): the mcap reader's KeyError, as one line."""
    path = tmp_path / "channel.mcap"
    write_states(path, compression="none")
    data = bytearray(path.read_bytes())
    middle = chunks(path)[len(chunks(path)) // 2]
    head = struct.pack("<BQH", 0x05, 22 + len(joint_state(0)), 1)      # a Message on channel 1
    at = data.index(head, middle.chunk_start_offset)
    data[at + 9:at + 11] = struct.pack("<H", 0xBEEF)
    crc = middle.chunk_start_offset + 33               # opcode, length, 3 x u64, then the CRC
    data[crc:crc + 4] = struct.pack("<I", 0)
    path.write_bytes(bytes(data))
    assert analyze.main([str(path), "--no-plots"]) == 2
    line = one_error_line(capsys, f"cr_analyze: error: {path}: damaged MCAP file")
    assert "KeyError" in line


def test_a_flipped_bit_inside_a_chunk_is_one_line(tmp_path, capsys):
    """One bit of a velocity flipped inside an uncompressed chunk (the message still decodes:
    0.1 rad/s as 1.8e307 rad/s): the chunk's CRC-32 refuses it."""
    path = tmp_path / "flipped.mcap"
    flipped_bit_in_chunk(path)
    assert analyze.main([str(path), "--no-plots"]) == 2
    line = one_error_line(capsys, f"cr_analyze: error: {path}: damaged MCAP file, a chunk's data "
                                  "fails its CRC-32 check (stored 0x")
    assert line.endswith("): changed since it was written")


def test_joint_states_recorded_with_two_types_is_one_line(tmp_path, capsys):
    path = tmp_path / "two_types.mcap"
    two_types(path)
    assert analyze.main([str(path), "--no-plots"]) == 2
    line = one_error_line(capsys, f"cr_analyze: error: {path}: /joint_states")
    assert "two types" in line and "std_msgs/msg/Float64MultiArray" in line


def test_joint_states_with_a_schema_of_other_fields_is_one_line(tmp_path, capsys):
    path = tmp_path / "other_schema.mcap"
    foreign_schema(path)
    assert analyze.main([str(path), "--no-plots"]) == 2
    line = one_error_line(capsys, f"cr_analyze: error: {path}: /joint_states")
    assert "schema is not ROS's" in line


def test_a_schema_that_does_not_parse_is_one_line(tmp_path, capsys):
    from mcap.writer import Writer

    path = tmp_path / "garbage_schema.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start("ros2", "test")
        schema = w.register_schema("sensor_msgs/msg/JointState", "ros2msg", b"int32[ !!garbage")
        channel = w.register_channel(topics.JOINT_STATES, "cdr", schema)
        w.add_message(channel, 1, joint_state(0), 1)
        w.finish()
    assert analyze.main([str(path), "--no-plots"]) == 2
    line = one_error_line(capsys, f"cr_analyze: error: {path}: /joint_states")
    assert "does not parse" in line


class _Unblock:
    """Opens a named pipe for writing after a delay, so that a reader blocked on it (the
    bug) returns and the test fails instead of hanging."""

    def __init__(self, fifo: Path, delay_s: float = 20.0) -> None:
        self.stop = threading.Event()

        def run() -> None:
            if not self.stop.wait(delay_s):
                with open(fifo, "wb"):
                    pass

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()

    def __enter__(self) -> _Unblock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()


def test_a_named_pipe_is_refused_without_waiting(tmp_path, capsys):
    fifo = tmp_path / "session.mcap"
    os.mkfifo(fifo)
    with _Unblock(fifo):
        assert analyze.main([str(fifo), "--no-plots"]) == 2
    assert one_error_line(capsys, f"cr_analyze: error: {fifo}: not a regular file")


# -- cr_sweep, cr_tune: YAML ---------------------------------------------------------------

def test_any_alias_is_refused_with_where_it_is():
    with pytest.raises(yaml.YAMLError) as info:
        ros_yaml.load("a: &x 1.0\nb: *x\n")
    assert ros_yaml.describe_error(info.value) == (
        "alias *x refused: aliases are not accepted, write the value out (line 2, column 4)")
    assert ros_yaml.load("a: &x 1.0\n") == {"a": 1.0}          # an anchor alone is harmless


def test_an_alias_bomb_spec_is_one_short_line(tmp_path, capsys):
    """Six levels (10^6 values if expanded: a regression costs memory, not the machine)."""
    path = tmp_path / "bomb.yaml"
    path.write_text("scheme: adaptive_impedance\nduration: 1.0\nvary: {plant.stiffness: [1.0]}\n"
                    "robot:\n" + "".join(f"  {line}\n" for line in alias_bomb(6).splitlines()))
    assert sweep.main([str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    line = one_error_line(capsys, f"cr_sweep: error: {path}: not valid YAML: alias *a0 refused")
    assert len(line) < 300
    with pytest.raises(SpecError, match="alias"):
        tune.load(path)


def test_deep_nesting_is_refused():
    with pytest.raises(yaml.YAMLError) as info:
        ros_yaml.load("[" * 10_000 + "]" * 10_000)
    assert "nested deeper than 64 levels" in ros_yaml.describe_error(info.value)


def test_a_file_over_1_mib_is_refused(tmp_path, capsys):
    path = tmp_path / "big.yaml"
    path.write_text("# " + "x" * ros_yaml.MAX_FILE_BYTES + "\n")
    assert sweep.main([str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert one_error_line(capsys, f"cr_sweep: error: {path}: larger than 1 MiB")


def test_a_named_pipe_or_device_as_spec_is_refused(tmp_path):
    fifo = tmp_path / "spec.yaml"
    os.mkfifo(fifo)
    with _Unblock(fifo), pytest.raises(SpecError, match="not a regular file"):
        read_yaml(fifo)
    with pytest.raises(SpecError, match="not a regular file"):
        read_yaml("/dev/zero")
    with pytest.raises(SpecError, match="is a directory"):
        read_yaml(tmp_path)
    bad = tmp_path / "latin1.yaml"
    bad.write_bytes(b"scheme: \xe9\n")
    with pytest.raises(SpecError, match="not UTF-8"):
        read_yaml(bad)


@pytest.mark.parametrize("line", [
    "robot: [" + ", ".join(["1"] * 50_000) + "]",           # a long value
    "robot: " + "r" * 200_000,                               # a long name
    "? colour" + "r" * 200_000 + "\n: 1",                    # a long unknown key
    "set:\n  ? plant." + "k" * 200_000 + "\n  : 1",          # a long parameter name
])
def test_a_long_value_is_cut_in_the_message(tmp_path, capsys, line):
    path = tmp_path / "long.yaml"
    path.write_text(f"scheme: adaptive_impedance\nduration: 1.0\nvary: {{plant.stiffness: [1.0]}}\n"
                    f"{line}\n")
    assert sweep.main([str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    message = one_error_line(capsys, "cr_sweep: error: ")
    assert len(message) < 400 and "..." in message


# -- the recorder: the disk full -----------------------------------------------------------

def disk_holding(monkeypatch, capacity: int) -> None:
    """McapBagWriter's file on a disk that holds ``capacity`` bytes: writes beyond are cut
    short, then raise ENOSPC, as a full file system does."""

    class FullDisk(io.FileIO):
        def write(self, data) -> int:
            room = capacity - self.tell()
            if room <= 0:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return super().write(memoryview(data)[:room])

    monkeypatch.setattr(mcap_writer, "open", lambda path, mode, buffering: io.BufferedWriter(
        FullDisk(path, mode), buffering), raising=False)


@pytest.mark.parametrize("share", [0.3, 0.7])
def test_disk_full_while_recording_leaves_a_readable_file(tmp_path, monkeypatch, share):
    complete = tmp_path / "complete.mcap"
    write_states(complete, compression="none")
    capacity = int(share * complete.stat().st_size)  # the disk fills during the chunks
    disk_holding(monkeypatch, capacity)
    path = tmp_path / "full.mcap"
    with pytest.raises(OSError) as info:
        write_states(path, compression="none")
    assert info.value.errno == errno.ENOSPC
    size = path.stat().st_size
    assert 0 < size <= capacity
    session = load_session(path)                     # the project's reader: no exception
    assert 0 < len(session.joint_states.time) < MESSAGES
    # cut back to a whole record: the reading ends at the end of the file, not inside a record
    assert session.warnings == [f"file ends early (EndOfFile); read {len(session.joint_states.time)} "
                                "messages"]
    np.testing.assert_allclose(session.joint_states.position[:, 0],
                               0.001 * np.arange(len(session.joint_states.time)))


def test_disk_full_at_close_keeps_every_chunk(tmp_path, monkeypatch):
    complete = tmp_path / "complete.mcap"
    write_states(complete)
    disk_holding(monkeypatch, complete.stat().st_size - 200)    # the summary does not fit
    path = tmp_path / "full.mcap"
    writer = McapBagWriter(path, chunk_size=4096)
    channel = writer.add_topic(topics.JOINT_STATES, "sensor_msgs/msg/JointState", has_header=True)
    for i in range(MESSAGES):
        writer.write(channel, joint_state(i), 1_000_000_000 + i * 1_000_000)
    with pytest.raises(OSError):
        writer.close()
    assert writer.error is not None and writer.error.errno == errno.ENOSPC
    writer.close()                                   # closed already: nothing more, no error
    with pytest.raises(OSError):                     # later writes say so again
        writer.add_metadata("late", {"a": "b"})
    session = load_session(path)
    assert len(session.joint_states.time) == MESSAGES
    assert "ends early" in session.warnings[0]


def test_the_recorder_reports_a_full_disk_in_one_line(tmp_path, monkeypatch):
    """record_to_file (what the recorder's main runs): the OSError that stopped the writing
    is returned, not raised; the file closed as far as it was written."""
    disk_holding(monkeypatch, 30_000)
    path = tmp_path / "session.mcap"
    writer = McapBagWriter(path, chunk_size=4096)
    channel = writer.add_topic(topics.JOINT_STATES, "sensor_msgs/msg/JointState", has_header=True)
    sent = iter(range(10**6))

    def take_all(flush: bool = False) -> int:
        for _ in range(50):
            i = next(sent)
            writer.write(channel, joint_state(i), 1_000_000_000 + i * 1_000_000)
        return 50

    node = SimpleNamespace(writer=writer, take_all=take_all, poll=lambda: None)
    executor = SimpleNamespace(spin_until_future_complete=lambda future, timeout_sec: None)
    failure = recorder.record_to_file(node, executor, recorder._StopRequest())
    assert isinstance(failure, OSError) and failure.errno == errno.ENOSPC
    line = recorder.write_failure(path, failure)
    assert "\n" not in line and f"stopped recording to {path}: the disk is full" in line
    assert len(load_session(path).joint_states.time) > 0
    other = recorder.write_failure(path, OSError(errno.EIO, os.strerror(errno.EIO)))
    assert "cannot write (Input/output error)" in other


# -- cr_identify_tool, cr_param, cr_lifecycle: command lines -------------------------------

@pytest.mark.parametrize("node", ["adaptive_impedance:\n  ros__parameters:\n    max_effort: 1e9\nx",
                                  "a b", "", "1abc", "/ns//x"])
def test_identify_tool_refuses_a_node_name_ros_would_not_take(tmp_path, capsys, node):
    out = tmp_path / "tool.yaml"
    assert identify_tool.main(["--node", node, "--out", str(out)]) == 2
    line = one_error_line(capsys, "cr_identify_tool: --node: invalid node name")
    assert len(line) < 300
    assert not out.exists()


def test_identify_tool_params_file_keeps_text_as_text():
    est = identify_tool.ToolEstimate(0.7, np.array([0.0, 0.001, 0.06]), np.arange(6.0), 0.01, 0.001)
    frame = 'link"\n    max_effort: 1e9'
    text = identify_tool.params_file("/ns/adaptive_impedance", frame, est, "a note\nx: {y: 1}")
    data = ros_yaml.load(text)
    assert list(data) == ["/ns/adaptive_impedance"]
    values = data["/ns/adaptive_impedance"]["ros__parameters"]
    assert set(values) == {"sensor_frame", "tool_mass", "tool_com", "ft_bias"}
    assert values["sensor_frame"] == frame and values["tool_mass"] == 0.7
    assert values["ft_bias"] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert text.startswith("# cr_identify_tool: a note x: {y: 1}\n")


@pytest.mark.parametrize("value", ["nan", "NaN", "inf", "-inf", "0", "-1", "3601", "1e300", "abc"])
@pytest.mark.parametrize("tool, argv", [
    (identify_tool.main, ["--controller", "/nobody"]),
    (param_tool.main, ["list", "/nobody"]),
    (lifecycle_tool.main, ["get", "/nobody"]),
])
def test_a_timeout_that_never_ends_is_refused(capsys, tool, argv, value):
    with pytest.raises(SystemExit) as info:
        tool([f"--timeout={value}", *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.splitlines()[-1].endswith(
        f"error: argument --timeout: must be a number of seconds > 0 and <= 3600, not {value!r}")


def test_a_timeout_in_range_is_taken():
    assert param_tool.timeout_seconds("0.5") == 0.5
    assert param_tool.timeout_seconds("3600") == 3600.0
