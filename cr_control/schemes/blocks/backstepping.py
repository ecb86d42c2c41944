"""Adaptive output-feedback backstepping with K-filters and tuning functions, for a linear
plant of any order n and relative degree rho (Krstic, Kanellakopoulos and Kokotovic 1995,
ch. 10 "[48]"; thesis 4.13-4.56 for n = 5, rho = 2 and C.11-C.56 for n = 2N, rho = 2N).

Plant in observer canonical form (4.10-4.12, C.6-C.10), output y = y_1, input u, m = n - rho:

    y' = A y - a y_1 + [0_{rho-1}; b] u,   theta = [b_m .. b_0, a_{n-1} .. a_0]  (p = m+1+n)

K-filters (thesis sign convention, 4.14-4.22): eta' = A0 eta - e_n y, xi = A0^n eta,
lam' = A0 lam + e_n u, v_j = A0^j lam (j = 0..m), A0 = A - lambda e_1^T, so that
y_hat = xi + Omega^T theta with Omega^T = [v_m .. v_0, A0^{n-1} eta .. eta] (4.13, 4.18) and
y - y_hat = eps, eps' = A0 eps (4.23-4.24).

Design (4.30-4.56, C.31-C.56; z_1 = y - y_r with a constant set point y_r):

    alpha_bar_1 = -c_1 z_1 - w_0 - w_bar^T theta_hat,  alpha_1 = rho_hat alpha_bar_1   (4.34)
    tau_1 = (w - rho_hat alpha_bar_1 e_1) z_1                                           (4.41)
    z_i = v_{m,i} - alpha_{i-1},  gamma_i = d alpha_{i-1}/dy,  tau_i = tau_{i-1} - gamma_i w z_i
    beta_i = lambda_i v_{m,1} + gamma_i (w_0 + w^T theta_hat) + d alpha_{i-1}/d eta eta'
             + d alpha_{i-1}/d lam (A0 lam) + d alpha_{i-1}/d rho_hat rho_hat'          (4.50)
    alpha_2 = -b_m_hat z_1 - (c_2 + d_2 gamma_2^2) z_2 + beta_2 + d alpha_1/d theta_hat Gamma tau_2
    alpha_i = -z_{i-1} - (c_i + d_i gamma_i^2) z_i + beta_i + d alpha_{i-1}/d theta_hat Gamma tau_i
              - sum_{k=2}^{i-1} z_k d alpha_{k-1}/d theta_hat Gamma gamma_i w          (i >= 3)
    u = alpha_rho - v_{m,rho+1}  (4.56, C.50),   theta_hat' = Gamma tau_rho,
    rho_hat' = -gamma alpha_bar_1 z_1  (4.40, C.40; b_m > 0)

with w_0 = xi_2, w = [v_{m,2} .. v_{0,2}, (A0^{n-1} eta)_2 - y, (A0^{n-2} eta)_2 .. eta_2] (4.27)
and w_bar = w with its first entry 0 (4.28). rho_hat is the estimate of 1/b_m (the thesis's
d_hat). Thesis ch. 4: c = [h_1, h_2], d = 0; appendix C: c_1 = zeta_1 + 1/2, c_i = zeta_i,
d_i = 1/4 (C.39, C.47, C.50).

One derivation for every (n, rho): the alpha_i are built in an expression graph with
hash-consing (shared subexpressions are stored once) and their partial derivatives come from
symbolic reverse-mode differentiation of that graph; nothing is expanded by hand for a given
n. (sympy's tree differentiation took 35 s for rho = 4 and did not finish rho = 6 in minutes:
the trees repeat the shared subexpressions exponentially; the graph stays small.) The result is
a tape of add/multiply instructions evaluated by one compiled kernel; tapes are cached on disk
(``$CR_CONTROL_CACHE`` or ``~/.cache/cr_control``), keyed by (n, rho) and this file's hash.

Note on the thesis's (4.47)/(4.50): alpha_bar_1 depends on v_{2,2}, v_{1,2}, v_{0,2} through
w_bar, whose derivatives the printed (4.47) leaves out; the design here keeps them (the
d alpha/d lam term of beta_i, as in [48] and in appendix C's beta_i).
:func:`thesis_rho2` writes (4.34), (4.49), (4.50), (4.56) as printed for the tests.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from cr_control.core.packing import Layout

# ----------------------------------------------------------------------------------------
# Expression graph with hash-consing and reverse-mode symbolic differentiation

OP_INPUT, OP_CONST, OP_ADD, OP_MUL = 0, 1, 2, 3


class Graph:
    """Nodes (op, a, b, value) created once each: equal subexpressions share one node."""

    def __init__(self):
        self.op: list[int] = []
        self.a: list[int] = []
        self.b: list[int] = []
        self.value: list[float] = []
        self._index: dict[tuple, int] = {}
        self.inputs: dict[str, int] = {}

    def _node(self, key: tuple, op: int, a: int, b: int, value: float) -> int:
        found = self._index.get(key)
        if found is not None:
            return found
        self.op.append(op)
        self.a.append(a)
        self.b.append(b)
        self.value.append(value)
        i = len(self.op) - 1
        self._index[key] = i
        return i

    def input(self, name: str, slot: int) -> Expr:
        """Leaf ``name`` read from the evaluation input vector at ``slot``."""
        i = self._node(("in", slot), OP_INPUT, slot, 0, 0.0)
        self.inputs[name] = i
        return Expr(self, i)

    def const(self, c: float) -> Expr:
        c = float(c)
        return Expr(self, self._node(("c", c), OP_CONST, 0, 0, c))

    def _is_const(self, i: int) -> bool:
        return self.op[i] == OP_CONST

    def add(self, i: int, j: int) -> int:
        if self._is_const(i) and self._is_const(j):
            return self.const(self.value[i] + self.value[j]).i
        if self._is_const(i) and self.value[i] == 0.0:
            return j
        if self._is_const(j) and self.value[j] == 0.0:
            return i
        i, j = min(i, j), max(i, j)
        return self._node(("+", i, j), OP_ADD, i, j, 0.0)

    def mul(self, i: int, j: int) -> int:
        if self._is_const(i) and self._is_const(j):
            return self.const(self.value[i] * self.value[j]).i
        for x, y in ((i, j), (j, i)):
            if self._is_const(x):
                if self.value[x] == 0.0:
                    return x
                if self.value[x] == 1.0:
                    return y
        i, j = min(i, j), max(i, j)
        return self._node(("*", i, j), OP_MUL, i, j, 0.0)

    def gradient(self, out: Expr, wrt: list[Expr]) -> list[Expr]:
        """d out / d x for every leaf x of ``wrt`` (reverse mode over the shared graph)."""
        reach = set()
        stack = [out.i]
        while stack:
            i = stack.pop()
            if i in reach:
                continue
            reach.add(i)
            if self.op[i] in (OP_ADD, OP_MUL):
                stack.extend((self.a[i], self.b[i]))
        adj: dict[int, int] = {out.i: self.const(1.0).i}
        for i in sorted(reach, reverse=True):
            g = adj.get(i)
            if g is None:
                continue
            op, a, b = self.op[i], self.a[i], self.b[i]
            if op == OP_ADD:
                for x in (a, b) if a != b else (a,):
                    gx = g if a != b else self.add(g, g)
                    adj[x] = self.add(adj[x], gx) if x in adj else gx
            elif op == OP_MUL:
                if a == b:
                    gx = self.mul(self.mul(g, a), self.const(2.0).i)
                    adj[a] = self.add(adj[a], gx) if a in adj else gx
                else:
                    for x, other in ((a, b), (b, a)):
                        gx = self.mul(g, other)
                        adj[x] = self.add(adj[x], gx) if x in adj else gx
        zero = self.const(0.0)
        return [Expr(self, adj[x.i]) if x.i in adj else zero for x in wrt]

    def tape(self, outputs: list[Expr]) -> Tape:
        """The instructions computing ``outputs``, in order, renumbered densely."""
        reach = set()
        stack = [o.i for o in outputs]
        while stack:
            i = stack.pop()
            if i in reach:
                continue
            reach.add(i)
            if self.op[i] in (OP_ADD, OP_MUL):
                stack.extend((self.a[i], self.b[i]))
        order = sorted(reach)
        new = {old: k for k, old in enumerate(order)}
        op = np.array([self.op[i] for i in order], dtype=np.int64)
        a = np.array([new[self.a[i]] if self.op[i] in (OP_ADD, OP_MUL) else self.a[i]
                      for i in order], dtype=np.int64)
        b = np.array([new[self.b[i]] if self.op[i] in (OP_ADD, OP_MUL) else 0
                      for i in order], dtype=np.int64)
        value = np.array([self.value[i] for i in order])
        return Tape(op, a, b, value, np.array([new[o.i] for o in outputs], dtype=np.int64))


class Expr:
    """A node of a :class:`Graph` with arithmetic operators."""

    __slots__ = ("g", "i")

    def __init__(self, g: Graph, i: int):
        self.g, self.i = g, i

    def _other(self, x) -> int:
        return x.i if isinstance(x, Expr) else self.g.const(x).i

    def __add__(self, x):
        return Expr(self.g, self.g.add(self.i, self._other(x)))

    __radd__ = __add__

    def __mul__(self, x):
        return Expr(self.g, self.g.mul(self.i, self._other(x)))

    __rmul__ = __mul__

    def __neg__(self):
        return self * -1.0

    def __sub__(self, x):
        return self + (-(x if isinstance(x, Expr) else self.g.const(x)))

    def __rsub__(self, x):
        return (-self) + x


def esum(terms, g: Graph) -> Expr:
    total = g.const(0.0)
    for t in terms:
        total = total + t
    return total


@dataclass
class Tape:
    """Straight-line add/multiply program: instruction k reads earlier values only."""

    op: np.ndarray
    a: np.ndarray
    b: np.ndarray
    value: np.ndarray
    outputs: np.ndarray

    def __len__(self) -> int:
        return len(self.op)


@njit(cache=True)
def run_tape(op, a, b, value, outputs, inp, vals, out):
    """Evaluate a tape on the input vector ``inp`` (``vals``: scratch of len(op))."""
    for k in range(op.shape[0]):
        o = op[k]
        if o == 2:
            vals[k] = vals[a[k]] + vals[b[k]]
        elif o == 3:
            vals[k] = vals[a[k]] * vals[b[k]]
        elif o == 0:
            vals[k] = inp[a[k]]
        else:
            vals[k] = value[k]
    for j in range(outputs.shape[0]):
        out[j] = vals[outputs[j]]


# ----------------------------------------------------------------------------------------
# The design


@dataclass(frozen=True)
class Sizes:
    """Dimensions of a design: order n, relative degree rho."""

    n: int
    rho: int

    @property
    def m(self) -> int:
        return self.n - self.rho

    @property
    def p(self) -> int:
        return self.m + 1 + self.n

    # Input vector of the tape: signals, then gains.
    @property
    def signals(self) -> int:
        """y, y_r, eta (n), lam (n), theta_hat (p), rho_hat."""
        return 2 + 2 * self.n + self.p + 1

    @property
    def gains(self) -> int:
        """c (rho), d (rho), lambda (n), Gamma diagonal (p), gamma."""
        return 2 * self.rho + self.n + self.p + 1

    @property
    def outputs(self) -> int:
        """u, tau_rho (p), alpha_bar_1, z (rho), gamma_2 (0 if rho = 1)."""
        return 1 + self.p + 1 + self.rho + 1


def a0_times(x: list, k: list) -> list:
    """A0 x with A0 = A - lambda e_1^T: (A0 x)_i = x_{i+1} - lambda_i x_1."""
    n = len(x)
    return [(x[i + 1] if i + 1 < n else 0.0) - k[i] * x[0] for i in range(n)]


def filter_signals(eta: list, lam: list, y, k: list, m: int):
    """(xi, v_0..v_m, [A0^{n-1} eta .. eta]) from the K-filter states (4.18-4.22); works
    on numbers and on graph expressions alike."""
    n = len(eta)
    powers = [list(eta)]
    for _ in range(n):
        powers.append(a0_times(powers[-1], k))
    xi = powers[n]
    etas = [powers[n - j] for j in range(1, n + 1)]       # eta_j = A0^{n-j} eta
    v = [list(lam)]
    for _ in range(m):
        v.append(a0_times(v[-1], k))
    return xi, v, etas


def regressor(eta, lam, y, k, m):
    """(w_0, w) of (4.25)-(4.27): y' = w_0 + w^T theta + eps_2."""
    xi, v, etas = filter_signals(eta, lam, y, k, m)
    w0 = xi[1]
    w = [v[m - j][1] for j in range(m + 1)] + [etas[0][1] - y] + [e[1] for e in etas[1:]]
    return w0, w, v


