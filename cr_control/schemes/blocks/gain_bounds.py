"""The bounds of the gains that act on the arm: the discrete-time rule
(:mod:`cr_control.models.discrete_gains`) applied at start-up to the chain's inertias, the
control period and the driver's transport delay.

A gain's loop is stable when its normalised stiffness k = K T^2 / M and damping
c = D T / M keep every root of z^d (z - 1)^2 + (k/2)(z + 1) + c (z - 1) inside the unit
circle (T the control period, d the delay in cycles, M the inertia it acts through). Here
the bounds ask that with a margin:

- at :data:`DELAY_FACTOR` (3) times the delay the robot declares (``command_delay_cycles``:
  a controller on a loaded machine answers late, and a driver may hold an answer longer
  than its nominal cycle), and
- with a gain margin of :data:`GAIN_MARGIN` (2, i.e. 6 dB) there: the gains twice as large
  would still be stable (the model's inertias, the torque loops and filters of the joints are
  not exact).

The inertia of each gain is the lightest it acts through, over the home pose (``posture``)
and :data:`SAMPLES` configurations drawn (seeded) within the URDF's joint limits: the
workspace's range (:func:`inertias`):

- the orientation impedance (``orientation_*``): 1 / the largest eigenvalue of the rotation
  rows' mobility J_o M^-1 N^T J_o^T in the position task's null space (the Panda's and the
  UR5's lightest is the turn about the tool's axis: 6.7e-3 and 1.7e-2 kg m^2);
- the posture task (``posture_*``, redundant arms): 1 / the largest eigenvalue of
  N_s M^-1, N_s the null space of position and orientation together;
- the joint limit guard (``joint_limit_*``): the lightest joint alone, 1 / max (M^-1)_jj;
- a law's own force-unit gains on the position task: 1 / the largest eigenvalue of
  J M^-1 J^T, the task's lightest direction.

Stiffness and damping act together, so a pair is judged together (:func:`pair_refusal`: a
stiffness needs at least the damping that holds it and at most what the damping allows; a
spring without damping is refused, as a sampled spring gains energy every period); each
one's bound in its descriptor is the most it may take with the best partner.

On the thesis's 2-link arm (no null space: every joint is the position task's; delay 0, as
its simulations) the bounds are the plain :class:`~cr_control.core.parameters.Bound` ones:
its gains are the thesis's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import pinocchio as pin

from cr_control.core.parameters import MATRIX_KINDS, VECTOR_KINDS, Param, ParameterError
from cr_control.models import discrete_gains as dg

#: The bounds hold at this many times the delay the robot declares (module docstring).
DELAY_FACTOR = 3
#: ... with this gain margin there.
GAIN_MARGIN = 2.0
#: A default damping above what the rule lets its stiffness take is lowered to this fraction
#: of the most it may be (the middle of the range, 0.58 N m s/rad on panda_ft's wrist, left the
#: arm holding still in free space too loosely for a ~/zero_ft: 0.07 rad/s at joint 6).
DEFAULT_DAMPING_FRACTION = 0.8
#: Configurations drawn within the joint limits for the inertias' range.
SAMPLES = 64
#: The orientation rows' scale in the posture projector (as task_space.ORIENTATION_LENGTH).
_ORIENTATION_LENGTH = 0.1
#: The task's apparent mass cap of the damped inverse (as task_space's singularity_mass
#: default): the posture projector uses it.
_SINGULARITY_MASS = 100.0

#: The controller's knowledge of its loop: the period and the driver's delay.
PARAMETERS = [
    Param("control_period", 0.001, "The period of the states this controller answers (s): "
          "the driver's cycle (franka_ros2: 1 ms; ur_robot_driver: 2 ms). With "
          "command_delay_cycles it bounds the gains that act on the joints (the discrete-time "
          "rule: docs/safety.md, 'Gains a sampled, delayed loop takes').", "positive",
          read_only=True, bound=1.0),
    Param("command_delay_cycles", 1, "The driver's transport delay (periods): the answer to "
          "the state of one cycle acts this many cycles later (libfranka and ur_robot_driver's "
          "effort interface: 1, the next cycle). The gains' bounds hold at 3 times it with a "
          "gain margin of 2; the controller warns at start when the round trip it measures "
          "is longer than the delay its gains tolerate.", "integer", read_only=True,
          bound=1000),
    Param("contact_stiffness", 0.0, "The stiffest surface the task presses on (N/m): the "
          "gains whose loop closes through the contact (the normal impedance's k_m, d_m, m_m; "
          "the fuzzy law's lambda and d_med; the force admittance's mass and damping) keep its "
          "damping ratio at least 0.15 there (docs/safety.md, 'Gains a sampled, delayed loop "
          "takes'). The robot profiles: their table's 5000 N/m; 0 = not judged.",
          "nonnegative", read_only=True, bound=1e9),
    Param("tolerated_delay_cycles", 0, "The largest delay (periods: the driver's and the "
          "answers' lateness together) these gains tolerate: the controller warns once at start "
          "when the round trip it measures in real time goes beyond it. The robot profiles set "
          "the measured margin of their scheme (docs/safety.md, 'Gains a sampled, delayed loop "
          "takes'); 0 = the discrete-time rule's figure for the joint-space gains in force.",
          "integer", read_only=True, bound=1000),
]
#: The thesis arm's: its simulations apply each answer over the period that starts with
#: the state it answers.
THESIS_DELAY_CYCLES = 0


@dataclass(frozen=True)
class Inertias:
    """The lightest inertia each family of gains acts through (kg m^2 or kg), at the home
    pose and the least over the sampled workspace."""

    orientation: tuple[float, float]
    posture: tuple[float, float]
    joint: tuple[float, float]
    task: tuple[float, float]


_INERTIAS: dict[int, tuple[object, Inertias]] = {}


def _mobility_max(A: np.ndarray) -> float:
    """The largest eigenvalue of a mobility matrix (symmetric up to round-off; 0 if empty)."""
    if A.size == 0:
        return 0.0
    return float(np.linalg.eigvalsh(0.5 * (A + A.T)).max())


def _damped_inverse(J: np.ndarray, M_inv: np.ndarray) -> np.ndarray:
    """Lambda = (J M^-1 J^T + lambda^2 I)^-1, the apparent mass capped (task_space)."""
    mobility = J @ M_inv @ J.T
    lam2 = max(0.0, 1.0 / _SINGULARITY_MASS - float(np.linalg.eigvalsh(mobility).min()))
    return np.linalg.inv(mobility + lam2 * np.eye(J.shape[0]))


def _at(model, q: np.ndarray, data) -> tuple[float, float, float, float]:
    """(orientation, posture, joint, task) mobility maxima at the configuration q."""
    chain = model.chain_model
    n = model.n
    qp = chain.configuration(q)
    M = pin.crba(chain.model, data, qp)
    M = (np.triu(M) + np.triu(M, 1).T)[:n, :n]
    M_inv = np.linalg.inv(M)
    J6 = pin.computeFrameJacobian(chain.model, data, qp, chain.tip,
                                  pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:, :n]
    position = [int(r) for r in model.task[3:3 + model.m]]
    rotation = [3 + int(r) for r in model.task[6:6 + len(model.orientation_axes)]]
    J, J_o = J6[position], J6[rotation]
    Lam = _damped_inverse(J, M_inv)
    N = np.eye(n) - M_inv @ J.T @ Lam @ J
    orientation = _mobility_max(J_o @ M_inv @ N.T @ J_o.T) if len(rotation) else 0.0
    posture = 0.0
    if model.redundant:
        stacked = np.vstack([J, _ORIENTATION_LENGTH * J_o])
        N_s = np.eye(n) - M_inv @ stacked.T @ _damped_inverse(stacked, M_inv) @ stacked
        posture = _mobility_max(N_s @ M_inv)
    return orientation, posture, float(np.max(np.diag(M_inv))), _mobility_max(J @ M_inv @ J.T)


def inertias(model, home: np.ndarray) -> Inertias:
    """The :class:`Inertias` of a task model (:class:`~cr_control.schemes.blocks.task_space.
    TaskModel`): at ``home`` and least over it and SAMPLES configurations within the joint
    limits (seeded: the same every start). Cached per model and home pose."""
    key = hash((id(model), np.asarray(home, dtype=float).tobytes()))
    cached = _INERTIAS.get(key)
    if cached is not None and cached[0] is model:
        return cached[1]
    chain = model.chain_model
    data = chain.model.createData()
    lim = chain.limits
    lower = np.where(np.isfinite(lim.lower), lim.lower, -math.pi)
    upper = np.where(np.isfinite(lim.upper), lim.upper, math.pi)
    rng = np.random.default_rng(0)
    configurations = [np.asarray(home, dtype=float)] + [rng.uniform(lower, upper)
                                                        for _ in range(SAMPLES)]
    mobility = np.array([_at(model, q, data) for q in configurations])

    def pair(i: int) -> tuple[float, float]:
        at_home, most = float(mobility[0, i]), float(mobility[:, i].max())
        return (1.0 / at_home if at_home > 0.0 else math.inf,
                1.0 / most if most > 0.0 else math.inf)

    result = Inertias(pair(0), pair(1), pair(2), pair(3))
    _INERTIAS[key] = (model, result)
    return result


@lru_cache(maxsize=256)
def _max_stiffness(c: float, delay: int) -> float:
    return dg.max_stiffness(c, delay, GAIN_MARGIN)


@lru_cache(maxsize=64)
def _best_stiffness(delay: int) -> float:
    limit = dg.damping_limit(delay) / GAIN_MARGIN
    return max(_max_stiffness(float(c), delay) for c in np.linspace(0.0, limit, 41)[1:])


@lru_cache(maxsize=256)
def _damping_range(k: float, delay: int) -> tuple[float, float]:
    return dg.damping_range(k, delay, GAIN_MARGIN)


@dataclass(frozen=True)
class Loop:
    """The rule's loop for one family of gains: its inertia M (the least over the workspace),
    the period T and the delay the bounds hold at (DELAY_FACTOR x the declared one)."""

    inertia: float
    period: float
    delay: int

    def normalised(self, stiffness: float, damping: float) -> tuple[float, float]:
        """(k, c) = (K T^2 / M, D T / M)."""
        T, M = self.period, self.inertia
        return stiffness * T * T / M, damping * T / M

    def max_damping(self) -> float:
        """The largest damping alone (N m s/rad or N s/m)."""
        return dg.damping_limit(self.delay) / GAIN_MARGIN * self.inertia / self.period

    def max_stiffness(self, damping: float) -> float:
        """The largest stiffness beside ``damping``."""
        c = self.normalised(0.0, damping)[1]
        return _max_stiffness(float(c), self.delay) * self.inertia / self.period ** 2

    def best_stiffness(self) -> float:
        """The largest stiffness with the best damping beside it (the bound alone)."""
        return _best_stiffness(self.delay) * self.inertia / self.period ** 2

    def damping_range(self, stiffness: float) -> tuple[float, float]:
        """(least, most) damping beside ``stiffness`` (nan, nan: none)."""
        k = self.normalised(stiffness, 0.0)[0]
        low, high = _damping_range(float(k), self.delay)
        return low * self.inertia / self.period, high * self.inertia / self.period

    def stable(self, stiffness: float, damping: float) -> bool:
        """Whether the pair is stable with the margin at the loop's delay."""
        k, c = self.normalised(stiffness, damping)
        return dg.stable_with_margin(k, c, self.delay, GAIN_MARGIN)

    def why(self) -> str:
        """The rule's figures in words, for a descriptor or a refusal."""
        return (f"inertia {self.inertia:.3g}, period {self.period * 1e3:g} ms, stable at "
                f"{self.delay} cycles of delay with gain margin {GAIN_MARGIN:g}")


