"""Declared, typed, validated parameters shared by the plant and controller nodes.

Each :class:`Param` is a documented parameter with a thesis default. Matrix gains are
given either as their diagonal (``m`` values) or in full, row-major (``m*m`` values),
so ``Q_a: [5.0, 5.0]`` and ``Q_a: [5.0, 0.0, 0.0, 5.0]`` mean the same; positive
(negative) definite ones are checked for symmetry and definiteness. Validation
turns a ROS value into the numpy value the math uses, or gives the reason it is refused.

Every numeric parameter has a ``bound``: the largest magnitude any of its values may take
(finite is not enough: ``Q_c = [1e308, 1e308]`` made the law's output overflow). Bounds are
physical: a gain, a length, a force a user would still call sensible (:class:`Bound` for the
families, the parameter's own where none fits); :func:`describe` prints it after the
description. Lists are checked for their size before any element is converted, so a huge
value is refused in O(1) (a request with 10^6 values must not stall a 1 kHz loop).
"""

from __future__ import annotations

import math
from collections.abc import Sequence, Sized
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Kinds of value a parameter may take.
SCALAR_KINDS = ("finite", "positive", "nonnegative")
VECTOR_KINDS = ("vector", "positive_vector", "nonnegative_vector")
MATRIX_KINDS = ("spd", "nd", "matrix")
OTHER_KINDS = ("string", "bool", "integer", "string_list", "choice")
#: Kinds whose every value is >= 0 (their bound reads "<= B").
_UNSIGNED_KINDS = ("positive", "nonnegative", "positive_vector", "nonnegative_vector")
#: Kinds with a bound (every numeric one).
BOUNDED_KINDS = SCALAR_KINDS + VECTOR_KINDS + MATRIX_KINDS + ("integer",)

#: Most values of a list parameter without a fixed size (a joint list, a chain of masses):
#: more than any arm or chain here has.
MAX_VALUES = 100


