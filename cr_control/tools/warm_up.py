"""Compile (or load from numba's on-disk cache) every plant and scheme kernel once.

The first call of a compiled kernel in a process costs its compilation (seconds, once per
source change, then cached beside the module) or at least loading it from the cache. The
Makefile runs this before the tests and the demo so no node has to compile inside a timed
start-up, and the controller node warms its scheme up before it subscribes.

    python -m cr_control.tools.warm_up
"""

from __future__ import annotations

import hashlib
import sys
import time
from pathlib import Path

from cr_control.schemes.registry import SCHEMES, default_scenario, make_controller
from cr_sim.plants.registry import make_plant

#: The packages whose numba kernels are cached beside their sources.
KERNEL_PACKAGES = ("cr_control", "cr_sim")
DIGEST_NAME = "kernel-sources.sha256"
#: The sub-packages that hold kernels and everything a kernel may call or read as a global
#: (nodes, tools, analysis and experiments hold none): an edit elsewhere keeps the caches.
KERNEL_LAYERS = frozenset({"core", "models", "schemes", "plants"})


def _package_dirs() -> list[Path]:
    return [Path(__import__(name).__file__).resolve().parent for name in KERNEL_PACKAGES]


def clear_stale_kernels() -> bool:
    """Delete every cached kernel if any source file changed since the caches were made.

    numba keys a cached kernel on its own module's file only: a kernel that calls a
    function of another module that has changed since (a building block) would be loaded
    stale. One digest of the kernel layers' sources (:data:`KERNEL_LAYERS`), kept beside
    them, tells; returns True if caches were cleared. Nothing happens where the packages are
    read-only."""
    dirs = _package_dirs()
    digest = hashlib.sha256()
    for d in dirs:
        for path in sorted(d.rglob("*.py")):
            if path.relative_to(d).parts[0] not in KERNEL_LAYERS:
                continue
            digest.update(f"{d.name}/{path.relative_to(d).as_posix()}".encode())
            digest.update(path.read_bytes())
    marker = dirs[0] / "__pycache__" / DIGEST_NAME
    if marker.exists() and marker.read_text() == digest.hexdigest():
        return False
    cleared = False
    try:
        for cache in (p for d in dirs for pattern in ("*.nbi", "*.nbc") for p in d.rglob(pattern)):
            cache.unlink()
            cleared = True
        marker.parent.mkdir(exist_ok=True)
        marker.write_text(digest.hexdigest())
    except OSError:
        return cleared
    return cleared


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
    if clear_stale_kernels():
        print("sources changed since the kernels were cached: caches cleared")
    print("compiling / loading the compiled kernels (once per source change):")
    print(f"done in {warm_up(args or None):.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
