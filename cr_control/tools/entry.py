"""The console scripts' entry points: a tool interrupted or terminated ends in one line.

A tool's imports (numpy, Pinocchio, rclpy, numba's kernels) take one to three seconds, and
Python turns Ctrl-C there into a KeyboardInterrupt traceback printed from inside some
library's import; rclpy's own SIGTERM handler made the ROS command-line tools end in an
ExternalShutdownException traceback. Each console script of setup.py therefore runs its
``main`` through :func:`run`:

- SIGINT (Ctrl-C) while the tool's module is imported (the signal is held until the import
  is done), or a KeyboardInterrupt that its ``main`` lets through: ``<tool>: interrupted``,
  exit code 130;
- SIGTERM while the module is imported: ``<tool>: terminated``, exit code 143 (128 + the
  signal's number, what a shell reports for a process the signal ended). While ``main``
  runs, a tool's SIGTERM is a KeyboardInterrupt (:class:`Terminated`): the tool stops as on
  Ctrl-C (cr_session stops its processes, cr_sweep keeps its finished points), says so in
  its line, and exits 143. rclpy passes the signal on to this handler after its own.
- The ROS nodes (``plant``, ``recorder``, the controllers) handle both signals themselves
  once ``main`` runs (:mod:`cr_control.nodes.spin`: a clean stop, the recording closed), so
  for them only the import is covered.
"""

from __future__ import annotations

import importlib
import signal
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

#: Exit codes of a tool ended by SIGINT and by SIGTERM (128 + the signal's number).
EXIT_INTERRUPTED = 128 + signal.SIGINT
EXIT_TERMINATED = 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """SIGTERM: raised where the tool runs, so that it stops as on Ctrl-C."""


#: Whether SIGTERM arrived (a tool that caught its Terminated returns 130: made 143).
_terminated = [False]


def _on_sigterm(signum: int, frame: object) -> None:
    _terminated[0] = True
    raise Terminated


@contextmanager
def _held(node: bool, previous: Any) -> Iterator[None]:
    """SIGINT and SIGTERM held while the tool's module is imported, then acted on.

    Raised inside a C extension's initialisation, a KeyboardInterrupt came out as that
    library's own import error (rclpy: "The C extension ... isn't present"). A signal that
    arrived meanwhile is taken from the pending ones and raised here, after the import;
    ``node``: SIGTERM's handler is then ``previous`` again (the node handles it itself)."""
    signals = {signal.SIGINT, signal.SIGTERM}
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        yield
    finally:
        pending = signal.sigpending() & signals
        for _ in pending:
            signal.sigwait(pending)
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        if node:
            signal.signal(signal.SIGTERM, previous)
        if signal.SIGTERM in pending:
            _terminated[0] = True
            raise Terminated
        if signal.SIGINT in pending:
            raise KeyboardInterrupt


def run(tool: str, target: str, node: bool = False) -> int:
    """Import ``target`` (``module:function``) and return what its function returns; the
    tool's one line and exit code if SIGINT or SIGTERM end it (module docstring). ``node``:
    a ROS node, which handles the signals itself once its ``main`` runs."""
    module, _, function = target.partition(":")
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        with _held(node, previous):
            main = getattr(importlib.import_module(module), function)
        code = main()
    except Terminated:
        print(f"{tool}: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        print(f"{tool}: interrupted", file=sys.stderr)
        return EXIT_TERMINATED if _terminated[0] else EXIT_INTERRUPTED
    return EXIT_TERMINATED if _terminated[0] and code == EXIT_INTERRUPTED else code


def entry(tool: str, target: str, node: bool = False) -> Callable[[], int]:
    """The console-script function of ``tool``, running ``target`` through :func:`run`."""
    def start() -> int:
        return run(tool, target, node)
    start.__name__ = start.__qualname__ = tool
    start.__doc__ = f"{tool}: {target} through cr_control.tools.entry.run."
    return start


#: Console script -> ``module:function``; setup.py points each script at its name here
#: (``cr_session = cr_control.tools.entry:cr_session``), and each controller node's script
#: at ``controller_<scheme>``.
TOOLS = {
    "plant": "cr_sim.plant_node:main",
    "recorder": "cr_control.recording.recorder:main",
    "cr_session": "cr_control.tools.session:main",
    "cr_analyze": "cr_control.analysis.analyze:main",
    "cr_benchmark": "cr_control.tools.benchmark:main",
    "cr_param": "cr_control.tools.param_tool:main",
    "cr_lifecycle": "cr_control.tools.lifecycle_tool:main",
    "cr_fuzz": "cr_control.tools.fuzz:main",
    "cr_identify_tool": "cr_control.tools.identify_tool:main",
    "cr_sweep": "cr_control.experiments.sweep:main",
    "cr_tune": "cr_control.experiments.tune:main",
    "cr_reproduce": "cr_control.experiments.reproduce:main",
}
#: The ROS nodes among them (the controllers' scripts are nodes too).
NODES = ("plant", "recorder")


def __getattr__(name: str) -> Callable[[], int]:
    """The console-script function ``name``: a tool of TOOLS, or ``controller_<scheme>``
    (the scheme's controller node, ``main_<scheme>`` of cr_control.nodes.controller_node)."""
    if name in TOOLS:
        return entry(name, TOOLS[name], node=name in NODES)
    if name.startswith("controller_"):
        scheme = name[len("controller_"):]
        return entry(scheme, f"cr_control.nodes.controller_node:main_{scheme}", node=True)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