class Bound:
    """Bounds shared by a family of parameters: the largest magnitude of any value (units
    as the parameter's own). A parameter that fits none states its own, with its reason."""

    #: Control and adaptation gains, whatever their unit (1/s, 1/s^2, N/m, N s/m, ...): 25x the
    #: largest thesis gain (B_m = 400); a gain beyond it times the 1 ms cycle is >> 1.
    GAIN = 1e4
    #: Positions, offsets, amplitudes, radii and lengths in the workspace (m): ~10x the reach
    #: of the arms modelled (thesis arm 0.6 m, Panda 0.86 m, UR5 0.85 m).
    LENGTH = 10.0
    #: Joint positions, postures and joint-space ranges (rad, or m for a prismatic joint):
    #: beyond +-3 turns.
    JOINT = 10.0
    #: Phases (rad): a phase counts modulo 2 pi; the thesis's largest is 12 rad.
    PHASE = 100.0
    #: Frequencies of a desired motion (rad/s): 16 Hz, 25x the fastest thesis path (4 rad/s);
    #: no arm's position loop follows a path faster.
    MOTION_FREQUENCY = 100.0
    #: Filter, observer and constraint-stabilisation rates (rad/s or 1/s): below the Nyquist
    #: frequency of the 1 kHz loop (3142 rad/s).
    BANDWIDTH = 1e3
    #: Forces (N): the weight of 100 kg, ~10x what a collaborative arm presses.
    FORCE = 1e3
    #: Joint efforts (N m): the strongest industrial arms' joints.
    EFFORT = 1e4
    #: Masses and inertial parameters (kg, kg m, kg m^2 combined): beyond any arm's links and
    #: payload (heavy industrial arms carry ~500 kg).
    MASS = 1e3
    #: Rotational inertias (kg m^2): a large industrial link is ~10 kg m^2.
    INERTIA = 100.0
    #: Stiffnesses of joints, springs and compliant layers (N/m, N m/rad): a harmonic drive
    #: is ~1e4-1e5 N m/rad.
    STIFFNESS = 1e6
    #: Contact stiffness of an environment (N/m): steel on steel; the plants' automatic RK4
    #: substeps resolve it (20 per 1 ms cycle for 1 kg).
    CONTACT_STIFFNESS = 1e8
    #: Damping of plants and environments (N s/m, N m s/rad).
    DAMPING = 1e4
    #: Coefficients of the force models' and observers' polynomials (chapter 4, appendix C):
    #: a fourth-order polynomial with every pole at -30 rad/s has p^4 = 8.1e5.
    POLYNOMIAL = 1e6
    #: Times within a run (s): a day, the longest soak run.
    TIME = 86400.0
    #: Speeds (m/s, rad/s) of a plant's own motions.
    SPEED = 10.0
    #: Accelerations of gravity (m/s^2): 10 g.
    GRAVITY = 100.0
    #: Dimensionless scales, ratios and raw directions (normalised where they are used): two
    #: orders of magnitude (a test of a deliberately absurd model scales its masses by 50).
    SCALE = 100.0
    #: Signs (+1 or -1).
    SIGN = 1.0
    #: Measurement noise, std (rad or m; rad/s or m/s): as large as the signal; forces: FORCE
    #: (the reflex tests drown a plant in 1e3 N and 100 rad/s of noise).
    POSITION_NOISE = 1.0
    VELOCITY_NOISE = 100.0
    #: Random seeds: 32 bits.
    SEED = 2.0**32 - 1
    #: RK4 substeps per control period: 1 us steps at 1 kHz, enough for CONTACT_STIFFNESS.
    SUBSTEPS = 1000
    #: Joint rates (rad/s) of network grids and margins: as max_joint_velocity's default.
    JOINT_RATE = 100.0
    #: Centres per axis of an RBF grid (the thesis's: 2-12).
    RBF_CENTRES = 100
    #: Nodes of an RBF network: each is evaluated every cycle (the thesis's: 16-256).
    RBF_NODES = 10000


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
    #: Largest magnitude of every value (every element of a list or matrix); None: unbounded.
    bound: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in SCALAR_KINDS + VECTOR_KINDS + MATRIX_KINDS + OTHER_KINDS:
            raise ValueError(f"unknown kind {self.kind!r} for {self.name}")
        if self.bound is not None and (self.kind not in BOUNDED_KINDS
                                       or not 0.0 < self.bound < math.inf):
            raise ValueError(f"bound {self.bound!r} of {self.name} ({self.kind}): a positive "
                             "finite number, for numeric kinds only")
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

    @property
    def max_values(self) -> int:
        """Most values a value of this parameter may hold: a list's largest size, 1 else."""
        if self.kind in MATRIX_KINDS:
            return self.size * self.size
        if self.kind in VECTOR_KINDS:
            return MAX_VALUES if self.size is None else self.size
        return MAX_VALUES if self.kind == "string_list" else 1


class ParameterError(ValueError):
    """A parameter value was refused; the message says why."""


def _number(x: float) -> str:
    """A bound as people write it: 0.05, 100, 86400, 1e4, 2.5e5."""
    if x != int(x):
        return repr(x)
    digits = str(int(x))
    mantissa = digits.rstrip("0")
    if len(digits) - len(mantissa) < 4:
        return digits
    return f"{mantissa[0]}{'.' + mantissa[1:] if len(mantissa) > 1 else ''}e{len(digits) - 1}"


def bound_text(param: Param) -> str:
    """``param``'s bound as it is printed: ``<= 1e4``, ``|x| <= 10``, ``each |x| <= 10``."""
    each = "" if param.kind in SCALAR_KINDS + ("integer",) else "each "
    magnitude = "" if param.kind in _UNSIGNED_KINDS else "|x| "
    return f"{each}{magnitude}<= {_number(param.bound)}"


