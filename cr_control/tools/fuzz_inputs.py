"""Hostile and careless input to the tools that read robot descriptions, files and command
lines: ``cr_fuzz --suite inputs``, and in CI ``test/test_fuzz_inputs.py`` (no ROS session).

Each case (:data:`INPUT_CASES`) writes its input into a folder and names the command that
reads it: a console script of this package and its arguments. The command runs as a process
of its own (a crash, a hang or a memory bomb cannot take the caller with it) under resource
limits: address space MEMORY_LIMIT_MB, CPU time CPU_LIMIT_S, killed after WALL_LIMIT_S. A
case is *refused* as it must be when the process exits with the case's code, prints no
traceback, and its stderr holds one line (argparse's usage lines aside) that gives the
case's reason; its row also says how long it took and its peak resident memory.

Robot descriptions go through ``cr_session``, which loads every node's URDF before it starts
anything (the same checks as the plant and the controllers:
:func:`cr_control.models.urdf.load_chain`); files through ``cr_analyze`` (MCAP), ``cr_sweep``
(a SPEC) and ``cr_session`` (params files); command lines through ``cr_identify_tool``,
``cr_param`` and ``cr_session``. The inputs are the Panda's URDF with one change, generated
chains and trees, MCAP files written as the recorder writes them and then damaged, and YAML.
"""

from __future__ import annotations

import importlib.metadata
import os
import resource
import signal
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from cr_control.core import topics

#: Limits of a case's process: address space (MiB), CPU time (s), wall time before it is
#: killed (s; a hang). A tool's start-up (numpy, Pinocchio, numba's LLVM) maps about
#: 1.5 GiB of address space; the alias bomb that grew cr_sweep to 6 GB stops far below.
MEMORY_LIMIT_MB = 4096
CPU_LIMIT_S = 60
WALL_LIMIT_S = 60.0
#: A refused case's peak resident memory must stay below this (MiB).
PEAK_MEMORY_MB = 1024

PANDA_FILE = "package://example-robot-data/robots/panda_description/urdf/panda.urdf"
PANDA_BASE, PANDA_TIP = "panda_link0", "panda_hand_tcp"
#: The Panda's link 7 inertial (mass and inertia), as its URDF writes it.
LINK7 = ('<mass value="0.735522"/>\n            <inertia ixx="0.012516" ixy="-0.000428" '
         'ixz="-0.001196" iyy="0.010027" iyz="-0.000741" izz="0.004815"/>')


# -- the inputs --------------------------------------------------------------------------

@cache
def panda_urdf() -> str:
    """The Panda's URDF (example-robot-data)."""
    from cr_control.models.urdf import resolve_urdf_file

    return resolve_urdf_file(PANDA_FILE).read_text()


def panda_with(old: str, new: str) -> str:
    """The Panda's URDF with the first ``old`` replaced by ``new``."""
    text = panda_urdf()
    if old not in text:
        raise ValueError(f"not in the Panda's URDF: {old!r}")
    return text.replace(old, new, 1)


def chain(depth: int, branches: bool = False) -> str:
    """A URDF chain of ``depth`` revolute joints (base_link ... l<depth>, tool0); with
    ``branches`` every link also carries a side link on a joint of its own (a tree)."""
    inertial = ('<inertial><origin xyz="0 0 0.05"/><mass value="0.1"/><inertia ixx="1e-4" ixy="0" '
                'ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial>')
    parts = ['<?xml version="1.0"?><robot name="chain"><link name="base_link"/>']

    def joint(name: str, parent: str, child: str) -> str:
        return (f'<link name="{child}">{inertial}</link><joint name="{name}" type="revolute">'
                f'<parent link="{parent}"/><child link="{child}"/><origin xyz="0 0 0.01"/>'
                '<axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>')

    for i in range(1, depth + 1):
        parent = "base_link" if i == 1 else f"l{i - 1}"
        parts.append(joint(f"j{i}", parent, f"l{i}"))
        if branches:
            parts.append(joint(f"b{i}", parent, f"s{i}"))
    parts.append(f'<link name="tool0"/><joint name="tool0_joint" type="fixed"><parent link="l{depth}"/>'
                 '<child link="tool0"/></joint></robot>')
    return "".join(parts)


