"""Chapter 6 building blocks: jet arithmetic against closed forms, the regressor (6.120)
against Pinocchio, the filtered-regressor identity, the corrected surface (6.116, 6.118)
and the exact derivatives of the desired motion, regressor and force (6.62-6.64)."""

import math

import numpy as np
import pytest

from cr_control.models.arm_model import LinkParameters, TwoLinkArm
from cr_control.schemes.blocks import jets
from cr_control.schemes.flexible_joint import flexible_joint_model as fm

# Deliberately unequal links: the regressor holds for any planar 2R arm, only p changes.
ODD = LinkParameters(length=[0.3, 0.45], com=[0.12, 0.2], mass=[0.1, 0.35], inertia=[0.3, 0.05])

# 8th-order central-difference stencils (offsets 1..4; the centre weight of d2 is -205/72).
D1 = np.array([4 / 5, -1 / 5, 4 / 105, -1 / 280])
D2 = np.array([8 / 5, -1 / 5, 8 / 315, -1 / 560])


def central(f, t, h):
    """(f'(t), f''(t)) by the 8th-order stencils; f returns an array."""
    f0 = np.asarray(f(t))
    d1 = sum(w * (np.asarray(f(t + k * h)) - np.asarray(f(t - k * h))) for k, w in enumerate(D1, 1)) / h
    d2 = (-205 / 72 * f0 + sum(w * (np.asarray(f(t + k * h)) + np.asarray(f(t - k * h)))
                               for k, w in enumerate(D2, 1))) / h**2
    return d1, d2


def jet_of(derivs):
    out = np.empty(len(derivs))
    jets.jet_from_derivatives(np.asarray(derivs, dtype=float), out)
    return out


def derivs_of(jet):
    out = np.empty(len(jet))
    jets.jet_to_derivatives(jet, out)
    return out


def assert_close(a, b, tol):
    a, b = np.asarray(a), np.asarray(b)
    err = np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b)))
    assert err < tol, f"error {err:.3g} > {tol:g}\n{a}\n{b}"


# -- jets -------------------------------------------------------------------------------------
@pytest.mark.parametrize("t", [-1.3, 0.0, 0.4, 2.1])
def test_sin_cos_of_t_squared(t):
    """sin(t^2), cos(t^2) through mul and the joint recurrence."""
    var, sq, s, c = np.empty((4, 5))
    jets.jet_variable(t, var)
    jets.jet_mul(var, var, sq)
    jets.jet_sin_cos(sq, s, c)
    S, C = math.sin(t * t), math.cos(t * t)
    sin_d = [S, 2 * t * C, 2 * C - 4 * t**2 * S, -12 * t * S - 8 * t**3 * C,
             -12 * S - 48 * t**2 * C + 16 * t**4 * S]
    cos_d = [C, -2 * t * S, -2 * S - 4 * t**2 * C, -12 * t * C + 8 * t**3 * S,
             -12 * C + 48 * t**2 * S + 16 * t**4 * C]
    assert_close(derivs_of(s), sin_d, 1e-12)
    assert_close(derivs_of(c), cos_d, 1e-12)


