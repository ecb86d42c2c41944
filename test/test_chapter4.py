"""Chapter 4: dynamic-constraint plant, K-filters, Diophantine equation, the generic
backstepping design against the thesis's rho = 2 equations, and the closed loops with numbers.

Run lengths: the plant is lightly damped (poles near -0.02 +- 0.78j) and A0's slowest mode is
~59 s, so the closed loops run 100 s and are judged on the last 10 s.
"""

import time
from fractions import Fraction

import numpy as np
import pytest

from cr_control.core.parameters import resolve
from cr_control.offline import run
from cr_control.schemes.blocks import backstepping as bs
from cr_control.schemes.blocks import diophantine
from cr_control.schemes.force.backstepping_force import INITIAL_ESTIMATES, TRUE_THETA
from cr_control.schemes.force.mrac_force import TRUE_THETA_F_CASE1
from cr_control.schemes.registry import make_controller
from cr_sim.plants import dynamic_constraint as dc
from cr_sim.plants.registry import make_plant

STIFF = {1: 20.0, 2: 50.0, 3: 80.0}
LAMBDA = [12.0, 5.0, 15.0, 2.0, 4.0]


def plant(case=1):
    return make_plant("dynamic_constraint", {"k_o": STIFF[case], "k_s": STIFF[case]})


@pytest.mark.parametrize("case", [1, 2, 3])
def test_true_theta_and_initial_equilibrium(case):
    values = resolve(dc.PARAMETERS, {"k_o": STIFF[case], "k_s": STIFF[case]})
    assert np.allclose(dc.true_theta(values), TRUE_THETA[case], rtol=1e-9, atol=1e-9)
    p = plant(case)
    assert p.command_interface == "position"
    m0 = p.measurement()
    assert m0.force[0] == pytest.approx(1.5)
    if case == 1:
        assert m0.position[0] == pytest.approx(0.225)
    for _ in range(2000):
        p.step(m0.position.copy(), 1e-3)
    assert np.allclose(p.measurement().force[0], 1.5, atol=1e-9)      # at rest stays at rest


def test_contact_loss_reports_zero_while_states_evolve():
    p = plant(1)
    for _ in range(3000):
        p.step(np.array([-0.5]), 1e-3)
    assert p.raw_force() < 0.0
    assert p.measurement().force[0] == 0.0
    x = p.state
    p.step(np.array([-0.5]), 1e-3)
    assert not np.allclose(p.state, x)


def observer_transform(A, B, C, theta):
    """T with y_oc = T x (observer canonical form 4.10-4.11 of the plant)."""
    n = A.shape[0]
    a = theta[4:]
    A_oc = np.eye(n, k=1)
    A_oc[:, 0] -= a
    C_oc = np.eye(n)[0]
    O_p = np.array([C @ np.linalg.matrix_power(A, i) for i in range(n)])
    O_oc = np.array([C_oc @ np.linalg.matrix_power(A_oc, i) for i in range(n)])
    return np.linalg.solve(O_oc, O_p)


@pytest.mark.parametrize("lam,tolerance", [(LAMBDA, None),
                                           (list(bs.observer_coefficients([-2.0] * 5)), 1e-6)])
def test_k_filters_reconstruct_the_observer_canonical_state(lam, tolerance):
    """4.23-4.24: with the true theta, y - (xi + Omega^T theta) = eps with eps' = A0 eps."""
    values = resolve(dc.PARAMETERS, {})
    A, B, C = dc.matrices(values)
    theta = dc.true_theta(values)
    T = observer_transform(A, B, C, theta)
    p = plant(1)
    sizes = bs.Sizes(5, 2)
    design = bs.Backstepping(sizes)
    design.set_gains([2.0, 2.0], [0.0, 0.0], lam, np.zeros(9), 0.0)
    state = bs.initial_state(sizes, theta, 1.0 / theta[0])
    A0 = bs.a0_matrix(lam)
    dt, eps0, worst = 1e-3, None, 0.0
    for k in range(15001):
        t = k * dt
        f = p.raw_force()           # the linear model's output (this input loses contact at times)
        design.cycle(state, f, 1.0, dt if k else 0.0)
        u = 0.225 + 0.05 * np.sin(0.7 * t) + 0.02 * np.sin(3.1 * t)
        state[2 * 5 + 9 + 2] = u                     # the input the filters hold next (u_prev)
        xi, v, etas = bs.filter_signals(list(state[:5]), list(state[5:10]), f, lam, 3)
        omega_t = np.column_stack([np.array(v[3 - j]) for j in range(4)] + [np.array(e) for e in etas])
        eps = T @ p.state - (np.array(xi) + omega_t @ theta)
        if eps0 is None:
            eps0 = eps
        elif k % 1000 == 0:
            predicted = _expm(A0 * t) @ eps0
            worst = max(worst, np.abs(eps - predicted).max() / np.abs(eps0).max())
        p.step(np.array([u]), dt)
    assert worst < 1e-6, worst                       # eps(t) = e^{A0 t} eps(0)
    if tolerance is not None:
        assert np.abs(eps).max() < tolerance * np.abs(eps0).max() * 1e3


