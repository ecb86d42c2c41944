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

Ctrl-C ends a node within 2 s (a plant under parameter traffic once took over 6 s): the
loop waits in slices of ``SPIN_SLICE_S`` (it waited 1 s, and a node with nothing to do
noticed the signal only then), and after the signal every wait for readers, also one
already under way (the plant's at the end of its run, 2 s; a lockstep pacer's, 10 s),
ends ``INTERRUPTED_WAIT_S`` after it (before: up to 2 s in the callback, then up to 2 s
more on the way out). ``EXIT_DEADLINE_S`` is the node's budget for all of it: a watchdog
thread, woken by the signal itself, ends the process that long after the signal if the
node has not stopped by then (a callback that does not return, or a Fast DDS
participant-deletion hang, 1 in ~100 process stops under load: :func:`_exit_if_stuck`).
The interpreter's own exit comes after that. test/test_sigint.py stops nodes under
parameter traffic and holds them to ``EXIT_DEADLINE_S`` plus a stated margin for it.
"""

from __future__ import annotations

import gc
import os
import re
import select
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import Any

import rclpy
import yaml
from rclpy.duration import Duration
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.task import Future

from cr_control.core import ros_yaml
from cr_control.core.parameters import ParameterError
from cr_control.core.ros_env import use_node_dds_profile
from cr_control.nodes import memory_reserve, realtime_priority

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


def params_files(argv: Sequence[str]) -> list[str]:
    """The files given with ``--params-file`` in the ``--ros-args`` parts of ``argv``."""
    files, ros_args = [], False
    for i, arg in enumerate(argv):
        if arg == "--ros-args":
            ros_args = True
        elif arg == "--":
            ros_args = False
        elif ros_args and arg == "--params-file" and i + 1 < len(argv):
            files.append(argv[i + 1])
    return files


def lockstep_requested(argv: Sequence[str]) -> bool:
    """True if ``argv``'s parameters put the node in lockstep (``lockstep: true``, a
    controller's, or ``mode: lockstep``, the plant's), given with ``-p`` or in a params file
    (any node's): the process then takes the lockstep Fast DDS profile."""
    def asks(name: str, value: Any) -> bool:
        return ((name == "lockstep" and str(value).lower() == "true")
                or (name == "mode" and str(value).strip("'\"") == "lockstep"))

    for i, arg in enumerate(argv[:-1]):
        if arg in ("-p", "--param") and ":=" in argv[i + 1]:
            name, value = argv[i + 1].split(":=", 1)
            if asks(name.rsplit(":", 1)[-1], value):
                return True
    for path in params_files(argv):
        try:
            with open(path, encoding="utf-8") as f:
                tree = ros_yaml.load(f.read())
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            continue        # rcl reports an unreadable file
        for node in (tree.values() if isinstance(tree, dict) else []):
            values = node.get("ros__parameters") if isinstance(node, dict) else None
            if isinstance(values, dict) and any(asks(k, v) for k, v in values.items()):
                return True
    return False


def refuse_empty_params_files(label: str, argv: Sequence[str]) -> bool:
    """True, after printing ``<label>: refused to start: params file ... is empty ...``, if a
    ``--params-file`` of ``argv`` is empty (nothing, only comments, ``{}``, ``null``): rcl
    takes such a file without a word, and a truncated or mistyped file would go unnoticed.
    Call it before ``rclpy.init``."""
    for path in params_files(argv):
        if ros_yaml.empty_params_file(path):
            print(f"{label}: refused to start: params file {path} is empty, no node's parameters "
                  f"(expected '{ros_yaml.PARAMS_FILE_FORM}')", file=sys.stderr)
            return True
    return False


def help_asked(argv: Sequence[str]) -> bool:
    """True if ``argv`` (the program name first) asks for ``-h`` / ``--help`` outside its
    ``--ros-args`` parts: a node executable then prints its usage and starts nothing."""
    ros_args = False
    for arg in argv[1:]:
        if arg == "--ros-args":
            ros_args = True
        elif arg == "--":
            ros_args = False
        elif not ros_args and arg in ("-h", "--help"):
            return True
    return False


def node_usage(program: str, what: str, params_hint: str) -> str:
    """The usage text of a node executable: how it is started, what it does, where its
    parameters are documented."""
    return (f"usage: {program} [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] "
            f"[-r __ns:=/NAMESPACE]]\n\n{what}\n\nParameters: {params_hint}\n"
            "Run it with ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE set for your network; "
            "Ctrl-C stops it.")


def start_nodes(label: str, argv: list[str], make: Callable[[], list[Node]]) -> list[Node] | None:
    """``rclpy.init(argv)`` and ``make()`` the nodes; on a refused start (also an empty
    params file: :func:`refuse_empty_params_files`) print ``<label>: refused to start:
    <reason>`` on stderr and return None."""
    if refuse_empty_params_files(label, argv):
        return None
    # before init: Fast DDS reads its profile once per process
    use_node_dds_profile(lockstep=lockstep_requested(argv))
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


#: Monotonic time the first SIGINT of the current :func:`spin_nodes` was handled (None: none).
_interrupted_at: float | None = None

#: The spin loop waits for events in slices this long: a SIGINT that comes while nothing
#: runs (a controller whose plant has stopped) ends the loop within this time (s).
SPIN_SLICE_S = 0.1

#: On the way out, a node waits at most this long for its readers to acknowledge its
#: last messages (a recorder a little behind still gets them).
LAST_MESSAGES_TIMEOUT_S = 2.0

#: After a SIGINT, waits for readers (:func:`wait_for_readers`, also one already under
#: way: the plant's at the end of its run, a lockstep pacer's) end at most this long after
#: the signal was handled, so that the process is gone within 2 s of Ctrl-C: healthy
#: readers acknowledge within ~10 ms (heartbeats every 10 ms, fastdds_profile.xml);
#: a reader that does not acknowledge in 0.5 s is stopping or stalled itself.
INTERRUPTED_WAIT_S = 0.5

#: :func:`wait_for_readers` waits in slices this long, so that a SIGINT can cut it short.
_WAIT_SLICE_S = 0.05

#: The node's budget for Ctrl-C (s): this long after the signal arrives the node is torn
#: down, or its watchdog ends the process (see :func:`_exit_if_stuck`), also when a
#: callback does not return or the middleware's teardown hangs. The teardown is done
#: 0.07 s after the signal (median), at most 0.56 s (a wait for readers that do not
#: acknowledge ends 0.5 s after it; nodes are destroyed in 10-60 ms). The interpreter's
#: own exit follows: 0.22 s median, at most 0.9 s on this 2-core machine at a load
#: average of 5-12 (204 stops, test/test_sigint.py). So the process is gone within 2 s.
EXIT_DEADLINE_S = 1.0

#: At an end without Ctrl-C, the teardown after the wait for readers gets this long.
TEARDOWN_TIMEOUT_S = 1.0


#: What :func:`_exit_if_stuck` says when it ends a process.
WATCHDOG_EXIT = "exiting without a clean teardown"


def _exit_if_stuck(torn_down: threading.Event, teardown_deadline: list[float | None], wake: int,
                   names: str) -> None:
    """Watchdog thread of :func:`spin_nodes`: end the process (status 0, the nodes' status
    on Ctrl-C, after one line on stderr) EXIT_DEADLINE_S after a SIGINT arrived, or at
    ``teardown_deadline[0]`` (set when the loop ends without Ctrl-C), whichever comes
    first, unless ``torn_down`` is set by then.

    It blocks on ``wake``, the read end of the pipe that :func:`signal.set_wakeup_fd`
    writes the signal's number to the moment the signal arrives, also while the main
    thread is stuck where no Python signal handler runs; :func:`spin_nodes` writes a zero
    byte to it when the loop ends and when the teardown is done. So the budget counts from
    the signal, as the one pressing Ctrl-C (and test/test_sigint.py) does, and the thread
    costs nothing while the loop runs.

    Why (a plant that took over 6 s to exit): Fast DDS 2.14 can hang for good
    in rmw_destroy_node, when the last node of the process deletes its DDS participant:
    DomainParticipant::set_listener(nullptr) waits for the participant listener's
    callbacks in progress and spins holding the listener mutex, while a discovery
    callback about a peer that is leaving at the same moment (a session stop: every
    process stops at once; cr_param processes coming and going) waits for that mutex.
    Seen in about 1 of 80 process stops on a loaded 2-core machine (gdb: main thread in
    DomainParticipant::set_listener under destroy_participant, a dds.udp thread blocked in
    MyRTPSParticipantListener::onWriterDiscovery / onParticipantDiscovery). rclpy releases
    the GIL around rcl_node_fini, so this Python thread still runs. Peers then see this
    participant go only when its lease expires; its endpoints are gone already."""
    with suppress(OSError, AttributeError):       # the loop's threads may run SCHED_FIFO
        if os.sched_getscheduler(0) == os.SCHED_FIFO:   # and hold every CPU: be ahead of them
            priority = os.sched_getparam(0).sched_priority
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(min(priority + 1, 99)))
    signalled_at: float | None = None
    try:
        while not torn_down.is_set():
            ends = [t for t in (teardown_deadline[0],
                                None if signalled_at is None else signalled_at + EXIT_DEADLINE_S)
                    if t is not None]
            now = time.monotonic()
            if ends and now >= min(ends):
                break
            ready, _, _ = select.select([wake], [], [], min(ends) - now if ends else None)
            if ready:
                with suppress(BlockingIOError):
                    if signal.SIGINT in os.read(wake, 512) and signalled_at is None:
                        signalled_at = time.monotonic()
        else:
            return
    finally:
        if torn_down.is_set():
            os.close(wake)
    with suppress(Exception):
        sys.stdout.flush()
        since = "in time" if signalled_at is None else f"{now - signalled_at:.1f} s after Ctrl-C"
        why = ("the middleware's teardown did not finish (a known Fast DDS hang when a peer leaves "
               "at the same moment)" if teardown_deadline[0] is not None else "a callback did not return")
        sys.stderr.write(f"{names}: {WATCHDOG_EXIT} {since}: {why}\n")
        sys.stderr.flush()
    os._exit(0)


