"""The benchmark's calibration: ns per plain Python loop iteration, µs per Pinocchio ABA
call, the plant step hot and after an idle period, and the log times of an MCAP file
(for the recorder's cost per message).
"""

from __future__ import annotations

import math
import struct
import sys
import time
from array import array
from collections.abc import Sequence
from pathlib import Path

from cr_control.tools.benchmark_figures import SCHEME
from cr_sim.loop_stats import percentiles


# -- calibration ---------------------------------------------------------------------------
def loop_ns_per_iteration(n: int = 300_000, repeats: int = 7) -> float:
    """ns per iteration of ``for i in range(n): pass``, best of ``repeats``."""
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _i in range(n):
            pass
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e9


def aba_us_per_call(n: int = 2000, repeats: int = 5) -> float | None:
    """µs per Pinocchio ABA call (TwoLinkArm.forward_dynamics), best of ``repeats``."""
    try:
        # lazy: loaded when the command runs (cr_control.tools)
        import numpy as np

        # lazy: loaded when the command runs (cr_control.tools)
        from cr_control.models.arm_model import TwoLinkArm
    except ImportError:
        return None
    arm = TwoLinkArm()
    q, v, tau = np.array([0.3, 0.5]), np.array([0.1, -0.2]), np.array([0.5, 0.1])
    fd = arm.forward_dynamics
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _i in range(n):
            fd(q, v, tau)
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def step_us_hot_and_after_idle(cycles: int = 400, idle_s: float = 0.0009) -> dict[str, float]:
    """Median µs of one ``Controller.step`` of the scheme back to back ("hot") and after
    sleeping ``idle_s`` before each, as a node does between its 1 kHz states ("after
    idle"): on a virtual machine the second is several times the first (caches and
    predictors go cold while the vCPU idles), which is why the compute time in a node
    exceeds the offline one."""
    # lazy: loaded when the command runs (cr_control.tools)
    import numpy as np

    # lazy: loaded when the command runs (cr_control.tools)
    from cr_control.schemes.registry import make_controller

    controller = make_controller(SCHEME)
    # An open loop on a frozen state: the law winds up to its limit and stops commanding
    # (max_bad_cycles) within the 800 steps; the step's cost is what is measured, not that.
    controller.log_warning = controller.log_error = lambda _message: None
    q, v, force = np.array([0.3, 0.4]), np.zeros(2), np.zeros(3)
    out = {}
    stamp = 0.0
    for label, idle in (("step_hot_us", 0.0), ("step_after_idle_us", idle_s)):
        times = []
        for _ in range(cycles):
            if idle:
                time.sleep(idle)
            stamp += 1e-3
            t0 = time.perf_counter_ns()
            controller.step(stamp, q, v, force)
            times.append(time.perf_counter_ns() - t0)
        out[label] = percentiles(times, 50)[0] / 1e3
    return out


def warm_up(robots: Sequence[str] = ()) -> None:
    """A few offline cycles of the scheme in this process, on its thesis plant and on each of
    ``robots``: compiled kernels are built and cached (numba ``cache=True``) before the runs,
    so that no run's first cycle compiles."""
    # lazy: loaded when the command runs (cr_control.tools)
    from cr_control.offline import run_scheme

    run_scheme(SCHEME, 0.01)
    for robot in robots:
        run_scheme(SCHEME, 0.01, robot=robot)


def calibrate() -> dict[str, float | None]:
    """This machine's speed now: ns per plain loop iteration, µs per ABA call, µs per
    controller step hot and after idling (:func:`step_us_hot_and_after_idle`)."""
    return {"loop_ns": loop_ns_per_iteration(), "aba_us": aba_us_per_call(), **step_us_hot_and_after_idle()}


def mcap_log_times(path: Path) -> list[int]:
    """Sorted log (receive) times of every message of an MCAP file, from its message
    indexes (no chunk is decompressed); from the messages themselves if it has no summary."""
    # lazy: loaded when the command runs (cr_control.tools)
    from mcap.opcode import Opcode
    from mcap.reader import make_reader

    times = array("q")
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None or not summary.chunk_indexes:
            times.extend(m.log_time for _, _, m in reader.iter_messages(log_time_order=False))
        else:
            for index in summary.chunk_indexes:
                for offset in index.message_index_offsets.values():
                    f.seek(offset)
                    opcode, _length, _channel, size = struct.unpack("<BQHI", f.read(15))
                    if opcode != Opcode.MESSAGE_INDEX:
                        continue
                    pairs = array("q")
                    pairs.frombytes(f.read(size))
                    if sys.byteorder != "little":
                        pairs.byteswap()
                    times.extend(pairs[0::2])
    return sorted(times)
