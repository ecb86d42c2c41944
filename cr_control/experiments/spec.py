"""The SPEC of a sweep (``cr_sweep SPEC.yaml``): which scheme, for how long, what varies.

A SPEC is a YAML mapping with these keys::

    scheme: adaptive_impedance        # an executable name (cr_control.schemes.registry)
    robot: panda                      # optional: the robot's wiping task (cr_control.robots)
    duration: 4.0                     # simulated seconds per point
    vary:                             # node.param -> values, as ``cr_session -p node.param=v``
      adaptive_impedance.Q_c: [[5, 5], [50, 50]]   # a list of values: a grid axis
      plant.stiffness: {low: 15, high: 1500, log: true}   # a range: random draws
    samples: 20                       # with ranges: how many random points
    seed: 1                           # with ranges: the draws' seed
    metrics: [pos_err_rms_last_half_m]  # optional: the metrics kept (names of cr_analyze)
    set: {plant.damping: 5.0}         # optional: fixed overrides of every point

``node`` is the scheme's name (the controller) or ``plant``. Lists of every ``vary`` entry
form a grid (their product, in the order written). With ranges the points are ``samples``
random draws (uniform, or log-uniform with ``log: true``; a list next to ranges is drawn
from uniformly). A number given for a list or matrix parameter means that number on every
element (a matrix given by its diagonal: x I). Every value is checked against the
parameter's own declaration (:class:`cr_control.core.parameters.Param`: kind, size, bound)
before anything runs, so a bad SPEC fails with one line (:class:`SpecError`). The file is
read as :func:`read_yaml` reads it (at most 1 MiB, no YAML aliases); a value quoted in a
message is cut to 80 characters.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from cr_control import offline, robots
from cr_control.core import ros_yaml
from cr_control.core.parameters import MATRIX_KINDS, VECTOR_KINDS, Param, ParameterError, resolve
from cr_control.core.parameters import _shown as shown  # a value in a message, cut to 80 chars
from cr_control.schemes.registry import SCHEMES, controller_class, default_scenario
from cr_sim.plants.registry import SCENARIOS

KEYS = ("scheme", "robot", "duration", "vary", "samples", "seed", "metrics", "set")
#: Longest simulated time of one point (s): an hour of 1 kHz control.
MAX_DURATION_S = 3600.0
#: Most points of one sweep.
MAX_POINTS = 1_000_000
PLANT = "plant"


class SpecError(ValueError):
    """A SPEC that cannot run; the message (one line) says why."""


@dataclass(frozen=True)
class Range:
    """A random-draw range of one parameter: uniform in [low, high], log-uniform if ``log``."""

    low: float
    high: float
    log: bool = False


@dataclass
class SweepSpec:
    """A checked SPEC (see the module docstring)."""

    scheme: str
    duration: float
    vary: dict[str, list[Any] | Range]
    robot: str | None = None
    samples: int | None = None
    seed: int | None = None
    metrics: list[str] | None = None
    fixed: dict[str, Any] = field(default_factory=dict)

    @property
    def is_random(self) -> bool:
        """Random draws (some entry of ``vary`` is a range) rather than a grid."""
        return any(isinstance(v, Range) for v in self.vary.values())

    def canonical(self) -> dict[str, Any]:
        """The SPEC as plain data in a fixed form (what a results directory records)."""
        vary = {k: ({"low": v.low, "high": v.high, "log": v.log} if isinstance(v, Range) else v)
                for k, v in self.vary.items()}
        return {"scheme": self.scheme, "robot": self.robot, "duration": self.duration,
                "vary": vary, "samples": self.samples, "seed": self.seed,
                "metrics": self.metrics, "set": self.fixed}

    def digest(self) -> str:
        """A hash of what the points compute (metrics kept aside: they only select columns)."""
        data = {k: v for k, v in self.canonical().items() if k != "metrics"}
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


# -- the parameters a point may set -----------------------------------------------------------

@dataclass
class Targets:
    """The declared parameters of the two nodes of an offline run, and their base values."""

    scheme: str
    robot: str | None
    controller: dict[str, Param]
    plant: dict[str, Param]
    controller_base: dict[str, Any]
    plant_base: dict[str, Any]

    def param(self, name: str) -> Param:
        """The Param of ``node.param`` (SpecError if there is none)."""
        node, dot, key = name.partition(".")
        if not dot or not node or not key:
            raise SpecError(f"{shown(name)} is not of the form node.param (node: {self.scheme} "
                            f"or {PLANT})")
        table = {self.scheme: self.controller, PLANT: self.plant}.get(node)
        if table is None:
            raise SpecError(f"{shown(name)}: no node {shown(node)} in an offline run of "
                            f"{self.scheme} (nodes: {self.scheme}, {PLANT})")
        if key not in table:
            raise SpecError(f"{name[:80]}: unknown parameter {shown(key)} of {node}")
        return table[key]

    def split(self, values: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
        """``node.param -> value`` as (controller overrides, plant overrides), numbers given
        for list or matrix parameters spread over every element."""
        controller: dict[str, Any] = {}
        plant: dict[str, Any] = {}
        for name, value in values.items():
            param = self.param(name)
            node, _, key = name.partition(".")
            (plant if node == PLANT else controller)[key] = spread(param, value, name)
        return controller, plant

    def check(self, values: dict[str, Any]) -> None:
        """SpecError unless both nodes take ``values`` (every declaration's check)."""
        controller, plant = self.split(values)
        for node, specs, base, given in ((self.scheme, self.controller, self.controller_base,
                                          controller),
                                         (PLANT, self.plant, self.plant_base, plant)):
            try:
                resolve(list(specs.values()), {**base, **given})
            except ParameterError as exc:
                raise SpecError(f"{node}: {exc}") from None


def spread(param: Param, value: Any, name: str) -> Any:
    """``value`` for ``param``: a number for a list or matrix parameter -> that number on
    each element of the default's length (a matrix given by its diagonal: x I)."""
    if param.kind in VECTOR_KINDS + MATRIX_KINDS and isinstance(value, (int, float)) \
            and not isinstance(value, bool):
        size = len(param.default)
        if size == 0:
            raise SpecError(f"{name}: a number cannot stand for this list (its default is "
                            "empty): give the list")
        return [float(value)] * size
    return value


def targets(scheme: str, robot: str | None) -> Targets:
    """The parameters of ``scheme``'s offline run (on ``robot``'s wiping task if given)."""
    if robot is None:
        scenario = default_scenario(scheme)
        controller_base: dict[str, Any] = {}
        plant_base = offline.scheme_plant_overrides(scheme)
    else:
        if robot not in robots.ROBOTS:
            raise SpecError(f"robot: unknown robot {shown(robot)}; known: {sorted(robots.ROBOTS)}")
        try:
            r = robots.robot(robot)
            controller_base = robots.controller_values(r, scheme)
        except ValueError as exc:
            raise SpecError(f"robot: {exc}") from None
        values = robots.plant_values(r)
        scenario = values["scenario"]
        plant_base = {k: v for k, v in values.items() if k != "scenario"}
    cls = controller_class(scheme)
    return Targets(scheme, robot, {p.name: p for p in cls.parameters(controller_base)},
                   {p.name: p for p in SCENARIOS[scenario][0]}, controller_base, plant_base)


# -- parsing ---------------------------------------------------------------------------------

def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError(f"{what} must be a finite number, got {shown(value)}")
    return float(value)


def _integer(value: Any, what: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise SpecError(f"{what} must be an integer in [{low}, {high}], got {shown(value)}")
    return value


def _range(name: str, body: dict[str, Any], param: Param) -> Range:
    unknown = set(body) - {"low", "high", "log"}
    if unknown or not {"low", "high"} <= set(body):
        raise SpecError(f"vary: {name}: a range is {{low, high, log}}, got keys "
                        f"{shown(sorted(map(str, body)))}")
    low, high = _number(body["low"], f"{name}.low"), _number(body["high"], f"{name}.high")
    log = body.get("log", False)
    if not isinstance(log, bool):
        raise SpecError(f"vary: {name}.log must be true or false, got {shown(log)}")
    if not low < high:
        raise SpecError(f"vary: {name}: low ({low}) must be below high ({high})")
    if log and low <= 0:
        raise SpecError(f"vary: {name}: a log range needs low > 0, got {low}")
    if param.kind not in ("finite", "positive", "nonnegative", "integer") + VECTOR_KINDS \
            + MATRIX_KINDS:
        raise SpecError(f"vary: {name}: a range needs a numeric parameter ({param.kind})")
    return Range(low, high, log)


def check_keys(data: Any, keys: Sequence[str], required: Sequence[str], source: str) -> None:
    """SpecError (one line) unless ``data`` is a mapping of ``keys`` only, ``required`` among
    them (a sweep SPEC's, a tune SPEC's)."""
    if not isinstance(data, dict):
        raise SpecError(f"{source}: a mapping with keys {', '.join(keys)} is expected")
    unknown = [k for k in data if k not in keys]
    if unknown:
        raise SpecError(f"{source}: unknown key {shown(unknown[0])} (keys: {', '.join(keys)})")
    for key in required:
        if key not in data:
            raise SpecError(f"{source}: missing key {key!r}")


def parse_spec(data: Any, source: str = "SPEC") -> tuple[SweepSpec, Targets]:
    """The checked SPEC of ``data`` (the YAML mapping) and its parameters; SpecError (one
    line) for anything that would not run: a missing or unknown key, an unknown scheme,
    robot, node or parameter, an empty grid, or a value the parameter refuses."""
    check_keys(data, KEYS, ("scheme", "duration", "vary"), source)
    scheme = data["scheme"]
    if scheme not in SCHEMES:
        raise SpecError(f"scheme: unknown scheme {shown(scheme)} (known: {', '.join(sorted(SCHEMES))})")
    robot = data.get("robot")
    if robot is not None and not isinstance(robot, str):
        raise SpecError(f"robot must be a robot name, got {shown(robot)}")
    duration = _number(data["duration"], "duration")
    if not 0 < duration <= MAX_DURATION_S:
        raise SpecError(f"duration must be in (0, {MAX_DURATION_S:g}] s, got {duration:g}")
    t = targets(scheme, robot)
    vary_in = data["vary"]
    if not isinstance(vary_in, dict) or not vary_in:
        raise SpecError("vary must be a non-empty mapping node.param -> list or range: "
                        "the grid is empty")
    vary: dict[str, list[Any] | Range] = {}
    for name, values in vary_in.items():
        name = str(name)
        param = t.param(name)
        if isinstance(values, dict):
            vary[name] = r = _range(name, values, param)
            for end in (r.low, r.high):
                t.check({name: int(end) if param.kind == "integer" else end})
        elif isinstance(values, list):
            if not values:
                raise SpecError(f"vary: {name} has no values: the grid is empty")
            for value in values:
                t.check({name: value})
            vary[name] = values
        else:
            raise SpecError(f"vary: {name} must be a list of values or a range "
                            f"{{low, high, log}}, got {shown(values)}")
    fixed_in = data.get("set") or {}
    if not isinstance(fixed_in, dict):
        raise SpecError(f"set must be a mapping node.param -> value, got {shown(fixed_in)}")
    fixed = {str(k): v for k, v in fixed_in.items()}
    overlap = sorted(set(fixed) & set(vary))
    if overlap:
        raise SpecError(f"{overlap[0]} is both in set and in vary")
    t.check(fixed)
    random = any(isinstance(v, Range) for v in vary.values())
    samples = seed = None
    if random:
        for key in ("samples", "seed"):
            if key not in data:
                raise SpecError(f"{key} is needed with a random range in vary")
        samples = _integer(data["samples"], "samples", 1, MAX_POINTS)
        seed = _integer(data["seed"], "seed", 0, 2**63 - 1)
    elif "samples" in data or "seed" in data:
        raise SpecError("samples and seed go with ranges {low, high, log}; lists in vary form "
                        "a grid")
    else:
        size = math.prod(len(v) for v in vary.values())          # type: ignore[arg-type]
        if size > MAX_POINTS:
            raise SpecError(f"the grid has {size} points; at most {MAX_POINTS}")
    metrics = data.get("metrics")
    if metrics is not None and (not isinstance(metrics, list) or not metrics
                                or not all(isinstance(m, str) for m in metrics)):
        raise SpecError(f"metrics must be a non-empty list of metric names, got {shown(metrics)}")
    spec = SweepSpec(scheme, duration, vary, robot, samples, seed, metrics, fixed)
    return spec, t


def read_yaml(path: str | Path) -> Any:
    """The YAML file ``path`` (a sweep's or a tune SPEC) as data; SpecError (one line) if it
    cannot be read, is not a regular file, is larger than 1 MiB (ros_yaml.MAX_FILE_BYTES),
    is not valid YAML or uses aliases (they can expand exponentially)."""
    try:
        text = ros_yaml.read_file(path)
    except OSError as exc:
        raise SpecError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise SpecError(f"{path}: {exc}") from None
    try:
        return ros_yaml.load(text)
    except yaml.YAMLError as exc:
        raise SpecError(f"{path}: not valid YAML: {ros_yaml.describe_error(exc)}") from None


def load_spec(path: str | Path) -> tuple[SweepSpec, Targets]:
    """:func:`parse_spec` of the YAML file ``path`` (SpecError as :func:`read_yaml` says)."""
    return parse_spec(read_yaml(path), str(path))