def entity_bomb(levels: int = 9) -> str:
    """The Panda's URDF with the "billion laughs": ``levels`` entities of ten of the one
    before, 10^levels copies of "lol" if expanded."""
    decls = ['<!ENTITY e0 "lol">'] + [f'<!ENTITY e{i} "{f"&e{i - 1};" * 10}">'
                                      for i in range(1, levels)]
    robot = panda_urdf()[panda_urdf().index("<robot"):]
    return (f'<?xml version="1.0"?><!DOCTYPE robot [{"".join(decls)}]>'
            + robot.replace("</robot>", f"<gazebo>&e{levels - 1};</gazebo></robot>"))


def external_entity() -> str:
    """The Panda's URDF naming /etc/passwd as an external entity in a link's name."""
    robot = panda_urdf()[panda_urdf().index("<robot"):]
    return ('<?xml version="1.0"?><!DOCTYPE robot [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
            + robot.replace("</robot>", "<gazebo>&x;</gazebo></robot>"))


def alias_bomb(levels: int) -> str:
    """``levels`` lists of ten aliases of the one before: 10^levels values in a few lines."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, levels)]
    return "\n".join(lines) + "\n"


JOINTS = ["joint1", "joint2"]


def joint_state(i: int) -> bytes:
    """The ``i``-th of a recording's joint states, serialized (CDR)."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    msg = JointState(name=JOINTS, position=[0.001 * i, -0.001 * i], velocity=[0.1, 0.2])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + i // 1000, (i % 1000) * 1_000_000
    return serialize_message(msg)


def write_states(path: Path, compression: str = "zstd", n: int = 400):
    """``n`` joint states on /joint_states in small chunks (several of them), written as the
    recorder writes them; the closed writer."""
    from cr_control.recording.mcap_writer import McapBagWriter

    writer = McapBagWriter(path, compression=compression, chunk_size=4096)
    channel = writer.add_topic(topics.JOINT_STATES, "sensor_msgs/msg/JointState", has_header=True)
    for i in range(n):
        writer.write(channel, joint_state(i), 1_000_000_000 + i * 1_000_000)
    writer.close()
    return writer