def loops(model, home: np.ndarray, period: float, delay_cycles: int) -> dict[str, Loop]:
    """The rule's loop of each family (module docstring): ``orientation``, ``posture``,
    ``joint`` and ``task``, at DELAY_FACTOR x ``delay_cycles``."""
    found = inertias(model, home)
    delay = DELAY_FACTOR * int(delay_cycles)
    return {name: Loop(getattr(found, name)[1], float(period), delay)
            for name in ("orientation", "posture", "joint", "task")}


#: The null-space gains governed by the rule: name -> (family, role, partner).
NULL_SPACE_RULES = {
    "orientation_stiffness": ("orientation", "stiffness", "orientation_damping"),
    "orientation_damping": ("orientation", "damping", "orientation_stiffness"),
    "posture_stiffness": ("posture", "stiffness", "posture_damping"),
    "posture_damping": ("posture", "damping", "posture_stiffness"),
    "joint_limit_stiffness": ("joint", "stiffness", None),
    "joint_limit_damping": ("joint", "damping", None),
}


def bounded(param: Param, loop: Loop, role: str) -> Param:
    """``param`` with the rule's bound (the most it may take with the best partner) and its
    default lowered to it if above (a vector's every value), the why in its description."""
    limit = loop.max_damping() if role == "damping" else loop.best_stiffness()
    if not math.isfinite(limit) or limit <= 0.0:
        return param
    bound = float(_round_down(limit))
    default = param.default
    if isinstance(default, (list, tuple)):
        default = [min(float(x), bound) for x in default]
    else:
        default = min(float(default), bound)
    return replace(param, bound=bound, default=default, description=(
        f"{param.description} Bounded by the discrete-time rule ({loop.why()})."))


