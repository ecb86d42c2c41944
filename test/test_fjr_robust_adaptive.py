"""Robust adaptive control of the constrained flexible-joint arm (theorem 6.2.1, 6.58;
section 6.3.1), closed loop on the flexible_joint_surface plant in the offline loop, plus
unit checks of the kernel against a plain numpy evaluation of (6.29) and (6.58).

Every number asserted here was measured first (1 kHz, 20 s; ``pytest -s`` prints the
table); the bounds leave a margin of about 1.5-2x over what was measured. What the runs
show (section 6.3.1 claims in brackets):
  * positions converge in every case [reproduced]; lambda - lambda_d stays bounded
    [reproduced]; estimates bounded [reproduced];
  * with the measured q_m'' (assumption 6.3; the default is the filtered one) the torque chatters between the
    +-max_effort clip (100 N m) every cycle from the start; without the clip it diverges
    (the term J_m_hat q_m'' feeds back the motor's own acceleration, see the scheme's
    docstring); the filtered q_m'' gives torques of a few N m and 4-6 times smaller
    position errors;
  * case 2 (K_s = 50) fluctuates more in lambda than case 1 [reproduced: std ~2x], in the
    torque only slightly (filtered q_m'': +8 %; measured: both at the clip);
  * K_s = 100 does not diverge within 20 s in either mode [thesis: divergent; NOT
    reproduced];
  * "torque and force quite smooth thanks to the boundary layer": with Delta = 0.002 at
    1 kHz the boundary layer is a limit cycle of a few N m (its gain k_tau / Delta ~ 10^3
    N m s/rad on z' acts on J_m = 0.5 at dt = 1 ms); at 10 kHz, or Delta = 0.02 at 1 kHz,
    the torque is smooth [reproduced only there].
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from cr_control.core.parameters import resolve
from cr_control.offline import run
from cr_control.schemes.flexible_joint.fjr_robust_adaptive import (
    STATE,
    FJRRobustAdaptiveController,
    motor_acceleration_filter,
)
from cr_control.schemes.flexible_joint.flexible_joint_model import P_HAT_0
from cr_sim.plants.registry import make_plant

CLS = FJRRobustAdaptiveController
DURATION = 20.0
WINDOWS = [(0.0, 5.0), (5.0, 10.0), (15.0, 20.0)]
MAX_EFFORT = 100.0


def controller(**overrides) -> FJRRobustAdaptiveController:
    return CLS(resolve(CLS.parameters(), overrides))


def plant(ks: float):
    return make_plant("flexible_joint_surface",
                      {"joint_stiffness": [ks, ks], "motor_inertia": [0.5, 0.5]})


@functools.cache
def offline(ks: float, mode: str = "measured", duration: float = DURATION,
            period: float = 1e-3, extra: tuple = (), supervise: bool = True):
    """Offline run of the scheme (thesis gains, q_m'' ``mode``) on the plant with K_s = ks
    I and J_m = 0.5 I (6.3.1); ``supervise`` False: without the plant's reflexes."""
    return run(controller(motor_acceleration=mode, **dict(extra)), plant(ks), duration, period,
               supervise=supervise)


def e_norm(r) -> np.ndarray:
    """|q_ld - q_l| (rad) per cycle."""
    return np.hypot(r.column("e_q_1"), r.column("e_q_2"))


def window(r, a, b) -> np.ndarray:
    return (r.time >= a - 1e-9) & (r.time < b - 1e-9)


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def p_hat(r) -> np.ndarray:
    return np.array([r.column(f"p_hat_{i + 1}") for i in range(10)])


def ks_inv(r) -> np.ndarray:
    return np.array([r.column(f"ks_inv_hat_{i + 1}") for i in range(2)])


def chatter(x: np.ndarray, samples: int) -> float:
    """RMS of x minus its centred moving average over ``samples`` (the part that changes
    faster than ~1/(samples dt))."""
    return rms(x - np.convolve(x, np.ones(samples) / samples, mode="same"))


