"""Chapter 6 singular-perturbation scheme (6.78 + 6.102-6.106) on the flexible-joint plant
(section 6.3.2: K_s = 300, J_m = 1), through the controller class and the offline loop.

``pytest -s`` prints the side-by-side table (with / without the slow control tau_s).
"""

import time
from pathlib import Path

import numpy as np
import pytest

from cr_control.core.parameters import resolve
from cr_control.offline import run
from cr_control.schemes.flexible_joint import fjr_singular_perturbation as sp
from cr_control.schemes.flexible_joint.fjr_singular_perturbation import FJRSingularPerturbationController
from cr_control.schemes.flexible_joint.flexible_joint_model import TRUE_P, mass_regressor_into
from cr_control.tools.config_files import node_yaml
from cr_sim.plants.registry import make_plant

DURATION = 20.0
PLANT = {"joint_stiffness": [300.0, 300.0], "motor_inertia": [1.0, 1.0]}
WINDOWS = [(0.0, 5.0), (5.0, 10.0), (15.0, 20.0)]
CONFIG = Path(__file__).resolve().parents[1] / "config" / "fjr_singular_perturbation.yaml"


def controller(**overrides):
    cls = FJRSingularPerturbationController
    return cls(resolve(cls.parameters(), overrides))


class Recording(FJRSingularPerturbationController):
    """Keeps a copy of the internal state after every cycle (the filters Z, F_w, Gamma)."""

    def compute(self, t, dt, q, v, force):
        out = super().compute(t, dt, q, v, force)
        self.log.append(self.internal.copy())
        return out


def closed_loop(slow_control: bool):
    cls = Recording
    c = cls(resolve(cls.parameters(), {"slow_control": slow_control}))
    c.log = []
    out = run(c, make_plant("flexible_joint_surface", PLANT), DURATION)
    return c, out, np.array(c.log)


@pytest.fixture(scope="module")
def with_ts():
    return closed_loop(True)


@pytest.fixture(scope="module")
def without_ts():
    return closed_loop(False)


def link_error(o):
    return np.hypot(o.column("e_q_1"), o.column("e_q_2"))


def window(o, a, b):
    return (o.time >= a - 1e-9) & (o.time < b - 1e-9)


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def estimates(o):
    return np.stack([o.column(f"p_hat_{i + 1}") for i in range(5)], axis=1)


def predicted_lambda(k_s=300.0, j_m=1.0, k_p=80.0, lambda_d=2.0):
    """Quasi-steady lambda under (6.78) as printed (module docstring)."""
    return lambda_d * (j_m * k_p + k_s) / (j_m * k_p + 2.0 * k_s)


def summary(c, o):
    e = link_error(o)
    row = {}
    for a, b in WINDOWS:
        m = window(o, a, b)
        row[f"rms {a:g}-{b:g}"] = rms(e[m]) * 1e3
        row[f"max {a:g}-{b:g}"] = float(e[m].max()) * 1e3
    lam = o.column("lambda")[o.time >= 1.0]
    row["lambda after 1 s"] = (float(lam.min()), float(lam.max()))
    lam5 = o.column("lambda")[o.time >= 5.0]
    row["lambda after 5 s"] = (float(lam5.min()), float(lam5.max()))
    row["peak |tau|"] = float(np.abs(o.command).max())
    row["rms tau 1, 2"] = tuple(float(v) for v in np.sqrt(np.mean(o.command ** 2, axis=0)))
    row["|p_hat| end"] = float(np.linalg.norm(estimates(o)[-1]))
    row["|Gamma^-1| end"] = float(o.column("gamma_inv_norm")[-1])
    row["compute us (median)"] = float(np.median(o.column("compute_time_us")))
    return row