def _round_down(x: float) -> float:
    """x rounded down to 3 significant digits (a bound as people write it, never above x)."""
    if x <= 0.0 or not math.isfinite(x):
        return x
    scale = 10.0 ** (math.floor(math.log10(x)) - 2)
    return float(f"{math.floor(x / scale * (1.0 + 1e-12)) * scale:.3g}")


def pair_refusal(name: str, stiffness: float, damping: float, loop: Loop, stiffness_name: str,
                 damping_name: str) -> str | None:
    """Why a stiffness and a damping together leave the rule's loop unstable (one line that
    names the bound), or None."""
    if stiffness == 0.0:
        limit = loop.max_damping()
        if damping <= limit:
            return None
        return (f"{damping_name} {damping:g} is above its bound {_round_down(limit):g} "
                f"({loop.why()})")
    if loop.stable(stiffness, damping):
        return None
    low, high = loop.damping_range(stiffness)
    if math.isnan(low):
        return (f"{stiffness_name} {stiffness:g} is above its bound "
                f"{_round_down(loop.best_stiffness()):g} ({loop.why()})")
    most = loop.max_stiffness(damping)
    if name == stiffness_name and most > 0.0:
        return (f"{stiffness_name} {stiffness:g} with {damping_name} {damping:g}: above its "
                f"bound {_round_down(most):g} beside that damping ({loop.why()})")
    if damping < low:
        return (f"{stiffness_name} {stiffness:g} with {damping_name} {damping:g}: that "
                f"stiffness needs {damping_name} >= {low:.3g} ({loop.why()}; a sampled spring "
                "without enough damping gains energy every period)")
    return (f"{damping_name} {damping:g} with {stiffness_name} {stiffness:g}: above its bound "
            f"{_round_down(high):g} beside that stiffness ({loop.why()})")