def derive(sizes: Sizes) -> tuple[Graph, list[Expr]]:
    """Build u, tau_rho, alpha_bar_1, z_1..z_rho, gamma_2 of the design as graph outputs."""
    n, rho, m, p = sizes.n, sizes.rho, sizes.m, sizes.p
    if not 2 <= rho <= n:
        raise ValueError(f"relative degree must be in 2..n, got rho = {rho}, n = {n}")
    g = Graph()
    slot = iter(range(sizes.signals + sizes.gains))
    y = g.input("y", next(slot))
    y_r = g.input("y_r", next(slot))
    eta = [g.input(f"eta{i}", next(slot)) for i in range(n)]
    lam = [g.input(f"lam{i}", next(slot)) for i in range(n)]
    th = [g.input(f"theta{i}", next(slot)) for i in range(p)]
    rh = g.input("rho_hat", next(slot))
    c = [g.input(f"c{i}", next(slot)) for i in range(rho)]
    d = [g.input(f"d{i}", next(slot)) for i in range(rho)]
    k = [g.input(f"lambda{i}", next(slot)) for i in range(n)]
    G = [g.input(f"Gamma{i}", next(slot)) for i in range(p)]
    gam = g.input("gamma", next(slot))

    w0, w, v = regressor(eta, lam, y, k, m)
    wbar = [g.const(0.0)] + w[1:]
    z1 = y - y_r
    ab1 = -(c[0] * z1) - w0 - esum((wb * t for wb, t in zip(wbar, th, strict=True)), g)
    alphas = [rh * ab1]
    tau = [(w[j] - (rh * ab1 if j == 0 else 0.0)) * z1 for j in range(p)]
    rho_dot = -(gam * ab1 * z1)
    zs = [z1]
    eta_dot = a0_times(eta, k)
    eta_dot[n - 1] = eta_dot[n - 1] - y
    lam_dot = a0_times(lam, k)                     # the e_n u part never reaches alpha_{i<rho}
    y_dot_known = w0 + esum((wi * t for wi, t in zip(w, th, strict=True)), g)
    leaves = [y, *eta, *lam, *th, rh]
    dalpha_dtheta: list[list[Expr]] = []
    gamma_2 = g.const(0.0)
    for i in range(2, rho + 1):
        a = alphas[-1]
        grad = g.gradient(a, leaves)
        d_y, d_eta = grad[0], grad[1:1 + n]
        d_lam, d_th, d_rh = grad[1 + n:1 + 2 * n], grad[1 + 2 * n:1 + 2 * n + p], grad[-1]
        zi = v[m][i - 1] - a
        gi = d_y
        if i == 2:
            gamma_2 = gi
        tau = [tau[j] - gi * w[j] * zi for j in range(p)]
        beta = (k[i - 1] * v[m][0] + gi * y_dot_known
                + esum((de * ed for de, ed in zip(d_eta, eta_dot, strict=True)), g)
                + esum((dl * ld for dl, ld in zip(d_lam, lam_dot, strict=True)), g) + d_rh * rho_dot)
        dalpha_dtheta.append(d_th)
        ai = (-(c[i - 1] + d[i - 1] * gi * gi) * zi + beta
              + esum((d_th[j] * G[j] * tau[j] for j in range(p)), g))
        if i == 2:
            ai = ai - th[0] * z1
        else:
            ai = ai - zs[-1]
            for j in range(p):
                s = esum((zs[kk - 1] * dalpha_dtheta[kk - 2][j] for kk in range(2, i)), g)
                ai = ai - s * G[j] * gi * w[j]
        zs.append(zi)
        alphas.append(ai)
    u = alphas[-1] - (v[m][rho] if rho < n else 0.0)
    return g, [u, *tau, ab1, *zs, gamma_2]


