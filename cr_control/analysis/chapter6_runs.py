"""Chapter 6 runs (constrained flexible-joint robots): :class:`FlexRun` built from a recorded
session or an offline run of ``fjr_robust_adaptive`` (Theorem 6.2.1) or
``fjr_singular_perturbation`` (section 6.2.1), which scheme and thesis case it is, the true
parameter vector p of Property 6.5, and where a run diverged (:func:`divergence`).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

ROBUST_SCHEME = "fjr_robust_adaptive"
SP_SCHEME = "fjr_singular_perturbation"
#: Status fields of both chapter 6 schemes (flexible_joint_scheme.STATUS and the torques).
REQUIRED = ("lambda", "e_lambda", "e_q_1", "e_q_2", "phi", "tau_1", "tau_2")
#: The schemes' own status fields (as published).
ROBUST_EXTRAS = (*(f"p_hat_{i}" for i in range(1, 11)), "ks_inv_hat_1", "ks_inv_hat_2",
                 "mu_1", "mu_2", "sigma_1", "sigma_2", "theta_d_1", "theta_d_2", "z_1", "z_2",
                 "s_1", "s_2", "k_tau", "qddot_m_1", "qddot_m_2", "qddot_m_filtered_1",
                 "qddot_m_filtered_2")
SP_EXTRAS = (*(f"p_hat_{i}" for i in range(1, 6)), "gamma_inv_norm", "forgetting", "tau_s_1",
             "tau_s_2", "z_tilde_1", "z_tilde_2", "q_md_hat_1", "q_md_hat_2", "e_m_hat_1",
             "e_m_hat_2")
#: Fields that tell the two schemes apart.
ROBUST_MARK = ("p_hat_10", "ks_inv_hat_1", "ks_inv_hat_2")
SP_MARK = ("gamma_inv_norm", "tau_s_1", "tau_s_2")
ROBUST, SP = "robust", "sp"
#: Windows (s) of the side-by-side table (cut to the run's length).
WINDOWS = ((0.0, 1.0), (1.0, 5.0), (5.0, 10.0), (10.0, 15.0), (15.0, 20.0))
#: |e_q| (rad) above which a run counts as diverged.
DIVERGENCE_RAD = 1.0
#: Thesis figure numbers of each case (section 6.3).
FIGURES: dict[str, dict[str, str]] = {
    "case 1": {"positions": "6.2", "force": "6.3", "torques": "6.4", "p_hat": "6.5",
               "ks_inv_hat": "6.6"},
    "case 2": {"positions": "6.7", "force": "6.8", "torques": "6.9", "p_hat": "6.10",
               "ks_inv_hat": "6.11"},
    "sp": {"positions": "6.12", "force": "6.13", "torques": "6.14", "estimates": "6.15"},
    "sp without tau_s": {"positions": "6.16", "force": "6.17", "torques": "6.18"},
}
#: Plant K_s of each thesis case (all joints alike).
CASE_STIFFNESS = {"case 1": 10.0, "case 2": 50.0, "sp": 300.0, "sp without tau_s": 300.0}
#: Sentinel of :func:`plot_chapter6`: take the case from the run.
AUTO = "auto"


@dataclass
class FlexRun:
    """Time series of one chapter 6 run, on a time axis starting at 0."""

    label: str
    kind: str                  #: ROBUST or SP
    time: np.ndarray
    q_ld: np.ndarray           #: (k, 2) desired link positions (rad); NaN where unknown
    e_q: np.ndarray            #: (k, 2) q_ld - q_l (rad)
    lam: np.ndarray            #: constraint force lambda (N)
    lam_d: np.ndarray
    tau: np.ndarray            #: (k, 2) motor torques tau_m (N m)
    phi: np.ndarray            #: Phi(q_l) (m)
    held: np.ndarray           #: (k,) bool: the controller held its last command
    #: The scheme's own status fields present (ROBUST_EXTRAS or SP_EXTRAS).
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    #: Plant K_s (N m/rad) where known and alike for both joints.
    joint_stiffness: float | None = None
    #: The SP scheme's slow_control parameter where known.
    slow_control: bool | None = None
    #: The controller's max_effort (N m: commands are clipped there) where known.
    max_effort: float | None = None
    #: The robust scheme's motor_acceleration parameter (q_m'' in tau_m: "measured" or
    #: "filtered") where known.
    motor_acceleration: str | None = None

    @property
    def q_l(self) -> np.ndarray:
        """Link positions q_l = q_ld - e_q (rad)."""
        return self.q_ld - self.e_q

    @property
    def e_q_norm(self) -> np.ndarray:
        return np.hypot(self.e_q[:, 0], self.e_q[:, 1])

    def p_hat(self) -> np.ndarray | None:
        """(k, l) the p_hat estimates, or None."""
        names = [n for n in self.extras if re.fullmatch(r"p_hat_\d+", n)]
        if not names:
            return None
        names.sort(key=lambda n: int(n.rsplit("_", 1)[1]))
        return np.column_stack([self.extras[n] for n in names])


def scheme_kind(status: dict[str, np.ndarray] | Sequence[str]) -> str | None:
    """ROBUST, SP, or None from the status field names."""
    if all(n in status for n in ROBUST_MARK):
        return ROBUST
    if all(n in status for n in SP_MARK):
        return SP
    return None


def is_chapter6(status: dict[str, np.ndarray] | Sequence[str]) -> bool:
    """True if the status carries the fields of one of the chapter 6 schemes."""
    return all(n in status for n in REQUIRED) and scheme_kind(status) is not None


def _clean(x: Any) -> np.ndarray:
    """Float array with inf as NaN (plots and limits cannot take inf)."""
    a = np.array(x, dtype=float)
    a[~np.isfinite(a)] = np.nan
    return a


def _stiffness(plant: dict[str, Any] | None) -> float | None:
    ks = (plant or {}).get("joint_stiffness")
    if ks is None:
        return None
    values = np.atleast_1d(np.asarray(ks, dtype=float))
    return float(values[0]) if len(values) and np.all(values == values[0]) else None


def _slow(controller: dict[str, Any] | None) -> bool | None:
    value = (controller or {}).get("slow_control")
    return None if value is None else bool(value)


def _max_effort(controller: dict[str, Any] | None) -> float | None:
    value = (controller or {}).get("max_effort")
    try:
        return float(value) if value is not None else None
    except (TypeError, ValueError):
        return None


def _build(label: str, t: np.ndarray, col: Callable[[str], np.ndarray], names: Any,
           q_ld: np.ndarray) -> FlexRun:
    kind = scheme_kind(names)
    if kind is None or not all(n in names for n in REQUIRED):
        raise ValueError(f"{label}: not a chapter 6 run (status lacks the fields of "
                         f"{ROBUST_SCHEME} and {SP_SCHEME})")
    lam = _clean(col("lambda"))
    held = (np.asarray(col("held"), dtype=float) > 0.5) if "held" in names \
        else np.zeros(len(t), dtype=bool)
    extras = ROBUST_EXTRAS if kind == ROBUST else SP_EXTRAS
    return FlexRun(label, kind, _clean(t), _clean(q_ld),
                   _clean(np.column_stack([col("e_q_1"), col("e_q_2")])), lam,
                   lam + _clean(col("e_lambda")),
                   _clean(np.column_stack([col("tau_1"), col("tau_2")])), _clean(col("phi")),
                   held, {n: _clean(col(n)) for n in extras if n in names})


def from_offline(run: Any, label: str, plant: dict[str, Any] | None = None,
                 controller: dict[str, Any] | None = None) -> FlexRun:
    """A FlexRun from :class:`cr_control.offline.OfflineRun`; ``plant`` and
    ``controller`` (parameter values, where known) give K_s and slow_control."""
    names = set(run.status_fields)
    q_ld = (np.column_stack([run.column("q_ld_1"), run.column("q_ld_2")])
            if "q_ld_1" in run.reference_fields else np.full((len(run.time), 2), np.nan))
    out = _build(label, run.time - run.time[0], run.column, names, q_ld)
    out.joint_stiffness, out.slow_control = _stiffness(plant), _slow(controller)
    out.max_effort = _max_effort(controller)
    out.motor_acceleration = (controller or {}).get("motor_acceleration")
    return out


def _on_stamps(reference: dict[str, np.ndarray], name: str, stamps: np.ndarray) -> np.ndarray:
    """Reference column ``name`` at the status stamps (NaN where missing)."""
    if name not in reference or "stamp" not in reference or not len(reference["stamp"]):
        return np.full(len(stamps), np.nan)
    ref_t, values = np.asarray(reference["stamp"], float), np.asarray(reference[name], float)
    if len(ref_t) == len(stamps) and np.array_equal(ref_t, stamps):
        return values
    order = np.argsort(ref_t, kind="stable")
    return np.interp(stamps, ref_t[order], values[order], left=np.nan, right=np.nan)


def from_session(session: Any) -> FlexRun:
    """A FlexRun from a loaded session (:func:`cr_control.analysis.analyze.load_session`)."""
    s = session.status
    stamps = np.asarray(s["stamp"], dtype=float)
    q_ld = np.column_stack([_on_stamps(session.reference, f"q_ld_{i}", stamps) for i in (1, 2)])
    out = _build(session.name, session.relative_time(stamps), s.__getitem__, s, q_ld)
    out.joint_stiffness = _stiffness(session.parameters.get("plant"))
    controller = session.parameters.get(session.controller or "", {})
    out.slow_control, out.max_effort = _slow(controller), _max_effort(controller)
    out.motor_acceleration = controller.get("motor_acceleration")
    return out


def _label_stiffness(label: str) -> float | None:
    m = re.search(r"K_?s\s*=\s*([0-9]+(?:\.[0-9]*)?)", label)
    return float(m.group(1)) if m else None


def true_p(run: FlexRun) -> np.ndarray | None:
    """What p_hat estimates for the section 6.3 links (flexible_joint_model.TRUE_P = p):
    p itself (singular perturbation, K_s known), Lambda^-1 p = [p / k_s1; p / k_s2] (robust,
    Property 6.5; only where the plant's K_s is known). None otherwise."""
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_control.schemes.flexible_joint.flexible_joint_model import TRUE_P  # analysis -> schemes (one way)

    p = run.p_hat()
    if p is None:
        return None
    if run.kind == SP and p.shape[1] == len(TRUE_P):
        return np.asarray(TRUE_P, dtype=float)
    if run.kind == ROBUST and run.joint_stiffness and p.shape[1] == 2 * len(TRUE_P):
        return np.concatenate([TRUE_P, TRUE_P]) / run.joint_stiffness
    return None


def thesis_case(run: FlexRun) -> str | None:
    """The section 6.3 case the run reproduces (a key of FIGURES), or None: robust with
    K_s = 10 / 50 (from the plant parameters, else the label), singular perturbation with
    K_s = 300 (or unknown) with / without tau_s (slow_control, else whether tau_s is ever
    non-zero)."""
    ks = run.joint_stiffness if run.joint_stiffness is not None else _label_stiffness(run.label)
    if run.kind == ROBUST:
        return next((c for c in ("case 1", "case 2") if ks == CASE_STIFFNESS[c]), None)
    if ks is not None and ks != CASE_STIFFNESS["sp"]:
        return None
    slow = run.slow_control
    if slow is None and "tau_s_1" in run.extras and "tau_s_2" in run.extras:
        tau_s = np.abs(np.column_stack([run.extras["tau_s_1"], run.extras["tau_s_2"]]))
        slow = bool(np.nanmax(tau_s, initial=0.0) > 0.0)
    if slow is None:
        return None
    return "sp" if slow else "sp without tau_s"


# -- divergence --------------------------------------------------------------------------
@dataclass
class Divergence:
    """Where a run blew up."""

    time: float     #: s
    reason: str


def divergence(run: FlexRun, limit: float = DIVERGENCE_RAD) -> Divergence | None:
    """The first time |e_q| exceeds ``limit`` rad, a tracked value (e_q, lambda, tau_m) is
    not finite, or the controller holds its command; None if none of it happens."""
    t = run.time
    found: list[tuple[int, str]] = []
    e = run.e_q_norm
    above = np.flatnonzero(e > limit)
    if len(above):
        found.append((int(above[0]), f"|e_q| > {limit:g} rad"))
    bad = ~np.isfinite(np.column_stack([run.e_q, run.lam, run.tau])).all(axis=1)
    if bad.any():
        found.append((int(np.argmax(bad)), "non-finite values"))
    if run.held.any():
        found.append((int(np.argmax(run.held)), "controller holding its command"))
    if not found:
        return None
    k, reason = min(found)
    return Divergence(float(t[k]), reason)


def before_divergence(run: FlexRun, div: Divergence | None = None) -> np.ndarray:
    """Mask of the samples before the divergence (all if none; at least the first)."""
    div = divergence(run) if div is None else div
    if div is None:
        return np.ones(len(run.time), dtype=bool)
    mask = run.time < div.time
    mask[:1] = True
    return mask