def test_table(with_ts, without_ts):
    """The lead engineer's table; no assertion beyond both runs being complete and clean."""
    rows = {"with tau_s": summary(*with_ts[:2]), "without tau_s": summary(*without_ts[:2])}
    print(f"\nfjr_singular_perturbation, {DURATION:g} s offline, 1 kHz, K_s = 300, J_m = 1, "
          "section 6.3.2 gains, k_0 = 5, K_e = 3.5 (link error |e_q| in mrad)")
    keys = list(rows["with tau_s"])
    print(f"{'':24s}{'with tau_s':>24s}{'without tau_s':>24s}")
    for k in keys:
        cells = []
        for name in rows:
            v = rows[name][k]
            sep = ", " if k.startswith("rms tau") else " .. "
            cells.append(f"{v[0]:.3f}{sep}{v[1]:.3f}" if isinstance(v, tuple) else f"{v:.3f}")
        print(f"{k:24s}{cells[0]:>24s}{cells[1]:>24s}")
    for c, o, _ in (with_ts, without_ts):
        assert c.held_cycles == 0 and c.restored_cycles == 0
        assert len(o.time) == int(DURATION * 1000)
    # the compiled kernel alone (compute_time_us above includes the Python step around it)
    c, o, _ = with_ts
    q, v, f = o.position[-1], o.velocity[-1], o.force[-1]
    state, out = c.internal.copy(), np.empty(c._output.size)
    n = 5000
    start = time.perf_counter()
    for k in range(n):
        sp.fjr_singular_perturbation_cycle(c.gains, state, 20.0 + k * 1e-3, 1e-3, q, v, f, out)
    print(f"kernel alone: {(time.perf_counter() - start) / n * 1e6:.1f} us per cycle")


# -- closed loop with the slow control ---------------------------------------------------
def test_positions_converge_with_slow_control(with_ts):
    """Theorem 6.2.2 / (6.95): q_l -> q_ld up to the O(eps) of the fast loop. Measured
    (20 s): RMS |e_q| 145.3 mrad over 0-1 s, 0.244 over 5-10 s, 0.199 over 15-20 s
    (max 0.31)."""
    c, o, _ = with_ts
    e = link_error(o)
    first = rms(e[window(o, 0.0, 1.0)])
    last = rms(e[window(o, 15.0, 20.0)])
    assert first > 0.1                       # 145 mrad: the start is 0.23 rad off q_ld(0)
    assert last < 0.3e-3                     # 0.199 mrad
    assert last < first / 500.0              # ratio 730
    assert e[window(o, 15.0, 20.0)].max() < 0.6e-3
    assert rms(e[window(o, 15.0, 20.0)]) < rms(e[window(o, 5.0, 10.0)])


def test_force_error_bounded_with_slow_control(with_ts):
    """lambda - lambda_d bounded (remark 6.2.6), not zero: lambda settles at the quasi-steady
    value lambda_d (J_m K_p + K_s) / (J_m K_p + 2 K_s) = 1.118 N of the printed law
    (module docstring). Measured after 5 s: 1.017 .. 1.173 N, mean 1.122 N over 15-20 s."""
    c, o, _ = with_ts
    lam = o.column("lambda")
    after = lam[o.time >= 5.0]
    assert np.all(np.abs(after - predicted_lambda()) < 0.15)
    assert abs(lam[window(o, 15.0, 20.0)].mean() - predicted_lambda()) < 0.02
    after1 = lam[o.time >= 1.0]
    assert after1.min() > -4.0 and after1.max() < 3.5   # -3.05 .. 2.48 N