def _cache_dir() -> Path:
    root = os.environ.get("CR_CONTROL_CACHE")
    path = Path(root) if root else Path.home() / ".cache" / "cr_control"
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".writable"
        probe.touch()
        return path
    except OSError:
        path = Path(tempfile.gettempdir()) / "cr_control_cache"
        path.mkdir(parents=True, exist_ok=True)
        return path


_SOURCE_HASH = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]
_TAPES: dict[Sizes, Tape] = {}


def tape_for(sizes: Sizes) -> Tape:
    """The design's tape: from memory, else the disk cache, else derived (and cached)."""
    if sizes in _TAPES:
        return _TAPES[sizes]
    path = _cache_dir() / f"backstepping_n{sizes.n}_rho{sizes.rho}_{_SOURCE_HASH}.npz"
    tape = None
    if path.is_file():
        try:
            with np.load(path) as f:
                tape = Tape(f["op"], f["a"], f["b"], f["value"], f["outputs"])
        except (OSError, ValueError, KeyError):
            tape = None
    if tape is None:
        graph, outputs = derive(sizes)
        tape = graph.tape(outputs)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        try:
            np.savez(tmp, op=tape.op, a=tape.a, b=tape.b, value=tape.value, outputs=tape.outputs)
            os.replace(tmp, path)
        except OSError:
            pass
    _TAPES[sizes] = tape
    return tape