def check_pairs(values: dict, loops_: dict[str, Loop], changed: str | None = None) -> None:
    """ParameterError (one line) if a stiffness and damping pair of the null space leaves its
    loop unstable, per axis for the orientation's; ``changed``: the parameter being set
    (named first in the line)."""
    for stiffness_name, damping_name, family in (
            ("orientation_stiffness", "orientation_damping", "orientation"),
            ("posture_stiffness", "posture_damping", "posture")):
        loop = loops_[family]
        if not math.isfinite(loop.inertia) or stiffness_name not in values:
            continue
        K = np.atleast_1d(np.asarray(values[stiffness_name], dtype=float))
        D = np.atleast_1d(np.asarray(values[damping_name], dtype=float))
        for i, (k, d) in enumerate(zip(K, D, strict=True)):
            name = changed if changed in (stiffness_name, damping_name) else stiffness_name
            why = pair_refusal(name, float(k), float(d), loop, stiffness_name, damping_name)
            if why is not None:
                axis = f" (axis {'xyz'[i]})" if len(K) > 1 else ""
                raise ParameterError(why + axis)


def home_pose(model, values: dict) -> np.ndarray:
    """The pose the inertias are taken at besides the sampled ones: ``posture`` where given,
    else the middle of each joint's limits (0 without limits)."""
    posture = np.asarray(values.get("posture", []), dtype=float).ravel()
    if posture.shape == (model.n,):
        return posture
    lim = model.chain_model.limits
    middle = 0.5 * (lim.lower + lim.upper)
    return np.where(np.isfinite(middle), middle, 0.0)


