"""A pre-faulted heap for the processes of the real-time loop, as real-time
Linux practice and ros2_control's ``lock_memory`` prepare a control process: memory the
loop's thread may need later is touched once at start, so that taking a large message
never waits for the kernel to supply fresh pages.

Why: rmw_fastrtps takes a message by copying it twice (into a CDR buffer, then into the
caller's), into buffers malloc'd for that take. glibc serves an allocation above its
mmap threshold (128 KiB to 32 MiB, adaptive) with a fresh mapping, and each of its pages
faults on first touch; on this project's 2-core VM a page fault costs 5-40 us, so the
controller's take of one 18 MB JointState (the fuzz's 640 000 names) took 26 ms quiet and
160-190 ms beside a busy process, all of it on the loop's only thread (measured
2026-11-25: sender_aware's take timed in a subscriber process, the state published by
another). With the heap below: 10.6 ms quiet, the two copies alone.

What :func:`reserve` does (glibc only; elsewhere a no-op that says why):
- ``mallopt(M_MMAP_MAX, 0)``: every allocation, however large, comes from the heap;
- ``mallopt(M_TRIM_THRESHOLD, 1 GiB)``: freed heap memory stays with the process;
- malloc the reserve, touch every page, free it: later allocations of the main
  arena reuse those pages.

And one malloc arena (``MALLOC_ARENA_MAX=1``, which :func:`loop_env` puts in the
environment of the processes ``cr_session`` starts; glibc reads it at process start, and
``mallopt(M_ARENA_MAX, 1)`` called later did not do it: a new thread's 16 MiB still
faulted 520 pages in), so every thread allocates from the main arena, the reserve's.
Without it glibc gives other threads arenas of their own, which
the reserve does not cover: the parameter gate's thread took an 8 MB request into fresh
pages (9-16 ms of page faults), and while it did the controller's *process* received the
plant's states 4-8 ms late (rmw's reception timestamps), whether or not they had a
receive thread of their own.

On by default for the processes of the real-time loop (64 MiB; ``CR_CONTROL_MEMORY_RESERVE_MB``
sets another size, 0 turns both off; lockstep processes take no reserve). A node started
by hand takes the reserve; export ``MALLOC_ARENA_MAX=1`` for the single arena too. Measured on this
project's 2-core VM (``cr_fuzz --cases Q_c_1e6_values``, the 8 MB request to the
controller, 2026-11-26): missed 5-8 ms in 8 sessions with neither (baselines 3-5), 7, 4
and 8 with the reserve alone, 9, 8 and 7 with one arena alone, and **3, 2, 3, 3, 4, 3**
with both set for every process (baselines 2-3: at most 1 ms over); as shipped (the
session sets the arena for its processes), 8 of 10 sessions within the fuzz's rule
(baseline + 2 ms; 8 and 6 ms against 3 and 2 in the other two), and ``make fuzz``
survived 14 of 14 for the first time. The reserve was opt-in before, because the
Panda row of ``cr_benchmark`` ran worse with it on a loaded day (2026-11-25, two single
pairs each: -46.7 and -64.3 pp fresh commands against the echo pair with 64 MiB, -39.7
and -33.5 pp without; the spread between pairs was as large as the differences); the row
measured again with both on, against both off, the same hour: -0.31 against -0.51 pp,
994.5 against 993.7 Hz, p99 1.08x against 1.12x the echo pair's: no difference beyond
the spread (docs/any_robot.md). The cost: 64 MiB
resident per loop process, touched once at start (~50 ms).
"""

from __future__ import annotations

import ctypes
import ctypes.util

from cr_control.core.ros_env import env_number

#: Environment variable: the reserve in MiB (0: none, and no single arena either).
RESERVE_VARIABLE = "CR_CONTROL_MEMORY_RESERVE_MB"
#: The reserve of a real-time loop process when the variable is unset (MiB).
DEFAULT_RESERVE_MB = 64
#: glibc's mallopt parameters (malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
#: glibc's environment variable for the number of malloc arenas, read at process start.
ARENA_VARIABLE = "MALLOC_ARENA_MAX"
_PAGE = 4096


def reserve_bytes(env: dict[str, str] | None = None) -> int:
    """The reserve asked for: RESERVE_VARIABLE of ``env`` (default: os.environ) in MiB
    (DEFAULT_RESERVE_MB if unset, 0 if not a number)."""
    return env_number(RESERVE_VARIABLE, DEFAULT_RESERVE_MB, 0, 4096, parse=int, invalid=0,
                      env=env) << 20


def loop_env(env: dict[str, str]) -> dict[str, str]:
    """``env`` with ARENA_VARIABLE=1 (one malloc arena: module docstring) unless it sets
    that variable already or asks for no reserve; for the processes a session starts."""
    if ARENA_VARIABLE not in env and reserve_bytes(env) > 0:
        env[ARENA_VARIABLE] = "1"
    return env


def reserve(size: int | None = None) -> str | None:
    """Keep large allocations on a heap of at least ``size`` bytes (default
    :func:`reserve_bytes`) already faulted in; None if done or none asked for, else why not
    (the process is left as it was)."""
    size = reserve_bytes() if size is None else size
    if size <= 0:
        return None
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError) as exc:                    # not glibc
        return f"no glibc mallopt ({exc})"
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    libc.malloc.argtypes, libc.malloc.restype = [ctypes.c_size_t], ctypes.c_void_p
    libc.free.argtypes, libc.free.restype = [ctypes.c_void_p], None
    if mallopt(M_MMAP_MAX, 0) != 1 or mallopt(M_TRIM_THRESHOLD, 1 << 30) != 1:
        return "mallopt refused"
    block = libc.malloc(size)
    if not block:
        return f"cannot allocate {size} bytes"
    ctypes.memset(block, 0, size)                               # fault every page in
    libc.free(block)
    return None


__all__ = ["ARENA_VARIABLE", "DEFAULT_RESERVE_MB", "RESERVE_VARIABLE", "loop_env", "reserve",
           "reserve_bytes"]