@pytest.mark.parametrize("t", [-0.9, 0.2, 1.1])
def test_mul_div_sqrt(t):
    sin_t = jet_of([math.sin(t), math.cos(t), -math.sin(t), -math.cos(t), math.sin(t)])
    cos_t = jet_of([math.cos(t), -math.sin(t), -math.cos(t), math.sin(t), math.cos(t)])
    out = np.empty(5)
    jets.jet_mul(sin_t, cos_t, out)  # sin t cos t = sin(2t)/2
    assert_close(derivs_of(out), [2 ** (k - 1) * math.sin(2 * t + k * math.pi / 2) for k in range(5)], 1e-12)
    jets.jet_div(sin_t, cos_t, out)  # tan t
    T = math.tan(t)
    T1 = 1 + T * T
    T2 = 2 * T * T1
    T3 = 2 * T1 * T1 + 2 * T * T2
    T4 = 6 * T1 * T2 + 2 * T * T3
    assert_close(derivs_of(out), [T, T1, T2, T3, T4], 1e-12)
    one_plus = jet_of([1 + t * t, 2 * t, 2, 0, 0])
    jets.jet_sqrt(one_plus, out)  # sqrt(1 + t^2)
    g = math.sqrt(1 + t * t)
    assert_close(derivs_of(out), [g, t / g, 1 / g**3, -3 * t / g**5, -3 / g**5 + 15 * t**2 / g**7], 1e-12)
    # in place: out may alias the first operand (and both operands of mul)
    a = sin_t.copy()
    jets.jet_mul(a, a, a)
    ref = np.empty(5)
    jets.jet_mul(sin_t, sin_t, ref)
    assert np.array_equal(a, ref)
    a = sin_t.copy()
    jets.jet_div(a, cos_t, a)
    jets.jet_div(sin_t, cos_t, ref)
    assert np.array_equal(a, ref)
    a = one_plus.copy()
    jets.jet_sqrt(a, a)
    jets.jet_sqrt(one_plus, ref)
    assert np.array_equal(a, ref)


def test_linear_operations_and_conversion():
    a, b = np.array([1.0, 2.0, 3.0]), np.array([0.5, -1.0, 4.0])
    out = np.empty(3)
    jets.jet_add(a, b, out)
    assert np.array_equal(out, a + b)
    jets.jet_sub(a, b, out)
    assert np.array_equal(out, a - b)
    jets.jet_scale(a, -2.0, out)
    assert np.array_equal(out, -2.0 * a)
    jets.jet_axpy(3.0, a, b, out)
    assert np.array_equal(out, 3.0 * a + b)
    jets.jet_shift(a, 0.25, out)
    assert np.array_equal(out, [1.25, 2.0, 3.0])
    jets.jet_constant(7.0, out)
    assert np.array_equal(out, [7.0, 0.0, 0.0])
    d = np.array([1.0, 2.0, 6.0, 24.0, 120.0])
    j = jet_of(d)
    assert np.array_equal(j, [1.0, 2.0, 3.0, 4.0, 5.0])
    assert np.array_equal(derivs_of(j), d)
    der = np.empty(4)
    jets.jet_derivative(j, der)   # coefficients of f'
    assert np.array_equal(der, [2.0, 6.0, 12.0, 20.0])


@pytest.mark.parametrize("t", [-1.5, 0.0, 0.7])
def test_atan2_of_known_functions(t):
    out = np.empty(5)
    # atan2(t, 1) = atan t
    jets.jet_atan2(jet_of([t, 1, 0, 0, 0]), jet_of([1, 0, 0, 0, 0]), out)
    w = 1 + t * t
    assert_close(derivs_of(out), [math.atan(t), 1 / w, -2 * t / w**2, (6 * t**2 - 2) / w**3,
                                  24 * t * (1 - t**2) / w**4], 1e-12)
    # atan2(rho sin phi, rho cos phi) = phi with rho = 2 + sin t, phi = 1.2 + t^2 + 0.5 t: the
    # angle crosses pi (x < 0, y -> 0) for t in the range, derivatives stay continuous
    var, phi, s, c, rho, rs, rc, y, x = np.empty((9, 5))
    jets.jet_variable(t, var)
    jets.jet_mul(var, var, phi)
    jets.jet_axpy(0.5, var, phi, phi)
    jets.jet_shift(phi, 1.2, phi)
    jets.jet_sin_cos(var, rs, rc)
    jets.jet_shift(rs, 2.0, rho)
    jets.jet_sin_cos(phi, s, c)
    jets.jet_mul(rho, s, y)
    jets.jet_mul(rho, c, x)
    jets.jet_atan2(y, x, out)
    ph = 1.2 + t * t + 0.5 * t
    assert out[0] == pytest.approx(math.atan2(math.sin(ph), math.cos(ph)), abs=1e-14)
    assert_close(derivs_of(out)[1:], [2 * t + 0.5, 2.0, 0.0, 0.0], 1e-12)


