"""Real-time scheduling for the processes of the real-time loop: opt-in, off by default.

``CR_CONTROL_REALTIME_PRIORITY=50`` (1..99; ros2_control's controller manager uses 50,
libfranka 80) puts every thread of a process that runs the real-time loop (its Python
thread, Fast DDS's receive, event and shared-memory threads, and those started later,
which inherit it) under SCHED_FIFO at that priority: ahead of every ordinary process.
Lockstep runs as fast as it can: it stays an ordinary process (it would otherwise hold
both CPUs). Without the privilege (CAP_SYS_NICE, or ``ulimit -r`` / ``@realtime - rtprio
50`` in /etc/security/limits.conf) the process keeps its ordinary scheduling and says so
once.

Why it is off by default (measured on a 2-core VM, hostile input from ``cr_fuzz``): with every
loop thread under SCHED_FIFO 50, 2 of 8 ten-second baseline sessions (cr_fuzz, nothing
sent) had the controller receive nothing for 244-245 ms at t = 2.35-2.47 s and the
plant's watchdog safe-stopped; with ordinary scheduling 0 of 8 (same day, run back to
back), and 0 of 14 in the fuzz's cases. A Python process whose threads all run FIFO
shares one GIL between them and Fast DDS's threads, which then wait on each other at
real-time priority on two CPUs; on a real-time kernel with isolated CPUs (what the
robot vendors ask for) it is the other way round, so it stays one variable away. The
stalls a node joining the domain caused were Fast DDS's shared-memory port check
(cr_control/core/fastdds_profile.xml), which ordinary scheduling does not bring back
(test/test_join_stalls.py).

CPU weight, on by default: a process of the real-time loop runs its threads at nice
``CR_CONTROL_LOOP_NICE`` (default -10: about 9 times an ordinary process's share of a
contended CPU; 0 = off) and, if it leads its session, its autogroup too
(``/proc/self/autogroup``): ``cr_session`` starts every node in a session of its own, so
each is an autogroup of its own, and Linux shares the CPU between autogroups first, where
a thread's nice alone does nothing. It is a weight, not a priority: no thread starves,
Fast DDS's included, and ordinary processes still run. Lowering nice takes CAP_SYS_NICE
or an ``ulimit -e`` / ``nice`` limit in /etc/security/limits.conf; without it the process
keeps its weight and says so once (INFO). Measured on this project's 2-core VM
(``cr_fuzz --cases second_state_source``, 50 000 states flooded by another process while
the recorder records them; alternating runs, 2026-11-26): 8 of 9 sessions survived at
nice -10, 4 of 8 without, alternating with them (7 of 23 in all runs without it that day;
the others safe-stopped, or the arm exceeded the baseline's speed, once 10 rad/s: the
controller, starved, fell hundreds of states behind). Joins and the Panda row
showed no difference beyond their spread (docs/benchmark.md).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence

from rclpy.node import Node

from cr_control.core.ros_env import env_number

#: SCHED_FIFO priority of the real-time loop's threads by default: 0, ordinary scheduling.
LOOP_PRIORITY = 0
#: Set CR_CONTROL_REALTIME_PRIORITY=50 for SCHED_FIFO at 50 (0 or unset: ordinary scheduling).
PRIORITY_VARIABLE = "CR_CONTROL_REALTIME_PRIORITY"
#: nice of the real-time loop's threads (and autogroup) by default; -20..0, 0 = unchanged.
LOOP_NICE = -10
#: CR_CONTROL_LOOP_NICE=0 keeps the loop at an ordinary process's CPU weight.
NICE_VARIABLE = "CR_CONTROL_LOOP_NICE"


def runs_realtime_loop(node: Node) -> bool:
    """True if ``node`` is on the real-time loop: it says so (``realtime_loop``, the plant
    in realtime mode), or it is a controller node not in lockstep (parameter ``lockstep``
    false)."""
    flag = getattr(node, "realtime_loop", None)
    if flag is not None:
        return bool(flag)
    try:
        return node.has_parameter("lockstep") and node.get_parameter("lockstep").value is False
    except Exception:  # noqa: BLE001 - a node that cannot tell is not on the loop
        return False


def _every_thread(set_one: Callable[[int], None]) -> None:
    """``set_one(tid)`` for every thread of this process (one that just ended is skipped)."""
    for tid in [int(t) for t in os.listdir("/proc/self/task")]:
        try:
            set_one(tid)
        except ProcessLookupError:
            continue


def use_loop_nice(nice: int = LOOP_NICE) -> str | None:
    """Every thread of this process at ``nice`` (threads started later inherit it) and, if
    the process leads its session, its autogroup too; None if done, else why not (the
    process is left as it was)."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)                # this thread: may we?
        _every_thread(lambda tid: os.setpriority(os.PRIO_PROCESS, tid, nice))
    except OSError as exc:                                      # no permission, not Linux
        return exc.strerror or str(exc)
    if os.getsid(0) == os.getpid():
        try:
            with open("/proc/self/autogroup", "w") as f:
                f.write(str(nice))
        except FileNotFoundError:
            pass                                                # no autogroups here
        except OSError as exc:
            return f"autogroup: {exc.strerror or exc}"
    return None


def use_realtime_priority(priority: int = LOOP_PRIORITY) -> str | None:
    """Put every thread of this process under SCHED_FIFO ``priority`` (threads started
    later inherit it); None if done, else why not (the process is left as it was)."""
    try:
        param = os.sched_param(priority)
        os.sched_setscheduler(0, os.SCHED_FIFO, param)          # this thread: may we?
        _every_thread(lambda tid: os.sched_setscheduler(tid, os.SCHED_FIFO, param))
    except (OSError, AttributeError) as exc:                    # no permission, not Linux
        return getattr(exc, "strerror", None) or str(exc)
    return None


def apply(nodes: Sequence[Node]) -> None:
    """The loop's CPU weight (nice), or real-time priority if asked, for this process if
    one of ``nodes`` runs the real-time loop and none says it does not (a lockstep plant);
    logged once by the first such node."""
    loop = [node for node in nodes if runs_realtime_loop(node)]
    if not loop or any(getattr(n, "realtime_loop", None) is False for n in nodes):
        return          # a lockstep plant in the process (composed): it runs flat out
    logger = loop[0].get_logger()
    priority = env_number(PRIORITY_VARIABLE, LOOP_PRIORITY, 0, 99, parse=int)
    nice = env_number(NICE_VARIABLE, LOOP_NICE, -20, 0, parse=int)
    if priority == 0:
        if nice:
            why = use_loop_nice(nice)
            logger.info(f"real-time loop: every thread at nice {nice}" if why is None else
                        f"real-time loop: nice {nice} refused ({why}): an ordinary process's "
                        "CPU weight; allow it with CAP_SYS_NICE or a nice limit")
        return
    why = use_realtime_priority(priority)
    if why is None:
        logger.info(f"real-time loop: every thread under SCHED_FIFO priority {priority}")
    else:
        logger.warn(f"real-time loop: SCHED_FIFO priority {priority} refused ({why}): ordinary "
                    "scheduling, so other processes (a node starting beside the loop) can "
                    "delay it; allow it with CAP_SYS_NICE or an rtprio limit")