def describe(param: Param) -> str:
    """The description as a node declares it and a params file comments it: the text, the
    forms of a matrix, the choices and the bound, e.g. ``"Integral adaptation gain of c_hat
    (3.11). 2 values (diagonal) or 4 (full, row-major). (each |x| <= 1e4)"``."""
    text = param.description
    if param.kind in MATRIX_KINDS:
        text += f" {param.size} values (diagonal) or {param.size ** 2} (full, row-major)."
    if param.choices:
        text += f" One of {list(param.choices)}."
    return text if param.bound is None else f"{text} ({bound_text(param)})"


def size_refusal(param: Param, n: int) -> str | None:
    """Why a value of ``n`` elements is refused for ``param`` (None if that many may do);
    needs nothing but the count, so it runs before any element is looked at."""
    m = param.size
    if param.max_values == 1 and param.kind not in VECTOR_KINDS:
        return None if n <= 1 else f"{param.name} takes a single value, got {n}"
    if param.kind in MATRIX_KINDS:
        if n in (m, m * m):
            return None
        return f"{param.name} needs {m} (diagonal) or {m * m} (full) values, got {n}"
    if param.kind in VECTOR_KINDS and m is not None:
        return None if n == m else f"{param.name} needs {m} values, got {n}"
    if n > param.max_values:
        return f"{param.name} takes at most {param.max_values} values, got {n}"
    return None


def _shown(value: Any, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _as_floats(value: Any) -> list[float] | None:
    try:
        return [float(v) for v in value]
    except (TypeError, ValueError):
        return None


def _beyond(param: Param, worst: float) -> str:
    return f"{param.name} is out of bounds ({bound_text(param)}): got {worst!r}"


def _matrix(param: Param, values: list[float]) -> tuple[bool, str, np.ndarray | None]:
    m = param.size
    matrix = np.diag(values) if len(values) == m else np.array(values).reshape(m, m)
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
        if param.bound is not None and abs(x) > param.bound:
            return False, _beyond(param, x), None
        return True, "", x
    if kind in VECTOR_KINDS + MATRIX_KINDS:
        if isinstance(value, (str, bytes, bool)) or not isinstance(value, Sized):
            return False, f"{param.name} must be a list of numbers", None
        if (reason := size_refusal(param, len(value))):
            return False, reason, None                      # before converting a single value
        values = _as_floats(value)
        if values is None:
            return False, f"{param.name} must be a list of numbers", None
        if not all(math.isfinite(v) for v in values):
            return False, f"{param.name} must be finite, got {_shown(values)}", None
        worst = max(values, key=abs, default=0.0)
        if param.bound is not None and abs(worst) > param.bound:
            return False, _beyond(param, worst), None
        if kind in MATRIX_KINDS:
            return _matrix(param, values)
        if kind == "positive_vector" and min(values, default=1.0) <= 0:
            return False, f"{param.name} must be all > 0, got {_shown(values)}", None
        if kind == "nonnegative_vector" and min(values, default=0.0) < 0:
            return False, f"{param.name} must be all >= 0, got {_shown(values)}", None
        return True, "", np.array(values)
    if kind == "bool":
        return (True, "", value) if isinstance(value, bool) else (False, f"{param.name} must be a bool", None)
    if kind == "integer":
        if isinstance(value, bool) or not isinstance(value, int):
            return False, f"{param.name} must be an integer", None
        if param.bound is not None and abs(value) > param.bound:
            return False, _beyond(param, value), None
        return True, "", value
    if kind == "string_list":
        if isinstance(value, str) or not isinstance(value, Sized):
            return False, f"{param.name} must be a list of strings", None
        if (reason := size_refusal(param, len(value))):
            return False, reason, None
        ok = all(isinstance(v, str) for v in value)
        return (True, "", list(value)) if ok else (False, f"{param.name} must be a list of strings", None)
    if not isinstance(value, str):
        return False, f"{param.name} must be a string", None
    if kind == "choice" and value not in param.choices:
        return False, f"{param.name} must be one of {list(param.choices)}, got {_shown(value)}", None
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
