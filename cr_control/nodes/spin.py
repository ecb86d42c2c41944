"""Starting, spinning and stopping nodes the way these machines hold 1 kHz.

Spinning: rclpy's EventsExecutor (SingleThreadedExecutor costs ~5x the CPU with 20-30 ms
garbage-collector stalls; MultiThreadedExecutor runs at 5-10 Hz, ros2/rclpy#1452).
EventsExecutor quirks (rclpy 7.1.6): it does not pick up timers created inside
callbacks (create every timer up front, started later with ``autostart=False`` and
``reset()``), and its spin() without a timeout delivers nothing here.

Starting: a bad ``--ros-args`` (a params file that is not YAML, a value of the wrong
type, ...) ends the process with one line ``<node>: refused to start: <reason>`` and
exit code 1, never a traceback (:func:`start_nodes`; rcl's own error line is dropped).

Stopping: with rclpy's own handler, Ctrl-C shuts the context down from a signal thread
while a callback may be running (its next publish raises RCLError "publisher's context
is invalid") and Python raises KeyboardInterrupt at whatever bytecode runs, often inside
a timer callback: EventsExecutor reports either as ``[FATAL] Exception in 'timers'
callback``. :func:`spin_nodes` therefore takes SIGINT itself and ends the loop between
callbacks; callbacks that publish are also wrapped with :func:`quiet_on_shutdown` for a
shutdown coming from elsewhere (SIGTERM, ``rclpy.shutdown()``). On the way out each
process waits (at most ``LAST_MESSAGES_TIMEOUT_S``) until its readers acknowledged its
last messages, so a recorder a little behind still gets them.
"""

from __future__ import annotations

import gc
import os
import re
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.task import Future

from cr_control.core.parameters import ParameterError
from cr_control.core.ros_env import use_node_dds_profile

#: rclpy's error for failures in rcl (a bad params file at init, a publish after shutdown).
RCLError = _rclpy.RCLError

#: What a node may raise while it starts because of what it was given.
START_ERRORS = (ParameterError, ParameterException, NameValidationException, RCLError,
                ValueError, OSError)


def one_line(exc: BaseException) -> str:
    """An exception's message on one line, without rcl's ``, at /path/file.c:NN`` trail."""
    text = re.sub(r",? at [^,]*\.c(pp)?:\d+", "", str(exc))
    return " ".join(text.split()) or type(exc).__name__


@contextmanager
def _held_stderr() -> Iterator[list[bytes]]:
    """Hold what C code writes to stderr (fd 2) meanwhile; the caller decides whether to
    replay it (rcl logs its own "Failed to parse global arguments" before raising)."""
    sys.stderr.flush()
    saved = os.dup(2)
    held: list[bytes] = []
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield held
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            held.append(tmp.read())


def start_nodes(label: str, argv: list[str], make: Callable[[], list[Node]]) -> list[Node] | None:
    """``rclpy.init(argv)`` and ``make()`` the nodes; on a refused start print
    ``<label>: refused to start: <reason>`` on stderr and return None."""
    use_node_dds_profile()   # before init: Fast DDS reads its profile once per process
    try:
        with _held_stderr() as held:
            try:
                rclpy.init(args=argv)
                init_error = None
            except RCLError as exc:
                init_error = exc
        if init_error is not None:
            raise init_error
        sys.stderr.buffer.write(held[0])   # init went well: whatever rcl said is for the user
        sys.stderr.flush()
        return make()
    except START_ERRORS as exc:
        print(f"{label}: refused to start: {one_line(exc)}", file=sys.stderr)
        rclpy.try_shutdown()
        return None


def quiet_on_shutdown(node: Node, callback: Callable[..., Any]) -> Callable[..., Any]:
    """``callback`` ending quietly when the process is being stopped while it runs.

    A publish failing because Ctrl-C already shut the context down is not an error;
    a KeyboardInterrupt raised inside the callback shuts the context down (the spin
    loop then ends) instead of escaping into the executor.
    """

    def guarded(*args: Any) -> Any:
        try:
            return callback(*args)
        except KeyboardInterrupt:
            node.context.try_shutdown()
        except (RCLError, ExternalShutdownException):
            if node.context.ok():
                raise
        return None

    guarded.__doc__ = callback.__doc__
    return guarded


def _stop_on_first_interrupt(until: Future) -> Callable[[int, Any], None]:
    """A SIGINT handler that ends the spin loop by completing ``until`` (no exception can
    then surface inside a callback); a second Ctrl-C interrupts as usual."""

    def handler(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if not until.done():
            until.set_result(None)

    return handler


#: On the way out, a node waits at most this long for its readers to acknowledge its
#: last messages (a recorder a little behind still gets them).
LAST_MESSAGES_TIMEOUT_S = 2.0


def wait_for_readers(publishers: Sequence[Publisher], timeout_s: float) -> bool:
    """Wait until every reader acknowledged what ``publishers`` sent, at most ``timeout_s``
    in all; False if some had not by then (a destroyed publisher counts as done)."""
    deadline = time.monotonic() + timeout_s
    acked = True
    for publisher in publishers:
        left = max(0.0, deadline - time.monotonic())
        with suppress(RCLError, RuntimeError):
            acked = publisher.wait_for_all_acked(Duration(seconds=left)) and acked
    return acked


def spin_nodes(nodes: Sequence[Node], until: Future | None = None) -> None:
    """Spin ``nodes`` on one EventsExecutor until Ctrl-C, shutdown or ``until`` completes."""
    # Long-lived nodes allocate little garbage that cycles; keep the collector from
    # stalling the loop by freezing start-up objects out of its generations.
    gc.collect()
    gc.freeze()
    executor = EventsExecutor()
    for node in nodes:
        executor.add_node(node)
    until = Future() if until is None else until
    in_main = threading.current_thread() is threading.main_thread()   # signals only there
    previous = signal.signal(signal.SIGINT, _stop_on_first_interrupt(until)) if in_main else None
    try:
        # Without a timeout, EventsExecutor's spin() and spin_until_future_complete()
        # never deliver anything here (rclpy 7.1.6): wait in bounded slices instead.
        while rclpy.ok() and not until.done():
            executor.spin_until_future_complete(until, timeout_sec=1.0)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # Ctrl-C mid-dispatch: EventsExecutor fails to hand a callback its message
        # ("Unable to convert call argument") once the context is gone.
        if rclpy.ok():
            raise
    finally:
        if in_main:
            signal.signal(signal.SIGINT, previous)
        executor.shutdown()
        if rclpy.ok():
            wait_for_readers([p for node in nodes for p in node.publishers], LAST_MESSAGES_TIMEOUT_S)
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