# ----------------------------------------------------------------------------------------
# Internal state and one control cycle


def state_layout(sizes: Sizes) -> Layout:
    """The internal state's blocks: the K-filters eta and lam (4.13-4.22), the estimates
    theta_hat and rho_hat, the previous cycle's y and u, and the estimates' derivatives."""
    n, p = sizes.n, sizes.p
    return Layout(eta=n, lam=n, theta_hat=p, rho_hat=1, y_prev=1, u_prev=1, theta_hat_dot=p,
                  rho_hat_dot=1)


def result_layout(sizes: Sizes) -> Layout:
    """The blocks of a cycle's results ``res`` (Sizes.outputs values): the control u, the
    tuning function tau_rho, alpha_bar_1, the errors z and gamma_2."""
    return Layout(u=1, tau=sizes.p, alpha_bar_1=1, z=sizes.rho, gamma_2=1)


def state_size(sizes: Sizes) -> int:
    """The internal state's size (:func:`state_layout`)."""
    return state_layout(sizes).size


def initial_state(sizes: Sizes, theta_hat_0, rho_hat_0: float) -> np.ndarray:
    """Filters at rest, the given initial estimates, nothing to integrate yet."""
    s = np.zeros(state_size(sizes))
    n, p = sizes.n, sizes.p
    s[2 * n:2 * n + p] = theta_hat_0
    s[2 * n + p] = rho_hat_0
    return s


