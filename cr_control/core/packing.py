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

Where the sizes depend on the robot (m task axes, n joints, known when the kernel runs),
one compiled function lays the blocks out and hands them to kernels as a named tuple of
views, block after block with :func:`take`, and :func:`views_layout` makes the Python
side's Layout from that same function::

    Blocks = namedtuple("Blocks", ["r_start", "quat", "q_start"])

    @njit
    def blocks(state, m, n):
        r_start, k = take(state, 0, m)
        quat, k = take(state, k, 4)
        q_start, k = take(state, k, n)
        return Blocks(r_start, quat, q_start), k     # k: where the blocks end

    views_layout(blocks, m, n).offset("q_start")     # m + 4
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
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

    def extended(self, **shapes: int | tuple[int, ...]) -> Layout:
        """This layout's blocks followed by ``shapes`` (a new Layout)."""
        return Layout(**self.shapes, **shapes)

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


@njit(cache=True, error_model="numpy", inline="always")
def take(vector, at, size):
    """(the ``size`` values of ``vector`` from ``at``, a view; where the next block starts):
    a kernel lays a packed vector out block after block with it (module docstring)."""
    return vector[at:at + size], at + size


def views_layout(views_of: Callable, *sizes: int) -> Layout:
    """The Layout of the blocks ``views_of(vector, *sizes)`` lays out: it returns a named
    tuple of 1-D views into ``vector``, one after the other from its start, and where they
    end (module docstring; called on an empty vector first, for that end). One definition
    of the blocks' order and sizes for the kernels and the Python side."""
    _, end = views_of(np.zeros(0), *sizes)
    vector = np.zeros(end)
    views, _ = views_of(vector, *sizes)
    layout = Layout(**{name: view.shape[0] for name, view in zip(views._fields, views, strict=True)})
    for name, view in zip(views._fields, views, strict=True):
        at = (view.ctypes.data - vector.ctypes.data) // vector.itemsize
        if view.size and at != layout.offset(name):
            raise ValueError(f"{views_of.__name__}: block {name} starts at {at}, not right "
                             f"after the block before it ({layout.offset(name)})")
    if layout.size != end:
        raise ValueError(f"{views_of.__name__}: its blocks end at {layout.size}, it says {end}")
    return layout
