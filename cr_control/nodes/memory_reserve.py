"""A pre-faulted heap for the processes of the real-time loop (issue 25), as real-time
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
  arena (the loop's thread, Python's objects) reuse those pages.

Opt-in: ``CR_CONTROL_MEMORY_RESERVE_MB=64`` (64 MiB: two copies of the fuzz's 18 MB
JointState, or the three buffers of an 8 MB parameter request, with room; 0 or unset:
none, glibc's defaults). Off by
default because the Panda row of ``cr_benchmark`` ran worse with it on a loaded day
(2026-11-25, two single pairs each: -46.7 and -64.3 pp fresh commands against the echo
pair with 64 MiB, -39.7 and -33.5 pp without, -26.7 to -43.8 pp before today's changes;
the spread between pairs is as large as the differences, so the cause is not settled).
Messages larger than the reserve still fault their excess pages in. The cost: the
reserve's resident memory per loop process, touched once at start.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

#: Environment variable: the reserve in MiB (0: none).
RESERVE_VARIABLE = "CR_CONTROL_MEMORY_RESERVE_MB"
#: glibc's mallopt parameters (malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
_PAGE = 4096


def reserve_bytes() -> int:
    """The reserve asked for: RESERVE_VARIABLE in MiB (0 if unset or not a number)."""
    text = os.environ.get(RESERVE_VARIABLE, "").strip()
    try:
        return max(0, min(4096, int(text))) << 20 if text else 0
    except ValueError:
        return 0


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


__all__ = ["RESERVE_VARIABLE", "reserve", "reserve_bytes"]