def pack_gains(sizes: Sizes, c, d, lam, Gamma, gamma) -> np.ndarray:
    """The gain part of the tape's input vector."""
    out = np.concatenate([np.broadcast_to(np.asarray(c, float), sizes.rho),
                          np.broadcast_to(np.asarray(d, float), sizes.rho),
                          np.asarray(lam, float), np.broadcast_to(np.asarray(Gamma, float), sizes.p),
                          [float(gamma)]])
    if out.shape != (sizes.gains,):
        raise ValueError(f"gains of the wrong size: {out.shape} for {sizes}")
    return out


@njit(cache=True)
def _a0_into(x, k, out):
    n = x.shape[0]
    for i in range(n - 1):
        out[i] = x[i + 1] - k[i] * x[0]
    out[n - 1] = -k[n - 1] * x[0]


@njit(cache=True)
def _filter_rk4(x, k, u0, u1, dt, work):
    """x' = A0 x + e_n u(t), u linear from u0 to u1 over dt: one classical RK4 step in place."""
    n = x.shape[0]
    k1, k2, k3, k4, xs = work[0], work[1], work[2], work[3], work[4]
    um = 0.5 * (u0 + u1)
    _a0_into(x, k, k1)
    k1[n - 1] += u0
    for i in range(n):
        xs[i] = x[i] + 0.5 * dt * k1[i]
    _a0_into(xs, k, k2)
    k2[n - 1] += um
    for i in range(n):
        xs[i] = x[i] + 0.5 * dt * k2[i]
    _a0_into(xs, k, k3)
    k3[n - 1] += um
    for i in range(n):
        xs[i] = x[i] + dt * k3[i]
    _a0_into(xs, k, k4)
    k4[n - 1] += u1
    for i in range(n):
        x[i] += dt / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])


