"""Named blocks of one flat float64 vector: how gains and internal state reach compiled kernels.

A control cycle calls one compiled kernel; passing one array per gain would cost an
argument conversion each (~2 interpreter loop iterations apiece), so a scheme packs its
gains into one vector (re-packed when a parameter changes) and keeps all of its evolving
internal state in another. :class:`Layout` names the blocks on the Python side; kernels
read them through the integer offsets it hands out, which numba freezes as constants.

    GAINS = Layout(A_m=(2, 2), c_0=2, alpha=1)
    gains = GAINS.pack({"A_m": np.eye(2), "c_0": [1, 1], "alpha": 0.5})
    GAINS.view(gains, "A_m")        # a 2x2 view
    A_M = GAINS.offset("A_m")       # for kernels: block2(gains, A_M)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit


class Layout:
    """Blocks (name -> shape) laid one after the other in a flat float64 vector."""

    def __init__(self, **shapes: int | tuple[int, ...]):
        self.shapes: dict[str, tuple[int, ...]] = {}
        self.offsets: dict[str, int] = {}
        offset = 0
        for name, shape in shapes.items():
            shape = (shape,) if isinstance(shape, int) else tuple(shape)
            self.shapes[name], self.offsets[name] = shape, offset
            offset += math.prod(shape)
        self.size = offset

    def offset(self, name: str) -> int:
        """Where block ``name`` starts."""
        return self.offsets[name]

    def view(self, vector: np.ndarray, name: str) -> np.ndarray:
        """Block ``name`` of ``vector`` in its shape (a view: writing to it writes the vector)."""
        start, shape = self.offsets[name], self.shapes[name]
        return vector[start:start + math.prod(shape)].reshape(shape)

    def pack(self, values: Mapping[str, Any], out: np.ndarray | None = None) -> np.ndarray:
        """A vector (or ``out``, filled in place) holding ``values`` of every block."""
        out = np.zeros(self.size) if out is None else out
        for name in self.shapes:
            self.view(out, name)[...] = values[name]
        return out


@njit(cache=True, error_model="numpy", inline="always")
def block2(vector, start):
    """The 2x2 block of ``vector`` at ``start`` (a view)."""
    return vector[start:start + 4].reshape((2, 2))


@njit(cache=True, error_model="numpy", inline="always")
def block(vector, start, size):
    """The ``size`` values of ``vector`` at ``start`` (a view)."""
    return vector[start:start + size]
