"""The discrete-time rule (cr_control.models.discrete_gains) and the bounds it gives the gains
that act on the robots' joints (cr_control.schemes.blocks.gain_bounds): the pure damping
loop's limit in closed form against a brute-force simulation, the PD loop's region, the
Panda's and the UR5's bounds, defaults lowered into them and pairs judged together."""

import math

import numpy as np
import pytest

from cr_control import robots
from cr_control.core.parameters import ParameterError, validate
from cr_control.models import discrete_gains as dg
from cr_control.schemes.blocks import gain_bounds
from cr_control.schemes.registry import controller_class, make_controller


def simulate(k: float, c: float, d: int, steps: int = 4000) -> float:
    """The loop of the module docstring stepped from x = 1, v = 0: the largest |x|, |v| of
    its last tenth (grows without bound when unstable)."""
    x, v = 1.0, 0.0
    past = [(x, v)] * (d + 1)
    worst = 0.0
    for i in range(steps):
        xd, vd = past[-(d + 1)]
        tau = -k * xd - c * vd                   # normalised: T = M = 1, gains k and c
        x, v = x + v + 0.5 * tau, v + tau
        past.append((x, v))
        past = past[-(d + 1):]
        if not abs(x) + abs(v) < 1e6:
            return math.inf                       # grown (before it overflows into NaN)
        if i >= 0.9 * steps:
            worst = max(worst, abs(x), abs(v))
    return worst


def test_the_damping_limit_in_closed_form():
    assert [round(dg.damping_limit(d), 3) for d in range(5)] == [2.0, 1.0, 0.618, 0.445, 0.347]
    for d in range(8):
        limit = dg.damping_limit(d)
        assert dg.stable(0.0, 0.99 * limit, d) and not dg.stable(0.0, 1.01 * limit, d)
        assert dg.spectral_radius(0.0, limit, d) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("d", [0, 1, 2, 3])
def test_the_roots_agree_with_a_simulation(d):
    rng = np.random.default_rng(d)
    for _ in range(40):
        k, c = rng.uniform(0.0, 0.3), rng.uniform(0.0, 1.2)
        rho = dg.spectral_radius(k, c, d)
        if abs(rho - 1.0) < 0.01:
            continue                              # too close to the edge for 4000 steps
        grows = simulate(k, c, d) > 1.0
        assert grows == (rho > 1.0), (k, c, d, rho)


def test_the_schur_cohn_test_agrees_with_the_roots():
    """stable() decides by the Schur-Cohn test: the same verdict as the largest root from
    np.roots on 20 000 random loops (stiffness, damping, delays 0-11), the boundary included
    to the roots' own round-off."""
    rng = np.random.default_rng(7)
    for _ in range(20000):
        d = int(rng.integers(0, 12))
        k = float(rng.uniform(0.0, 1.0)) if rng.random() < 0.8 else 0.0
        c = float(rng.uniform(0.0, 2.2))
        by_roots = dg.spectral_radius(k, c, d) < 1.0 - dg.UNIT_CIRCLE_TOLERANCE
        assert dg.stable(k, c, d) == by_roots, (k, c, d)
    assert dg.schur_stable([1.0, -0.5]) and not dg.schur_stable([1.0, -1.5])
    assert not dg.schur_stable([1.0, 0.0, 1.0])                      # z = +-i: on the circle


def test_the_pd_region():
    # d = 0: the product of the roots is 1 + k/2 - c, so k < 2 c
    assert dg.max_stiffness(0.3, 0) == pytest.approx(0.6, rel=1e-6)
    for d in range(5):
        assert dg.max_stiffness(0.0, d) == 0.0                      # a spring needs damping
        assert not dg.stable(1e-6, 0.0, d)
        low, high = dg.damping_range(0.01, d)
        assert 0.0 < low < high < dg.damping_limit(d)
        assert dg.stable(0.01, 0.5 * (low + high), d)
        assert not dg.stable(0.01, 0.9 * low, d) and not dg.stable(0.01, 1.02 * high, d)
        # with a margin of 2 the gains twice as large are stable too
        k = dg.max_stiffness(0.1, d, margin=2.0)
        assert dg.stable(2.0 * 0.99 * k, 0.2, d) and not dg.stable(2.0 * 1.01 * k, 0.2, d)
    # the stable set shrinks as the delay grows
    assert [dg.max_stiffness(0.1, d) > dg.max_stiffness(0.1, d + 1) for d in range(4)] == [True] * 4


def test_no_nan_and_impossible_delays():
    assert math.isinf(dg.spectral_radius(math.nan, 0.1, 1))
    assert not dg.stable(-1.0, 0.1, 1)
    with pytest.raises(ValueError):
        dg.damping_limit(-1)
    with pytest.raises(ValueError):
        dg.damping_limit(1.5)