@njit(cache=True)
def backstepping_cycle(op, a, b, value, outputs, n, rho, p, inp, vals, work, state, y, y_r, dt,
                       res):
    """One cycle: advance the K-filters and estimates from the previous cycle by ``dt``
    (input filter with the held u, output filter with y interpolated linearly, estimates
    explicitly with the previous cycle's derivatives), then evaluate the design at the
    measured ``y`` into ``res`` (Sizes.outputs values: u, tau, alpha_bar_1, z, gamma_2)
    and store this cycle's derivatives. ``inp`` holds the packed gains after its signals."""
    eta = state[0:n]
    lam = state[n:2 * n]
    th = state[2 * n:2 * n + p]
    i_rho = 2 * n + p
    i_prev = i_rho + 1
    th_dot = state[i_prev + 2:i_prev + 2 + p]
    n_sig = 2 + 2 * n + p + 1
    k = inp[n_sig + 2 * rho:n_sig + 2 * rho + n]
    G = inp[n_sig + 2 * rho + n:n_sig + 2 * rho + n + p]
    gam = inp[n_sig + 2 * rho + n + p]
    if dt > 0.0:
        y_prev, u_prev = state[i_prev], state[i_prev + 1]
        _filter_rk4(eta, k, -y_prev, -y, dt, work)
        _filter_rk4(lam, k, u_prev, u_prev, dt, work)
        for j in range(p):
            th[j] += dt * th_dot[j]
        state[i_rho] += dt * state[i_prev + 2 + p]
    inp[0] = y
    inp[1] = y_r
    for i in range(n):
        inp[2 + i] = eta[i]
        inp[2 + n + i] = lam[i]
    for j in range(p):
        inp[2 + 2 * n + j] = th[j]
    inp[2 + 2 * n + p] = state[i_rho]
    run_tape(op, a, b, value, outputs, inp, vals, res)
    # res: u, tau (p), alpha_bar_1, z (rho), gamma_2
    for j in range(p):
        th_dot[j] = G[j] * res[1 + j]
    state[i_prev + 2 + p] = -gam * res[1 + p] * res[2 + p]
    state[i_prev] = y
    state[i_prev + 1] = res[0]


class Backstepping:
    """The design for one (n, rho): its tape, scratch and packed inputs; schemes call
    :meth:`cycle` with their ``internal`` state (:func:`initial_state`)."""

    def __init__(self, sizes: Sizes):
        self.sizes = sizes
        self.tape = tape_for(sizes)
        self.inp = np.zeros(sizes.signals + sizes.gains)
        self.vals = np.zeros(len(self.tape))
        self.work = np.zeros((5, sizes.n))
        self.res = np.zeros(sizes.outputs)

    def set_gains(self, c, d, lam, Gamma, gamma) -> None:
        self.inp[self.sizes.signals:] = pack_gains(self.sizes, c, d, lam, Gamma, gamma)

    def cycle(self, state: np.ndarray, y: float, y_r: float, dt: float) -> np.ndarray:
        """Advance ``state`` and return [u, tau_rho, alpha_bar_1, z, gamma_2] (a view)."""
        t, s = self.tape, self.sizes
        backstepping_cycle(t.op, t.a, t.b, t.value, t.outputs, s.n, s.rho, s.p, self.inp,
                           self.vals, self.work, state, y, y_r, dt, self.res)
        return self.res

    def evaluate(self, y, y_r, eta, lam, theta_hat, rho_hat) -> np.ndarray:
        """The design's outputs at one point (no integration): for tests and analysis."""
        s = self.sizes
        self.inp[:s.signals] = np.concatenate([[y, y_r], eta, lam, theta_hat, [rho_hat]])
        out = np.zeros(s.outputs)
        t = self.tape
        run_tape(t.op, t.a, t.b, t.value, t.outputs, self.inp, self.vals, out)
        return out