def loop_settings(values: dict, thesis: bool) -> tuple[float, int]:
    """(period, declared delay) from ``values`` (defaults where absent; the thesis arm's delay
    is THESIS_DELAY_CYCLES)."""
    defaults = {p.name: p.default for p in parameters(thesis)}
    period = float(values.get("control_period", defaults["control_period"]))
    delay = int(values.get("command_delay_cycles", defaults["command_delay_cycles"]))
    return period, delay


def parameters(thesis: bool) -> list[Param]:
    """:data:`PARAMETERS` (on the thesis's arm with its delay, 0)."""
    if not thesis:
        return list(PARAMETERS)
    return [replace(p, default=THESIS_DELAY_CYCLES) if p.name == "command_delay_cycles" else p
            for p in PARAMETERS]


def null_space_parameters(specs: list[Param], loops_: dict[str, Loop]) -> list[Param]:
    """``specs`` (the null-space parameters) with the rule's bounds (:func:`bounded`); the
    defaults of a stiffness and damping pair moved where the pair would not be stable: the
    stiffness to its bound, then a damping above the range that stiffness takes to
    DEFAULT_DAMPING_FRACTION of that range's top (at the top itself the stiffness would have
    no room left)."""
    out = {p.name: p for p in specs}
    for name, (family, role, _) in NULL_SPACE_RULES.items():
        loop = loops_[family]
        if name in out and math.isfinite(loop.inertia):
            out[name] = bounded(out[name], loop, role)
    for stiffness_name, damping_name, family in (
            ("orientation_stiffness", "orientation_damping", "orientation"),
            ("posture_stiffness", "posture_damping", "posture")):
        loop = loops_[family]
        if not math.isfinite(loop.inertia) or stiffness_name not in out:
            continue
        K, D = out[stiffness_name], out[damping_name]
        stiffness = np.atleast_1d(np.asarray(K.default, dtype=float))
        damping = np.atleast_1d(np.asarray(D.default, dtype=float))
        for i, k in enumerate(stiffness):
            if k > 0.0:
                low, high = loop.damping_range(float(k))
                if damping[i] > high:
                    damping[i] = _round_down(max(DEFAULT_DAMPING_FRACTION * high, low))
                damping[i] = max(damping[i], low)
        value = damping.tolist() if isinstance(D.default, (list, tuple)) else float(damping[0])
        out[damping_name] = replace(D, default=value)
    return [out[p.name] for p in specs]


#: The rule's tolerated delay is searched up to this many cycles.
MAX_TOLERATED_CYCLES = 100


def tolerated_delay(values: dict, loops_: dict[str, Loop]) -> int:
    """The discrete-time rule's largest delay (cycles) at which every joint-space gain in
    ``values`` is still stable (no margin: the edge), on the inertias of ``loops_``."""
    pairs = []
    for stiffness_name, damping_name, family in (
            ("orientation_stiffness", "orientation_damping", "orientation"),
            ("posture_stiffness", "posture_damping", "posture")):
        loop = loops_[family]
        if math.isfinite(loop.inertia) and stiffness_name in values:
            K = np.atleast_1d(np.asarray(values[stiffness_name], dtype=float))
            D = np.atleast_1d(np.asarray(values[damping_name], dtype=float))
            pairs += [loop.normalised(float(k), float(d)) for k, d in zip(K, D, strict=True)]
    joint = loops_["joint"]
    if math.isfinite(joint.inertia) and "joint_limit_damping" in values:
        pairs.append(joint.normalised(0.0, float(values["joint_limit_damping"])))
    d = 0
    while d < MAX_TOLERATED_CYCLES and all(dg.stable(k, c, d + 1) for k, c in pairs):
        d += 1
    return d


# -- the laws' own gains --------------------------------------------------------------------------
def gain_size(value) -> float:
    """The size of a gain: a scalar's magnitude, a vector's largest element, a matrix's
    largest singular value (its largest gain in any direction)."""
    x = np.asarray(value, dtype=float)
    if x.ndim == 2:
        return float(np.linalg.norm(x, 2))
    return float(np.max(np.abs(x))) if x.size else 0.0