def _on_first_interrupt(signum: int, frame: Any) -> None:
    """SIGINT handler of :func:`spin_nodes`: note the time; the spin loop, which waits in
    slices of SPIN_SLICE_S, then ends between callbacks (no exception can surface inside
    a callback). A second Ctrl-C interrupts as usual.

    It only notes the time (it used to complete the loop's future): a Python signal
    handler runs in the main thread between any two bytecodes, also while that thread
    holds the future's non-reentrant lock in add_done_callback/remove_done_callback,
    which EventsExecutor calls on every slice; set_result there would wait for ever."""
    global _interrupted_at
    signal.signal(signal.SIGINT, signal.default_int_handler)
    if _interrupted_at is None:
        _interrupted_at = time.monotonic()


def wait_for_readers(publishers: Sequence[Publisher], timeout_s: float) -> bool:
    """Wait until every reader acknowledged what ``publishers`` sent, at most ``timeout_s``
    in all; False if some had not by then (a destroyed publisher counts as done).

    After a SIGINT the wait ends at most INTERRUPTED_WAIT_S after the signal, and the
    result is True: the process is being stopped, a reader that did not acknowledge by
    then is not to be given up on as dead (lockstep.ReaderPacer would)."""
    deadline = time.monotonic() + timeout_s
    acked = True
    for publisher in publishers:
        while True:
            end = deadline if _interrupted_at is None else min(deadline, _interrupted_at + INTERRUPTED_WAIT_S)
            left = end - time.monotonic()
            try:
                if publisher.wait_for_all_acked(Duration(seconds=max(0.0, min(left, _WAIT_SLICE_S)))):
                    break
            except (RCLError, RuntimeError):
                break                       # destroyed meanwhile: nothing left to wait for
            if left <= _WAIT_SLICE_S:
                acked = False
                break
    return acked or _interrupted_at is not None