def chunk_indexes(path: Path) -> list:
    """The chunk indexes of an MCAP file's summary."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return make_reader(f).get_summary().chunk_indexes


def corrupt_zstd_chunk(path: Path) -> None:
    """States in zstd chunks, the middle chunk's frame header and first block header
    overwritten (a zstd frame carries no checksum of its data)."""
    write_states(path)
    middle = chunk_indexes(path)[len(chunk_indexes(path)) // 2]
    data = bytearray(path.read_bytes())
    at = middle.chunk_start_offset + 53          # the chunk's fields with "zstd", then the frame
    if data[at:at + 4] != b"\x28\xb5\x2f\xfd":
        raise ValueError("no zstd frame where the chunk's data begins")
    data[at + 4:at + 36] = b"\xa5" * 32
    path.write_bytes(bytes(data))


def flipped_bit_in_chunk(path: Path) -> None:
    """States in uncompressed chunks, one bit of a velocity inside the middle chunk flipped:
    the message still decodes, its 0.1 rad/s read as 1.8e307 rad/s (the chunk's CRC-32 no longer
    matches)."""
    write_states(path, compression="none")
    middle = chunk_indexes(path)[len(chunk_indexes(path)) // 2]
    data = bytearray(path.read_bytes())
    at = data.index(struct.pack("<d", 0.1), middle.chunk_start_offset)
    data[at + 7] ^= 0x40                          # the exponent's top bit: 0x3fb9... -> 0x7fb9...
    path.write_bytes(bytes(data))


def two_types(path: Path) -> None:
    """/joint_states recorded once as a JointState and once as a Float64MultiArray."""
    from mcap.writer import Writer
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64MultiArray

    from cr_control.recording.definitions import message_definition

    with open(path, "wb") as f:
        w = Writer(f)
        w.start("ros2", "cr_fuzz")
        for i, (type_name, data) in enumerate((
                ("sensor_msgs/msg/JointState", joint_state(0)),
                ("std_msgs/msg/Float64MultiArray", serialize_message(Float64MultiArray(data=[1.0]))))):
            encoding, text = message_definition(type_name)
            schema = w.register_schema(type_name, encoding, text.encode())
            channel = w.register_channel(topics.JOINT_STATES, "cdr", schema)
            w.add_message(channel, i, data, i)
        w.finish()


def foreign_schema(path: Path) -> None:
    """/joint_states under a schema named sensor_msgs/msg/JointState with other fields."""
    from mcap_ros2.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        schema = w.register_msgdef("sensor_msgs/msg/JointState", "string data")
        for i in range(3):
            w.write_message(topics.JOINT_STATES, schema, {"data": "x"}, log_time=i, publish_time=i)
        w.finish()


# -- the cases -----------------------------------------------------------------------------

@dataclass(frozen=True)
class InputCase:
    """One hostile input: ``build(folder)`` writes it and returns the command that reads it
    (a console script's name, then its arguments); the process must exit with ``exit_code``
    and its one stderr line contain ``reason``."""

    name: str
    kind: str           # "description", "file" or "command line"
    what: str
    build: Callable[[Path], list[str]]
    reason: str
    exit_code: int


def _file(folder: Path, name: str, content: str | bytes) -> Path:
    path = folder / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    return path


def _fifo(folder: Path, name: str) -> Path:
    path = folder / name
    os.mkfifo(path)
    return path


def _session(folder: Path, *args: str) -> list[str]:
    """cr_session on the Panda with a wrist sensor, unrecorded, sessions under ``folder``."""
    return ["cr_session", "--robot", "panda_ft", "--no-record", "--duration", "1",
            "--out", str(folder / "sessions"), *args]


def _description(xml: Callable[[], str | bytes], node: str = "plant",
                 chain_ends: tuple[str, str] | None = None) -> Callable[[Path], list[str]]:
    """cr_session with ``node``'s urdf_file a file holding ``xml()`` (and its chain's ends);
    ``xml`` is called when the case is built, not when this module is imported."""
    def build(folder: Path) -> list[str]:
        path = _file(folder, "robot.urdf", xml())
        ends = [f"{node}.base_link={chain_ends[0]}", f"{node}.tip_link={chain_ends[1]}"] \
            if chain_ends else []
        return _session(folder, "-p", f"{node}.urdf_file={path}",
                        *[arg for end in ends for arg in ("-p", end)])
    return build


def _params(content: Callable[[Path], Path]) -> Callable[[Path], list[str]]:
    return lambda folder: _session(folder, "--params-file", str(content(folder)))


def _analyze(write: Callable[[Path], None]) -> Callable[[Path], list[str]]:
    def build(folder: Path) -> list[str]:
        path = folder / "session.mcap"
        write(path)
        return ["cr_analyze", str(path), "--no-plots"]
    return build


def _sweep(content: Callable[[Path], Path]) -> Callable[[Path], list[str]]:
    return lambda folder: ["cr_sweep", str(content(folder)), "--out", str(folder / "out"), "--quiet"]


SPEC_HEAD = "scheme: adaptive_impedance\nduration: 1.0\nvary: {plant.stiffness: [1.0]}\n"
LINK7_ZERO = ('<mass value="0"/>\n            <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" '
              'izz="0"/>')
NODE_NEWLINE = "adaptive_impedance:\n  ros__parameters:\n    max_effort: 1e9\nx"
CHAIN_ENDS = ("base_link", "tool0")

INPUT_CASES = [
    # -- robot descriptions (cr_session loads every node's URDF before it starts anything)
    InputCase("urdf_chain_4000", "description", "a chain 4000 links deep (SIGSEGV in Pinocchio)",
              _description(lambda: chain(4000), chain_ends=CHAIN_ENDS),
              "the URDF has 4002 links: more than the 500", 1),
    InputCase("urdf_tree_4000", "description", "a tree 4000 links deep",
              _description(lambda: chain(4000, branches=True), chain_ends=CHAIN_ENDS),
              "the URDF has 8002 links", 1),
    InputCase("urdf_origin_1e300", "description", "a joint origin of 1e300 m (NaN states)",
              _description(lambda: panda_with('xyz="0 0 0.333"', 'xyz="0 0 1e300"')),
              "places a frame 1e+300 m from its parent", 1),
    InputCase("urdf_origin_1e300_controller", "description",
              "the controller's URDF with a joint origin of 1e300 m",
              _description(lambda: panda_with('xyz="0 0 0.333"', 'xyz="0 0 1e300"'),
                           node="adaptive_impedance"),
              "adaptive_impedance: joint 'panda_joint1'", 1),
    InputCase("urdf_zero_mass", "description", "zero mass and inertia on the Panda's link 7",
              _description(lambda: panda_with(LINK7, LINK7_ZERO)),
              "moves link 'panda_link7', which has mass 0 kg", 1),
    InputCase("urdf_negative_mass", "description", "a negative mass",
              _description(lambda: panda_with('<mass value="3.228604"/>',
                                                    '<mass value="-3.228604"/>')),
              "a link's mass must be >= 0", 1),
    InputCase("urdf_inertia_not_pd", "description", "an inertia with a negative principal moment",
              _description(lambda: panda_with('izz="0.004815"', 'izz="-0.004815"')),
              "is not positive semi-definite", 1),
    InputCase("urdf_lower_above_upper", "description", "a lower position limit above the upper",
              _description(lambda: panda_with('lower="-2.8973" upper="2.8973"',
                                                    'lower="2.8973" upper="-2.8973"')),
              "the lower position limit is above the upper one", 1),
    InputCase("urdf_effort_limit_0", "description", "an effort limit of 0",
              _description(lambda: panda_with('effort="12.0"', 'effort="0"')),
              "an effort limit must be > 0", 1),
    InputCase("urdf_velocity_limit_0", "description", "a velocity limit of 0",
              _description(lambda: panda_with('velocity="2.61"', 'velocity="0"')),
              "a velocity limit must be > 0", 1),
    InputCase("urdf_limit_nan", "description", "a NaN velocity limit",
              _description(lambda: panda_with('velocity="2.61"', 'velocity="nan"')),
              "<limit velocity=\"nan\"> needs a finite number", 1),
    InputCase("urdf_entity_bomb", "description", "the billion laughs (10^9 x 'lol')",
              _description(entity_bomb), "the URDF declares an entity", 1),
    InputCase("urdf_external_entity", "description", "an external entity (file:///etc/passwd)",
              _description(external_entity), "the URDF declares an entity", 1),
    InputCase("urdf_not_utf8", "description", "a URDF in Latin-1 (a link named 'bras\\xe9')",
              _description(lambda: panda_with('name="panda_link8"', 'name="bras\xe9"')
                                 .encode("latin-1")),
              "cannot read it ('utf-8' codec can't decode byte 0xe9", 1),
    InputCase("urdf_5_mib", "description", "a URDF of 5 MiB (a comment)",
              _description(lambda: panda_urdf() + "<!--" + "x" * (5 << 20) + "-->"),
              "more than the 4 MiB", 1),
    InputCase("urdf_fifo", "description", "urdf_file a named pipe (a reader would wait for ever)",
              lambda folder: _session(folder, "-p", f"plant.urdf_file={_fifo(folder, 'r.urdf')}"),
              "not a regular file", 1),
    # -- files
    InputCase("mcap_corrupt_chunk", "file", "an MCAP file whose zstd chunk is damaged",
              _analyze(corrupt_zstd_chunk), "damaged MCAP file, stopped at a corrupt record", 2),
    InputCase("mcap_flipped_bit", "file", "one bit flipped inside an MCAP chunk's messages",
              _analyze(flipped_bit_in_chunk), "a chunk's data fails its CRC-32 check", 2),
    InputCase("mcap_two_types", "file", "/joint_states recorded with two types",
              _analyze(two_types), "was recorded with two types", 2),
    InputCase("mcap_foreign_schema", "file", "/joint_states with a JointState schema of other fields",
              _analyze(foreign_schema), "schema is not ROS's", 2),
    InputCase("mcap_fifo", "file", "a named pipe as the MCAP file",
              lambda folder: ["cr_analyze", str(_fifo(folder, "s.mcap")), "--no-plots"],
              "not a regular file", 2),
    InputCase("spec_alias_bomb", "file", "a SPEC with a YAML alias bomb (10^9 values)",
              _sweep(lambda folder: _file(folder, "spec.yaml", SPEC_HEAD + "robot:\n" + "".join(
                  f"  {line}\n" for line in alias_bomb(9).splitlines()))),
              "alias *a0 refused", 2),
    InputCase("spec_fifo", "file", "a named pipe as the SPEC",
              _sweep(lambda folder: _fifo(folder, "spec.yaml")), "not a regular file", 2),
    InputCase("params_alias_bomb", "file", "a params file with a YAML alias bomb",
              _params(lambda folder: _file(folder, "p.yaml", "plant:\n  ros__parameters:\n" + "".join(
                  f"    {line}\n" for line in alias_bomb(9).splitlines()))),
              "alias *a0 refused", 1),
    InputCase("params_2_mib", "file", "a params file of 2 MiB",
              _params(lambda folder: _file(folder, "p.yaml", "# " + "x" * (2 << 20) + "\n")),
              "larger than 1 MiB", 1),
    InputCase("params_fifo", "file", "a named pipe as the params file",
              _params(lambda folder: _fifo(folder, "p.yaml")), "not a regular file", 1),
    InputCase("params_dev_zero", "file", "/dev/zero as the params file",
              _params(lambda folder: Path("/dev/zero")), "not a regular file", 1),
    InputCase("params_not_utf8", "file", "a params file in Latin-1",
              _params(lambda folder: _file(folder, "p.yaml", b"plant:\n  ros__parameters:\n"
                                                             b"    name: \xe9\n")),
              "not UTF-8 text", 1),
    # -- command lines
    InputCase("identify_node_newline", "command line",
              "cr_identify_tool --node with a newline (YAML injected into its params file)",
              lambda folder: ["cr_identify_tool", "--node", NODE_NEWLINE,
                              "--out", str(folder / "tool.yaml")],
              "--node: invalid node name", 2),
    InputCase("identify_timeout_nan", "command line", "cr_identify_tool --timeout nan",
              lambda folder: ["cr_identify_tool", "--timeout", "nan", "--controller", "/nobody"],
              "--timeout: must be a number of seconds > 0 and <= 3600, not 'nan'", 2),
    InputCase("param_timeout_inf", "command line", "cr_param --timeout inf",
              lambda folder: ["cr_param", "--timeout", "inf", "list", "/nobody"],
              "--timeout: must be a number of seconds > 0 and <= 3600, not 'inf'", 2),
    InputCase("session_duration_nan", "command line", "cr_session --duration nan",
              lambda folder: _session(folder, "--duration", "nan"),
              "duration must be a finite number > 0, not nan", 1),
    InputCase("session_name_traversal", "command line", "cr_session --name ../../x",
              lambda folder: _session(folder, "--name", "../../x"),
              "--name '../../x': must be a plain directory name", 1),
]
INPUT_CASE_NAMES = [case.name for case in INPUT_CASES]


# -- running them ------------------------------------------------------------------------

@dataclass
class InputRow:
    """What a case's process did."""

    case: str
    kind: str
    exit_code: int          #: negative: killed by that signal
    seconds: float
    peak_mb: float          #: peak resident memory (MiB)
    line: str               #: the last stderr line
    error_lines: int        #: stderr lines, argparse's usage lines aside
    traceback: bool
    hung: bool = False
    verdict: str = ""


