"""Compile (or load from numba's on-disk cache) every plant and scheme kernel once.

The first call of a compiled kernel in a process costs its compilation (seconds, once per
source change, then cached beside the module) or at least loading it from the cache. The
Makefile runs this before the tests and the demo so no node has to compile inside a timed
start-up, and the controller node warms its scheme up before it subscribes.

    python -m cr_control.tools.warm_up
"""

from __future__ import annotations

import sys
import time

from cr_control.schemes.registry import SCHEMES, default_scenario, make_controller
from cr_sim.plants.registry import make_plant


def warm_up(schemes: list[str] | None = None, progress=print) -> float:
    """A few offline cycles of every scheme on its plant; returns the seconds it took."""
    start = time.perf_counter()
    for scheme in schemes or list(SCHEMES):
        t0 = time.perf_counter()
        plant, controller = make_plant(default_scenario(scheme)), make_controller(scheme)
        for _ in range(3):
            m = plant.measurement()
            out = controller.step(m.time, m.position, m.velocity, m.force)
            plant.step(out.command, 1e-3)
        progress(f"  {scheme}: {time.perf_counter() - t0:.1f} s")
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    """Warm up every kernel (or the schemes named on the command line)."""
    args = sys.argv[1:] if argv is None else argv
    unknown = [a for a in args if a not in SCHEMES]
    if unknown:
        print(f"warm_up: unknown scheme(s) {unknown}; known: {sorted(SCHEMES)}", file=sys.stderr)
        return 2
    print("compiling / loading the compiled kernels (once per source change):")
    print(f"done in {warm_up(args or None):.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