def observer_coefficients(poles) -> np.ndarray:
    """lambda (monic characteristic polynomial coefficients after the leading 1) of A0 with
    the given poles: det(sI - A0) = s^n + lambda_1 s^{n-1} + ... + lambda_n."""
    return np.real(np.poly(np.asarray(poles, dtype=complex)))[1:]


def a0_matrix(lam) -> np.ndarray:
    """A0 = A - lambda e_1^T (4.16)."""
    n = len(lam)
    A0 = np.eye(n, k=1)
    A0[:, 0] -= np.asarray(lam, float)
    return A0


def thesis_rho2(y, y_r, eta, lam, theta_hat, d_hat, h1, h2, k, Gamma, gamma) -> dict:
    """Equations (4.34), (4.49), (4.50), (4.56) for n = 5, rho = 2 written out as printed
    (partial derivatives by hand: alpha_bar_1 is affine in eta_5, y_1, theta_hat), plus the
    term the printed (4.47) leaves out (``missing``: d_hat * d alpha_bar_1/d v * v')."""
    n, m = 5, 3
    A0 = a0_matrix(k)
    eta = np.asarray(eta, float)
    lam = np.asarray(lam, float)
    th = np.asarray(theta_hat, float)
    Ap = [np.linalg.matrix_power(A0, j) for j in range(n + 1)]
    v = [Ap[j] @ lam for j in range(m + 1)]                 # v_0..v_3
    c2 = np.eye(n)[1]
    c5 = np.eye(n)[4]
    A_eta = np.array([c2 @ Ap[4], c2 @ Ap[3], c2 @ Ap[2], c2 @ Ap[1], c2])   # (4.29)
    w = np.concatenate([[v[3][1], v[2][1], v[1][1], v[0][1]], A_eta @ eta - y * np.eye(n)[0]])
    wbar = w.copy()
    wbar[0] = 0.0
    z1 = y - y_r
    xi2 = c2 @ Ap[5] @ eta
    ab1 = -h1 * z1 - xi2 - wbar @ th                                        # (4.34)
    alpha1 = d_hat * ab1
    z2 = v[3][1] - alpha1
    tau1 = (w - d_hat * ab1 * np.eye(9)[0]) * z1                            # (4.41)
    dab1_dy = -h1 + th[4]                       # w_bar's a_4 entry holds -y
    dab1_deta = -(c2 @ Ap[5]) - th[4:] @ A_eta
    dab1_dth = -wbar
    gamma2 = d_hat * dab1_dy                                                # (4.49)
    beta2 = (k[1] * v[3][0] + d_hat * dab1_deta @ (A0 @ eta - c5 * y)
             - gamma * ab1 ** 2 * z1 + gamma2 * (xi2 + w @ th))             # (4.50)
    tau2 = tau1 - gamma2 * w * z2                                           # (4.55)
    delta_c = (-h2 * z2 - th[0] * z1 + beta2 + d_hat * dab1_dth @ (np.asarray(Gamma) * tau2)
               - v[3][2])                                                   # (4.56)
    # d alpha_1/d lam through v_{2,2}, v_{1,2}, v_{0,2} (left out of 4.47):
    v_dot = [A0 @ vj for vj in v]
    missing = d_hat * sum(-th[3 - j] * v_dot[j][1] for j in range(3))
    return {"alpha_bar_1": ab1, "z2": z2, "gamma2": gamma2, "beta2": beta2, "tau2": tau2,
            "delta_c": delta_c, "missing": missing}