def _expm(M):
    from cr_sim.plants.lti import expm

    return expm(M)


def test_diophantine_solution_satisfies_4_65_identically():
    for case in (1, 2, 3):
        sol = diophantine.solve(TRUE_THETA[case], 0.7, 0.5, [1.0, 19.0, 65.0, 77.0, 30.0])
        residual = diophantine.residual(sol)
        assert np.abs(residual).max() < 1e-9 * np.abs(np.polymul(sol["P_o"], sol["A_m"])).max()
        assert np.allclose(sol["theta_f"], diophantine.closed_form(TRUE_THETA[case], 0.7, 0.5,
                                                                   [1, 19, 65, 77, 30]))
    design_md = [-9.325, -68.057, -75.138, -30.690, 4.1533, 5.3017, 5.3378, 1.7298, 0.4785,
                 0.0125, 0.2375, 0.8125, 0.9625, 0.375]
    assert np.allclose(TRUE_THETA_F_CASE1, design_md, atol=6e-4)
    assert diophantine.solve(TRUE_THETA[1], 0.7, 0.5, [1, 19, 65, 77, 30])["r"] == pytest.approx(-0.345)


def test_diophantine_solution_is_the_exact_one_rounded_once():
    """Exact arithmetic, no LAPACK: the shipped theta_f_hat_0 default is the same on every
    machine (a LAPACK solve differed in the last bits between two of ours)."""
    for case in (1, 2, 3):
        exact = diophantine.closed_form([Fraction(x) for x in TRUE_THETA[case]], Fraction(0.7),
                                        Fraction(0.5), [Fraction(o) for o in (1, 19, 65, 77, 30)])
        sol = diophantine.solve(TRUE_THETA[case], 0.7, 0.5, [1.0, 19.0, 65.0, 77.0, 30.0])
        assert sol["theta_f"].tolist() == [float(v) for v in exact]


def test_generic_design_reproduces_4_34_4_49_4_50_4_56():
    """rho = 2: the generic design equals the printed equations, plus exactly the d alpha_1/d v
    term the printed (4.47) leaves out."""
    rng = np.random.default_rng(7)
    design = bs.Backstepping(bs.Sizes(5, 2))
    G = np.array([45, 60, 60, 60, 45, 45, 45, 45, 10.0])
    design.set_gains([2.0, 3.0], [0.0, 0.0], LAMBDA, G, 0.01)
    for _ in range(20):
        y, y_r = rng.normal(size=2)
        eta, lam = rng.normal(size=5) * 0.05, rng.normal(size=5) * 0.05
        th, d_hat = rng.normal(size=9) * 3.0, rng.normal()
        out = design.evaluate(y, y_r, eta, lam, th, d_hat)
        ref = bs.thesis_rho2(y, y_r, eta, lam, th, d_hat, 2.0, 3.0, LAMBDA, G, 0.01)
        scale = 1.0 + abs(ref["delta_c"])
        assert out[10] == pytest.approx(ref["alpha_bar_1"], rel=1e-12, abs=1e-12)   # (4.34)
        assert out[12] == pytest.approx(ref["z2"], rel=1e-12, abs=1e-12)
        assert out[13] == pytest.approx(ref["gamma2"], rel=1e-12, abs=1e-12)        # (4.49)
        assert np.allclose(out[1:10], ref["tau2"], rtol=1e-10, atol=1e-10 * scale)  # (4.55)
        assert abs(out[0] - (ref["delta_c"] + ref["missing"])) < 1e-10 * scale      # (4.50, 4.56)