# -- on the robots ---------------------------------------------------------------------------------
def specs(robot: str, scheme: str = "impedance") -> dict:
    values = robots.controller_values(robots.robot(robot), scheme)
    return {p.name: p for p in controller_class(scheme).parameters(values)}


#: (orientation damping, orientation stiffness, posture damping, joint limit damping) bounds:
#: at 3 cycles of delay with gain margin 2, the lightest inertias over the workspace
#: (orientation about the tool axis: 6.7e-3, 4.9e-3 with the wrist sensor's lighter tool, 1.7e-2
#: kg m^2; the lightest joint alone 5.0e-3, 3.8e-3, 1.6e-2).
BOUNDS = {"panda": (1.48, 150.0, 2.76, 1.11), "panda_ft": (1.08, 110.0, 2.76, 0.854),
          "ur5": (1.9, 96.4, None, 1.77), "ur5_ft": (1.9, 96.4, None, 1.77)}


@pytest.mark.parametrize("robot", list(BOUNDS))
def test_the_robots_bounds(robot):
    p = specs(robot)
    d_o, k_o, d_n, d_lim = BOUNDS[robot]
    assert p["orientation_damping"].bound == pytest.approx(d_o, rel=0.01)
    assert p["orientation_stiffness"].bound == pytest.approx(k_o, rel=0.01)
    assert p["joint_limit_damping"].bound == pytest.approx(d_lim, rel=0.01)
    if d_n is not None:
        assert p["posture_damping"].bound == pytest.approx(d_n, rel=0.01)
    assert "discrete-time rule" in p["orientation_damping"].description
    # defaults lowered into the bounds (the thesis's 3 N m s/rad was stable at 1 cycle only)
    assert max(p["orientation_damping"].default) <= d_o
    assert p["joint_limit_damping"].default <= d_lim
    ok, why, _ = validate(p["orientation_damping"], [3.0, 3.0, 3.0])
    assert not ok and f"<= {p['orientation_damping'].bound:g}" in why


def test_the_bounds_follow_period_and_delay():
    """Twice the delay or twice the period: lower bounds; the thesis arm keeps its own."""
    r = robots.robot("panda")
    base = robots.controller_values(r, "impedance")
    cls = controller_class("impedance")
    bound = lambda values: next(p.bound for p in cls.parameters(values)     # noqa: E731
                                if p.name == "orientation_damping")
    assert bound({**base, "command_delay_cycles": 2}) < bound(base)
    assert bound({**base, "control_period": 2e-3}) < bound(base)
    thesis = {p.name: p for p in cls.parameters()}
    assert thesis["orientation_damping"].bound == 1e4 and thesis["command_delay_cycles"].default == 0


def test_pairs_are_judged_together():
    """A stiffness with no damping, and a damping beside a stiffness it cannot hold, are
    refused on a live change (one line naming the bound; the old value stays)."""
    r = robots.robot("panda")
    ctl = make_controller("impedance", robots.controller_values(r, "impedance"))
    why = ctl.check_parameter("orientation_damping", np.zeros(3))
    assert why is not None and "needs orientation_damping >=" in why and "\n" not in why
    why = ctl.check_parameter("orientation_stiffness", np.full(3, 149.0))
    assert why is not None and "orientation_stiffness 149" in why and "bound" in why
    assert ctl.check_parameter("orientation_stiffness", np.full(3, 40.0)) is None
    assert ctl.check_parameter("posture_damping", 0.0) is not None        # K_n = 10 stays
    assert ctl.check_parameter("posture_stiffness", 0.0) is None
    with pytest.raises(ParameterError, match="orientation"):
        make_controller("impedance", {**robots.controller_values(r, "impedance"),
                                      "orientation_damping": [0.0, 0.0, 0.0]})


def test_the_thesis_gains_are_not_refused():
    """The thesis's own arm keeps every thesis gain (no null space; its bounds the plain ones)."""
    for scheme in robots.TASK_SPACE_SCHEMES:
        ctl = make_controller(scheme, {})
        assert ctl.check_parameter("orientation_damping", np.zeros(3)) is None


def test_inertias_are_the_lightest_over_the_workspace():
    ctl = make_controller("impedance", robots.controller_values(robots.robot("panda"), "impedance"))
    found = gain_bounds.inertias(ctl.model, np.array(robots.robot("panda").home))
    assert found.orientation[0] == pytest.approx(6.7e-3, rel=0.02)
    assert found.posture[1] < found.posture[0]                     # lighter elsewhere
    assert all(least <= home for home, least in (found.orientation, found.posture, found.joint,
                                                 found.task))