def test_estimates_and_gain_bounded_lemma_6_2_1(with_ts):
    """p_hat bounded, gamma(t) >= 0 and ||Gamma^-1|| <= k_0 throughout (lemma 6.2.1), Gamma
    exactly symmetric. Measured: ||Gamma^-1|| <= 4.60 (k_0 = 5), gamma >= 0.081, |p_hat|
    <= 0.80, p_hat(20 s) within 0.045 of p (all of it along W's weakly excited direction)."""
    c, o, log = with_ts
    k_0 = c.values["k_0"]
    gamma = o.column("forgetting")
    norm = o.column("gamma_inv_norm")
    assert gamma.min() >= 0.0
    assert norm.max() <= k_0
    Gamma = log[:, sp._GAMMA:sp._GAMMA + 25].reshape(-1, 5, 5)
    assert np.array_equal(Gamma, np.transpose(Gamma, (0, 2, 1)))
    lam_min = np.linalg.eigvalsh(Gamma[::500]).min(axis=1)
    assert np.all(1.0 / lam_min <= k_0)
    # the status reports the norm the cycle used: that of the previous cycle's Gamma
    assert np.allclose(1.0 / lam_min[:-1], norm[1::500][:len(lam_min) - 1], rtol=1e-9)
    p_hat = estimates(o)
    assert np.all(np.isfinite(p_hat)) and np.linalg.norm(p_hat, axis=1).max() < 1.2
    assert gamma.min() > 0.04
    assert np.linalg.norm(p_hat[-1] - TRUE_P) < 0.08


def test_filter_z_equals_w_p_along_the_run(with_ts):
    """(6.100): z = W p exactly in continuous time, W(0) = 0. Z (filtered K_s theta +
    J_Phi^T lambda, from the plant's measured state and force) against W p with the true p
    and W = alpha Psi_M(q_l, q_l') + F_w. Both filters use the trapezoidal rule (dt =
    1 ms, alpha dt = 0.005): the difference is O(dt^2); measured max 2.9e-5 over 0-1 s
    (|Z| up to 1.36), 7.3e-7 after 5 s."""
    c, o, log = with_ts
    alpha = c.values["alpha"]
    Z = log[:, sp._Z:sp._Z + 2]
    F_w = log[:, sp._FW:sp._FW + 10].reshape(-1, 2, 5)
    W = np.empty_like(F_w)
    for k in range(len(log)):
        mass_regressor_into(o.position[k, :2], o.velocity[k, :2], W[k])
    W = alpha * W + F_w
    diff = np.abs(Z - W @ TRUE_P)
    assert np.abs(Z).max() > 1.0
    assert np.all(W[0] == 0.0) and np.all(Z[0] == 0.0)
    assert diff.max() < 1e-4
    assert diff[o.time >= 5.0].max() < 3e-6


# -- without the slow control (figures 6.16-6.18) ------------------------------------------
def test_without_slow_control_position_does_not_converge(with_ts, without_ts):
    """Section 6.3.2: without tau_s "the link position cannot converge ... and the constraint
    force shows bigger tracking errors". Measured: RMS |e_q| 6.35 mrad over 5-10 s and
    6.95 over 15-20 s (no decay; 35x the tau_s run), lambda 0.40 .. 2.61 N after 5 s
    (1.02 .. 1.17 with tau_s), max |lambda - lambda_d| after 5 s 1.60 N (0.98 N), RMS
    1.03 N (0.89 N: with tau_s the error is mostly the constant offset of the printed law),
    p_hat stays p_hat(0)."""
    _, o_with, _ = with_ts
    c, o, _ = without_ts
    e, e_with = link_error(o), link_error(o_with)
    late = rms(e[window(o, 15.0, 20.0)])
    assert late > 4e-3
    assert late > 0.8 * rms(e[window(o, 5.0, 10.0)])          # no convergence
    assert late > 20.0 * rms(e_with[window(o_with, 15.0, 20.0)])
    lam = o.column("lambda")[o.time >= 5.0]
    lam_with = o_with.column("lambda")[o_with.time >= 5.0]
    assert np.ptp(lam) > 1.5 and np.ptp(lam) > 10.0 * np.ptp(lam_with)
    assert np.abs(lam - 2.0).max() > 1.4 * np.abs(lam_with - 2.0).max()
    assert rms(lam - 2.0) > rms(lam_with - 2.0)
    assert np.all(o.column("tau_s_1") == 0.0) and np.all(o.column("tau_s_2") == 0.0)
    assert np.all(estimates(o) == np.asarray(c.values["p_hat_0"]))