@dataclass(frozen=True)
class LawRule:
    """One loop a law's gains close, in the rule's normalised gains: ``gains(values, T, M)``
    gives (k, c) or None where the law has no such loop; ``names`` are the parameters it
    reads; ``through``: ``plant`` (the torque acts through the arm: DELAY_FACTOR x the
    declared delay, the task's lightest inertia M) or ``internal`` (an integrator inside the
    law, stepped once a period: no delay, M unused); ``what`` says which loop."""

    what: str
    names: tuple[str, ...]
    through: str
    gains: object


def _ch5(stiffness: str, damping: str):
    def gains(v, T, M):
        m = float(v["m_m"])
        return gain_size(v[stiffness]) * T * T / m, gain_size(v[damping]) * T / m
    return gains


def _fuzzy(damping: str):
    def gains(v, T, M):
        m, d = float(v["m_m"]), float(v[damping])
        return float(v["lambda"]) * d * T * T / m, d * T / m
    return gains


def _adaptation(v, T, M):
    """The estimates' linear part (3.11-3.14): c_hat = c_hat(0) - Q_c int(varpi) - Q_c*
    varpi, varpi = P1 xi + P2 xi', acts as a damping Q_c* P2 and a stiffness Q_c* P1 +
    Q_c P2 beside the impedance A_hat(0), B_hat(0) it starts from (accelerations: the law's
    model of the arm cancels M)."""
    p1, p2 = gain_size(v["P1"]), gain_size(v["P2"])
    damping = gain_size(v["A_hat_0"]) + gain_size(v["Q_c_star"]) * p2
    stiffness = gain_size(v["B_hat_0"]) + gain_size(v["Q_c_star"]) * p1 + gain_size(v["Q_c"]) * p2
    return stiffness * T * T, damping * T


LAW_RULES = (
    LawRule("the normal impedance (5.6): k_m, d_m through m_m", ("k_m", "d_m", "m_m"), "plant",
            _ch5("k_m", "d_m")),
    LawRule("the tangential impedance through m_m",
            ("tangential_stiffness", "tangential_damping", "m_m"), "plant",
            _ch5("tangential_stiffness", "tangential_damping")),
    *(LawRule(f"the fuzzy impedance's {name} (k = lambda d) through m_m",
              (name, "lambda", "m_m"), "plant", _fuzzy(name)) for name in ("d_s", "d_med", "d_b")),
    LawRule("the estimates' linear part (3.11-3.14)",
            ("A_hat_0", "B_hat_0", "P1", "P2", "Q_c", "Q_c_star"), "plant", _adaptation),
    LawRule("the reference model (3.8), stepped each period", ("A_m", "B_m"), "internal",
            lambda v, T, M: (gain_size(v["B_m"]) * T * T, gain_size(v["A_m"]) * T)),
    LawRule("the sliding gain K_s s (3.48) through the task's lightest inertia", ("K_s",),
            "plant", lambda v, T, M: (0.0, gain_size(v["K_s"]) * T / M)),
    LawRule("the compensator z' = D z + ... (3.40), whose K_2 z' drives r_eq'' (3.50) through "
            "the arm", ("D",), "plant", lambda v, T, M: (0.0, gain_size(v["D"]) * T)),
    LawRule("the G_r network's adaptation (3.81): G_r^' = Gamma_G |xi|^2 s, a stiffness on s "
            "beside K_s through the task's lightest inertia (|xi|^2 <= rbf_max_nodes: every "
            "activation (3.69) is at most 1)", ("Gamma_G", "K_s", "rbf_max_nodes"), "plant",
            lambda v, T, M: (gain_size(v["Gamma_G"]) * float(v["rbf_max_nodes"]) * T * T / M,
                             gain_size(v["K_s"]) * T / M)),
    LawRule("the force admittance m_a delta'' + d_a delta' = f_d - f through the arm",
            ("force_admittance_mass", "force_admittance_damping"), "plant",
            lambda v, T, M: (0.0, float(v["force_admittance_damping"]) * T
                             / float(v["force_admittance_mass"]))),
)
#: The least damping ratio of a loop that closes through the contact, on a surface of
#: ``contact_stiffness`` K_c: zeta = d / (2 sqrt(m k)) of m x'' + d x' + k x (a step of the
#: force target then overshoots by at most 62 %). The profiles' defaults: 0.19 (the chapter 5
#: impedance on the Panda and the UR5), 0.35 (the chapter 3 force admittance). Measured below
#: it: k_m 8050 N/m (0.12) pressed 22 N, m_m 1000 kg (0.007) rang at 26 N.
CONTACT_DAMPING_RATIO = 0.15