@pytest.mark.parametrize("t", [-0.8, 0.1, 0.9])
def test_acos_of_known_functions(t):
    a = 0.9
    theta, sin_theta = np.empty((2, 5))
    jets.jet_acos(jet_of([a * t, a, 0, 0, 0]), theta, sin_theta)
    w = 1 - a * a * t * t
    assert_close(derivs_of(theta), [math.acos(a * t), -a * w**-0.5, -a**3 * t * w**-1.5,
                                    -a**3 * w**-1.5 - 3 * a**5 * t**2 * w**-2.5,
                                    -9 * a**5 * t * w**-2.5 - 15 * a**7 * t**3 * w**-3.5], 1e-12)
    # sin(acos(u)) = sqrt(1 - u^2)
    sq = np.empty(5)
    jets.jet_sqrt(jet_of([w, -2 * a * a * t, -2 * a * a, 0, 0]), sq)
    assert_close(sin_theta, sq, 1e-12)
    # acos(cos phi) = phi for phi in (0, pi)
    var, phi, s, c = np.empty((4, 5))
    jets.jet_variable(t, var)
    jets.jet_mul(var, var, phi)
    jets.jet_shift(phi, 1.0, phi)
    jets.jet_sin_cos(phi, s, c)
    jets.jet_acos(c, theta, sin_theta)
    assert_close(theta, phi, 1e-12)
    assert_close(sin_theta, s, 1e-12)
    jets.jet_acos(jet_of([1.5, 1, 0, 0, 0]), theta, sin_theta)
    assert np.isnan(theta).all()


# -- regressor (6.120) against Pinocchio -------------------------------------------------------
@pytest.mark.parametrize("params", [LinkParameters(), ODD], ids=["thesis", "odd"])
def test_regressor_matches_pinocchio(params):
    arm = TwoLinkArm(params)
    p = params.base_parameters()
    if params is not ODD:
        assert np.abs(p - fm.TRUE_P).max() < 1e-12
    rng = np.random.default_rng(6)
    Psi, Psi10, PsiM, PsiN, Mp = np.empty((2, 5)), np.empty((2, 10)), np.empty((2, 5)), np.empty((2, 5)), \
        np.empty((2, 2))
    p10 = np.empty(10)
    fm.expand_parameters(p, p10)
    ks = np.array([10.0, 50.0])
    for _ in range(50):
        q, qd, x, xd = rng.uniform(-3, 3, size=(4, 2))
        M, C, G = arm.mass_matrix(q), arm.coriolis_matrix(q, qd), arm.gravity(q)
        fm.regressor_into(xd, x, qd, q, Psi)
        assert np.abs(Psi @ p - (M @ xd + C @ x + G)).max() < 1e-10
        fm.expanded_regressor_into(xd, x, qd, q, Psi10)
        assert np.abs(Psi10 @ p10 - Psi @ p).max() < 1e-14
        assert not Psi10[0, 5:].any() and not Psi10[1, :5].any()
        # Property 6.5: K_s Psi p = Psi Lambda p, Lambda = diag(k_s1 I5, k_s2 I5)
        assert np.abs(Psi10 @ (np.repeat(ks, 5) * p10) - ks * (Psi @ p)).max() < 1e-12
        fm.mass_regressor_into(q, xd, PsiM)
        assert np.abs(PsiM @ p - M @ xd).max() < 1e-12
        fm.rest_regressor_into(q, qd, PsiN)
        assert np.abs(PsiN @ p - (G - C.T @ qd)).max() < 1e-12
        fm.mass_matrix_from_p(q, p, Mp)
        assert np.abs(Mp - M).max() < 1e-12


def _trajectory(t):
    """A smooth joint trajectory (not at rest at t = 0) with exact q', q''."""
    q = np.array([0.2 + 0.5 * math.sin(1.3 * t), -1.1 + 0.7 * math.cos(0.9 * t)])
    qd = np.array([0.65 * math.cos(1.3 * t), -0.63 * math.sin(0.9 * t)])
    qdd = np.array([-0.845 * math.sin(1.3 * t), -0.567 * math.cos(0.9 * t)])
    return q, qd, qdd


