"""Constrained rigid-body dynamics: a URDF model plus holonomic constraints Phi(q) = 0.

    M(q) q'' + h(q, q') = tau + J_Phi(q)^T lambda                         (2.16, 2.20)
    J_Phi q'' + J_Phi' q' = -2 alpha Phi' - beta^2 Phi                  (Baumgarte)

lambda (one multiplier per constraint) is the constraint force along the constraint
normal. Baumgarte's stabilisation turns the index-3 problem into an ODE whose constraint
error obeys Phi'' + 2 alpha Phi' + beta^2 Phi = 0, so integration error cannot drift
away; a consistent initial state (Phi = Phi' = 0) keeps |Phi| at round-off level.

Two implementations of the same equations:

* :class:`ConstrainedModel` - generic, any Pinocchio model (n joints, 3-D) and any list of
  :class:`PointOnPlane` constraints (a point of one body kept on a plane fixed to another
  body or to the world: the chapter 2 end effector on the moving object, the chapter 6
  end effector on a rigid surface). Uses Pinocchio's constrained forward dynamics
  (``pin.forwardDynamics`` with the constraint Jacobian and drift: a KKT solve), one
  Python-level call per algorithm: ~10 Pinocchio calls per evaluation. The reference.

* the compiled kernels below for the planar mechanisms of the thesis: a planar revolute
  chain (:mod:`cr_control.models.planar_chain`, read from the same Pinocchio model) plus
  prismatic "carriers" (decoupled masses on fixed axes, e.g. manipulator 2 of ch. 2),
  the plane fixed to the last carrier (or to the world with none). One call per RK4 step,
  a few microseconds; tests check them against :class:`ConstrainedModel` to round-off.
  The KKT solve (:func:`kkt_solve_into`) is generic in n joints and m constraints.

Pinocchio conventions used: ``pin.forwardDynamics(model, data, q, v, tau, J, gamma)``
solves M a + h = tau + J^T lambda, J a + gamma = 0 and leaves lambda in
``data.lambda_c``; here gamma = J' q' + 2 alpha Phi' + beta^2 Phi.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
from numba import njit

from cr_control.models.planar_chain import (
    GEOMETRY_ROWS,
    HEADER,
    PER_LINK,
    PlanarChain,
    geometry_into,
    mass_matrix_geo,
    rnea_geo,
    solve_spd_into,
    tool_geo,
)

_LWA = pin.LOCAL_WORLD_ALIGNED


def _skew(u: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])


@dataclass
class PointOnPlane:
    """Holonomic constraint: the origin of frame ``point_frame`` stays on the plane through
    frame ``plane_frame``'s origin (plus ``offset`` along the normal) with unit normal
    ``normal`` expressed in ``plane_frame``:

        Phi(q) = n_w . (p_point - p_plane) - offset,   n_w = R_plane n

    lambda > 0 pushes the point along +n_w (and the plane's body the other way).
    ``plane_frame`` may be a frame of the world (fixed plane)."""

    point_frame: str
    plane_frame: str
    normal: np.ndarray
    offset: float = 0.0
    _ids: tuple[int, int] = field(default=(-1, -1), repr=False)

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=float).reshape(3)
        norm = float(np.linalg.norm(n))
        if not math.isfinite(norm) or norm == 0.0:
            raise ValueError(f"normal must be a finite non-zero 3-vector, got {self.normal}")
        self.normal = n / norm

    def bind(self, model: pin.Model) -> None:
        """Look the frames up in ``model`` (ValueError naming a missing one)."""
        ids = []
        for name in (self.point_frame, self.plane_frame):
            if not model.existFrame(name):
                raise ValueError(f"frame {name!r} not in model {model.name!r}")
            ids.append(model.getFrameId(name))
        self._ids = (ids[0], ids[1])

    def evaluate(self, model: pin.Model, data: pin.Data) -> tuple[float, np.ndarray, float]:
        """(Phi, J_Phi (nv), J_Phi' q') from ``data`` after forwardKinematics(q, v, 0),
        updateFramePlacements and computeJointJacobians.

        J_Phi = n_w^T (J_c - J_o + [d]x J_w,o) with d = p_c - p_o (the point's velocity
        relative to the plane body's point coinciding with it); the drift is the second
        derivative of n_w . d at q'' = 0: n_w'' . d + 2 n_w' . d' + n_w . d''."""
        ic, io = self._ids
        oc, oo = data.oMf[ic], data.oMf[io]
        n_w = oo.rotation @ self.normal
        d = oc.translation - oo.translation
        Jc = pin.getFrameJacobian(model, data, ic, _LWA)
        Jo = pin.getFrameJacobian(model, data, io, _LWA)
        J = n_w @ (Jc[:3] - Jo[:3] + _skew(d) @ Jo[3:])
        vc = pin.getFrameVelocity(model, data, ic, _LWA)
        vo = pin.getFrameVelocity(model, data, io, _LWA)
        ac = pin.getFrameClassicalAcceleration(model, data, ic, _LWA).linear
        ao = pin.getFrameClassicalAcceleration(model, data, io, _LWA)
        w, alpha = vo.angular, ao.angular
        n_dot = np.cross(w, n_w)
        n_ddot = np.cross(alpha, n_w) + np.cross(w, n_dot)
        d_dot = vc.linear - vo.linear
        drift = float(n_ddot @ d + 2.0 * n_dot @ d_dot + n_w @ (ac - ao.linear))
        return float(n_w @ d) - self.offset, J, drift


class ConstrainedModel:
    """Generic constrained dynamics of a Pinocchio model with holonomic constraints (KKT
    solve by Pinocchio), Baumgarte-stabilised with ``alpha``, ``beta`` (1/s)."""

    def __init__(self, model: pin.Model, constraints: list[PointOnPlane], alpha: float = 20.0,
                 beta: float = 20.0):
        if not constraints:
            raise ValueError("at least one constraint")
        if not (alpha >= 0.0 and beta >= 0.0):
            raise ValueError("Baumgarte alpha and beta must be >= 0")
        self.model, self.data = model, model.createData()
        self.constraints = constraints
        for c in constraints:
            c.bind(model)
        self.alpha, self.beta = float(alpha), float(beta)
        self._zero = np.zeros(model.nv)

    @property
    def n_constraints(self) -> int:
        return len(self.constraints)

    def constraint(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Phi (m), J_Phi (m x nv), J_Phi' q' (m)) at (q, q')."""
        model, data = self.model, self.data
        pin.forwardKinematics(model, data, q, v, self._zero)
        pin.updateFramePlacements(model, data)
        pin.computeJointJacobians(model, data, q)
        rows = [c.evaluate(model, data) for c in self.constraints]
        return (np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                np.array([r[2] for r in rows]))

    def accelerations(self, q: np.ndarray, v: np.ndarray,
                      tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q'', lambda) of the Baumgarte-stabilised constrained dynamics at (q, q', tau)."""
        phi, J, drift = self.constraint(q, v)
        gamma = drift + 2.0 * self.alpha * (J @ v) + self.beta**2 * phi
        qdd = pin.forwardDynamics(self.model, self.data, q, v, tau, J, gamma)
        return qdd.copy(), self.data.lambda_c.copy()

    def rk4_step(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray,
                 dt: float) -> tuple[np.ndarray, np.ndarray]:
        """One classical RK4 step of [q, q'] with tau held (vector spaces: revolute and
        prismatic joints)."""
        def f(x):
            n = q.shape[0]
            qdd, _ = self.accelerations(x[:n], x[n:], tau)
            return np.concatenate([x[n:], qdd])

        x = np.concatenate([q, v])
        k1 = f(x)
        k2 = f(x + 0.5 * dt * k1)
        k3 = f(x + 0.5 * dt * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return x[:q.shape[0]].copy(), x[q.shape[0]:].copy()

    def static_command(self, q: np.ndarray, force: np.ndarray) -> np.ndarray:
        """tau holding the mechanism at rest at q while the constraints carry ``force``
        (lambda): tau = G(q) - J_Phi^T lambda."""
        _, J, _ = self.constraint(q, self._zero)
        return pin.computeGeneralizedGravity(self.model, self.data, q) - J.T @ force


# -- compiled planar mechanisms: a revolute chain plus prismatic carriers --------------------
#
# Packed mechanism vector ``mech`` (float64):
#   [n_arm, base_x, base_y, n_carriers,
#    per carrier: mass, axis_x, axis_y, origin_x, origin_y  (origin: the carrier frame at q = 0),
#    plane normal n_x, n_y (unit, world: carriers only translate), plane offset,
#    alpha, beta]
# followed by the PlanarChain vector of the arm. Joint order: arm joints, then carriers.
# The constraint is the arm's tool on the plane (a line in 2-D) through the last carrier's
# frame (through the world origin with no carrier):
#   Phi = n . (p_tool - p_carrier) - offset,  J_Phi = [n^T J_tool, -n . axis_k (last carrier)].
MECH_HEADER = 4
PER_CARRIER = 5
MECH_TAIL = 5


def pack_mechanism(chain: np.ndarray, base: np.ndarray, carriers: list[tuple], normal: np.ndarray,
                   offset: float, alpha: float, beta: float) -> np.ndarray:
    """The packed mechanism (layout above); ``carriers`` = [(mass, axis(2), origin(2)), ...]."""
    n = np.asarray(normal, dtype=float)
    n = n / math.hypot(n[0], n[1])
    values = [chain[0], base[0], base[1], float(len(carriers))]
    for mass, axis, origin in carriers:
        axis = np.asarray(axis, dtype=float)
        axis = axis / math.hypot(axis[0], axis[1])
        values += [mass, axis[0], axis[1], origin[0], origin[1]]
    values += [n[0], n[1], offset, alpha, beta]
    return np.concatenate([np.array(values, dtype=float), chain])


def planar_mechanism(model: pin.Model, tool_frame: str, plane_frame: str, normal: np.ndarray,
                     offset: float, alpha: float, beta: float) -> np.ndarray:
    """Pack a Pinocchio model made of a planar revolute chain (the first joints, ending in
    ``tool_frame``) and prismatic joints on the world (carriers, the last one holding
    ``plane_frame``) into ``mech``; ValueError if the model is not such a mechanism."""
    arm_ids = [j for j in range(1, model.njoints) if model.joints[j].shortname() == "JointModelRZ"]
    carrier_ids = [j for j in range(1, model.njoints) if j not in arm_ids]
    if arm_ids != list(range(1, len(arm_ids) + 1)):
        raise ValueError("the revolute chain must come first in the joint order")
    for j in carrier_ids:
        short = model.joints[j].shortname()
        if short not in ("JointModelPX", "JointModelPY") or model.parents[j] != 0:
            raise ValueError(f"joint {model.names[j]} is not a prismatic x/y joint on the world")
    plane = model.frames[model.getFrameId(plane_frame)]
    if carrier_ids and plane.parentJoint != carrier_ids[-1]:
        raise ValueError(f"{plane_frame} must be attached to the last prismatic joint")
    if not carrier_ids and plane.parentJoint != 0:
        raise ValueError(f"{plane_frame} must be a world frame when there is no carrier")
    arm = pin.buildReducedModel(model, carrier_ids, pin.neutral(model)) if carrier_ids else model
    chain = PlanarChain.from_model(arm, tool_frame).chain
    base = model.jointPlacements[1].translation[:2]
    carriers = []
    for j in carrier_ids:
        axis = [1.0, 0.0] if model.joints[j].shortname() == "JointModelPX" else [0.0, 1.0]
        sub = model.subtrees[j]
        mass = sum(model.inertias[k].mass for k in sub)
        origin = (model.jointPlacements[j] * plane.placement).translation[:2] \
            if j == carrier_ids[-1] else model.jointPlacements[j].translation[:2]
        carriers.append((mass, axis, origin))
    if not carrier_ids:
        origin = plane.placement.translation[:2]
        offset = offset + float(np.dot(normal[:2], origin) / math.hypot(normal[0], normal[1]))
    return pack_mechanism(chain, base, carriers, np.asarray(normal, dtype=float)[:2], offset,
                          alpha, beta)


def mechanism_dofs(mech: np.ndarray) -> int:
    """Joints of the packed mechanism (arm + carriers)."""
    return int(mech[0]) + int(mech[3])


def mechanism_chain(mech: np.ndarray) -> np.ndarray:
    """The arm's PlanarChain vector inside ``mech``."""
    return mech[MECH_HEADER + PER_CARRIER * int(mech[3]) + MECH_TAIL:]


@njit(cache=True)
def kkt_solve_into(M, b, Jc, gamma, work, a, lam):
    """Solve M a = b + Jc^T lam, Jc a = gamma (n joints, m constraints) by the Schur
    complement: a0 = M^-1 b, Y = M^-1 Jc^T, (Jc Y) lam = gamma - Jc a0, a = a0 + Y lam.
    M (n x n, SPD) is overwritten by its Cholesky factor; ``work`` holds >= n (m + 2) + m^2
    + m floats. Nothing is allocated."""
    n, m = b.shape[0], gamma.shape[0]
    a0 = work[:n]
    col = work[n:2 * n]
    Y = work[2 * n:2 * n + n * m].reshape((m, n))   # rows: M^-1 Jc_k^T
    S = work[2 * n + n * m:2 * n + n * m + m * m].reshape((m, m))
    r = work[2 * n + n * m + m * m:2 * n + n * m + m * m + m]
    # Cholesky M = L L^T in place (lower triangle)
    for i in range(n):
        for j in range(i + 1):
            s = M[i, j]
            for k in range(j):
                s -= M[i, k] * M[j, k]
            M[i, j] = math.sqrt(s) if i == j else s / M[j, j]
    for c in range(m + 1):
        # solve L L^T x = rhs, rhs = b (c = 0) or Jc_{c-1}^T
        for i in range(n):
            s = b[i] if c == 0 else Jc[c - 1, i]
            for k in range(i):
                s -= M[i, k] * col[k]
            col[i] = s / M[i, i]
        out = a0 if c == 0 else Y[c - 1]
        for i in range(n - 1, -1, -1):
            s = col[i]
            for k in range(i + 1, n):
                s -= M[k, i] * out[k]
            out[i] = s / M[i, i]
    for i in range(m):
        s = gamma[i]
        for k in range(n):
            s -= Jc[i, k] * a0[k]
        r[i] = s
        for j in range(m):
            t = 0.0
            for k in range(n):
                t += Jc[i, k] * Y[j, k]
            S[i, j] = t
    solve_spd_into(S, r, lam)   # S lam = r (S SPD, m small)
    for i in range(n):
        s = a0[i]
        for j in range(m):
            s += Y[j, i] * lam[j]
        a[i] = s


def mechanism_work_size(mech: np.ndarray) -> int:
    """Scratch floats of one constrained evaluation / RK4 step of ``mech``."""
    n_arm, n = int(mech[0]), mechanism_dofs(mech)
    return (GEOMETRY_ROWS * n_arm + 3 * n_arm + 2 * n_arm + 4 + n * n + 3 * n + 1
            + (n * 3 + 2) + 6 * 2 * n)


@njit(cache=True)
def mechanism_constraint(mech, q, v, geo, J, tool, Jc):
    """Phi, Phi' and the drift J_Phi' q' of the packed mechanism; fills ``geo``, the tool's
    ``J``/``tool`` (tool_geo) and the constraint row ``Jc`` (1 x n)."""
    n_arm, n_car = int(mech[0]), int(mech[3])
    t = MECH_HEADER + PER_CARRIER * n_car
    nx, ny, offset = mech[t], mech[t + 1], mech[t + 2]
    chain = mech[t + MECH_TAIL:]
    geometry_into(chain, q, geo)
    tool_geo(chain, geo, v, J, tool)
    px, py = mech[1] + tool[0], mech[2] + tool[1]
    for j in range(n_arm):
        Jc[0, j] = nx * J[0, j] + ny * J[1, j]
    ox = oy = 0.0
    for k in range(n_car):
        Jc[0, n_arm + k] = 0.0
    if n_car > 0:
        c = MECH_HEADER + PER_CARRIER * (n_car - 1)
        x = q[n_arm + n_car - 1]
        ox, oy = mech[c + 3] + mech[c + 1] * x, mech[c + 4] + mech[c + 2] * x
        Jc[0, n_arm + n_car - 1] = -(nx * mech[c + 1] + ny * mech[c + 2])
    phi = nx * (px - ox) + ny * (py - oy) - offset
    phi_dot = 0.0
    for j in range(n_arm + n_car):
        phi_dot += Jc[0, j] * v[j]
    return phi, phi_dot, nx * tool[2] + ny * tool[3]


@njit(cache=True)
def mechanism_dynamics_into(mech, q, v, tau, work, qdd, lam):
    """q'' and lambda of the Baumgarte-stabilised constrained dynamics of ``mech`` at
    (q, q', tau); returns (Phi, Phi'). ``work``: mechanism_work_size floats (its last
    12 n are left to the RK4 buffers)."""
    n_arm, n_car = int(mech[0]), int(mech[3])
    n = n_arm + n_car
    t = MECH_HEADER + PER_CARRIER * n_car
    alpha, beta = mech[t + 3], mech[t + 4]
    chain = mech[t + MECH_TAIL:]
    o = 0
    geo = work[o:o + GEOMETRY_ROWS * n_arm].reshape((GEOMETRY_ROWS, n_arm))
    o += GEOMETRY_ROWS * n_arm
    scratch = work[o:o + 3 * n_arm]
    o += 3 * n_arm
    J = work[o:o + 2 * n_arm].reshape((2, n_arm))
    o += 2 * n_arm
    tool = work[o:o + 4]
    o += 4
    M = work[o:o + n * n].reshape((n, n))
    o += n * n
    h = work[o:o + n]
    o += n
    b = work[o:o + n]
    o += n
    Jc = work[o:o + n].reshape((1, n))
    o += n
    gamma = work[o:o + 1]
    o += 1
    kkt = work[o:o + n * 3 + 2]
    phi, phi_dot, drift = mechanism_constraint(mech, q, v, geo, J, tool, Jc)
    zero = b  # b is rewritten below; use it as the zero acceleration for the RNEA
    zero[:] = 0.0
    rnea_geo(chain, geo, v, zero, True, scratch, h)
    M[:, :] = 0.0
    mass_matrix_geo(chain, geo, M[:n_arm, :n_arm])
    gx, gy = chain[1], chain[2]
    for k in range(n_car):
        c = MECH_HEADER + PER_CARRIER * k
        mass = mech[c]
        M[n_arm + k, n_arm + k] = mass
        h[n_arm + k] = -mass * (gx * mech[c + 1] + gy * mech[c + 2])
    for i in range(n):
        b[i] = tau[i] - h[i]
    gamma[0] = -drift - 2.0 * alpha * phi_dot - beta * beta * phi
    kkt_solve_into(M, b, Jc, gamma, kkt, qdd, lam)
    return phi, phi_dot


@njit(cache=True)
def mechanism_rk4(mech, x, tau, dt, substeps, work, lam):
    """Advance x = [q, q'] in place by ``dt`` (``substeps`` classical RK4 steps, tau held);
    ``lam`` gets lambda at the new state with the same tau. Returns (Phi, Phi') there."""
    m = x.shape[0]
    n = m // 2
    rk = work.shape[0] - 6 * m
    k1, k2, k3 = work[rk:rk + m], work[rk + m:rk + 2 * m], work[rk + 2 * m:rk + 3 * m]
    k4, xs = work[rk + 3 * m:rk + 4 * m], work[rk + 4 * m:rk + 5 * m]
    h = dt / substeps
    for _ in range(substeps):
        for stage in range(4):
            if stage == 0:
                for j in range(m):
                    xs[j] = x[j]
                out = k1
            elif stage == 3:
                for j in range(m):
                    xs[j] = x[j] + h * k3[j]
                out = k4
            else:
                prev = k1 if stage == 1 else k2
                for j in range(m):
                    xs[j] = x[j] + 0.5 * h * prev[j]
                out = k2 if stage == 1 else k3
            for j in range(n):
                out[j] = xs[n + j]
            mechanism_dynamics_into(mech, xs[:n], xs[n:], tau, work, out[n:], lam)
        for j in range(m):
            x[j] = x[j] + (h / 6.0) * (k1[j] + k4[j] + 2.0 * (k2[j] + k3[j]))
    acc = work[rk + 5 * m:rk + 5 * m + n]
    return mechanism_dynamics_into(mech, x[:n], x[n:], tau, work, acc, lam)


def chain_link_parameters(mech: np.ndarray) -> np.ndarray:
    """(n_arm x PER_LINK) view of the arm's link rows (for tests and tools)."""
    chain = mechanism_chain(mech)
    n = int(chain[0])
    return chain[HEADER:HEADER + PER_LINK * n].reshape((n, PER_LINK))