@dataclass(frozen=True)
class ContactRule:
    """A loop a law's gains close through the contact: ``loop(values, K_c)`` gives its mass,
    damping and stiffness (m, d, k) on a surface of stiffness K_c, or None where the law has
    no such loop; ``names`` are the parameters it reads."""

    what: str
    names: tuple[str, ...]
    loop: object


def _fuzzy_contact(v, K):
    d = float(v["d_med"])
    return float(v["m_m"]), d, float(v["lambda"]) * d + K


def _admittance_contact(v, K):
    d = float(v["force_admittance_damping"])
    return None if d == 0.0 else (float(v["force_admittance_mass"]), d, K)


CONTACT_RULES = (
    ContactRule("the normal impedance (5.6) on the contact, m_m x'' + d_m x' + (k_m + K_c) x",
                ("k_m", "d_m", "m_m"),
                lambda v, K: (float(v["m_m"]), gain_size(v["d_m"]), gain_size(v["k_m"]) + K)),
    ContactRule("the fuzzy impedance at its force target (5.20 gives d_m = d_med, k_m = "
                "lambda d_med) on the contact", ("lambda", "d_med", "m_m"), _fuzzy_contact),
    ContactRule("the force admittance on the contact, m_a delta'' + d_a delta' + K_c delta",
                ("force_admittance_mass", "force_admittance_damping"), _admittance_contact),
)
#: The parameters a contact rule reads.
CONTACT_GAINS = frozenset(name for rule in CONTACT_RULES for name in rule.names)


def contact_refusal(values: dict, reading: str | None = None) -> str | None:
    """Why a loop through the contact (:data:`CONTACT_RULES`) has a damping ratio below
    CONTACT_DAMPING_RATIO on ``contact_stiffness``, in one line, or None (also where
    ``contact_stiffness`` is 0 or absent)."""
    K = float(values.get("contact_stiffness", 0.0))
    if not K > 0.0:
        return None
    for rule in CONTACT_RULES:
        if not all(name in values for name in rule.names) or (
                reading is not None and reading not in rule.names):
            continue
        loop = rule.loop(values, K)
        if loop is None:
            continue
        m, d, k = loop
        zeta = d / (2.0 * math.sqrt(m * k)) if m * k > 0.0 else math.inf
        if not zeta >= CONTACT_DAMPING_RATIO:
            shown = ", ".join(f"{name} {_shown(values[name])}" for name in rule.names)
            return (f"{shown}: {rule.what} has damping ratio {zeta:.3g} on a surface of "
                    f"contact_stiffness {K:g} N/m, below {CONTACT_DAMPING_RATIO:g}")
    return None


#: A least size below this fraction of the given one is the roots' round-off at z = 1 (the
#: loop of a vanishing gain), not a bound.
LEAST_FRACTION = 1e-3
#: The parameters a law rule or a contact rule reads.
LAW_GAINS = frozenset(name for rule in LAW_RULES for name in rule.names) | CONTACT_GAINS | {
    "contact_stiffness"}


def law_refusal(values: dict, period: float, delay_cycles: int, task_inertia: float,
                reading: str | None = None) -> str | None:
    """Why the laws' gains in ``values`` leave one of their loops (:data:`LAW_RULES`) unstable
    with the margin, or a loop through the contact too little damped (:func:`contact_refusal`),
    in one line, or None; ``reading``: only the loops that read that gain."""
    for rule in LAW_RULES:
        if not all(name in values for name in rule.names) or (
                reading is not None and reading not in rule.names):
            continue
        k, c = rule.gains(values, period, task_inertia)
        delay = DELAY_FACTOR * int(delay_cycles) if rule.through == "plant" else 0
        if not dg.stable_with_margin(k, c, delay, GAIN_MARGIN):
            shown = ", ".join(f"{name} {_shown(values[name])}" for name in rule.names)
            return (f"{shown}: {rule.what} is not stable with gain margin {GAIN_MARGIN:g} at "
                    f"{delay} cycles of delay (period {period * 1e3:g} ms; normalised stiffness "
                    f"{k:.3g}, damping {c:.3g})")
    return contact_refusal(values, reading)


