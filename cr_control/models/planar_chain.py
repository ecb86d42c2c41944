"""Compiled rigid-body dynamics of a planar serial chain of revolute joints (the thesis arms).

The hot path of the 1 kHz loop cannot afford a Python-level call per Pinocchio
algorithm (~40 interpreter loop iterations each, four RK4 stages, several algorithms per
stage). The arms of chapters 2, 3, 5 and 6 are planar chains, so their dynamics is
compiled here once (numba, cached on disk) from the parameters of the **Pinocchio model
built from the URDF**: :meth:`PlanarChain.from_model` reads the joint placements, link
inertias, tool frame and gravity out of that model, and the tests check every quantity
against Pinocchio (ABA, RNEA, CRBA, frame Jacobian and its time variation) to 1e-12 and
against the thesis's closed forms (2.103), (6.117). Any number of links.

Notation: joint i turns about +z at p_i; absolute link angle phi_i = q_1 + ... + q_i;
link i carries joint i+1 at p_{i+1} = p_i + R(phi_i) a_i and its centre of mass at
p_i + R(phi_i) rho_i (mass m_i, inertia I_i about the centre of mass); the tool sits at
p_n + R(phi_n) t. Gravity g is a vector in the plane ((0, -9.8) in the thesis).

The packed parameter vector ``chain`` (float64) is laid out as
    [n, g_x, g_y, t_x, t_y, then per link: a_x, a_y, rho_x, rho_y, m, I]
so one array carries the whole model into a kernel.

Kernels (all take ``chain`` first; the ``*_geo``/``*_into`` forms share one geometry pass
and write into caller-provided arrays, for the plants' allocation-free RK4 stages):
    rnea(chain, q, v, a, gravity_on) -> tau   recursive Newton-Euler, tau = M a + C v + G
    mass_matrix(chain, q) -> M                 sum of m_k J_ck^T J_ck + I_k a_k a_k^T
    forward_dynamics(chain, q, v, tau) -> q''  M q'' = tau - (C v + G), Cholesky
    tool_kinematics(chain, q, v) -> (r, J, J' v)
    coriolis_matrix(chain, q, v) -> C           Christoffel form
    tool_jacobian_dot(chain, q, v) -> J'
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from numba import njit

from cr_control.core.linalg import matvec  # noqa: F401 - re-exported for the plants

HEADER = 5   # n, g_x, g_y, t_x, t_y
PER_LINK = 6  # a_x, a_y, rho_x, rho_y, m, I


#: Rows of the geometry block (8 x n) computed once per configuration and shared by the
#: algorithms below: joint origin p_i, rotated link vector e_i = R(phi_i) a_i, rotated
#: centre-of-mass offset R(phi_i) rho_i, cos and sin of phi_i.
GEOMETRY_ROWS = 8


@njit(cache=True, error_model="numpy")
def geometry_into(chain, q, geo):
    """Fill ``geo`` (GEOMETRY_ROWS x n) for configuration q."""
    n = int(chain[0])
    x = y = phi = 0.0
    for i in range(n):
        k = HEADER + PER_LINK * i
        phi += q[i]
        c, s = math.cos(phi), math.sin(phi)
        geo[0, i], geo[1, i] = x, y
        geo[2, i], geo[3, i] = c * chain[k] - s * chain[k + 1], s * chain[k] + c * chain[k + 1]
        geo[4, i], geo[5, i] = c * chain[k + 2] - s * chain[k + 3], s * chain[k + 2] + c * chain[k + 3]
        geo[6, i], geo[7, i] = c, s
        x, y = x + geo[2, i], y + geo[3, i]


@njit(cache=True, error_model="numpy")
def rnea_geo(chain, geo, v, a, gravity_on, scratch, tau):
    """tau = M(q) a + C(q, v) v + G(q) (G only if ``gravity_on``): 2-D recursive Newton-Euler.

    Forward pass: angular rate w_i, acceleration al_i and the linear acceleration of the joint
    origins (a base acceleration of -g carries gravity); backward pass: the force f and moment
    n that link i+1 exerts on link i. ``scratch`` holds >= 3 n floats; nothing is allocated.
    """
    n = int(chain[0])
    al, acx, acy = scratch[:n], scratch[n:2 * n], scratch[2 * n:3 * n]
    ax = -chain[1] if gravity_on else 0.0
    ay = -chain[2] if gravity_on else 0.0
    wi = ali = 0.0
    for i in range(n):
        wi += v[i]
        ali += a[i]
        al[i] = ali
        w2 = wi * wi
        acx[i] = ax - ali * geo[5, i] - w2 * geo[4, i]
        acy[i] = ay + ali * geo[4, i] - w2 * geo[5, i]
        ax, ay = ax - ali * geo[3, i] - w2 * geo[2, i], ay + ali * geo[2, i] - w2 * geo[3, i]
    fx = fy = nz = 0.0
    for i in range(n - 1, -1, -1):
        k = HEADER + PER_LINK * i
        mfx, mfy = chain[k + 4] * acx[i], chain[k + 4] * acy[i]
        # moment about joint i: I al + rho x m a_c + a_i x f_{i+1} + n_{i+1}
        nz = (chain[k + 5] * al[i] + geo[4, i] * mfy - geo[5, i] * mfx + geo[2, i] * fy
              - geo[3, i] * fx + nz)
        fx, fy = mfx + fx, mfy + fy
        tau[i] = nz


@njit(cache=True, error_model="numpy")
def mass_matrix_geo(chain, geo, M):
    """M(q) = sum_k m_k J_ck^T J_ck + I_k a_k a_k^T, with the centre-of-mass Jacobian columns
    dc_k/dq_i = perp(c_k - p_i) for i <= k (planar revolute chain)."""
    n = int(chain[0])
    for i in range(n):
        for j in range(i + 1):
            total = 0.0
            for k in range(i, n):
                base = HEADER + PER_LINK * k
                cx, cy = geo[0, k] + geo[4, k], geo[1, k] + geo[5, k]
                total += (chain[base + 4] * ((cx - geo[0, i]) * (cx - geo[0, j])
                                             + (cy - geo[1, i]) * (cy - geo[1, j]))
                          + chain[base + 5])
            M[i, j] = total
            M[j, i] = total


@njit(cache=True, error_model="numpy")
def tool_geo(chain, geo, v, J, out):
    """Tool position r (out[0:2]), Jacobian J (2 x n, r' = J q', column j = perp(r - p_j)) and
    J'(q, q') q' (out[2:4], the tool's acceleration at q'' = 0: a_{i+1} = a_i - w_i^2 e_i)."""
    n = int(chain[0])
    c, s = geo[6, n - 1], geo[7, n - 1]
    tx, ty = c * chain[3] - s * chain[4], s * chain[3] + c * chain[4]
    x, y = geo[0, n - 1] + tx, geo[1, n - 1] + ty
    wi = ax = ay = 0.0
    for i in range(n):
        wi += v[i]
        ex, ey = (tx, ty) if i == n - 1 else (geo[2, i], geo[3, i])
        ax, ay = ax - wi * wi * ex, ay - wi * wi * ey
        J[0, i], J[1, i] = -(y - geo[1, i]), x - geo[0, i]
    out[0], out[1], out[2], out[3] = x, y, ax, ay


@njit(cache=True, error_model="numpy")
def solve_spd_into(M, b, x):
    """x with M x = b for a symmetric positive-definite M: Cholesky in place (M is overwritten
    by its factor L in the lower triangle), no pivoting, no allocation."""
    n = b.shape[0]
    for i in range(n):
        for j in range(i + 1):
            s = M[i, j]
            for k in range(j):
                s -= M[i, k] * M[j, k]
            M[i, j] = math.sqrt(s) if i == j else s / M[j, j]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= M[i, k] * x[k]
        x[i] = s / M[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= M[k, i] * x[k]
        x[i] = s / M[i, i]


@njit(cache=True, error_model="numpy")
def forward_dynamics_geo(chain, geo, v, tau, work, qdd):
    """q'' from M q'' + C q' + G = tau into ``qdd`` for the configuration whose geometry is
    ``geo``: one RNEA for C q' + G, the mass matrix from the centre-of-mass Jacobians,
    Cholesky. ``work`` holds >= 6 n + n^2 floats; nothing is allocated."""
    n = int(chain[0])
    zero, h, rhs = work[:n], work[n:2 * n], work[2 * n:3 * n]
    zero[:] = 0.0
    rnea_geo(chain, geo, v, zero, True, work[3 * n:6 * n], h)
    for i in range(n):
        rhs[i] = tau[i] - h[i]
    M = work[6 * n:6 * n + n * n].reshape((n, n))
    mass_matrix_geo(chain, geo, M)
    solve_spd_into(M, rhs, qdd)


# -- allocating entry points (tests, controllers, Python) -------------------------------------
@njit(cache=True, error_model="numpy")
def rnea(chain, q, v, a, gravity_on):
    """tau = M(q) a + C(q, v) v + G(q) (G only if ``gravity_on``)."""
    n = int(chain[0])
    work = np.empty(GEOMETRY_ROWS * n + 3 * n)
    geo = work[:GEOMETRY_ROWS * n].reshape((GEOMETRY_ROWS, n))
    geometry_into(chain, q, geo)
    tau = np.empty(n)
    rnea_geo(chain, geo, v, a, gravity_on, work[GEOMETRY_ROWS * n:], tau)
    return tau


@njit(cache=True, error_model="numpy")
def mass_matrix(chain, q):
    """M(q), symmetric positive definite."""
    n = int(chain[0])
    geo = np.empty((GEOMETRY_ROWS, n))
    geometry_into(chain, q, geo)
    M = np.empty((n, n))
    mass_matrix_geo(chain, geo, M)
    return M


@njit(cache=True, error_model="numpy")
def solve_spd(M, b):
    """x with M x = b for a symmetric positive-definite M (M is left unchanged)."""
    x = np.empty(b.shape[0])
    solve_spd_into(M.copy(), b, x)
    return x


@njit(cache=True, error_model="numpy")
def forward_dynamics(chain, q, v, tau):
    """q'' from M q'' + C q' + G = tau."""
    n = int(chain[0])
    geo = np.empty((GEOMETRY_ROWS, n))
    geometry_into(chain, q, geo)
    qdd = np.empty(n)
    forward_dynamics_geo(chain, geo, v, tau, np.empty(6 * n + n * n), qdd)
    return qdd