def command(name: str) -> list[str]:
    """How to run console script ``name``: the installed script beside this interpreter,
    else its entry point through ``python -c``."""
    script = Path(sys.executable).with_name(name)
    if script.exists():
        return [str(script)]
    (entry,) = importlib.metadata.entry_points(group="console_scripts", name=name)
    module, function = entry.value.split(":")
    return [sys.executable, "-c", f"import sys; from {module} import {function}; "
            f"sys.argv[0] = {name!r}; sys.exit({function}())"]


def _limits() -> None:
    """In the case's process before it runs: its resource limits, and no core file."""
    memory = MEMORY_LIMIT_MB << 20
    resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    resource.setrlimit(resource.RLIMIT_CPU, (CPU_LIMIT_S, CPU_LIMIT_S))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def _error_lines(stderr: str) -> list[str]:
    """stderr's lines without argparse's usage lines (``usage: ...`` and its indented
    continuation) and Fast DDS's shared-memory notices."""
    lines, usage = [], False
    for line in stderr.splitlines():
        usage = line.startswith("usage: ") or (usage and line.startswith(" "))
        if line.strip() and not usage and "RTPS_TRANSPORT_SHM" not in line:
            lines.append(line)
    return lines


def run_input(case: InputCase, folder: Path) -> InputRow:
    """Build ``case`` in ``folder``, run its command under the limits; its row (verdict set)."""
    argv = case.build(folder)
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "PYTHONUNBUFFERED": "1"}
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        start = time.monotonic()
        proc = subprocess.Popen([*command(argv[0]), *argv[1:]], stdin=subprocess.DEVNULL,
                                stdout=out, stderr=err, env=env, cwd=folder, preexec_fn=_limits,
                                start_new_session=True)    # its group: killed whole on a hang
        hung = False
        try:
            while True:
                pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
                if pid:
                    break
                if time.monotonic() - start > WALL_LIMIT_S:
                    hung = True
                    os.killpg(proc.pid, signal.SIGKILL)
                    pid, status, usage = os.wait4(proc.pid, 0)
                    break
                time.sleep(0.02)
        except BaseException:                  # interrupted: the case's processes go too
            os.killpg(proc.pid, signal.SIGKILL)
            os.wait4(proc.pid, 0)
            raise
        seconds = time.monotonic() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        stderr = err.read().decode("utf-8", "replace")
    lines = _error_lines(stderr)
    row = InputRow(case.name, case.kind, proc.returncode, seconds, usage.ru_maxrss / 1024.0,
                   lines[-1] if lines else "", len(lines), "Traceback" in stderr, hung)
    row.verdict = input_verdict(row, case)
    return row