# -- the desired motor motion --------------------------------------------------------------
def numpy_q_md(t, p, k_s=300.0, lambda_d=2.0, l1=0.3, l2=0.3):
    """q_md of (6.62) in plain numpy: r_d, inverse kinematics (branch sin theta2 < 0),
    q_ld' = J^-1 r_d', q_ld'' = J^-1 (r_d'' - J' q_ld'), Psi of (6.120), f_d = J_Phi^T
    lambda_d with J_Phi = n^T J (n = (1, -1)/sqrt 2)."""
    c, a, w = np.array([0.0, 0.35]), np.array([-0.1, -0.1]), 2.0
    r, rd, rdd = c + a * np.cos(w * t), -a * w * np.sin(w * t), -a * w * w * np.cos(w * t)
    c2 = (r @ r - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    q2 = -np.arccos(c2)
    q1 = np.arctan2(r[1], r[0]) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    q = np.array([q1, q2])
    s1, c1, s12, c12 = np.sin(q1), np.cos(q1), np.sin(q1 + q2), np.cos(q1 + q2)
    J = np.array([[-l1 * s1 - l2 * s12, -l2 * s12], [l1 * c1 + l2 * c12, l2 * c12]])
    qd = np.linalg.solve(J, rd)
    w1, w12 = qd[0], qd[0] + qd[1]
    Jd = np.array([[-l1 * c1 * w1 - l2 * c12 * w12, -l2 * c12 * w12],
                   [-l1 * s1 * w1 - l2 * s12 * w12, -l2 * s12 * w12]])
    qdd = np.linalg.solve(J, rdd - Jd @ qd)
    cq2, sq2 = np.cos(q2), np.sin(q2)
    x, xd = qd, qdd
    Psi = np.array([
        [xd[0], 2 * cq2 * xd[0] + cq2 * xd[1] - sq2 * (qd[0] + qd[1]) * x[1] - sq2 * qd[1] * x[0],
         xd[1], c1, c12],
        [0.0, cq2 * xd[0] + sq2 * qd[0] * x[0], xd[1] + xd[0], 0.0, c12]])
    n = np.array([1.0, -1.0]) / np.sqrt(2.0)
    f_d = (n @ J) * lambda_d
    return (Psi @ p - f_d) / k_s + q


def test_q_md_hat_is_6_62_for_the_true_p():
    """With p_hat = p, q_md_hat (6.65, the published q_md_hat) is q_md (6.62) from plain
    numpy (measured agreement ~1e-16 rad)."""
    c = controller(p_hat_0=list(TRUE_P))
    q = np.array([2.85, -2.12, 2.86, -2.11])
    for t in (0.0, 0.37, 1.2, 2.9):
        out = c.compute(t, 0.0, q, np.zeros(4), np.zeros(3))     # dt = 0: p_hat stays p
        fields = c.status_fields[1:]
        got = [out.status[fields.index(f"q_md_hat_{i}")] for i in (1, 2)]
        assert np.allclose(got, numpy_q_md(t, TRUE_P), rtol=0.0, atol=1e-12)


def test_q_md_hat_derivatives_are_exact():
    """q_md_hat' (6.66) and q_md_hat'' (6.67) against central differences of q_md_hat and
    q_md_hat' along t (h = 1e-4 s: truncation ~1e-8 of the values; measured < 3e-9)."""
    c = controller()
    p = np.array(c.values["p_hat_0"])
    h = 1e-4
    for t in (0.1, 0.8, 2.0, 3.3):
        md = sp.desired_motor_at(c.gains, t, p)
        plus, minus = sp.desired_motor_at(c.gains, t + h, p), sp.desired_motor_at(c.gains, t - h, p)
        assert np.allclose(md[1], (plus[0] - minus[0]) / (2 * h), rtol=0.0, atol=1e-7)
        assert np.allclose(md[2], (plus[1] - minus[1]) / (2 * h), rtol=0.0, atol=1e-7)
        assert np.abs(md[2]).max() > 0.5        # not trivially small


# -- building blocks, parameters, config -------------------------------------------------
def test_jacobi_inverse_matches_numpy():
    rng = np.random.default_rng(4)
    work, V, w, inv = np.empty((5, 5)), np.empty((5, 5)), np.empty(5), np.empty((5, 5))
    for scale in (1e-3, 1.0, 60.0, 1e3):
        B = rng.normal(size=(5, 5))
        A = scale * (B @ B.T + 0.05 * np.eye(5))
        lo, hi = sp.spd_inverse(A, inv, work, V, w)
        ev = np.linalg.eigvalsh(A)
        assert np.isclose(lo, ev[0], rtol=1e-10) and np.isclose(hi, ev[-1], rtol=1e-12)
        assert np.allclose(inv, np.linalg.inv(A), rtol=1e-9, atol=1e-12 / scale)
        assert np.array_equal(inv, inv.T)


def test_parameter_change_takes_effect():
    """K_p, slow_control and k_0 changed live act from the next cycle: the command moves by
    exactly J_m dK_p e_m_hat, tau_s drops out, gamma follows (6.106)."""
    c = controller()
    fields = c.status_fields[1:]
    q = np.array([2.85, -2.12, 2.86, -2.11])
    v = np.array([0.1, -0.2, 0.0, 0.3])
    f = np.array([1.0, -1.0, 0.0])
    start = c.internal.copy()

    def cycle():
        np.copyto(c.internal, start)
        out = c.compute(0.5, 0.0, q, v, f)
        return out.command.copy(), out.status.copy()

    tau0, st0 = cycle()
    e_m = st0[[fields.index("e_m_hat_1"), fields.index("e_m_hat_2")]]
    c.set_parameter("K_p", np.diag([100.0, 90.0]))
    tau1, _ = cycle()
    assert np.allclose(tau1 - tau0, np.array([20.0, 10.0]) * e_m, rtol=1e-12, atol=1e-15)
    tau_s = st0[[fields.index("tau_s_1"), fields.index("tau_s_2")]]
    assert np.abs(tau_s).max() > 0.0
    c.set_parameter("slow_control", False)
    tau2, st2 = cycle()
    assert st2[fields.index("tau_s_1")] == 0.0
    assert np.allclose(tau2, tau1 - tau_s, rtol=1e-12, atol=1e-15)
    c.set_parameter("k_0", 0.1)
    _, st3 = cycle()
    assert np.isclose(st3[fields.index("forgetting")], 1.0 * (1.0 - (1.0 / 60.0) / 0.1))


def test_gamma_1_not_above_gamma_2_refused():
    with pytest.raises(ValueError, match="gamma_1 .* must exceed gamma_2"):
        controller(gamma_1=2.0, gamma_2=2.0)
    c = controller()
    gains = c.gains.copy()
    # what the node asks before rclpy stores a change (the old value stays in force)
    assert "must exceed gamma_2" in c.check_parameter("gamma_2", 7.5)
    assert "lemma 6.2.1" in c.check_parameter("k_0", 0.01)
    assert c.check_parameter("gamma_2", 6.5) is None
    assert c.values["gamma_2"] == 2.0 and np.array_equal(c.gains, gains)
    with pytest.raises(ValueError, match="gamma_1"):
        c.set_parameter("gamma_2", 7.5)
    assert c.values["gamma_2"] == 2.0 and np.array_equal(c.gains, gains)
    with pytest.raises(ValueError, match="k_0"):
        c.set_parameter("k_0", 0.01)            # below ||Gamma_0^-1|| = 1/60
    assert c.values["k_0"] == 5.0 and np.array_equal(c.gains, gains)
    c.set_parameter("gamma_1", 9.0)             # a valid change is taken
    assert c.values["gamma_1"] == 9.0


def test_config_file_is_generated_from_the_parameters():
    cls = FJRSingularPerturbationController
    assert CONFIG.read_text() == node_yaml(cls.scheme, cls.parameters(), cls.scheme)