@njit(cache=True, error_model="numpy")
def tool_kinematics(chain, q, v):
    """Tool position r, Jacobian J (2 x n, r' = J q') and J'(q, q') q'."""
    n = int(chain[0])
    geo = np.empty((GEOMETRY_ROWS, n))
    geometry_into(chain, q, geo)
    J = np.empty((2, n))
    out = np.empty(4)
    tool_geo(chain, geo, v, J, out)
    return out[:2], J, out[2:]


@njit(cache=True, error_model="numpy")
def tool_jacobian_dot(chain, q, v):
    """J'(q, q'): column j = -sum_{i >= j} w_i e_i (e_i the link vectors, the tool's for the
    last link, w_i the absolute angular rates): the time derivative of perp(r - p_j)."""
    n = int(chain[0])
    ex, ey, w = np.empty(n), np.empty(n), np.empty(n)
    phi = wi = 0.0
    for i in range(n):
        k = HEADER + PER_LINK * i
        phi += q[i]
        wi += v[i]
        c, s = math.cos(phi), math.sin(phi)
        lx, ly = (chain[3], chain[4]) if i == n - 1 else (chain[k], chain[k + 1])
        ex[i], ey[i], w[i] = c * lx - s * ly, s * lx + c * ly, wi
    J_dot = np.empty((2, n))
    sx = sy = 0.0
    for j in range(n - 1, -1, -1):
        sx += w[j] * ex[j]
        sy += w[j] * ey[j]
        J_dot[0, j], J_dot[1, j] = -sx, -sy
    return J_dot