def _reserve_memory(nodes: Sequence[Node]) -> None:
    """A pre-faulted heap (memory_reserve) for a process that runs the real-time loop."""
    loop = [node for node in nodes if realtime_priority.runs_realtime_loop(node)]
    if loop and not any(getattr(n, "realtime_loop", None) is False for n in nodes):
        why = memory_reserve.reserve()
        if why is not None:
            loop[0].get_logger().warn(f"real-time loop: no pre-faulted heap ({why})")


def spin_nodes(nodes: Sequence[Node], until: Future | None = None) -> None:
    """Spin ``nodes`` on one EventsExecutor until Ctrl-C, shutdown or ``until`` completes."""
    global _interrupted_at
    # Long-lived nodes allocate little garbage that cycles; keep the collector from
    # stalling the loop by freezing start-up objects out of its generations.
    gc.collect()
    gc.freeze()
    executor = EventsExecutor()
    for node in nodes:
        executor.add_node(node)
    realtime_priority.apply(nodes)   # the real-time loop's threads ahead of other processes
    _reserve_memory(nodes)           # and large messages taken without page faults
    until = Future() if until is None else until
    _interrupted_at = None
    in_main = threading.current_thread() is threading.main_thread()   # signals only there
    previous = signal.signal(signal.SIGINT, _on_first_interrupt) if in_main else None
    torn_down = threading.Event()
    teardown_deadline: list[float | None] = [None]
    if in_main:
        wake, wake_write = os.pipe()
        os.set_blocking(wake, False)
        os.set_blocking(wake_write, False)
        previous_wakeup = signal.set_wakeup_fd(wake_write, warn_on_full_buffer=False)
        threading.Thread(target=_exit_if_stuck, name="cr_exit_watchdog", daemon=True,
                         args=(torn_down, teardown_deadline, wake,
                               ", ".join(node.get_name() for node in nodes))).start()

    def rouse() -> None:
        if in_main:
            with suppress(OSError):
                os.write(wake_write, b"\0")
    try:
        # Without a timeout, EventsExecutor's spin() and spin_until_future_complete()
        # never deliver anything here (rclpy 7.1.6): wait in bounded slices instead.
        while rclpy.ok() and not until.done() and _interrupted_at is None:
            executor.spin_until_future_complete(until, timeout_sec=SPIN_SLICE_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # Ctrl-C mid-dispatch: EventsExecutor fails to hand a callback its message
        # ("Unable to convert call argument") once the context is gone.
        if rclpy.ok():
            raise
    finally:
        # Our SIGINT handler stays until the end: a Ctrl-C during the teardown shortens it
        # (and is no KeyboardInterrupt traceback).
        teardown_deadline[0] = time.monotonic() + LAST_MESSAGES_TIMEOUT_S + TEARDOWN_TIMEOUT_S
        rouse()
        try:
            executor.shutdown()
            if rclpy.ok():
                wait_for_readers([p for node in nodes for p in node.publishers], LAST_MESSAGES_TIMEOUT_S)
            for node in nodes:
                node.destroy_node()
            rclpy.try_shutdown()
        finally:
            torn_down.set()
            rouse()
            if in_main:
                signal.set_wakeup_fd(previous_wakeup)
                os.close(wake_write)
                signal.signal(signal.SIGINT, previous)