def _shown(value) -> str:
    x = np.asarray(value, dtype=float)
    return f"{gain_size(x):g}" if x.size > 1 else f"{float(x):g}"


def of_size(param: Param, x: float):
    """``param``'s value of size x (:func:`gain_size`), as a parameter is written: a vector's
    every element x, a matrix x I in its diagonal form (-x I if negative definite), a scalar x."""
    sign = -1.0 if param.kind == "nd" else 1.0
    if param.kind in MATRIX_KINDS:
        return [sign * x] * param.size
    if param.kind in VECTOR_KINDS:
        return [x] * (param.size or 1)
    return x


_RANGES: dict[tuple, tuple[float, float]] = {}


def law_range(param: Param, values: dict, period: float, delay_cycles: int,
              task_inertia: float) -> tuple[float, float]:
    """(least, most) size of ``param`` the law rules accept with the other ``values``
    (bisection in the size; 0 and its plain bound where nothing limits it). Cached: the
    same robot and gains give the same range every start."""
    key = (param.name, param.kind, param.size, param.bound, float(period), int(delay_cycles),
           float(task_inertia), tuple(sorted((k, np.asarray(v, dtype=float).tobytes())
                                             for k, v in values.items())))
    if key not in _RANGES:
        _RANGES[key] = _law_range(param, values, period, delay_cycles, task_inertia)
    return _RANGES[key]


def _law_range(param: Param, values: dict, period: float, delay_cycles: int,
               task_inertia: float) -> tuple[float, float]:
    def ok(x: float) -> bool:
        return law_refusal({**values, param.name: of_size(param, x)}, period, delay_cycles,
                           task_inertia, param.name) is None
    top = float(param.bound)
    base = gain_size(values[param.name])
    high = top
    if not ok(top):
        low = base if base > 0.0 and ok(base) else 0.0
        if low == 0.0:
            low = next((x for x in np.geomspace(top, top * 1e-12, 60) if ok(x)), 0.0)
        hi = top
        for _ in range(60):
            mid = math.sqrt(low * hi) if low > 0.0 else 0.5 * hi
            if ok(mid):
                low = mid
            else:
                hi = mid
        high = low
    least = 0.0
    if not ok(1e-12 * max(base, 1.0)):
        lo, hi = 0.0, base if ok(base) else high
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if ok(mid):
                hi = mid
            else:
                lo = mid
        least = hi if hi > LEAST_FRACTION * base else 0.0    # below: round-off at z = 1
    return least, high


def law_parameters(specs: list[Param], values: dict, period: float, delay_cycles: int,
                   task_inertia: float) -> list[Param]:
    """``specs`` with the bounds the law rules give each gain beside the others' ``values``
    (the descriptor states it; a least size, for a mass, in words: it is refused below), the
    default lowered to the bound if above."""
    out = []
    for p in specs:
        if p.name not in LAW_GAINS or p.read_only or p.name not in values:
            out.append(p)
            continue
        least, most = law_range(p, values, period, delay_cycles, task_inertia)
        if not most > 0.0:              # no size of it alone helps: the others decide
            out.append(p)
            continue
        bound = float(_round_down(most)) if most < p.bound else p.bound
        text = (f"{p.description} Bounded by the discrete-time rule beside the other gains' "
                f"defaults (period {period * 1e3:g} ms, stable at "
                f"{DELAY_FACTOR * int(delay_cycles)} cycles of delay with gain margin "
                f"{GAIN_MARGIN:g}; judged with the gains in force on a change)")
        if p.name in CONTACT_GAINS and float(values.get("contact_stiffness", 0.0)) > 0.0:
            text += (f"; and its loop through the contact kept at a damping ratio of at least "
                     f"{CONTACT_DAMPING_RATIO:g} on contact_stiffness")
        if least > 0.0:
            text += f"; at least {least:.3g} with them"
            if p.kind.startswith("nonneg") and law_refusal(
                    {**values, p.name: of_size(p, 0.0)}, period, delay_cycles, task_inertia,
                    p.name) is None:
                text += ", or 0 (off)"
        default = of_size(p, bound) if gain_size(values[p.name]) > bound else p.default
        out.append(replace(p, bound=bound, default=default, description=text + "."))
    return out