@njit(cache=True, error_model="numpy")
def coriolis_matrix(chain, q, v):
    """C(q, q') in Christoffel form (M' - 2C skew-symmetric, as Pinocchio's and 2.103):
    C_ij = sum_k c_ijk q'_k, c_ijk = (d_k M_ij + d_j M_ik - d_i M_jk)/2, with
    d_k M_ij = sum_{l >= max(i,j,k)} m_l [(c_l - p_max(i,k)) x (c_l - p_j)
                                         + (c_l - p_max(j,k)) x (c_l - p_i)]."""
    n = int(chain[0])
    px, py, cx, cy = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    x = y = phi = 0.0
    for i in range(n):
        k = HEADER + PER_LINK * i
        px[i], py[i] = x, y
        phi += q[i]
        c, s = math.cos(phi), math.sin(phi)
        cx[i] = x + c * chain[k + 2] - s * chain[k + 3]
        cy[i] = y + s * chain[k + 2] + c * chain[k + 3]
        x, y = x + c * chain[k] - s * chain[k + 1], y + s * chain[k] + c * chain[k + 1]
    dM = np.zeros((n, n, n))  # dM[k, i, j] = d M_ij / d q_k
    for k in range(n):
        for i in range(n):
            for j in range(n):
                total = 0.0
                for link in range(max(i, j, k), n):
                    m = chain[HEADER + PER_LINK * link + 4]
                    a, b = max(i, k), max(j, k)
                    total += m * ((cx[link] - px[a]) * (cy[link] - py[j])
                                  - (cy[link] - py[a]) * (cx[link] - px[j])
                                  + (cx[link] - px[b]) * (cy[link] - py[i])
                                  - (cy[link] - py[b]) * (cx[link] - px[i]))
                dM[k, i, j] = total
    C = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += 0.5 * (dM[k, i, j] + dM[j, i, k] - dM[i, j, k]) * v[k]
            C[i, j] = s
    return C