def metrics(r) -> dict:
    e = e_norm(r)
    after = r.time >= 1.0
    late = window(r, 15.0, 20.0)
    lam = r.column("lambda")
    tau = r.command
    ct = r.column("compute_time_us")[1:]
    return {
        "windows": [(rms(e[window(r, a, b)]), float(e[window(r, a, b)].max())) for a, b in WINDOWS],
        "first_second": rms(e[window(r, 0.0, 1.0)]),
        "lam_range": (float(lam[after].min()), float(lam[after].max())),
        "e_lam_max": float(np.abs(r.column("lambda_d")[after] - lam[after]).max()),
        "lam_std_late": float(lam[late].std()),
        "tau_peak": float(np.abs(tau).max()),
        "tau_peak_after": float(np.abs(tau[after]).max()),
        "tau_rms": rms(tau),
        "tau_std_late": float(tau[late].std(axis=0).max()),
        "clipped_after": float((np.abs(tau[after]) >= MAX_EFFORT).mean()),
        "p_norm_end": float(np.linalg.norm(p_hat(r)[:, -1])),
        "p_norm_max": float(np.linalg.norm(p_hat(r), axis=0).max()),
        "ks_inv_end": ks_inv(r)[:, -1],
        "ks_inv_range": (float(ks_inv(r).min()), float(ks_inv(r).max())),
        "held_after_start": int(r.column("held")[1:].sum()),
        "compute_us": (float(np.median(ct)), float(np.percentile(ct, 99))),
    }


def table_row(label: str, m: dict) -> str:
    w = "  ".join(f"{1e3 * a:7.2f}/{1e3 * b:7.2f}" for a, b in m["windows"])
    lo, hi = m["lam_range"]
    k1, k2 = m["ks_inv_end"]
    return (f"{label:<22} {w}  {lo:5.2f}..{hi:5.2f}  {m['tau_peak']:6.1f} {m['tau_rms']:6.2f}  "
            f"{m['p_norm_end']:.4f} {k1:.4f} {k2:.4f}  {m['compute_us'][0]:5.1f}/"
            f"{m['compute_us'][1]:5.1f}")


TABLE_HEADER = (f"{'case':<22} {'|e_q| RMS/max (mrad) [0-5] [5-10] [15-20] s':<50}"
                f"  lambda>1s (N)  tau pk/RMS (N m)  |p_hat| ks_inv_hat end  us/cycle med/p99")