def test_the_laws_gains_by_the_same_rule():
    """A law's gain beyond what its loop takes is refused in one line naming the loop; the
    same value on the thesis's arm is not (its plain bounds)."""
    r = robots.robot("panda")
    ctl = make_controller("robust_adaptive_impedance",
                          robots.controller_values(r, "robust_adaptive_impedance"))
    spec = {p.name: p for p in controller_class("robust_adaptive_impedance").parameters(
        robots.controller_values(r, "robust_adaptive_impedance"))}
    assert spec["K_s"].bound == pytest.approx(190.0, rel=0.02)        # 0.22 x 0.86 kg / 1 ms
    assert spec["Q_c_star"].bound == pytest.approx(27.0, rel=0.05)
    ok, why, _ = validate(spec["K_s"], [1e4] * 3)
    assert not ok and "<= 190" in why
    why = ctl.check_parameter("Q_c_star", np.diag([26.0] * 3))
    assert why is None
    why = ctl.check_parameter("P2", np.diag([100.0] * 3))          # Q_c* P2 beside P2 = 100
    assert why is None
    impedance = make_controller("impedance", robots.controller_values(r, "impedance"))
    why = impedance.check_parameter("m_m", 0.3)
    assert why is not None and "m_m 0.3" in why and "\n" not in why
    thesis = make_controller("robust_adaptive_impedance", {})
    assert thesis.check_parameter("K_s", np.diag([1e4, 1e4])) is None


def test_the_loops_through_the_contact_keep_their_damping_ratio():
    """On the declared contact_stiffness (the profiles' 5 kN/m table) a change that leaves a
    loop through the contact with a damping ratio below 0.15 is refused in one line naming the
    loop and the ratio, and the old value stays; the same change beside more damping is taken
    (judged with the gains in force); the thesis's arm (no contact_stiffness) is not judged."""
    zeta = gain_bounds.CONTACT_DAMPING_RATIO
    r = robots.robot("panda")
    values = robots.controller_values(r, "impedance")
    assert values["contact_stiffness"] == robots.TABLE_STIFFNESS
    ctl = make_controller("impedance", values)
    m, d, k = ctl.values["m_m"], ctl.values["d_m"], ctl.values["k_m"]
    K = robots.TABLE_STIFFNESS
    assert d / (2 * math.sqrt(m * (k + K))) >= zeta                     # the defaults: 0.19
    most_k = d * d / (4 * zeta * zeta * m) - K                           # 3333 N/m
    why = ctl.check_parameter("k_m", 1.01 * most_k)
    assert why is not None and "\n" not in why
    assert "the normal impedance (5.6) on the contact" in why and "below 0.15" in why
    assert ctl.check_parameter("k_m", 0.99 * most_k) is None
    why = ctl.check_parameter("m_m", 1000.0)
    assert why is not None and "damping ratio 0.00667" in why
    assert ctl.values["m_m"] == m                                        # refused: unchanged
    ctl.set_parameter("d_m", 100.0)                                      # more damping ...
    assert ctl.check_parameter("k_m", 1.01 * most_k) is None             # ... takes it
    fuzzy = make_controller("fuzzy_unidirectional",
                            robots.controller_values(r, "fuzzy_unidirectional"))
    assert "the fuzzy impedance at its force target" in fuzzy.check_parameter("lambda", 256.0)
    ch3 = make_controller("adaptive_impedance", robots.controller_values(r, "adaptive_impedance"))
    assert "the force admittance on the contact" in ch3.check_parameter(
        "force_admittance_mass", 1000.0)
    assert ch3.check_parameter("force_admittance_damping", 0.0) is None  # off: no such loop
    thesis = make_controller("impedance", {})
    assert thesis.values["contact_stiffness"] == 0.0
    assert thesis.check_parameter("m_m", 1000.0) is None


def test_the_compensator_is_judged_through_the_arm():
    """The robust term's D (3.40) drives r_eq'' (3.50) through the arm: bounded at 3 x the
    delay with gain margin 2 (c = |D| T < 0.445 / 2 at 3 cycles: 222 on the Panda's 1 ms, 111
    on the UR5's 2 ms), not by 1/T."""
    for robot, bound in (("panda", 222.0), ("ur5", 111.0), ("panda_ft", 222.0)):
        values = robots.controller_values(robots.robot(robot), "robust_adaptive_impedance")
        spec = {p.name: p for p in controller_class("robust_adaptive_impedance").parameters(values)}
        assert spec["D"].bound == pytest.approx(bound, rel=0.01)
        period = values["control_period"]
        assert dg.damping_limit(3) / gain_bounds.GAIN_MARGIN / period == pytest.approx(
            bound, rel=0.01)