@pytest.mark.parametrize("n,rho", [(5, 2), (3, 3), (4, 4), (5, 3)])
def test_generic_design_makes_the_lyapunov_derivative_negative(n, rho):
    """With eps = 0, V = z'z/2 + theta~' Gamma^-1 theta~/2 + b_m rho~^2/(2 gamma) has
    V' = -sum c_i z_i^2 exactly (tuning functions): checks every rho, not just 2."""
    rng = np.random.default_rng(n * 10 + rho)
    s = bs.Sizes(n, rho)
    design = bs.Backstepping(s)
    lam = bs.observer_coefficients(-np.linspace(1.0, 3.0, n))
    c = rng.uniform(1.0, 2.0, rho)
    G = rng.uniform(0.5, 2.0, s.p)
    gam = 0.7
    design.set_gains(c, np.zeros(rho), lam, G, gam)
    theta = rng.uniform(0.5, 2.0, s.p)
    A0 = bs.a0_matrix(lam)
    e_n = np.eye(n)[-1]

    def y_of(eta, lf):
        xi, v, etas = bs.filter_signals(list(eta), list(lf), 0.0, list(lam), s.m)
        om = np.column_stack([np.array(v[s.m - j]) for j in range(s.m + 1)] + [np.array(e) for e in etas])
        return np.array(xi) + om @ theta

    def field(X):
        eta, lf, th, rh = X[:n], X[n:2 * n], X[2 * n:2 * n + s.p], X[-1]
        y1 = y_of(eta, lf)[0]
        out = design.evaluate(y1, 0.0, eta, lf, th, rh)
        dX = np.concatenate([A0 @ eta - e_n * y1, A0 @ lf + e_n * out[0], G * out[1:1 + s.p],
                             [-gam * out[1 + s.p] * y1]])
        return dX, out[2 + s.p:2 + s.p + rho]

    X = np.concatenate([rng.normal(size=2 * n) * 1e-5, theta + rng.normal(size=s.p) * 0.3,
                        [1.0 / theta[0] + 0.2]])
    dX, z = field(X)
    h = 1e-6
    z_dot = (field(X + h * dX)[1] - field(X - h * dX)[1]) / (2 * h)
    th_t, rh_t = theta - X[2 * n:2 * n + s.p], 1.0 / theta[0] - X[-1]
    v_dot = z @ z_dot - th_t @ (dX[2 * n:2 * n + s.p] / G) - theta[0] / gam * rh_t * dX[-1]
    assert v_dot == pytest.approx(-(c * z * z).sum(), rel=1e-4)


def metrics(r, f_d=1.0, tail=10.0):
    t, f, dcmd = r.time, r.force[:, 0], r.command[:, 0]
    band = np.abs(f - f_d) > 0.02 * f_d
    settling = float(t[np.nonzero(band)[0][-1]]) if band.any() else 0.0
    late = t >= t[-1] - tail
    after = t >= 5.0
    win = 1000
    smooth = np.convolve(dcmd, np.ones(win) / win, mode="same")
    chatter = float(np.sqrt(np.mean((dcmd - smooth)[after & (t < t[-1] - 1.0)] ** 2)))
    return {
        "settling_2pct_s": settling,
        "undershoot_N": float(f_d - f[t > 0.1].min()),
        "overshoot_N": float(f[t > 2.0].max() - f_d),
        "ss_error_N": float(np.mean(f[late]) - f_d),
        "late_peak_to_peak_N": float(np.ptp(f[late])),
        "chatter_rms_delta_c_m": chatter,
        "delta_c_range": (float(dcmd.min()), float(dcmd.max())),
        "contact_lost_s": float((f <= 0.0).sum() * 1e-3),
    }


def ranges(r, names):
    return {n: (round(float(r.column(n).min()), 4), round(float(r.column(n).max()), 4)) for n in names}


EST = ["b3_hat", "b2_hat", "b1_hat", "b0_hat", "a4_hat", "a3_hat", "a2_hat", "a1_hat", "a0_hat", "d_hat"]


@pytest.fixture(scope="module")
def backstepping_runs():
    runs = {}
    for case in (1, 2, 3):
        c = make_controller("backstepping_force")
        start = time.perf_counter()
        runs[case] = (run(c, plant(case), 100.0), c, time.perf_counter() - start)
    c4 = make_controller("backstepping_force", {"gamma": 0.0, "Gamma": [0.0] * 9})
    runs[4] = (run(c4, plant(1), 100.0), c4, 0.0)
    return runs


