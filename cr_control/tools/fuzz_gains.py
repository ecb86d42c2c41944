"""cr_fuzz's ``gains`` and ``gains_impedance`` suites: the Panda (``panda``) wiping with
adaptive_impedance and with impedance, one gain (or the careless user's pair) set live to its
accepted extreme: the largest value the controller accepts, and for a damping or a mass the
least (test/test_gain_matrix.py's offline matrix, here in a real-time session).

The extreme is found as a user would find it: through the controller's own parameter
service, by bisection (:func:`bisect_extreme`). A refused request leaves the value in force,
so every accepted step is set live on the way (the gain only ever moves towards its
extreme), and the last accepted value is the extreme beside the gains in force. The row's
"seen" says where it went. Judged, besides alive, finite and resumed: no safe stop (no
reflex), every joint below its URDF velocity limit, the true contact force at most
1.5 x the 10 N wiping target.
"""

from __future__ import annotations

import math
from functools import cache

from cr_control import robots
from cr_control.tools.fuzz_case import Case, Suite, nothing

SUITES = {"gains": Suite("gains_baseline", "panda", "adaptive_impedance"),
          "gains_impedance": Suite("gains_impedance_baseline", "panda", "impedance")}
#: The largest true contact force at an accepted extreme (N).
FORCE_LIMIT = 1.5 * robots.WIPE_FORCE
#: Bisection steps (requests) per gain: the extreme to 1e-9 of its range's logarithm.
BISECTION_STEPS = 30
#: The extremes each suite sets: (case name, [(parameter, "most" or "least"), ...]).
NULL_SPACE = [
    ("orientation_stiffness_most", [("orientation_stiffness", "most")]),
    ("orientation_damping_least", [("orientation_damping", "least")]),
    ("orientation_damping_most", [("orientation_damping", "most")]),
    ("posture_stiff_damped", [("posture_stiffness", "most"), ("posture_damping", "most")]),
]
EXTREMES = {
    "gains": NULL_SPACE + [("Q_c_most", [("Q_c", "most")]),
                           ("Q_c_star_most", [("Q_c_star", "most")])],
    "gains_impedance": NULL_SPACE + [("k_m_most", [("k_m", "most")]),
                                     ("m_m_least", [("m_m", "least")])],
}


@cache
def parameter_spec(scheme: str, robot: str, name: str):
    """The :class:`~cr_control.core.parameters.Param` ``name`` of ``scheme`` on ``robot``."""
    from cr_control.schemes.registry import controller_class

    specs = controller_class(scheme).parameters(
        robots.controller_values(robots.robot(robot), scheme))
    return next(p for p in specs if p.name == name)


def current_value(intruder, name: str):
    """The controller's value of ``name`` now (its ~/get_parameters)."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    client = intruder.node.create_client(GetParameters, f"{intruder.controller}/get_parameters")
    if not intruder.spin_until(client.service_is_ready, 10.0):
        raise RuntimeError(f"{intruder.controller}/get_parameters never appeared")
    future = client.call_async(GetParameters.Request(names=[name]))
    if not intruder.spin_until(future.done, 10.0):
        raise RuntimeError(f"no answer to get_parameters {name}")
    return parameter_value_to_python(future.result().values[0])


def bisect_extreme(accepted, now: float, bound: float, floor: float, side: str,
                   steps: int = BISECTION_STEPS) -> float:
    """The most (``side`` "most") or least size of a gain ``accepted(size)`` takes, found
    from the size ``now`` (taken): its ``bound`` (or ``floor``) if taken, else a bisection,
    geometric up to the bound, linear down to the floor. ``accepted`` may set it: every
    size it is asked beyond the last taken one lies between that one and the extreme."""
    if side == "most":
        if accepted(bound):
            return bound
        low, high = max(now, 1e-12 * bound), bound      # a gain at 0: from just above it
        for _ in range(steps):
            mid = math.sqrt(low * high)
            low, high = (mid, high) if accepted(mid) else (low, mid)
        return low
    if accepted(floor):
        return floor
    low, high = floor, now
    for _ in range(steps):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if accepted(mid) else (mid, high)
    return high


def set_extreme(intruder, name: str, side: str) -> None:
    """Set ``name`` live to the most (or least) size the controller accepts; a note says where."""
    from cr_control.schemes.blocks.gain_bounds import gain_size, of_size

    spec = parameter_spec(intruder.controller.lstrip("/"), intruder.robot, name)
    now = gain_size(current_value(intruder, name))

    def accepted(size: float) -> bool:
        future = intruder.set_parameters({name: of_size(spec, size)})
        return bool(future.done() and future.result().results[0].successful)

    floor = 0.0 if spec.kind.startswith("nonneg") else 1e-9
    size = bisect_extreme(accepted, now, float(spec.bound), floor, side)
    intruder.notes.append(f"{name} {now:.4g} -> {size:.4g} ({side}; bound {spec.bound:g})")


def set_extremes(changes: list[tuple[str, str]]):
    """A send that sets each (parameter, side) of ``changes`` to its extreme, in turn."""
    def send(intruder) -> None:
        for name, side in changes:
            set_extreme(intruder, name, side)
    return send


def _gain_case(suite: str, name: str, changes: list[tuple[str, str]]) -> Case:
    what = " then ".join(f"{param} to its {side} accepted" for param, side in changes)
    return Case(name if suite == "gains" else f"impedance_{name}", what, set_extremes(changes),
                suite=suite, extra_s=2.0, speed_judged=False, speed_limit_share=1.0,
                force_limit=FORCE_LIMIT)


CASES = [
    case
    for suite, (baseline, _, scheme) in SUITES.items()
    for case in [Case(baseline, f"nothing, {scheme} (the run the {suite} cases are judged "
                      "against)", nothing, suite=suite)]
    + [_gain_case(suite, name, changes) for name, changes in EXTREMES[suite]]
]
