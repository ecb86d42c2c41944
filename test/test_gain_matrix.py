"""Every gain a parameter accepts is a gain the arm survives: each rule-bounded gain of the five
task-space schemes, set live to its accepted extreme (the largest value its bound and the
discrete-time rule accept beside the gains in force, and for a damping or a mass the least),
one at a time and in the careless user's pairs, on the Panda and the UR5 wiping at the profile's
delay (and, with a wrist force/torque sensor, ``panda_ft`` and ``ur5_ft``, the gains of the loops
that close through the measured force: the others see the same arm as without it), with the
plant node's command limits (a lockstep session's): no reflex, every joint below its velocity
limit, the true contact force at most 1.5 x the 10 N target. The change is
made as the node makes it (check_parameter, then set_parameter) 1.5 s into the run, judged over
the 2 s after.

Before the rule (the plain bounds, 1e4 for every gain): orientation_stiffness 1e4, damping
1e4, posture gains 1e4, Q_c 1e4, Q_c_star 1e4, P2 1e4, K_s 1e4, D -1e4, m_m 1e-9, d_m 1e4,
k_m 1e4, tangential_damping 1e4, force_admittance_damping 1e4, Gamma_M and Gamma_G 1e4 all
ended in the joint-velocity reflex (measured 1.00-1.14x the limit) or above 15 N.

The loops that close through the contact are bounded by a second rule, on the surface's
stiffness the profile declares (``contact_stiffness``, the table's 5 kN/m): their damping ratio
stays at least gain_bounds.CONTACT_DAMPING_RATIO (0.15). Before it, k_m 8050 N/m pressed 22 N
on the Panda, the fuzzy lambda 256 1/s 16.9 N, m_m 1000 kg rang at 21-27 N on ur5, panda_ft
and ur5_ft, and ur5_ft's force admittance mass 1000 kg 15.3 N; with it (k_m <= 3330, lambda
<= 111, m_m <= 1.97 kg, force admittance mass <= 5.55 kg) they peak at 6.7-10.5 N.

The robust term's compensator D is judged as a loop through the arm (its K_2 z' drives r_eq''
(3.50)): |D| <= 222 / 111 on the Panda / UR5. As a loop inside the law (|D| <= 1/T: 999 / 499)
it passed the wrist sensor's noise on to the arm: 1.01-1.09x the velocity limit on panda_ft,
16.9 and 31.7 N on ur5_ft.

The NN law's G_r network adapts as G_r^' = Gamma_G |xi|^2 s (3.81), a stiffness on s beside
K_s through the task's lightest inertia (|xi|^2 <= rbf_max_nodes): Gamma_G <= 36 / 18.9 on
the Panda / UR5. Before it, Gamma_G 1e4 ended in the reflex (1.00-1.09x the velocity limit,
22-38 N); set live offline, 100 holds and 300 trips the reflex on the Panda, 36 holds and
100 trips it on the UR5.

What still fails at its accepted extreme is marked xfail with its figures: the NN's Gamma_M,
whose loop gain Gamma_M |xi|^2 |r_eq''|^2 the rule cannot bound (r_eq'' is the state's), and
on panda_ft the NN law's D at its bound.
"""

from __future__ import annotations

import numpy as np
import pytest

from cr_control import offline, robots
from cr_control.core.parameters import validate
from cr_control.schemes.blocks.gain_bounds import gain_size, of_size
from cr_control.schemes.registry import controller_class
from cr_control.tools.fuzz_gains import bisect_extreme

T_SET = 1.5
DURATION = 3.5
FORCE_MAX = 1.5 * robots.WIPE_FORCE

NULL = ["orientation_stiffness", "orientation_damping", "posture_stiffness", "posture_damping",
        "joint_limit_stiffness", "joint_limit_damping"]
CH3 = ["A_m", "B_m", "P1", "P2", "Q_a", "Q_b", "Q_c", "Q_a_star", "Q_b_star", "Q_c_star",
       "force_admittance_mass", "force_admittance_damping"]
GAINS = {
    "adaptive_impedance": NULL + CH3,
    "robust_adaptive_impedance": NULL + CH3 + ["K_s", "D"],
    "nn_adaptive_impedance": NULL + CH3 + ["K_s", "D", "Gamma_M", "Gamma_C", "Gamma_G"],
    "impedance": NULL + ["m_m", "d_m", "k_m", "tangential_stiffness", "tangential_damping"],
    "fuzzy_unidirectional": NULL + ["m_m", "lambda", "d_s", "d_med", "d_b",
                                    "tangential_stiffness", "tangential_damping"],
}
#: Also their least accepted value (a damping or a mass: less is where a loop gives way).
LEAST = {"orientation_damping", "posture_damping", "d_m", "tangential_damping", "A_m", "m_m",
         "force_admittance_mass"}
