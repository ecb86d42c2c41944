"""The console scripts' entry (cr_control/tools/entry.py): SIGINT or SIGTERM while a tool
imports its modules, or while its main runs, end it in one line with exit code 130 or 143,
never a traceback. A stand-in tool (a module whose import, or main, waits for the signal)
runs as a process; the signal is sent once it says where it is (an import goes on only
after that: the signal is held until the import is done). No ROS.

Before (each console script sent SIGINT 0.3, 1 and 2.5 s after it started): a
KeyboardInterrupt traceback from inside numpy's, rclpy's or numba's import in plant,
recorder, cr_session, cr_analyze, cr_param, cr_lifecycle, cr_fuzz and cr_identify_tool,
and later from main in plant (creating a publisher), cr_fuzz and cr_identify_tool (spinning);
SIGTERM once a ROS tool ran: an ExternalShutdownException traceback (cr_param,
cr_lifecycle, cr_identify_tool), and cr_session died at once, leaving its recorder and
controller running.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from cr_control.tools import entry

TOOL = '''
import os, sys, time
print("importing", flush=True)
while {wait_in_import} and not os.path.exists({go!r}):      # the signal is sent by then
    time.sleep(0.01)


def main():
    try:
        print("running", flush=True)
        time.sleep(60)
    except KeyboardInterrupt:
        if {catches}:
            print("stand_in: stopped, cleaned up", file=sys.stderr)
            return 130
        raise
    return 0
'''


def run_stand_in(tmp_path: Path, sig: int, wait_in_import: bool, catches: bool = False,
                 node: bool = False) -> tuple[int, list[str], str]:
    """The stand-in tool through entry.run, ``sig`` sent once it is importing (or running);
    its exit code, stderr's lines and stdout."""
    tmp_path = tmp_path / f"run{len(list(tmp_path.iterdir()))}"     # a fresh "go" and module
    tmp_path.mkdir()
    go = tmp_path / "go"
    (tmp_path / "stand_in.py").write_text(TOOL.format(wait_in_import=wait_in_import,
                                                       catches=catches, go=str(go)))
    code = (f"import sys; sys.path.insert(0, {str(tmp_path)!r}); from cr_control.tools import entry; "
            f"sys.exit(entry.run('stand_in', 'stand_in:main', node={node}))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    marker = "importing" if wait_in_import else "running"
    seen = ""
    while marker not in seen:
        line = proc.stdout.readline()
        assert line, proc.stderr.read()
        seen += line
    proc.send_signal(sig)
    go.touch()
    out, err = proc.communicate(timeout=60)
    return proc.returncode, err.splitlines(), seen + out


@pytest.mark.parametrize("sig, code, line", [
    (signal.SIGINT, 130, "stand_in: interrupted"),
    (signal.SIGTERM, 143, "stand_in: terminated"),
])
def test_a_signal_during_the_import_is_one_line(tmp_path, sig, code, line):
    returncode, lines, out = run_stand_in(tmp_path, sig, wait_in_import=True)
    assert (returncode, lines) == (code, [line])
    assert "running" not in out                          # main never ran


@pytest.mark.parametrize("sig, code, line", [
    (signal.SIGINT, 130, "stand_in: interrupted"),
    (signal.SIGTERM, 143, "stand_in: terminated"),
])
def test_a_signal_main_lets_through_is_one_line(tmp_path, sig, code, line):
    assert run_stand_in(tmp_path, sig, wait_in_import=False)[:2] == (code, [line])


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_tool_that_stops_on_ctrl_c_stops_so_on_sigterm(tmp_path, sig, code):
    """Its own clean-up and line; SIGTERM's exit code 143, not the 130 it returns."""
    returncode, lines, _ = run_stand_in(tmp_path, sig, wait_in_import=False, catches=True)
    assert (returncode, lines) == (code, ["stand_in: stopped, cleaned up"])


def test_a_node_keeps_its_own_sigterm_handling_once_it_runs(tmp_path):
    """A ROS node's spin loop handles SIGTERM itself; here (no handler of its own) the
    signal ends it as Python's default does, silently."""
    returncode, lines, _ = run_stand_in(tmp_path, signal.SIGTERM, wait_in_import=False, node=True)
    assert (returncode, lines) == (-signal.SIGTERM, [])
    returncode, lines, _ = run_stand_in(tmp_path, signal.SIGTERM, wait_in_import=True, node=True)
    assert (returncode, lines) == (143, ["stand_in: terminated"])


def console_scripts() -> dict[str, str]:
    return {ep.name: ep.value for ep in importlib.metadata.entry_points(group="console_scripts")
            if ep.dist is not None and ep.dist.name == "cr_control"}


def test_every_console_script_goes_through_the_entry():
    from cr_control.nodes import controller_node
    from cr_control.schemes.registry import SCHEMES

    scripts = console_scripts()
    assert set(entry.TOOLS) | set(SCHEMES) == set(scripts)
    for name, value in scripts.items():
        assert value == f"cr_control.tools.entry:{name if name in entry.TOOLS else 'controller_' + name}"
        assert callable(getattr(entry, value.split(":")[1]))
    for target in entry.TOOLS.values():
        module, function = target.split(":")
        assert importlib.util.find_spec(module) is not None, module
    assert all(callable(getattr(controller_node, f"main_{scheme}")) for scheme in SCHEMES)
    with pytest.raises(AttributeError):
        entry.no_such_tool  # noqa: B018