def test_mass_and_rest_regressors_split_psi():
    """Psi(q'', q', q', q) p = d/dt(Psi_M(q, q') p) + Psi_N(q, q') p along a trajectory."""
    p = fm.TRUE_P
    PsiM, PsiN, Psi = np.empty((3, 2, 5))

    def momentum(t):
        q, qd, _ = _trajectory(t)
        fm.mass_regressor_into(q, qd, PsiM)
        return PsiM @ p

    for t in np.linspace(0.0, 5.0, 11):
        q, qd, qdd = _trajectory(t)
        dmom, _ = central(momentum, t, 1e-2)
        fm.rest_regressor_into(q, qd, PsiN)
        fm.regressor_into(qdd, qd, qd, q, Psi)
        assert np.abs(dmom + PsiN @ p - Psi @ p).max() < 1e-9


def test_filtered_regressor_equals_filtered_psi():
    """W = alpha Psi_M + Fw (Fw' = alpha(u - Fw), Fw(0) = -alpha Psi_M(0)) equals the filter
    alpha/(s + alpha) applied to Psi(q'', q', q', q) directly (6.99), from a moving start."""
    alpha, h = 5.0, 1e-3
    u, Psi, W = np.empty((3, 2, 5))

    def direct(t, state):
        q, qd, qdd = _trajectory(t)
        fm.regressor_into(qdd, qd, qd, q, Psi)
        return alpha * (Psi - state)

    def split(t, state):
        q, qd, _ = _trajectory(t)
        fm.filtered_regressor_input_into(q, qd, alpha, u)
        return alpha * (u - state)

    def rk4(f, t, x):
        k1 = f(t, x)
        k2 = f(t + h / 2, x + h / 2 * k1)
        k3 = f(t + h / 2, x + h / 2 * k2)
        k4 = f(t + h, x + h * k3)
        return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    q0, qd0, _ = _trajectory(0.0)
    Wd = np.zeros((2, 5))
    Fw = np.empty((2, 5))
    fm.filtered_regressor_initial_into(q0, qd0, alpha, Fw)
    fm.filtered_regressor_into(q0, qd0, alpha, Fw, W)
    assert np.abs(W).max() < 1e-15     # the convolution over [0, 0]
    for k in range(3000):
        t = k * h
        Wd, Fw = rk4(direct, t, Wd), rk4(split, t, Fw)
    q, qd, _ = _trajectory(3000 * h)
    fm.filtered_regressor_into(q, qd, alpha, Fw, W)
    assert np.abs(W - Wd).max() < 1e-10
    assert np.abs(Wd).max() > 0.1


# -- the rigid surface -------------------------------------------------------------------------
def _motion(t, n=5, elbow=fm.ELBOW_SIGN, omega=fm.MOTION_OMEGA, phase=fm.MOTION_PHASE):
    out = np.empty((n, 2))
    fm.desired_motion_jets(t, fm.MOTION_CENTRE, fm.MOTION_AMPLITUDE, omega, phase, fm.LINK_LENGTH,
                           elbow, out)
    return out


def _constraint(q, qd, offset=fm.SURFACE_OFFSET, normal=fm.SURFACE_NORMAL):
    out = np.empty(fm.CONSTRAINT_SIZE)
    fm.constraint_into(q, qd, fm.LINK_LENGTH, normal, offset, out)
    return out