def kinematics_only(chain: np.ndarray) -> np.ndarray:
    """A copy of ``chain`` with zero gravity, masses and inertias: geometry only, for laws
    that must not use a dynamics model."""
    out = chain.copy()
    out[1:3] = 0.0
    for i in range(int(chain[0])):
        k = HEADER + PER_LINK * i
        out[k + 4] = out[k + 5] = 0.0
    return out


@dataclass(frozen=True)
class PlanarChain:
    """A planar revolute chain read from a Pinocchio model; ``chain`` is its packed form."""

    chain: np.ndarray
    joint_names: tuple[str, ...]

    @classmethod
    def from_model(cls, model: pin.Model, tool_frame: str) -> PlanarChain:
        """Pack ``model`` (revolute joints about z, placements in the x-y plane, gravity in
        the plane, ``tool_frame`` fixed to the last link); ValueError if it is not such a chain."""
        n = model.njoints - 1
        g = model.gravity.linear
        tool = model.frames[model.getFrameId(tool_frame)]
        if tool.parentJoint != n:
            raise ValueError(f"{tool_frame} is not attached to the last joint")
        t = tool.placement.translation
        values = [float(n), g[0], g[1], t[0], t[1]]
        for j in range(1, n + 1):
            joint = model.joints[j]
            if joint.shortname() != "JointModelRZ" or model.parents[j] != j - 1:
                raise ValueError(f"joint {model.names[j]} is not a revolute z joint of a serial chain")
            placement = model.jointPlacements[j]
            if not np.allclose(placement.rotation, np.eye(3)) or abs(placement.translation[2]) > 0:
                raise ValueError(f"joint {model.names[j]} is not placed in the x-y plane")
            a = model.jointPlacements[j + 1].translation if j < n else np.zeros(3)
            inertia = model.inertias[j]
            values += [a[0], a[1], inertia.lever[0], inertia.lever[1], inertia.mass,
                       inertia.inertia[2, 2]]
        if abs(g[2]) > 0:
            raise ValueError("gravity must lie in the x-y plane")
        return cls(np.array(values, dtype=float), tuple(model.names[1:]))
