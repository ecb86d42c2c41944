"""Real-time scheduling for the processes of the real-time loop: opt-in, off by default.

``CR_CONTROL_REALTIME_PRIORITY=50`` (1..99; ros2_control's controller manager uses 50,
libfranka 80) puts every thread of a process that runs the real-time loop (its Python
thread, Fast DDS's receive, event and shared-memory threads, and those started later,
which inherit it) under SCHED_FIFO at that priority: ahead of every ordinary process.
Lockstep runs as fast as it can: it stays an ordinary process (it would otherwise hold
both CPUs). Without the privilege (CAP_SYS_NICE, or ``ulimit -r`` / ``@realtime - rtprio
50`` in /etc/security/limits.conf) the process keeps its ordinary scheduling and says so
once.

Why it is off by default (issue 25, measured on this project's 2-core VM): with every
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
"""

from __future__ import annotations

import os
from collections.abc import Sequence

from rclpy.node import Node

#: SCHED_FIFO priority of the real-time loop's threads by default: 0, ordinary scheduling.
LOOP_PRIORITY = 0
#: Set CR_CONTROL_REALTIME_PRIORITY=50 for SCHED_FIFO at 50 (0 or unset: ordinary scheduling).
PRIORITY_VARIABLE = "CR_CONTROL_REALTIME_PRIORITY"


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


def _priority() -> int:
    text = os.environ.get(PRIORITY_VARIABLE, "")
    try:
        return max(0, min(99, int(text))) if text else LOOP_PRIORITY
    except ValueError:
        return LOOP_PRIORITY


def use_realtime_priority(priority: int = LOOP_PRIORITY) -> str | None:
    """Put every thread of this process under SCHED_FIFO ``priority`` (threads started
    later inherit it); None if done, else why not (the process is left as it was)."""
    try:
        param = os.sched_param(priority)
        os.sched_setscheduler(0, os.SCHED_FIFO, param)          # this thread: may we?
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except (OSError, AttributeError) as exc:                    # no permission, not Linux
        return getattr(exc, "strerror", None) or str(exc)
    for tid in tids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
        except ProcessLookupError:
            continue                                            # a thread that just ended
    return None


def apply(nodes: Sequence[Node]) -> None:
    """Real-time priority for this process if one of ``nodes`` runs the real-time loop and
    none says it does not (a lockstep plant); logged once by the first such node."""
    loop = [node for node in nodes if runs_realtime_loop(node)]
    priority = _priority()
    if not loop or priority == 0 or any(getattr(n, "realtime_loop", None) is False for n in nodes):
        return          # a lockstep plant in the process (composed): it runs flat out
    why = use_realtime_priority(priority)
    logger = loop[0].get_logger()
    if why is None:
        logger.info(f"real-time loop: every thread under SCHED_FIFO priority {priority}")
    else:
        logger.warn(f"real-time loop: SCHED_FIFO priority {priority} refused ({why}): ordinary "
                    "scheduling, so other processes (a node starting beside the loop) can "
                    "delay it; allow it with CAP_SYS_NICE or an rtprio limit")