@pytest.mark.parametrize("case", [1, 2, 3])
def test_backstepping_cases_1_to_3_converge_to_f_d(backstepping_runs, case):
    r, c, wall = backstepping_runs[case]
    m = metrics(r)
    print(f"\ncase {case}: {m}\n  estimates {ranges(r, EST)}\n  wall {wall:.1f} s for 100 s")
    assert c.held_cycles == 0
    assert abs(m["ss_error_N"]) < 0.01
    assert m["late_peak_to_peak_N"] < 0.05
    est = np.array([r.column(n) for n in EST])
    assert np.all(np.isfinite(est)) and np.abs(est).max() < 1e4      # bounded


@pytest.mark.xfail(strict=True, reason="the thesis's 'chattering grows with stiffness' (cases 2, "
                   "3) does not reproduce: the rms of delta_c about its 1 s moving average is "
                   "~1.1e-4 m in every case (exact plant, 1 kHz)")
def test_chattering_grows_with_stiffness(backstepping_runs):
    chatter = [metrics(backstepping_runs[c][0])["chatter_rms_delta_c_m"] for c in (1, 2, 3)]
    print(f"\nchatter rms of delta_c (1 s moving average removed, t > 5 s): {chatter}")
    assert chatter[0] < chatter[1] < chatter[2]


def test_case4_without_adaptation_does_not_reach_f_d(backstepping_runs):
    """Thesis: f does not converge to f_d. Here (printed-nominal estimates frozen) the loop is
    unstable: f grows to thousands of N and delta_c saturates at max_effort."""
    m1, m4 = metrics(backstepping_runs[1][0]), metrics(backstepping_runs[4][0])
    print(f"\ncase 4: {m4}")
    assert abs(m4["ss_error_N"]) > 5 * abs(m1["ss_error_N"])
    assert abs(m4["ss_error_N"]) > 0.01


def test_backstepping_with_true_initial_estimates():
    theta0, d0 = INITIAL_ESTIMATES["true_case1"]
    c = make_controller("backstepping_force", {"theta_hat_0": theta0, "d_hat_0": d0})
    r = run(c, plant(1), 100.0)
    m = metrics(r)
    print(f"\ncase 1, 0.65 x true theta: {m}")
    assert abs(m["ss_error_N"]) < 0.01


def test_mrac_with_the_true_theta_f_follows_the_reference_model():
    c = make_controller("mrac_force", {"gamma_f": 0.0, "theta_f_hat_0": list(TRUE_THETA_F_CASE1),
                                       "b3_hat_0": 20.0, "bumpless_start": True})
    r = run(c, plant(1), 40.0)
    err = r.force[:, 0] - r.column("f_m")
    print(f"\nMRAC, true theta_f, no adaptation: max |f - f_m| = {np.abs(err).max():.4g} N")
    assert np.abs(err).max() < 5e-3
    assert abs(r.force[-1, 0] - 1.0) < 5e-3


@pytest.mark.xfail(strict=True, reason="thesis case 5 does not reproduce: with 0.65 x the true "
                   "theta_f and gamma_f = 0.8 the plain-gradient MRAC diverges (see report)")
def test_mrac_case5_converges_to_f_d():
    c = make_controller("mrac_force")
    r = run(c, plant(1), 60.0)
    f = r.force[:, 0]
    print(f"\nMRAC case 5: f(60 s) = {f[-1]:.4g}, max f = {f.max():.4g}, held {c.held_cycles}")
    assert c.held_cycles == 0 and abs(f[-1] - 1.0) < 0.05


def test_compute_time_per_cycle_beside_calibration():
    c = make_controller("backstepping_force")
    p = plant(1)
    run(c, p, 0.5)                                            # compiled
    n = 200_000
    start = time.perf_counter()
    for _ in range(n):
        pass
    loop_ns = (time.perf_counter() - start) / n * 1e9
    for scheme in ("backstepping_force", "mrac_force"):
        c = make_controller(scheme)
        r = run(c, plant(1), 2.0)
        us = float(np.median(r.column("compute_time_us")))
        print(f"\n{scheme}: median compute {us:.2f} us per cycle; plain loop {loop_ns:.1f} ns "
              f"per iteration ({us * 1e3 / loop_ns:.0f} iterations)")
        assert us < 1000.0
