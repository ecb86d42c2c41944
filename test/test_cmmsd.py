"""Appendix C: the chain of N mass-spring-dampers and the adaptive output-feedback
backstepping regulation of q_1 (C.50), any N; the scheme reads q_1 only."""

import numpy as np
import pytest

from cr_control.core.parameters import resolve
from cr_control.offline import run
from cr_control.schemes.registry import make_controller
from cr_sim.plants import cmmsd
from cr_sim.plants.registry import make_plant


def controller(n, **extra):
    return make_controller("cmmsd_backstepping", {"joint_names": [f"q{i + 1}" for i in range(n)],
                                                  **extra})


def test_chain_matches_c1():
    values = resolve(cmmsd.PARAMETERS, {"masses": 3, "mass": [1.0, 2.0, 3.0],
                                        "damping": [0.1, 0.2, 0.3], "stiffness": [4.0, 5.0]})
    A, B = cmmsd.matrices(values)
    q, v = np.array([0.1, -0.2, 0.3]), np.array([1.0, 2.0, -1.0])
    x = np.ravel(np.column_stack([q, v]))
    u = 0.7
    acc = (A @ x + B[:, 2] * u)[1::2]
    expect = [(-0.1 * v[0] - 4 * q[0] + 4 * q[1]) / 1.0,
              (-0.2 * v[1] - 9 * q[1] + 4 * q[0] + 5 * q[2]) / 2.0,
              (-0.3 * v[2] - 5 * q[2] + 5 * q[1] + u) / 3.0]
    assert np.allclose(acc, expect)
    theta = cmmsd.true_theta(values)
    assert theta[0] == pytest.approx(4 * 5 / (1 * 2 * 3))      # d_2N of C.5


def test_scheme_reads_q1_only():
    a, b = controller(3), controller(3)
    rng = np.random.default_rng(0)
    for k in range(50):
        q1 = 0.1 * np.cos(0.01 * k)
        qa = np.array([q1, 0.0, 0.0])
        qb = np.array([q1, *rng.normal(size=2)])
        oa = a.step(k * 1e-3, qa, np.zeros(3), np.zeros(3))
        ob = b.step(k * 1e-3, qb, rng.normal(size=3), np.array([5.0, -3.0, 1.0]))
        assert np.array_equal(oa.command, ob.command)
        assert oa.command[:2].tolist() == [0.0, 0.0]
    assert np.array_equal(a.internal, b.internal)


@pytest.mark.parametrize("n", [1, 2])
def test_q1_regulated_to_zero(n):
    c = controller(n)
    r = run(c, make_plant("cmmsd", {"masses": n}), 60.0)
    q1 = r.position[:, 0]
    late = r.time >= 50.0
    print(f"\nN = {n}: |q1| max over 50-60 s {np.abs(q1[late]).max():.2e} m, max |u| "
          f"{np.abs(r.command[:, -1]).max():.3f} N, d_hat {r.column('d_hat')[-1]:.4f}, "
          f"|theta_hat| {r.column('theta_hat_norm')[-1]:.4f}, compute "
          f"{np.median(r.column('compute_time_us')):.1f} us")
    assert c.held_cycles == 0
    assert np.abs(q1[late]).max() < 1e-4
    assert np.all(np.isfinite(r.position)) and np.abs(r.position).max() < 1.0


@pytest.mark.xfail(strict=True, reason="N = 3 (order 6, rho = 6) diverges from q_1(0) = 0.1 m "
                   "with the default gains: the alpha_i peak (see report)")
def test_q1_regulated_to_zero_three_masses():
    c = controller(3)
    r = run(c, make_plant("cmmsd", {"masses": 3}), 30.0)
    assert c.held_cycles == 0 and abs(r.position[-1, 0]) < 1e-3