def input_verdict(row: InputRow, case: InputCase) -> str:
    """``refused`` or ``FAILED: <first reason>``."""
    reasons = [text for bad, text in (
        (row.hung, f"still running after {WALL_LIMIT_S:g} s"),
        (row.exit_code < 0, f"killed by signal {-row.exit_code}"),
        (row.traceback, "a traceback"),
        (row.exit_code != case.exit_code, f"exit {row.exit_code}, not {case.exit_code}"),
        (row.error_lines != 1, f"{row.error_lines} error lines, not 1"),
        (case.reason not in row.line, f"the line does not say {case.reason!r}"),
        (not row.peak_mb < PEAK_MEMORY_MB, f"peak memory {row.peak_mb:.0f} MiB"))
        if bad]
    return f"FAILED: {reasons[0]}" if reasons else "refused"


def format_input_rows(rows: list[InputRow]) -> str:
    """The suite's table: one row per case, then each case's line."""
    head = f"{'case':30} {'kind':12} {'exit':>4} {'s':>5} {'peak MiB':>8}  verdict"
    lines = [head, "-" * len(head)]
    lines += [f"{r.case:30} {r.kind:12} {r.exit_code:4d} {r.seconds:5.1f} {r.peak_mb:8.0f}  "
              f"{r.verdict}" for r in rows]
    lines.append("")
    lines += [f"{r.case}: {r.line[:150]}" for r in rows]
    return "\n".join(lines)


def run_inputs(names: list[str], progress=print) -> list[InputRow]:
    """The named cases, each in a fresh temporary folder."""
    cases = {case.name: case for case in INPUT_CASES}
    rows = []
    for i, name in enumerate(names, 1):
        case = cases[name]
        progress(f"[{i}/{len(names)}] {name}: {case.what} ...")
        with tempfile.TemporaryDirectory(prefix="cr_fuzz-input-") as folder:
            rows.append(run_input(case, Path(folder)))
        progress(f"    {rows[-1].verdict}")
    return rows
