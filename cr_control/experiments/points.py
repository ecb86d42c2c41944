"""The points of a sweep: the grid of the ``vary`` lists, or seeded random draws.

A point is ``(index, {node.param: value})``; its index is its place in the sweep and names it
in the results (rows are sorted by it, so the table does not depend on which worker finished
first). Grid: the product of the lists in the order the SPEC writes them, the last one
fastest. Random: ``samples`` draws from ``numpy.random.default_rng(seed)``, point by point and
parameter by parameter in SPEC order, so the same SPEC gives the same points anywhere.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from cr_control.experiments.spec import Range, SweepSpec, Targets

Point = tuple[int, dict[str, Any]]


def _draw(rng: np.random.Generator, values: list[Any] | Range, integer: bool) -> Any:
    """One draw of a range (uniform or log-uniform; an integer parameter: an integer in
    [ceil(low), floor(high)]) or one element of a list (uniform)."""
    if isinstance(values, Range):
        if integer:
            return int(rng.integers(math.ceil(values.low), math.floor(values.high) + 1))
        if values.log:
            return float(math.exp(rng.uniform(math.log(values.low), math.log(values.high))))
        return float(rng.uniform(values.low, values.high))
    return values[int(rng.integers(len(values)))]


def points(spec: SweepSpec, targets: Targets) -> list[Point]:
    """Every point of ``spec`` with its index (see the module docstring)."""
    names = list(spec.vary)
    if not spec.is_random:
        grid = itertools.product(*(spec.vary[n] for n in names))      # type: ignore[misc]
        return [(i, dict(zip(names, combo, strict=True))) for i, combo in enumerate(grid)]
    rng = np.random.default_rng(spec.seed)
    integer = {n: targets.param(n).kind == "integer" for n in names}
    return [(i, {n: _draw(rng, spec.vary[n], integer[n]) for n in names})
            for i in range(spec.samples or 0)]
