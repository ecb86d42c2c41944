"""mrac_force's normalised gradient (``normalised_gradient``, off by default): the laws
(4.76)-(4.77) divided by m^2 = 1 + phi^T phi + xi^2, and in closed loop with the true theta_f
it still adapts and follows f_d. (Case 5 with it: cr_reproduce's ch4_normalised_gradient.)"""

from __future__ import annotations

import numpy as np

from cr_control.offline import run
from cr_control.schemes.force import mrac_force as mf
from cr_control.schemes.registry import make_controller
from cr_sim.plants.registry import make_plant


def test_default_is_the_thesis_plain_gradient():
    assert make_controller("mrac_force").values["normalised_gradient"] is False


def test_normalised_law_is_the_plain_one_divided_by_m2():
    """One cycle from the filters' steady state (bumpless_start: phi != 0 at once), the
    same inputs: theta_f_hat' and b3_hat' of the normalised law times m^2 are the plain's."""
    overrides = {"bumpless_start": True}
    plain = make_controller("mrac_force", overrides)
    normalised = make_controller("mrac_force", {**overrides, "normalised_gradient": True})
    q, v, f = np.array([4.0]), np.array([0.0]), np.array([15.0, 0.0, 0.0])
    for c in (plain, normalised):
        c.compute(0.0, 0.0, q, v, f)
    phi = plain._phi
    np.testing.assert_array_equal(normalised._phi, phi)
    th_p = plain.internal[mf._THD:mf._THD + 14]
    th_n = normalised.internal[mf._THD:mf._THD + 14]
    b_p, b_n = plain.internal[mf._B3D], normalised.internal[mf._B3D]
    j = int(np.argmax(np.abs(phi)))
    eps_gamma = th_p[j] / phi[j]           # plain: theta' = gamma_f phi eps, b3' = gamma_f xi eps
    xi = b_p / eps_gamma
    m2 = 1.0 + phi @ phi + xi * xi
    print(f"\nphi^T phi = {phi @ phi:.4g}, xi = {xi:.4g}, m^2 = {m2:.6g}")
    assert abs(eps_gamma) > 1e-3 and m2 > 1.5              # a case where m^2 matters
    np.testing.assert_allclose(th_n * m2, th_p, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(b_n * m2, b_p, rtol=1e-12)


def test_normalised_adapting_from_the_true_theta_f_follows_f_d():
    c = make_controller("mrac_force", {"normalised_gradient": True,
                                       "theta_f_hat_0": list(mf.TRUE_THETA_F_CASE1)})
    r = run(c, make_plant("dynamic_constraint", {}), 40.0)
    f = r.force[:, 0]
    late = r.time >= 30.0
    print(f"\nnormalised, true theta_f, gamma_f 0.8: f 30-40 s {f[late].min():.4g} .. "
          f"{f[late].max():.4g} N, held {c.held_cycles}")
    assert c.held_cycles == 0
    assert np.abs(f[late] - 1.0).max() < 0.05
