"""Declared, typed, validated parameters shared by the plant and controller nodes.

Each :class:`Param` is a documented parameter with a thesis default. Matrix gains are
given either as their diagonal (``m`` values) or in full, row-major (``m*m`` values),
so ``Q_a: [5.0, 5.0]`` and ``Q_a: [5.0, 0.0, 0.0, 5.0]`` mean the same; positive
(negative) definite ones are checked for symmetry and definiteness. Validation
turns a ROS value into the numpy value the math uses, or gives the reason it is refused.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Kinds of value a parameter may take.
SCALAR_KINDS = ("finite", "positive", "nonnegative")
VECTOR_KINDS = ("vector", "positive_vector", "nonnegative_vector")
MATRIX_KINDS = ("spd", "nd", "matrix")
OTHER_KINDS = ("string", "bool", "integer", "string_list", "choice")


@dataclass(frozen=True)
class Param:
    """One parameter: name, thesis default, meaning and the values it accepts."""

    name: str
    default: Any
    description: str
    kind: str = "finite"
    size: int | None = None
    read_only: bool = False
    choices: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in SCALAR_KINDS + VECTOR_KINDS + MATRIX_KINDS + OTHER_KINDS:
            raise ValueError(f"unknown kind {self.kind!r} for {self.name}")
        ok, reason, _ = validate(self, self.default)
        if not ok:
            raise ValueError(f"default of {self.name} is invalid: {reason}")

    @property
    def ros_default(self) -> Any:
        """The default as a ROS parameter value (floats for double types)."""
        if self.kind in SCALAR_KINDS:
            return float(self.default)
        if self.kind in VECTOR_KINDS + MATRIX_KINDS:
            return [float(v) for v in self.default]
        return self.default


class ParameterError(ValueError):
    """A parameter value was refused; the message says why."""


def _as_floats(value: Any) -> list[float] | None:
    if isinstance(value, (str, bytes, bool)) or not isinstance(value, Iterable):
        return None
    try:
        return [float(v) for v in value]
    except (TypeError, ValueError):
        return None


def _matrix(param: Param, values: list[float]) -> tuple[bool, str, np.ndarray | None]:
    m = param.size
    if len(values) == m:
        matrix = np.diag(values)
    elif len(values) == m * m:
        matrix = np.array(values).reshape(m, m)
    else:
        return False, f"{param.name} needs {m} (diagonal) or {m * m} (full) values, got {len(values)}", None
    if param.kind in ("spd", "nd"):
        if not np.allclose(matrix, matrix.T, atol=1e-12):
            return False, f"{param.name} must be symmetric", None
        eig = np.linalg.eigvalsh(matrix)
        if param.kind == "spd" and eig.min() <= 0:
            return False, f"{param.name} must be positive definite (eigenvalues {eig})", None
        if param.kind == "nd" and eig.max() >= 0:
            return False, f"{param.name} must be negative definite (eigenvalues {eig})", None
    return True, "", matrix


def validate(param: Param, value: Any) -> tuple[bool, str, Any]:
    """(accepted, reason if refused, value converted for the math)."""
    kind = param.kind
    if kind in SCALAR_KINDS:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False, f"{param.name} must be a number", None
        x = float(value)
        if not math.isfinite(x):
            return False, f"{param.name} must be finite, got {value}", None
        if kind == "positive" and x <= 0:
            return False, f"{param.name} must be > 0, got {value}", None
        if kind == "nonnegative" and x < 0:
            return False, f"{param.name} must be >= 0, got {value}", None
        return True, "", x
    if kind in VECTOR_KINDS + MATRIX_KINDS:
        values = _as_floats(value)
        if values is None:
            return False, f"{param.name} must be a list of numbers", None
        if not all(math.isfinite(v) for v in values):
            return False, f"{param.name} must be finite, got {list(value)}", None
        if kind in MATRIX_KINDS:
            return _matrix(param, values)
        if param.size is not None and len(values) != param.size:
            return False, f"{param.name} needs {param.size} values, got {len(values)}", None
        if kind == "positive_vector" and min(values, default=1.0) <= 0:
            return False, f"{param.name} must be all > 0, got {values}", None
        if kind == "nonnegative_vector" and min(values, default=0.0) < 0:
            return False, f"{param.name} must be all >= 0, got {values}", None
        return True, "", np.array(values)
    if kind == "bool":
        return (True, "", value) if isinstance(value, bool) else (False, f"{param.name} must be a bool", None)
    if kind == "integer":
        ok = isinstance(value, int) and not isinstance(value, bool)
        return (True, "", value) if ok else (False, f"{param.name} must be an integer", None)
    if kind == "string_list":
        ok = not isinstance(value, str) and all(isinstance(v, str) for v in value)
        return (True, "", list(value)) if ok else (False, f"{param.name} must be a list of strings", None)
    if not isinstance(value, str):
        return False, f"{param.name} must be a string", None
    if kind == "choice" and value not in param.choices:
        return False, f"{param.name} must be one of {list(param.choices)}, got {value!r}", None
    return True, "", value


def resolve(specs: Sequence[Param], overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Converted values of ``specs``: defaults with ``overrides``; raise ParameterError if refused."""
    overrides = dict(overrides or {})
    unknown = set(overrides) - {p.name for p in specs}
    if unknown:
        raise ParameterError(f"unknown parameters: {sorted(unknown)}")
    values = {}
    for param in specs:
        ok, reason, converted = validate(param, overrides.get(param.name, param.default))
        if not ok:
            raise ParameterError(reason)
        values[param.name] = converted
    return values


def matrix(size: int, diagonal: float) -> list[float]:
    """Default of a matrix gain ``diagonal * I`` given by its diagonal."""
    return [float(diagonal)] * size