def test_constraint_on_the_desired_path():
    arm = TwoLinkArm()
    n = fm.SURFACE_NORMAL / math.sqrt(2)
    for t in np.linspace(0.0, math.pi, 40):
        qj = _motion(t)
        c = _constraint(qj[0], qj[1])
        assert abs(c[fm.PHI]) < 1e-12
        assert abs(c[fm.PHI_DOT]) < 1e-12            # moving along the surface
        J_phi, L = c[fm.J_PHI:fm.J_PHI + 2], c[fm.L_VEC:fm.L_VEC + 2]
        assert np.abs(J_phi - n @ arm.jacobian(qj[0])).max() < 1e-12
        assert abs(J_phi @ L) < 1e-12                # Property 6.1, L^T J^T = 0
        assert np.abs(L * qj[1][0] - qj[1]).max() < 1e-12   # q_ld' = L q_ld^1' (6.8)
    # Phi = n . p_tool + c/|n_raw| with the URDF arm; the raw/normalised inputs agree
    q = np.array([0.4, 1.9])
    c = _constraint(q, np.zeros(2))
    assert c[fm.PHI] == pytest.approx(n @ arm.tool_position(q) + 0.35 / math.sqrt(2), abs=1e-14)
    assert_close(_constraint(q, np.ones(2), 0.35 / math.sqrt(2), n), _constraint(q, np.ones(2)), 1e-14)


def _near_surface(t):
    """A trajectory around q_l(0), away from the singularity J_Phi2 = 0 of L (s12 + c12 = 0)."""
    q = np.array([2.85 + 0.3 * math.sin(1.3 * t), -2.12 + 0.3 * math.cos(0.9 * t)])
    qd = np.array([0.39 * math.cos(1.3 * t), -0.27 * math.sin(0.9 * t)])
    return q, qd


def test_constraint_derivatives_and_corrected_L():
    """L', J_Phi', Phi' against central differences; L2 = -1 - l1(s1+c1)/(l2(s12+c12))."""
    for t in np.linspace(0.0, 4.0, 9):
        c = _constraint(*_near_surface(t))
        d1, _ = central(lambda s: _constraint(*_near_surface(s)), t, 1e-2)
        assert np.abs(c[fm.L_DOT:fm.L_DOT + 2] - d1[fm.L_VEC:fm.L_VEC + 2]).max() < 1e-12
        assert np.abs(c[fm.J_PHI_DOT:fm.J_PHI_DOT + 2] - d1[fm.J_PHI:fm.J_PHI + 2]).max() < 1e-12
        assert abs(c[fm.PHI_DOT] - d1[fm.PHI]) < 1e-12
    l1, l2 = fm.LINK_LENGTH
    for q in (fm.Q_L0, _motion(0.0)[0], np.array([0.3, 2.0])):
        s1, c1 = math.sin(q[0]), math.cos(q[0])
        s12, c12 = math.sin(q[0] + q[1]), math.cos(q[0] + q[1])
        L2 = _constraint(q, np.zeros(2))[fm.L_VEC + 1]
        corrected = -1 - l1 * (s1 + c1) / (l2 * (s12 + c12))
        assert abs(L2 - corrected) < 1e-12 * abs(corrected)
        printed = -1 - l1 * (s1 + c1) / (l2 * s12 * c12)   # (6.118) as printed
        assert abs(L2 - printed) > 0.1


def test_initial_state():
    """docs/thesis.md: q_l(0) = [2.85, -2.1202] is on x - y + 0.35 = 0; the printed [2.85, -1.77]
    lies on neither line."""
    assert abs(_constraint(fm.Q_L0, np.zeros(2))[fm.PHI]) < 1e-5
    for offset in (fm.SURFACE_OFFSET, fm.PRINTED_SURFACE_OFFSET):
        assert abs(_constraint(np.array([2.85, -1.77]), np.zeros(2), offset)[fm.PHI]) > 0.05


# -- desired motion in jets --------------------------------------------------------------------
def _r_d(t):
    """r_d, r_d', r_d'' of section 6.3."""
    c, s = math.cos(2 * t), math.sin(2 * t)
    return (np.array([-0.1 * c, 0.35 - 0.1 * c]), np.array([0.2 * s, 0.2 * s]),
            np.array([0.4 * c, 0.4 * c]))