# -- unit checks ----------------------------------------------------------------------------
def _numpy_theta_d_tau(c, t, q, v, force, qddot):
    """theta_d (6.29) and tau_m (6.58) in plain numpy from the printed formulas (desired
    motion by closed-form inverse kinematics, q_ld' = J^-1 r_d', q_ld'' = J^-1 (r_d'' -
    J' q_ld'); L2 = -1 - l1 (s1 + c1) / (l2 (s12 + c12)) (corrected 6.118); Psi of 6.120
    in the block form of section 6.3), with the internal state as it is (dt = 0)."""
    val = c.values
    l1, l2 = val["link_length"]
    st = {k: STATE.view(c.internal, k).copy() for k in STATE.shapes}
    ctr, amp, w, ph = (np.asarray(val["path_centre"]), np.asarray(val["path_amplitude"]),
                       val["path_frequency"], val["path_phase"])
    rd = ctr + amp * np.cos(w * t + ph)
    rd1 = -amp * w * np.sin(w * t + ph)
    rd2 = -amp * w * w * np.cos(w * t + ph)
    c2 = (rd @ rd - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    th2 = -math.acos(c2)
    th1 = math.atan2(rd[1], rd[0]) - math.atan2(l2 * math.sin(th2), l1 + l2 * math.cos(th2))

    def jac(a, b):
        return np.array([[-l1 * math.sin(a) - l2 * math.sin(a + b), -l2 * math.sin(a + b)],
                         [l1 * math.cos(a) + l2 * math.cos(a + b), l2 * math.cos(a + b)]])

    Jd = jac(th1, th2)
    qd1 = np.linalg.solve(Jd, rd1)
    w1, w12 = qd1[0], qd1[0] + qd1[1]
    Jd_dot = np.array([[-l1 * math.cos(th1) * w1 - l2 * math.cos(th1 + th2) * w12,
                        -l2 * math.cos(th1 + th2) * w12],
                       [-l1 * math.sin(th1) * w1 - l2 * math.sin(th1 + th2) * w12,
                        -l2 * math.sin(th1 + th2) * w12]])
    qd2 = np.linalg.solve(Jd, rd2 - Jd_dot @ qd1)
    q_l, v_l = q[:2], v[:2]
    n = np.array([1.0, -1.0]) / math.sqrt(2.0)
    J_phi = n @ jac(*q_l)
    lam = n @ force[:2]
    lam_d = val["lambda_d"]

    def L2(a, b):
        return -1.0 - l1 * (math.sin(a) + math.cos(a)) / (l2 * (math.sin(a + b) + math.cos(a + b)))

    h = 1e-6
    L = np.array([1.0, L2(*q_l)])
    L_dot = np.array([0.0, (L2(*(q_l + h * v_l)) - L2(*(q_l - h * v_l))) / (2 * h)])
    k_e = val["K_e"][0, 0]
    e1, e1_dot = th1 - q_l[0], qd1[0] - v_l[0]
    r1 = e1_dot + k_e * e1
    qr_dot, qr_ddot = qd1[0] + k_e * e1, qd2[0] + k_e * e1_dot
    mu = st["mu"]
    mu_dot = -val["K_mu"] @ mu - J_phi * (lam_d - lam)
    sigma = L * r1 + mu
    nu = L * qr_dot + mu
    nu_dot = L_dot * qr_dot + L * qr_ddot + mu_dot
    x, xd = nu, nu_dot
    t1, t2 = q_l
    c2_, s2_ = math.cos(t2), math.sin(t2)
    psi = np.array([
        [xd[0], 2 * c2_ * xd[0] + c2_ * xd[1] - s2_ * (v_l[0] + v_l[1]) * x[1] - s2_ * v_l[1] * x[0],
         xd[1], math.cos(t1), math.cos(t1 + t2)],
        [0.0, c2_ * xd[0] + s2_ * v_l[0] * x[0], xd[1] + xd[0], 0.0, math.cos(t1 + t2)]])
    Psi10 = np.zeros((2, 10))
    Psi10[0, :5], Psi10[1, 5:] = psi[0], psi[1]
    theta_d = val["K_sigma"] @ sigma - st["ks_inv_hat"] * J_phi * lam_d + Psi10 @ st["p_hat"]
    k_tau = val["delta_K"] * np.linalg.norm(theta_d) + val["delta_J"] * np.linalg.norm(qddot)
    sat = np.clip(st["s"] / val["boundary_layer"], -1.0, 1.0)
    tau = val["K_s_hat"] @ theta_d + val["J_m_hat"] @ qddot + k_tau * sat
    return theta_d, sigma, tau


def _settled_controller(mode="measured"):
    """A controller after 0.7 s on the case-1 plant (non-trivial mu, estimates, s), and the
    plant."""
    c = controller(motor_acceleration=mode)
    p = plant(10.0)
    run(c, p, 0.7)
    return c, p


def test_theta_d_and_torque_equal_a_plain_numpy_evaluation():
    """At an arbitrary state (off the trajectory, moving), with dt = 0 (no integration),
    the kernel's theta_d (6.29), sigma (6.15) and tau_m (6.58) equal a numpy evaluation
    of the printed formulas."""
    c, _ = _settled_controller()
    t = 0.731
    q = np.array([2.81, -2.09, 2.86, -2.02])
    v = np.array([0.31, -0.52, 0.27, -0.4])
    force = np.array([2.3, -2.3, 0.0]) / math.sqrt(2.0)
    qddot = np.array([0.7, -1.1])
    c.plant_sensors[:] = qddot
    assert np.abs(STATE.view(c.internal, "mu")).max() > 1e-3      # non-trivial state
    out = c.compute(t, 0.0, q, v, force)
    col = {f: out.status[c.status_fields.index(f) - 1] for f in c.status_fields[1:]}
    theta_d, sigma, tau = _numpy_theta_d_tau(c, t, q, v, force, qddot)
    got_theta = np.array([col["theta_d_1"], col["theta_d_2"]])
    got_sigma = np.array([col["sigma_1"], col["sigma_2"]])
    print(f"\ntheta_d kernel {got_theta}, numpy {theta_d}; tau kernel {out.command}, numpy {tau}")
    assert np.allclose(got_sigma, sigma, rtol=0, atol=1e-9)
    assert np.allclose(got_theta, theta_d, rtol=0, atol=1e-8)
    assert np.allclose(out.command, tau, rtol=0, atol=1e-7)
    assert np.allclose([col["z_1"], col["z_2"]], theta_d - (q[2:] - q[:2]), atol=1e-8)


def test_motor_acceleration_filter_is_exact_and_stable():
    """The state-variable filter recovers the slope of a ramp q_m' (x2 -> a) and stays
    bounded for w dt far beyond explicit Euler's limit of 2 (there x2, sampled, sees the
    staircase input: about half the slope)."""
    a = np.array([3.0, -1.5])
    for w, dt in ((50.0, 1e-3), (3000.0, 1e-3)):
        x1, x2 = np.zeros(2), np.zeros(2)
        for k in range(1, 2001):
            motor_acceleration_filter(x1, x2, a * k * dt, w, dt)
            assert np.abs(x2).max() <= np.abs(a).max() * 1.01
        if w * dt < 0.1:
            assert np.allclose(x2, a, rtol=2e-2), (w, x2)
    # a step of q_m': the impulse response w^2 t e^{-w t} of the derivative, peak w / e
    x1, x2 = np.zeros(2), np.zeros(2)
    peak = 0.0
    for _ in range(200):
        motor_acceleration_filter(x1, x2, np.ones(2), 50.0, 1e-3)
        peak = max(peak, x2[0])
    assert abs(peak - 50.0 / math.e) < 0.01 * 50.0 / math.e


def test_measured_mode_uses_the_filter_until_the_sensor_arrives():
    c, p = _settled_controller()
    m = p.measurement()
    c.plant_sensors[:] = np.nan
    out = c.compute(0.7, 1e-3, m.position, m.velocity, m.force)
    f = c.status_fields
    used = out.status[[f.index("qddot_m_1") - 1, f.index("qddot_m_2") - 1]]
    filt = out.status[[f.index("qddot_m_filtered_1") - 1, f.index("qddot_m_filtered_2") - 1]]
    assert np.all(np.isfinite(out.command)) and np.array_equal(used, filt)


def test_parameter_change_takes_effect():
    """set_parameter("K_sigma") changes theta_d by (K_sigma' - K_sigma) sigma at once, and
    the loop after it."""
    c, p = _settled_controller()
    m = p.measurement()
    c.plant_sensors[:] = p.sensors()[3:5]
    f = c.status_fields
    idx = [f.index("theta_d_1") - 1, f.index("theta_d_2") - 1]
    isg = [f.index("sigma_1") - 1, f.index("sigma_2") - 1]
    a = c.compute(0.7, 0.0, m.position, m.velocity, m.force)
    theta_a, sigma = a.status[idx].copy(), a.status[isg].copy()
    c.set_parameter("K_sigma", np.diag([3.0, 2.0]))
    b = c.compute(0.7, 0.0, m.position, m.velocity, m.force)
    assert np.allclose(b.status[idx] - theta_a, np.array([2.0, 1.0]) * sigma, atol=1e-12)
    assert np.abs(sigma).max() > 1e-4
    # and the closed loop continues differently
    c2, p2 = _settled_controller()
    r1 = run(c, p, 0.5)
    r2 = run(c2, p2, 0.5)
    assert np.abs(r1.column("theta_d_1") - r2.column("theta_d_1")).max() > 1e-3


def test_s_is_the_remark_6_2_2_difference():
    """s = (s_z,k - s_z,k-1) / dt with s_z = int sigma + z (6.60) equals sigma_k +
    (z_k - z_k-1) / dt to round-off. Against sigma + z' with the measured theta' (z' =
    theta_d' - (q_m' - q_l')): within 2-6 % (RMS) in the first second (|s| >> Delta);
    inside the boundary layer later (|s| ~ Delta, theta chattering at the sampling rate)
    the backward difference lags by half a period: 45 % cycle by cycle, 11 % in the
    20 ms averages, same sign in 86 % of the cycles (measured, filtered q_m'', case 1)."""
    r = offline(10.0, "filtered")
    dt = np.diff(r.time)
    s = np.array([r.column("s_1"), r.column("s_2")])
    sig = np.array([r.column("sigma_1"), r.column("sigma_2")])
    z = np.array([r.column("z_1"), r.column("z_2")])
    th_d = np.array([r.column("theta_d_1"), r.column("theta_d_2")])
    assert np.all(s[:, 0] == 0.0)                                    # first cycle
    gap = np.abs(s[:, 1:] - (sig[:, 1:] + np.diff(z, axis=1) / dt)).max()
    theta_dot = (r.velocity[:, 2:] - r.velocity[:, :2]).T
    exact = sig[:, 1:] + np.diff(th_d, axis=1) / dt - theta_dot[:, 1:]
    t = r.time[1:]
    early, late = t < 1.0, (t >= 5.0)
    lines = [f"\ns vs sigma + dz/dt: max |difference| {gap:.2e}"]
    for i in range(2):
        a, b = s[i, 1:], exact[i]
        e_early = rms(a[early] - b[early]) / rms(a[early])
        av = functools.partial(np.convolve, v=np.ones(21) / 21, mode="same")
        e_late = rms(a[late] - b[late]) / rms(a[late])
        e_late_avg = rms(av(a[late]) - av(b[late])) / rms(av(a[late]))
        agree = float(np.mean(np.sign(a[late]) == np.sign(b[late])))
        lines.append(f"  joint {i + 1}: vs sigma + theta_d'(diff) - theta'(measured): RMS "
                     f"{e_early:.3f} of RMS s in 0-1 s; after 5 s {e_late:.3f} per cycle, "
                     f"{e_late_avg:.3f} in 20 ms averages, same sign {agree:.3f}")
        assert e_early < 0.1 and e_late_avg < 0.25 and agree > 0.75
    print("\n".join(lines))
    assert gap < 1e-8


# -- closed loop, section 6.3.1 -------------------------------------------------------------
def _common_claims(m: dict, late_rms_bound: float, e_lam_bound: float):
    first, late = m["first_second"], m["windows"][2][0]
    assert late < late_rms_bound and late < 0.05 * first, (late, first)
    assert m["e_lam_max"] < e_lam_bound
    assert m["held_after_start"] == 0
    assert m["p_norm_max"] < 0.35 and 0.05 < m["ks_inv_range"][0] <= m["ks_inv_range"][1] < 0.25


def test_case1_strong_flexibility():
    """K_s = 10 I (case 1), thesis gains, measured q_m'' (assumption 6.3): |e_q| RMS over
    15-20 s 4.1 mrad (162 mrad in the first second), |lambda - lambda_d| <= 0.44 N after
    1 s, estimates bounded; the torque sits at the +-100 N m clip (measured: 99.8 % of the
    cycles after 1 s)."""
    m = metrics(offline(10.0))
    _common_claims(m, late_rms_bound=8e-3, e_lam_bound=0.8)
    assert m["clipped_after"] > 0.9


def test_case2_weak_flexibility_fluctuates_more():
    """K_s = 50 I (case 2), other gains unchanged (K_s_hat = 8 I although ||K_s - K_s_hat||
    = 42 > delta_K = 4: assumption 6.2 does not hold): positions converge as in case 1;
    lambda fluctuates ~2x more (late std 0.177 vs 0.098 N measured, 0.130 vs 0.054 N
    filtered q_m''); the torque only slightly (filtered: late std 3.94 vs 3.66 N m;
    measured: both at the clip)."""
    for mode, late_bound, elam_bound in (("measured", 8e-3, 1.6), ("filtered", 2e-3, 1.3)):
        m1, m2 = metrics(offline(10.0, mode)), metrics(offline(50.0, mode))
        _common_claims(m2, late_rms_bound=late_bound, e_lam_bound=elam_bound)
        assert m2["lam_std_late"] > 1.5 * m1["lam_std_late"], mode
        if mode == "filtered":
            assert m2["tau_std_late"] > m1["tau_std_late"]
            assert m2["tau_peak_after"] < 15.0
        else:
            assert m2["clipped_after"] > 0.9 and m1["clipped_after"] > 0.9


def test_stiff_joints_ks100_stay_bounded():
    """K_s = 100 I: the thesis reports divergence; here it does not diverge in 20 s in
    either mode (measured q_m'': late RMS 5.8 mrad, lambda 0.03..3.6 N after 1 s, at the
    torque clip; filtered: 2.4 mrad, lambda 1.07..2.81 N)."""
    for mode, late_bound, lam_lo, lam_hi in (("measured", 1.2e-2, -0.5, 4.5),
                                             ("filtered", 5e-3, 0.5, 3.5)):
        m = metrics(offline(100.0, mode))
        assert m["held_after_start"] == 0, mode
        assert m["windows"][2][0] < late_bound and m["windows"][2][1] < 2.5 * late_bound, mode
        assert lam_lo < m["lam_range"][0] and m["lam_range"][1] < lam_hi, mode
        assert np.all(np.isfinite(m["ks_inv_end"])) and m["p_norm_max"] < 0.35


def test_measured_versus_filtered_motor_acceleration():
    """Side by side (20 s, late RMS |e_q|): the filtered q_m'' (w = 50 rad/s) tracks 4-6x
    better than the measured one at every K_s and never reaches the torque clip after 1 s;
    with the clip lifted (max_effort 1e4) the measured q_m'' diverges within 6 s (cycles
    held on absurd states) while the filtered run is unchanged."""
    print("\nmeasured vs filtered q_m'' (|e_q| RMS 15-20 s, mrad; tau peak after 1 s, N m)")
    for ks in (10.0, 50.0, 100.0):
        mm, mf = metrics(offline(ks, "measured")), metrics(offline(ks, "filtered"))
        print(f"  K_s = {ks:5.0f}: measured {1e3 * mm['windows'][2][0]:6.2f} (tau "
              f"{mm['tau_peak_after']:5.1f}), filtered {1e3 * mf['windows'][2][0]:6.2f} (tau "
              f"{mf['tau_peak_after']:5.1f})")
        assert mf["windows"][2][0] < 0.6 * mm["windows"][2][0]
        assert mf["clipped_after"] == 0.0 and mf["tau_peak_after"] < 15.0
    free = (("max_effort", 1e4),)
    # the law with its clip lifted, without the plant's force reflex (which stops the
    # diverging run at lambda = 20 N, 0.23 s)
    rm = offline(10.0, "measured", 6.0, extra=free, supervise=False)
    rf = offline(10.0, "filtered", 6.0, extra=free, supervise=False)
    capped = offline(10.0, "filtered", 6.0, supervise=False)
    print(f"  max_effort 1e4, 6 s: measured held {int(rm.column('held').sum())} cycles, "
          f"|tau| up to {np.abs(rm.command).max():.0f} N m, lambda down to "
          f"{rm.column('lambda').min():.1f} N; filtered held {int(rf.column('held').sum())}, "
          f"|tau| up to {np.abs(rf.command).max():.1f} N m")
    assert rm.column("held").sum() > 100 and rm.column("lambda").min() < -5.0
    assert rf.column("held").sum() == 0 and np.array_equal(rf.command, capped.command)


def test_boundary_layer_is_a_limit_cycle_at_1khz_and_smooth_at_10khz():
    """Filtered q_m'', case 1, 6 s: the torque's fast part (RMS minus its 20 ms moving
    average, 4-6 s) is 3.9 N m with Delta = 0.002 at 1 kHz, 0.03 N m at 10 kHz and with
    Delta = 0.02 at 1 kHz (what scales is Delta / dt): the thesis's 'quite smooth' torque
    needs a period well below 1 ms at its Delta."""
    runs = {"1 kHz, Delta 0.002": (offline(10.0, "filtered", 6.0), 21),
            "10 kHz, Delta 0.002": (offline(10.0, "filtered", 6.0, 1e-4), 201),
            "1 kHz, Delta 0.02": (offline(10.0, "filtered", 6.0, extra=(("boundary_layer", 0.02),)), 21)}
    fast = {}
    for label, (r, n) in runs.items():
        late = r.time >= 4.0
        fast[label] = chatter(r.command[late, 0], n)
        print(f"\n  {label}: fast torque {fast[label]:.3f} N m, |tau| max "
              f"{np.abs(r.command[late]).max():.2f} N m, |e_q| RMS "
              f"{1e3 * rms(e_norm(r)[late]):.2f} mrad", end="")
    print()
    assert fast["1 kHz, Delta 0.002"] > 1.5
    assert fast["10 kHz, Delta 0.002"] < 0.1 and fast["1 kHz, Delta 0.02"] < 0.1


def test_print_table():
    """The table for the lead engineer (pytest -s)."""
    lines = ["", TABLE_HEADER]
    for ks in (10.0, 50.0, 100.0):
        for mode in ("measured", "filtered"):
            m = metrics(offline(ks, mode))
            lines.append(table_row(f"K_s={ks:g} {mode}", m))
            assert m["held_after_start"] == 0
    print("\n".join(lines))


@pytest.mark.parametrize("name", ["p_hat_0", "ks_inv_hat_0"])
def test_initial_estimates(name):
    """p_hat(0) = the section 6.3 values in both blocks; k_s_inv_hat(0) = 1/K_s_hat."""
    c = controller()
    got = STATE.view(c.internal, "p_hat" if name == "p_hat_0" else "ks_inv_hat")
    want = np.concatenate([P_HAT_0, P_HAT_0]) if name == "p_hat_0" else np.full(2, 0.125)
    assert np.array_equal(got, want)
