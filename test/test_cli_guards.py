"""Guards of the command-line tools found by a fuzz: one line on stderr and a
non-zero exit, never a traceback, and nothing done outside what was asked.

- ``cr_param`` refuses a node name ROS would not take (InvalidServiceNameException before)
  and gives up on an absent node within ``--timeout`` (10.4 s before);
- ``cr_session --name`` cannot put the session outside ``--out``;
- an empty params file (nothing, only comments, ``{}``, ``null``) is refused by
  ``cr_session --params-file`` and by the nodes started with ``--ros-args --params-file``
  (rcl takes it without a word).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_clean_errors import error_line

from cr_control.core import ros_yaml
from cr_control.nodes.spin import help_asked, params_files
from cr_control.tools import param_tool
from cr_control.tools.session import Session, SessionConfig, SessionError

SCHEME = "adaptive_impedance"


def run(module: str, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], env=env, capture_output=True,
                          text=True, timeout=120)


def cr_param(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    return run("cr_control.tools.param_tool", *args, env=env)


# -- cr_param: node names ---------------------------------------------------------------

BAD_NODE_NAMES = [
    ("/bad name", "node name must not contain characters other than alphanumerics"),
    ("", "it is empty"),
    ("///..", "it contains '//'"),
    ("/1node", "node name must not start with a number"),
    ("a b", "node name must not contain"),
    ("//", "it contains '//'"),
    ("/ns//plant", "it contains '//'"),
    ("/plant/", "it ends with '/'"),
    ("/", "it ends with '/'"),
    ("/pl\u00e4nt", "node name must not contain"),             # unicode
    ("/\u8282\u70b9", "node name must not contain"),
    ("/n\u00e4s/plant", "namespace must not contain"),
    ("/ns/1x/plant", "namespace must not have a token that starts with a number"),
    ("~/plant", "namespace must not contain"),
    ("/{plant}", "node name must not contain"),
    ("/" + "a" * 300, "node name length should not exceed"),
    ("/" + "a/" * 120 + "b", "service name"),           # fine itself; its services' names are too long
]


@pytest.mark.parametrize("name,reason", BAD_NODE_NAMES)
def test_full_node_name_refuses_what_ros_refuses(name, reason):
    with pytest.raises(ValueError) as exc:
        param_tool.full_node_name(name)
    assert str(exc.value).startswith(f"invalid node name {name!r}: ") and reason in str(exc.value)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("name,full", [("plant", "/plant"), ("/plant", "/plant"), ("ns/plant", "/ns/plant"),
                                       ("/ns/sub/plant_2", "/ns/sub/plant_2"), ("_x", "/_x")])
def test_full_node_name_takes_what_ros2_param_takes(name, full):
    assert param_tool.full_node_name(name) == full


INVALID_ON_THE_COMMAND_LINE = ["/bad name", "", "///..", "/1node", "/plant/", "/pl\u00e4nt"]
COMMANDS = [("get", "{}", "Q_c"), ("set", "{}", "Q_c", "[1.0, 1.0]"), ("list", "{}")]


@pytest.mark.ros
@pytest.mark.parametrize("name,command", [(name, COMMANDS[i % len(COMMANDS)])
                                          for i, name in enumerate(INVALID_ON_THE_COMMAND_LINE)])
def test_cr_param_invalid_node_name(ros_env, name, command):
    proc = cr_param(ros_env, *(arg.format(name) for arg in command))
    assert proc.returncode == 2
    assert error_line(proc).startswith(f"cr_param: invalid node name {name!r}: ")


# -- cr_param: absent node --------------------------------------------------------------

@pytest.mark.ros
@pytest.mark.parametrize("args,timeout", [
    (("get", "/nobody", "Q_c"), param_tool.TIMEOUT_S),                   # default: 3 s
    (("--timeout", "1", "set", "ns/nobody", "Q_c", "2.0"), 1.0),
    (("list", "nobody", "--timeout", "0.5"), 0.5),                      # option after the command
])
def test_cr_param_absent_node_within_timeout(ros_env, args, timeout):
    start = time.monotonic()
    proc = cr_param(ros_env, *args)
    elapsed = time.monotonic() - start
    assert proc.returncode == 2
    node = "/ns/nobody" if "ns/nobody" in args else "/nobody"
    assert error_line(proc) == (f"cr_param: no node {node} on ROS_DOMAIN_ID {ros_env['ROS_DOMAIN_ID']} "
                                f"(its parameter services did not appear within {timeout:g} s; "
                                "see --timeout)")
    assert elapsed >= timeout            # it waited its --timeout (how much longer: load)


@pytest.mark.ros
@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "soon"])
def test_cr_param_timeout_must_be_positive(ros_env, value):
    proc = cr_param(ros_env, "--timeout", value, "get", "/plant", "resume")
    assert proc.returncode == 2 and "--timeout: must be a number of seconds > 0" in proc.stderr
    assert "Traceback" not in proc.stderr


# -- cr_session --name ------------------------------------------------------------------

def session(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    """cr_session with ``args``; it picks its own free domain (the test's is held here)."""
    env = {k: v for k, v in env.items() if k != "ROS_DOMAIN_ID"}
    return run("cr_control.tools.session", "--duration", "0.1", "--no-record", *args, env=env)


def tree(path: Path) -> list[str]:
    return sorted(str(p.relative_to(path)) for p in path.rglob("*"))


@pytest.mark.ros
@pytest.mark.parametrize("name,why", [
    ("../../x", "path separator"), ("../x", "path separator"), ("a/b", "path separator"),
    ("x/", "path separator"), ("/tmp/cr_session_outside", "path separator"),
    ("", "empty"), ("  ", "empty"), (".", "'.' or '..'"), ("..", "'.' or '..'"),
])
def test_session_name_cannot_leave_out(tmp_path, ros_env, name, why):
    base = tmp_path / "base"
    (base / "out").mkdir(parents=True)
    before = tree(tmp_path)
    line = error_line(session(ros_env, "--out", str(base / "out"), "--name", name))
    assert line.startswith(f"cr_session: --name {name!r}: must be a plain directory name to make "
                           "under --out (") and why in line
    assert tree(tmp_path) == before                               # nothing created anywhere
    assert not Path("/tmp/cr_session_outside").exists()


@pytest.mark.parametrize("name", ["run-1", "my.session", "...", "x..y", "sess ion"])
def test_session_name_plain_names_are_taken(tmp_path, name):
    s = Session(SessionConfig(out=tmp_path / "out", name=name, duration=0.1, record=False))
    assert s.dir == tmp_path / "out" / name and s.dir.parent == tmp_path / "out"
    assert not (tmp_path / "out").exists()                        # nothing made before run()


def test_session_name_refused_in_process(tmp_path):
    with pytest.raises(SessionError, match=r"--name '\.\./x': must be a plain directory name"):
        Session(SessionConfig(out=tmp_path, name="../x"))


# -- empty params files -----------------------------------------------------------------

EMPTY_FILES = {"empty": "", "comments": "# nothing here\n\n   # nor here\n", "braces": "{}\n",
               "null": "null\n", "tilde": "~\n"}


@pytest.mark.parametrize("text", EMPTY_FILES.values(), ids=EMPTY_FILES.keys())
def test_empty_params_file_is_recognised(tmp_path, text):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    assert ros_yaml.empty_params_file(str(path))


@pytest.mark.parametrize("text", ["plant:\n  ros__parameters: {}\n", "[1, 2\n", "\x00\x01", "- 1\n"])
def test_nonempty_or_unreadable_params_file_is_left_to_its_reader(tmp_path, text):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    assert not ros_yaml.empty_params_file(str(path))
    assert not ros_yaml.empty_params_file(str(tmp_path / "missing.yaml"))


@pytest.mark.ros
@pytest.mark.parametrize("text", EMPTY_FILES.values(), ids=EMPTY_FILES.keys())
def test_session_refuses_empty_params_file(tmp_path, ros_env, text):
    params = tmp_path / "params.yaml"
    params.write_text(text)
    line = error_line(session(ros_env, "--out", str(tmp_path / "out"), "--params-file", str(params)))
    assert line == (f"cr_session: params file {params}: empty, no node's parameters "
                    f"(expected '{ros_yaml.PARAMS_FILE_FORM}')")
    assert not (tmp_path / "out").exists()


NODES = {"plant": ["cr_sim.plant_node"], SCHEME: ["cr_control.nodes.controller_node", SCHEME],
         "container": ["cr_control.tools.container", SCHEME], "recorder": ["cr_control.recording.recorder"]}


@pytest.mark.ros
@pytest.mark.parametrize("node,text", [("plant", t) for t in EMPTY_FILES.values()]
                         + [(SCHEME, ""), (SCHEME, "{}\n"), ("container", "# only a comment\n"),
                            ("recorder", "null\n")],
                         ids=[f"plant-{k}" for k in EMPTY_FILES] + [f"{SCHEME}-empty", f"{SCHEME}-braces",
                                                                   "container-comments", "recorder-null"])
def test_node_refuses_empty_params_file(tmp_path, ros_env, node, text):
    good = tmp_path / "good.yaml"
    good.write_text("plant:\n  ros__parameters:\n    duration: 1.0\n")
    params = tmp_path / "params.yaml"
    params.write_text(text)
    proc = run(*NODES[node], "--ros-args", "--params-file", str(good), "--params-file", str(params),
               env=ros_env)
    assert proc.returncode == 1
    assert error_line(proc) == (f"{node}: refused to start: params file {params} is empty, no node's "
                                f"parameters (expected '{ros_yaml.PARAMS_FILE_FORM}')")


@pytest.mark.parametrize("node", ["plant", SCHEME, "controller_node"])
def test_node_help_prints_its_usage_and_starts_nothing(ros_env, node):
    """``-h`` / ``--help`` before ``--ros-args``: the usage on stdout, exit 0, no node (a
    started node would run until the timeout); after ``--ros-args`` it is rcl's."""
    args = NODES[node] if node != "controller_node" else ("cr_control.nodes.controller_node",)
    proc = run(*args, "--help", env=ros_env)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    usage = proc.stdout.splitlines()[0]
    assert usage.startswith(f"usage: {node} ") and "--ros-args" in usage, usage
    if node != "controller_node":
        assert "\nParameters: " in proc.stdout and "config/" in proc.stdout
    assert help_asked(["x", "--ros-args", "-p", "a:=1", "--", "-h"])
    assert not help_asked(["x", "--ros-args", "--help"])


def test_params_files_are_read_from_ros_args_only():
    argv = ["node", "--params-file", "not_ros", "--ros-args", "--params-file", "a", "-p", "x:=1", "--",
            "--params-file", "b", "--ros-args", "-r", "__ns:=/x", "--params-file", "c", "--params-file"]
    assert params_files(argv) == ["a", "c"]


# -- cr_param: the visitor profile ---------------------------------------------------------
@pytest.mark.ros
def test_cr_param_on_its_udp_only_profile_reaches_a_node_on_shared_memory(ros_env):
    """Started as a user starts them (no Fast DDS profile chosen), the plant takes the node
    profile (shared memory and UDP) and cr_param the visitor profile (UDP only, so the loop
    never runs the shared-memory port check on it): they still talk."""
    from ros_probe import start_node, stop_node

    from cr_control.core.ros_env import DDS_PROFILE_VARIABLE

    env = {k: v for k, v in ros_env.items() if k != DDS_PROFILE_VARIABLE}
    plant = start_node([sys.executable, "-m", "cr_sim.plant_node"], env, "-p", "rate_hz:=500.0")
    try:
        got = cr_param(env, "--timeout", "30", "get", "/plant", "rate_hz")
        assert got.returncode == 0, got.stderr
        assert got.stdout.strip().endswith("500.0"), got.stdout
    finally:
        stop_node(plant)