#: The careless user's pairs (the issue's table), each set in turn to its accepted extreme.
PAIRS = {
    "stiff_wrist_undamped": [("orientation_damping", "least"), ("orientation_stiffness", "most")],
    "stiff_damped_posture": [("posture_stiffness", "most"), ("posture_damping", "most")],
    "every_adaptation_gain": [(name, "most") for name in ("Q_a", "Q_b", "Q_c", "Q_a_star",
                                                           "Q_b_star", "Q_c_star")],
}
#: The gains whose loop closes through the measured force (the wrist sensor's profiles).
FORCE_LOOP = {"force_admittance_mass", "force_admittance_damping", "A_m", "B_m", "P1", "P2",
              "Q_a", "Q_b", "Q_c", "Q_a_star", "Q_b_star", "Q_c_star", "K_s", "D", "Gamma_M",
              "Gamma_C", "Gamma_G", "m_m", "d_m", "k_m", "lambda", "d_s", "d_med", "d_b"}
#: The robots: the sensor-less profiles with every gain, the wrist sensor's with FORCE_LOOP's.
ROBOTS = {"panda": None, "ur5": None, "panda_ft": FORCE_LOOP, "ur5_ft": FORCE_LOOP}
#: Still failing at the accepted extreme (measured at the profile's delay).
OPEN = {
    ("panda", "nn_adaptive_impedance", "Gamma_M", "most"): "1e4: 1.12x the velocity limit, 38 N",
    ("ur5", "nn_adaptive_impedance", "Gamma_M", "most"): "1e4: 1.00x the velocity limit, 51 N",
    # the wrist sensor's profiles (its measured force, not the driver's estimate)
    ("panda_ft", "nn_adaptive_impedance", "D", "most"): "222: 1.01x the velocity limit, 14.7 N",
    ("panda_ft", "nn_adaptive_impedance", "Gamma_M", "most"): "1e4: 1.03x the velocity limit",
    ("ur5_ft", "nn_adaptive_impedance", "Gamma_M", "most"): "1e4: the force reflex, 59 N",
}


def cases() -> list:
    out = []
    for robot, only in ROBOTS.items():
        for scheme, names in GAINS.items():
            for name in (n for n in names if only is None or n in only):
                for side in ("most", "least") if name in LEAST else ("most",):
                    marks = ()
                    why = OPEN.get((robot, scheme, name, side))
                    if why is not None:
                        marks = pytest.mark.xfail(reason=why, strict=True)
                    out.append(pytest.param(robot, scheme, [(name, side)],
                                            id=f"{robot}-{scheme}-{name}-{side}", marks=marks))
            for pair, changes in PAIRS.items():
                if all(name in names and (only is None or name in only) for name, _ in changes):
                    out.append(pytest.param(robot, scheme, changes,
                                            id=f"{robot}-{scheme}-{pair}"))
    return out


def extreme(controller, param, side: str):
    """The most (or least) size of ``param`` its bound and the controller's checks accept
    beside the gains in force (bisection on the size), as the validated value."""
    def accepted(x: float):
        ok, _, value = validate(param, of_size(param, x))
        if ok and controller.check_parameter(param.name, value) is None:
            return value
        return None

    floor = 0.0 if param.kind.startswith("nonneg") else 1e-9
    size = bisect_extreme(lambda x: accepted(x) is not None,
                          gain_size(controller.values[param.name]), float(param.bound), floor,
                          side, steps=50)
    return accepted(size)


@pytest.mark.parametrize("robot,scheme,changes", cases())
def test_a_gain_at_its_accepted_extreme_holds_the_task(robot, scheme, changes):
    controller, plant = offline.build_scheme(scheme, robot=robot)
    controller.log_error = controller.log_warning = controller.log_info = lambda message: None
    specs = {p.name: p for p in controller_class(scheme).parameters(
        robots.controller_values(robots.robot(robot), scheme))}
    applied = []

    def hook(k: int, t: float, ctl, _plant) -> None:
        if applied or t < T_SET:
            return
        for name, side in changes:
            value = extreme(ctl, specs[name], side)
            assert value is not None and ctl.check_parameter(name, value) is None
            ctl.set_parameter(name, value)
            applied.append((name, gain_size(value)))

    period = offline.robot_period(robot)
    run = offline.run(controller, plant, DURATION, period, hook,
                      limiter=offline.build.node_limiter(plant, scheme, robot, None, period),
                      delay=offline.build.node_delay(scheme, robot))
    n = len(controller.state_joint_names)
    after = run.time >= T_SET
    speed = np.abs(run.velocity[after, :n]) / controller.model.limits[2 * n:3 * n]
    force = float(run.true_force[after, 2].max())
    print(f"\n{robot} {scheme} {applied}: joints at {speed.max():.2f} of their limits, "
          f"force peak {force:.1f} N, reflex {run.safe_stop_reason}")
    assert applied
    assert run.safe_stop_reason == 0
    assert speed.max() < 1.0
    assert force <= FORCE_MAX