def test_desired_motion_kinematics():
    arm = TwoLinkArm()
    for t in np.linspace(0.0, math.pi, 25):
        qj = _motion(t)
        r, rd, rdd = _r_d(t)
        assert np.abs(arm.tool_position(qj[0]) - r).max() < 1e-12
        assert math.sin(qj[0, 1]) < 0.0
        _, J, jdot_v = arm.kinematics(qj[0], qj[1])
        assert np.abs(qj[1] - np.linalg.solve(J, rd)).max() < 1e-12      # q' = J^-1 r_d'
        assert np.abs(qj[2] - np.linalg.solve(J, rdd - jdot_v)).max() < 1e-11
        assert np.abs(_motion(t, n=3) - qj[:3]).max() == 0.0             # any order
    # the other branch reaches the same points
    qj = _motion(0.3, elbow=1.0)
    assert math.sin(qj[0, 1]) > 0.0
    assert np.abs(arm.tool_position(qj[0]) - _r_d(0.3)[0]).max() < 1e-12
    # per-axis omega/phase arrays give the same as scalars
    assert np.array_equal(_motion(0.3, omega=np.array([2.0, 2.0]), phase=np.zeros(2)), _motion(0.3))
    # near the initial state of section 6.3 (docs/thesis.md)
    t0 = math.acos(0.636) / 2
    assert np.abs(_r_d(t0)[0] - [-0.0636, 0.2864]).max() < 1e-12
    assert np.abs(_motion(t0)[0] - [2.85, -2.12]).max() < 2e-3
    # out of reach: NaN
    out = np.empty((5, 2))
    fm.desired_motion_jets(0.0, np.array([1.0, 1.0]), fm.MOTION_AMPLITUDE, 2.0, 0.0, fm.LINK_LENGTH,
                           -1.0, out)
    assert np.isnan(out).all()


def test_desired_motion_higher_derivatives():
    """q''' and q'''' against 8th-order central differences of q'' (h = 0.01: truncation
    ~h^8 |q^(11)| / 630 and rounding ~1e-16 |q''| / h^2 (|q''| <= 2.5, |q''''| <= 25) stay
    below ~1e-10; measured 4e-12 for q''' and 6e-11 for q'''', so the bounds are 1e-10 and
    1e-9. The exact values then agree with the step-free J^-1 forms to 1e-15 above."""
    for t in np.linspace(0.0, math.pi, 13):
        qj = _motion(t)
        d1, d2 = central(lambda s: _motion(s, n=3)[2], t, 1e-2)
        assert np.abs(qj[3] - d1).max() < 1e-10
        assert np.abs(qj[4] - d2).max() < 1e-9


def _psi_d(t):
    qj = _motion(t, n=3)
    out = np.empty((2, 5))
    fm.regressor_into(qj[2], qj[1], qj[1], qj[0], out)
    return out


def _f_d(t):
    qj = _motion(t, n=1)
    return fm.LAMBDA_D * _constraint(qj[0], np.zeros(2))[fm.J_PHI:fm.J_PHI + 2]


def test_regressor_and_force_jets():
    R, F = np.empty((3, 2, 5)), np.empty((3, 2))
    for t in np.linspace(0.0, math.pi, 13):
        qj = _motion(t)
        fm.regressor_jets_into(qj, R)
        assert np.abs(R[0] - _psi_d(t)).max() < 1e-13
        d1, d2 = central(_psi_d, t, 1e-2)
        assert np.abs(R[1] - d1).max() < 1e-10   # measured 5e-12 (stencil error as above)
        assert np.abs(R[2] - d2).max() < 1e-9    # measured 6e-11
        fm.force_jets_into(qj, fm.LINK_LENGTH, fm.SURFACE_NORMAL, fm.SURFACE_OFFSET, fm.LAMBDA_D, F)
        assert np.abs(F[0] - _f_d(t)).max() < 1e-14
        d1, d2 = central(_f_d, t, 1e-2)
        assert np.abs(F[1] - d1).max() < 1e-12   # measured 4e-14
        assert np.abs(F[2] - d2).max() < 1e-10   # measured 9e-12
