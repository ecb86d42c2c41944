"""Chapter 4 and appendix C analysis: explicit force control on the dynamic constraint
(thesis figs. 4.2-4.11) and the n-mass chain (appendix C).

Force runs (:class:`ForceRun`) come from ``backstepping_force`` (cases 1-3 via the plant's
k_o = k_s = 20/50/80, case 4 = gamma = 0, Gamma = 0) or ``mrac_force`` (case 5): both publish
f (f_x), f_d - f (f_err_x), delta (r_x) and the command delta_c (tau_1) in their status,
plus the estimates (b3_hat..a0_hat, d_hat; or theta_f hats r3p_hat..t0_hat, b3_hat, and the
reference-model output f_m). Chain runs (:class:`ChainRun`) come from
``cmmsd_backstepping`` (q_1 in r_x, u, d_hat, theta_hat_norm, z_1).

:func:`force_metrics` gives the figures of a force step response: settling time (2 % band), undershoot
and overshoot, steady-state error and peak-to-peak over the last 10 s, chattering (RMS of
delta_c about its 1 s moving average), delta_c range, time without contact, and when the
controller started holding its command (a diverged loop). :func:`plot_force_run` draws one
run (force, delta_c, estimates: figs. 4.2-4.6, 4.9-4.11), :func:`compare_force` overlays
several (cases 1-3: figs. 4.2/4.3; case 1 vs 4: 4.7/4.8; case 1 vs 5: 4.9/4.10) with a table;
:func:`plot_chains` draws q_1 and u for n = 1, 2, 3 masses. A diverged run would flatten the
others: the force and delta_c panels are then zoomed on the converging runs, with a second
panel on a symmetric-log scale showing the whole of every run.

``python -m cr_control.analysis.chapter4 OUT_DIR [DURATION]`` runs all of it offline
(default 100 s per case, 60 s per chain) and writes the figures and ch4_comparison.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cr_control.analysis.chapter2 import figure
from cr_control.analysis.figures import save_figure as save
from cr_control.core.parameters import resolve

BACKSTEPPING_NAMES = ("b3", "b2", "b1", "b0", "a4", "a3", "a2", "a1", "a0")
MRAC_NAMES = ("r3p", "r2p", "r1p", "r0p", "s4", "s3", "s2", "s1", "s0",
              "t4", "t3", "t2", "t1", "t0")
#: Status fields that mark the two force schemes and the chain scheme.
BACKSTEPPING_FIELDS = ("f_x", "f_err_x", "r_x", "tau_1", "z_1", "z_2", "d_hat", "b3_hat")
MRAC_FIELDS = ("f_x", "f_err_x", "r_x", "tau_1", "f_m", "eps_p", "b3_hat", "r3p_hat")
CHAIN_FIELDS = ("r_x", "u", "d_hat", "theta_hat_norm", "z_1")
#: Force metrics: steady state over the last TAIL_S; chattering after CHATTER_FROM_S.
TAIL_S = 10.0
CHATTER_FROM_S = 5.0
CHATTER_WINDOW_S = 1.0
SETTLING_FRACTION = 0.02


@dataclass
class ForceRun:
    """Time series of one chapter 4 run, on a time axis starting at 0."""

    label: str
    scheme: str                #: "backstepping_force" or "mrac_force"
    time: np.ndarray
    f: np.ndarray              #: measured constraint force (N)
    f_d: np.ndarray            #: desired force (N)
    delta: np.ndarray          #: end-effector (constraint) displacement (m)
    delta_c: np.ndarray        #: command displacement (m)
    held: np.ndarray           #: True where the controller held its last command
    #: Estimates by name (theta_hat elements, d_hat / b3_hat), in the thesis's order.
    estimates: dict[str, np.ndarray] = field(default_factory=dict)
    f_m: np.ndarray | None = None       #: MRAC reference-model output
    #: True values of the estimates (same names) where the plant is known.
    true: dict[str, float] = field(default_factory=dict)


@dataclass
class ChainRun:
    """One appendix C run: the n-mass chain regulated from an initial displacement."""

    label: str
    n: int
    time: np.ndarray
    q: np.ndarray              #: (k, n) mass displacements (column 0 = q_1, all the scheme reads)
    u: np.ndarray              #: force on the last mass (N)
    d_hat: np.ndarray
    theta_norm: np.ndarray     #: |theta_hat|
    held: np.ndarray
    true_theta_norm: float | None = None
    true_d: float | None = None   #: 1/d_2n, what d_hat estimates


def is_force_run(status: dict[str, np.ndarray] | Sequence[str]) -> bool:
    """True if the status is a chapter 4 force scheme's."""
    return (all(n in status for n in BACKSTEPPING_FIELDS)
            or all(n in status for n in MRAC_FIELDS))


def is_chain_run(status: dict[str, np.ndarray] | Sequence[str]) -> bool:
    """True if the status is the appendix C chain scheme's."""
    return all(n in status for n in CHAIN_FIELDS) and "b3_hat" not in status


# -- true values -------------------------------------------------------------------------
def _values(specs: Sequence[Any], given: dict[str, Any] | None) -> dict[str, Any]:
    """Defaults of ``specs`` with the entries of ``given`` that name one of them."""
    names = {p.name for p in specs}
    return resolve(specs, {k: v for k, v in (given or {}).items() if k in names})


def true_estimates(scheme: str, plant: dict[str, Any] | None,
                   controller: dict[str, Any] | None = None) -> dict[str, float]:
    """What the estimates of ``scheme`` would be for the plant: theta and 1/b_3
    (backstepping), or theta_f of (4.69) from the Diophantine solution and b_3 (MRAC)."""
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_sim.plants import dynamic_constraint

    theta = dynamic_constraint.true_theta(_values(dynamic_constraint.PARAMETERS, plant))
    if scheme == "backstepping_force":
        out = {f"{n}_hat": float(x) for n, x in zip(BACKSTEPPING_NAMES, theta, strict=True)}
        out["d_hat"] = 1.0 / float(theta[0])
        return out
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_control.schemes.blocks import diophantine
    from cr_control.schemes.force.mrac_force import PARAMETERS

    c = _values(PARAMETERS, controller)
    theta_f = diophantine.solve(theta, c["zeta"], c["omega"],
                                [1.0, *c["observer_polynomial"]])["theta_f"]
    out = {f"{n}_hat": float(x) for n, x in zip(MRAC_NAMES, theta_f, strict=True)}
    out["b3_hat"] = float(theta[0])
    return out


def _estimate_names(scheme: str) -> list[str]:
    if scheme == "backstepping_force":
        return [f"{n}_hat" for n in BACKSTEPPING_NAMES] + ["d_hat"]
    return [f"{n}_hat" for n in MRAC_NAMES] + ["b3_hat"]


def _scheme_of(fields: Sequence[str]) -> str:
    return "backstepping_force" if "z_2" in fields else "mrac_force"


def _force_run(label: str, scheme: str, t: np.ndarray, col: Any, fields: Sequence[str]
               ) -> ForceRun:
    f = col("f_x")
    return ForceRun(label, scheme, t, f, f + col("f_err_x"), col("r_x"), col("tau_1"),
                    col("held") > 0.5 if "held" in fields else np.zeros(len(t), bool),
                    {n: col(n) for n in _estimate_names(scheme) if n in fields},
                    col("f_m") if "f_m" in fields else None)


def force_from_offline(run: Any, label: str, plant: dict[str, Any] | None = None,
                       controller: dict[str, Any] | None = None) -> ForceRun:
    """A ForceRun from :class:`cr_control.offline.OfflineRun` (plant and controller:
    the overrides it ran with, for the true values)."""
    scheme = _scheme_of(run.status_fields)
    out = _force_run(label, scheme, run.time - run.time[0], run.column, run.status_fields)
    out.true = true_estimates(scheme, plant, controller)
    return out


def force_from_session(session: Any) -> ForceRun:
    """A ForceRun from a loaded session (:func:`cr_control.analysis.analyze.load_session`)."""
    s = session.status
    scheme = _scheme_of(list(s))
    out = _force_run(session.name, scheme, session.relative_time(s["stamp"]), s.__getitem__,
                     list(s))
    try:
        out.true = true_estimates(scheme, session.parameters.get("plant"),
                                  session.parameters.get(session.controller or "", {}))
    except Exception:  # a plant that is not the dynamic constraint: no true values
        out.true = {}
    return out


def _chain_truth(plant: dict[str, Any] | None, n: int) -> tuple[float | None, float | None]:
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_sim.plants import cmmsd

    try:
        theta = cmmsd.true_theta(_values(cmmsd.PARAMETERS, {**(plant or {}), "masses": n}))
    except Exception:
        return None, None
    return float(np.linalg.norm(theta)), 1.0 / float(theta[0])


def chain_from_offline(run: Any, label: str, plant: dict[str, Any] | None = None) -> ChainRun:
    """A ChainRun from an offline run of ``cmmsd_backstepping``."""
    col = run.column
    n = run.position.shape[1]
    out = ChainRun(label, n, run.time - run.time[0], np.asarray(run.position), col("u"),
                   col("d_hat"), col("theta_hat_norm"), col("held") > 0.5)
    out.true_theta_norm, out.true_d = _chain_truth(plant, n)
    return out


def chain_from_session(session: Any) -> ChainRun:
    """A ChainRun from a loaded session: q_1 from the status (what the scheme read); the
    other masses from /joint_states where their stamps match the status's."""
    s = session.status
    t = session.relative_time(s["stamp"])
    q = s["r_x"][:, None]
    states = session.joint_states
    if states is not None and states.position.shape[1] > 1:
        idx = np.searchsorted(states.time, s["stamp"])
        ok = (idx < len(states.time))
        if ok.all() and np.allclose(states.time[idx], s["stamp"]):
            q = np.column_stack([q, states.position[idx, 1:]])
    n = q.shape[1]
    params = session.parameters.get(session.controller or "", {})
    if isinstance(params.get("joint_names"), list):
        n = max(n, len(params["joint_names"]))
    out = ChainRun(session.name, n, t, q, s["u"], s["d_hat"], s["theta_hat_norm"],
                   s["held"] > 0.5 if "held" in s else np.zeros(len(t), bool))
    out.true_theta_norm, out.true_d = _chain_truth(session.parameters.get("plant"), n)
    return out


# -- metrics -----------------------------------------------------------------------------
def _first_held(t: np.ndarray, held: np.ndarray) -> float:
    k = np.flatnonzero(held)
    return float(t[k[0]]) if len(k) else float("nan")


def force_metrics(run: ForceRun, tail: float = TAIL_S) -> dict[str, float]:
    """The step-response figures of one run (SI units; keys end with the unit).

    ``settling_s``: last time |f - f_d| left the 2 % band (NaN if outside at the end);
    ``undershoot_N``: f_d - min f (t > 0.1 s); ``overshoot_N``: max f - f_d after that
    minimum; ``ss_error_N`` and ``p2p_tail_N``: mean(f) - f_d and the peak-to-peak of f over
    the last ``tail`` s; ``chatter_m``: RMS of delta_c about its 1 s moving average over
    [5 s, end - 1 s]; ``no_contact_s``: time with f reported 0 (contact lost);
    ``held_from_s``: first cycle the controller held its command (NaN: never)."""
    t, f, fd, dc = run.time, run.f, run.f_d, run.delta_c
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1e-3
    outside = np.abs(f - fd) > SETTLING_FRACTION * np.abs(fd)
    k_out = np.flatnonzero(outside | ~np.isfinite(f))
    if not len(k_out):
        settling = 0.0
    elif k_out[-1] == len(t) - 1:
        settling = float("nan")
    else:
        settling = float(t[k_out[-1] + 1])
    start = t > min(0.1, float(t[-1]))
    k_min = int(np.flatnonzero(start)[np.nanargmin(f[start])]) if start.any() else 0
    late = t >= t[-1] - tail
    win = max(1, int(round(CHATTER_WINDOW_S / dt)))
    smooth = np.convolve(dc, np.ones(win) / win, mode="same")
    band = (t >= CHATTER_FROM_S) & (t < t[-1] - CHATTER_WINDOW_S)
    return {
        "settling_s": settling,
        "undershoot_N": float(fd[k_min] - f[k_min]),
        "overshoot_N": float(np.nanmax(f[k_min:] - fd[k_min:])),
        "ss_error_N": float(np.nanmean(f[late] - fd[late])),
        "p2p_tail_N": float(np.nanmax(f[late]) - np.nanmin(f[late])),
        "f_max_N": float(np.nanmax(f)),
        "chatter_m": float(np.sqrt(np.nanmean((dc - smooth)[band] ** 2))) if band.any()
        else float("nan"),
        "delta_c_min_m": float(np.nanmin(dc)), "delta_c_max_m": float(np.nanmax(dc)),
        "no_contact_s": float(np.count_nonzero((f <= 0.0) & (t > 0.0)) * dt),
        "held_from_s": _first_held(t, run.held),
    }


def chain_metrics(run: ChainRun, tail: float = TAIL_S) -> dict[str, float]:
    """q_1 regulation numbers: max |q_1| over the last ``tail`` s, time after which |q_1|
    stays below 2 % of |q_1(0)|, peak |u|, max |q_i| of any mass, final |theta_hat| and
    d_hat, first held cycle."""
    t, q1 = run.time, run.q[:, 0]
    late = t >= t[-1] - tail
    band = SETTLING_FRACTION * max(abs(float(q1[0])), 1e-12)
    k_out = np.flatnonzero(~(np.abs(q1) <= band))
    settling = 0.0 if not len(k_out) else (float("nan") if k_out[-1] == len(t) - 1
                                           else float(t[k_out[-1] + 1]))
    return {
        "q1_max_tail_m": float(np.nanmax(np.abs(q1[late]))),
        "settling_s": settling,
        "u_peak_N": float(np.nanmax(np.abs(run.u))),
        "q_max_m": float(np.nanmax(np.abs(run.q))),
        "theta_hat_norm_end": float(run.theta_norm[-1]),
        "d_hat_end": float(run.d_hat[-1]),
        "held_from_s": _first_held(t, run.held),
    }


FORCE_COLUMNS = [
    ("settling_s", "settling 2 % [s]", 1.0, "{:.1f}"),
    ("undershoot_N", "undershoot [N]", 1.0, "{:.3f}"),
    ("overshoot_N", "overshoot [N]", 1.0, "{:.3g}"),
    ("ss_error_N", "f − f_d, last 10 s [N]", 1.0, "{:.2e}"),
    ("p2p_tail_N", "f p-p, last 10 s [N]", 1.0, "{:.2e}"),
    ("chatter_m", "δ_c chatter RMS [mm]", 1e3, "{:.3f}"),
    ("delta_c_min_m", "δ_c min [m]", 1.0, "{:.3g}"),
    ("delta_c_max_m", "δ_c max [m]", 1.0, "{:.3g}"),
    ("no_contact_s", "no contact [s]", 1.0, "{:.2f}"),
    ("held_from_s", "held from [s]", 1.0, "{:.2f}"),
]
FORCE_NOTE = ("Settling: last time |f − f_d| left ±2 % of f_d (n/a: still outside at the end). "
              "Undershoot: f_d − min f after 0.1 s (f starts at 1.5 N); overshoot: max f − f_d "
              "after that minimum. δ_c chatter: RMS of δ_c about its 1 s moving average from "
              "5 s to the end − 1 s. No contact: time with f reported 0. Held from: first "
              "cycle the controller held its last command (absurd or non-finite state: the "
              "loop diverged; '–' never); δ_c is clipped at ±max_effort = ±100 m.")
CHAIN_COLUMNS = [
    ("q1_max_tail_m", "max \\|q_1\\|, last 10 s [m]", 1.0, "{:.2e}"),
    ("settling_s", "settling 2 % [s]", 1.0, "{:.1f}"),
    ("u_peak_N", "max \\|u\\| [N]", 1.0, "{:.3g}"),
    ("q_max_m", "max \\|q_i\\| [m]", 1.0, "{:.3g}"),
    ("theta_hat_norm_end", "‖θ̂‖ end", 1.0, "{:.4g}"),
    ("d_hat_end", "d̂ end", 1.0, "{:.4g}"),
    ("held_from_s", "held from [s]", 1.0, "{:.2f}"),
]


def _cell(value: float, scale: float, fmt: str) -> str:
    return "n/a" if not np.isfinite(value) else fmt.format(value * scale)


def table(rows: Sequence[tuple[str, dict[str, float]]], columns: Sequence[tuple]) -> str:
    """A Markdown table, one row per (label, metrics)."""
    lines = ["| run | " + " | ".join(h for _, h, _, _ in columns) + " |",
             "|" + "---|" * (len(columns) + 1)]
    for label, m in rows:
        cells = [("–" if key == "held_from_s" and not np.isfinite(m[key])
                  else _cell(m[key], scale, fmt)) for key, _, scale, fmt in columns]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# -- figures -----------------------------------------------------------------------------
def _zoom_limits(series: Sequence[np.ndarray], floor: Sequence[float] = ()) -> tuple[float, float]:
    values = np.concatenate([*(s[np.isfinite(s)] for s in series), np.asarray(floor, float)])
    lo, hi = float(values.min()), float(values.max())
    pad = 0.08 * (hi - lo) or 0.1 * max(abs(hi), 1.0)
    return lo - pad, hi + pad


def _well_behaved(runs: Sequence[Any]) -> list[Any]:
    """Runs whose controller never held (did not diverge); all runs if none is."""
    good = [r for r in runs if not r.held.any()]
    return good or list(runs)


def _held_marks(ax: Any, runs: Sequence[Any], colours: Sequence[str]) -> None:
    for run, colour in zip(runs, colours, strict=True):
        t_held = _first_held(run.time, run.held)
        if np.isfinite(t_held):
            ax.axvline(t_held, color=colour, ls=":", lw=1.0)


def _overlay(axes_zoom: Any, axes_full: Any | None, runs: Sequence[Any], get: Any,
             desired: Any | None, ylabel: str, floor: Sequence[float] = (),
             skip: float = 0.0) -> None:
    """Plot get(run) of every run in ``axes_zoom`` (y limits from the runs that did not
    diverge, after ``skip`` s) and, if given, on a symmetric-log scale in ``axes_full``."""
    colours = [f"C{i}" for i in range(len(runs))]
    for ax in (axes_zoom, axes_full):
        if ax is None:
            continue
        if desired is not None:
            ax.plot(runs[0].time, desired(runs[0]), "k-", lw=1.8, alpha=0.45,
                    label="desired $f_d$")
        for run, colour in zip(runs, colours, strict=True):
            ax.plot(run.time, get(run), color=colour, lw=0.9, label=run.label)
        _held_marks(ax, runs, colours)
    good = _well_behaved(runs)
    axes_zoom.set_ylim(*_zoom_limits([get(r)[r.time >= min(skip, r.time[-1])] for r in good],
                                     floor))
    axes_zoom.set_ylabel(ylabel + (f"\n(zoom: after {skip:g} s)" if skip else ""))
    if axes_full is not None:
        axes_full.set_yscale("symlog", linthresh=1.0)
        lo = min(float(np.nanmin(get(r))) for r in runs)
        if lo >= 0.0:
            axes_full.set_ylim(bottom=-0.2)
        axes_full.set_ylabel(ylabel + "\n(whole range, symlog)")


def _needs_full(runs: Sequence[Any], get: Any) -> bool:
    good = _well_behaved(runs)
    lo, hi = _zoom_limits([get(r) for r in good])
    return any(np.nanmax(get(r)) > hi + (hi - lo) or np.nanmin(get(r)) < lo - (hi - lo)
               for r in runs)


def compare_force(runs: Sequence[ForceRun], out_dir: str | Path, stem: str = "ch4_comparison",
                  title: str = "Chapter 4: force control on the dynamic constraint"
                  ) -> list[Path]:
    """Force f (with f_d) and command delta_c of the runs overlaid in one figure
    (``stem``.png) and their metrics table (``stem``.md). A dotted vertical line marks
    where a run's controller started holding its command (diverged)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    def get_f(r):
        return r.f

    def get_dc(r):
        return r.delta_c

    full_f = _needs_full(runs, get_f)
    fig, axes = figure(3 + full_f, height=2.1)
    _overlay(axes[0], axes[1] if full_f else None, runs, get_f, lambda r: r.f_d,
             "force f [N]", floor=[0.0])
    k = 1 + full_f                # delta_c: its start-up surge is the thesis's point
    _overlay(axes[k + 1], axes[k], runs, get_dc, None, r"command $\delta_c$ [m]", skip=1.0)
    axes[-1].set_xlabel("t [s]")
    diverged = [r.label for r in runs if r.held.any()]
    fig.suptitle(title + ("\n(dotted: controller holding from there on — diverged: "
                          + ", ".join(diverged) + ")" if diverged else ""))
    save(fig, out / f"{stem}.png", written)
    md = out / f"{stem}.md"
    md.write_text(f"### {title}\n\n" + table([(r.label, force_metrics(r)) for r in runs],
                                             FORCE_COLUMNS) + "\n" + FORCE_NOTE + "\n")
    written.append(md)
    return written


def _estimate_panels(run: ForceRun) -> list[tuple[str, list[str]]]:
    if run.scheme == "backstepping_force":
        groups = [(r"$\hat\theta_1..\hat\theta_4$ = $\hat b_3..\hat b_0$ (fig. 4.4)",
                   [f"{n}_hat" for n in BACKSTEPPING_NAMES[:4]]),
                  (r"$\hat\theta_5..\hat\theta_9$ = $\hat a_4..\hat a_0$ (fig. 4.5)",
                   [f"{n}_hat" for n in BACKSTEPPING_NAMES[4:]]),
                  (r"$\hat d$ (fig. 4.6)", ["d_hat"])]
    else:
        groups = [(r"$\hat\theta_f(5..7)$, $\hat b_3$ (fig. 4.11)",
                   ["s4_hat", "s3_hat", "s2_hat", "b3_hat"]),
                  (r"$\hat\theta_f(1..4)$: $r_3'..r_0'$", [f"{n}_hat" for n in MRAC_NAMES[:4]]),
                  (r"$\hat\theta_f$: $s_1, s_0, t_4..t_0$",
                   [f"{n}_hat" for n in MRAC_NAMES[7:]])]
    return [(label, [n for n in names if n in run.estimates]) for label, names in groups]


def _tex(name: str) -> str:
    """'b3_hat' -> $\\hat b_3$, 'r3p_hat' -> $\\hat r'_3$, 'd_hat' -> $\\hat d$."""
    base = name.removesuffix("_hat")
    prime = "'" if base.endswith("p") and len(base) > 2 else ""
    base = base.removesuffix("p") if prime else base
    sub = f"_{base[1:]}" if len(base) > 1 else ""
    return rf"$\hat {base[0]}{prime}{sub}$"


def plot_force_run(run: ForceRun, out_dir: str | Path) -> list[Path]:
    """One run as PNG in ``out_dir``: ch4_force (f, f_d, f_m), ch4_command (delta_c, delta),
    ch4_estimates (with the true values dotted). Returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    t = run.time
    mrac = run.scheme == "mrac_force"
    figs = ("4.9", "4.10", "4.11") if mrac else ("4.2", "4.3", "4.4-4.6")

    fig, axes = figure(1, height=2.8)
    ax = axes[0]
    ax.plot(t, run.f_d, "k-", lw=1.8, alpha=0.45, label="desired $f_d$")
    if run.f_m is not None:
        ax.plot(t, run.f_m, "C2--", lw=1.0, label="reference model $f_m$ (4.62)")
    ax.plot(t, run.f, "C0", lw=0.9, label="measured f")
    _held_marks(ax, [run], ["C3"])
    if run.held.any():
        ax.set_yscale("symlog", linthresh=1.0)
    ax.set_ylabel("force f [N]")
    ax.set_xlabel("t [s]")
    fig.suptitle(f"{run.label}: force response (cf. thesis fig. {figs[0]})"
                 + ("\n(dotted: controller holding from there on — diverged)"
                    if run.held.any() else ""))
    save(fig, out / "ch4_force.png", written)

    fig, axes = figure(2, height=2.3)
    settled = t >= min(1.0, float(t[-1]))
    for ax in axes:
        ax.plot(t, run.delta_c, "C1", lw=0.9, label=r"command $\delta_c$")
        ax.plot(t, run.delta, "C0--", lw=0.9, label=r"end effector $\delta$")
        _held_marks(ax, [run], ["C3"])
    if run.held.any():
        axes[0].set_yscale("symlog", linthresh=1.0)
    axes[0].set_ylabel("displacement [m]\n(whole run" + (", symlog)" if run.held.any() else ")"))
    good = settled & ~run.held
    axes[1].set_ylim(*_zoom_limits([run.delta_c[good], run.delta[good]]))
    axes[1].set_ylabel("displacement [m]\n(zoom: after 1 s)")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{run.label}: command displacement (cf. thesis fig. {figs[1]})")
    save(fig, out / "ch4_command.png", written)

    groups = [g for g in _estimate_panels(run) if g[1]]
    if groups:
        fig, axes = figure(len(groups), height=2.2)
        for ax, (label, names) in zip(axes, groups, strict=True):
            for i, name in enumerate(names):
                ax.plot(t, run.estimates[name], color=f"C{i}", lw=1.0, label=_tex(name))
                if name in run.true:
                    ax.axhline(run.true[name], color=f"C{i}", ls=":", lw=1.0)
            ax.set_ylabel(label, fontsize="small")
        axes[-1].set_xlabel("t [s]")
        fig.suptitle(f"{run.label}: parameter estimates (cf. thesis fig. {figs[2]}; "
                     "dotted: true values)")
        save(fig, out / "ch4_estimates.png", written)
    return written


def plot_chains(runs: Sequence[ChainRun], out_dir: str | Path, stem: str = "appC_chain"
                ) -> list[Path]:
    """Appendix C: q_1 and the control u of every run overlaid (n = 1, 2, 3 masses...), the
    other masses thin, |theta_hat| and d_hat with their true values dotted (``stem``.png)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []

    def q1(r):
        return r.q[:, 0]

    full = _needs_full(runs, q1)
    fig, axes = figure(4 + full, height=2.0)
    _overlay(axes[0], axes[1] if full else None, runs, q1, None, r"$q_1$ [m]", floor=[0.0])
    good = _well_behaved(runs)
    for i, run in enumerate(runs):
        if run in good:
            for j in range(1, run.q.shape[1]):
                axes[0].plot(run.time, run.q[:, j], color=f"C{i}", lw=0.5, alpha=0.4)
    axes[0].axhline(0.0, color="k", lw=1.8, alpha=0.45, label=r"desired $q_1 = 0$")
    k = 1 + full
    for i, run in enumerate(runs):
        kw = dict(color=f"C{i}", lw=0.9, label=run.label)
        axes[k].plot(run.time, run.u, **kw)
        axes[k + 1].plot(run.time, run.theta_norm, **kw)
        axes[k + 2].plot(run.time, run.d_hat, **kw)
        if run.true_theta_norm is not None:
            axes[k + 1].axhline(run.true_theta_norm, color=f"C{i}", ls=":", lw=1.0)
        if run.true_d is not None:
            axes[k + 2].axhline(run.true_d, color=f"C{i}", ls=":", lw=1.0)
    truths = ([], [r.true_theta_norm for r in good if r.true_theta_norm is not None],
              [r.true_d for r in good if r.true_d is not None])
    for j, get, label, floor in ((k, lambda r: r.u, "control u [N]", truths[0]),
                                 (k + 1, lambda r: r.theta_norm, r"$\|\hat\theta\|$",
                                  truths[1]),
                                 (k + 2, lambda r: r.d_hat, r"$\hat d$ (est. of $1/d_{2n}$)",
                                  truths[2])):
        axes[j].set_ylim(*_zoom_limits([get(r) for r in good], floor))
        axes[j].set_ylabel(label)
        _held_marks(axes[j], runs, [f"C{i}" for i in range(len(runs))])
    axes[-1].set_xlabel("t [s]")
    diverged = [r.label for r in runs if r.held.any()]
    fig.suptitle("Appendix C: adaptive output-feedback backstepping regulation of $q_1$ (C.50)\n"
                 "(thin: the other masses; dotted horizontal: true values"
                 + (";\ndotted vertical: controller holding — diverged: " + ", ".join(diverged)
                    if diverged else "") + ")")
    save(fig, out / f"{stem}.png", written)
    md = out / f"{stem}.md"
    md.write_text("### Appendix C: q_1 regulation\n\n"
                  + table([(r.label, chain_metrics(r)) for r in runs], CHAIN_COLUMNS))
    written.append(md)
    return written


# -- cr_analyze hooks --------------------------------------------------------------------
def session_figures(session: Any, out_dir: str | Path) -> list[Path]:
    """Chapter 4 / appendix C figures of a loaded session if it is one (else nothing)."""
    if is_force_run(session.status):
        return plot_force_run(force_from_session(session), out_dir)
    if is_chain_run(session.status):
        return plot_chains([chain_from_session(session)], out_dir)
    return []


def compare_sessions(sessions: Sequence[Any], labels: Sequence[str],
                     out_dir: str | Path) -> list[Path]:
    """Overlay the chapter 4 force sessions (and the appendix C sessions) among
    ``sessions`` when there are two or more of a kind."""
    force, chains = [], []
    for session, label in zip(sessions, labels, strict=True):
        if is_force_run(session.status):
            force.append(force_from_session(session))
            force[-1].label = label
        elif is_chain_run(session.status):
            chains.append(chain_from_session(session))
            chains[-1].label = label
    written: list[Path] = []
    if len(force) > 1:
        written += compare_force(force, out_dir)
    if len(chains) > 1:
        written += plot_chains(chains, out_dir)
    return written


# -- offline reproduction ----------------------------------------------------------------
#: The thesis's five cases: (label, scheme, controller overrides, plant overrides).
CASES = [
    ("case 1 (k_o = k_s = 20)", "backstepping_force", {}, {}),
    ("case 2 (k_o = k_s = 50)", "backstepping_force", {}, {"k_o": 50.0, "k_s": 50.0}),
    ("case 3 (k_o = k_s = 80)", "backstepping_force", {}, {"k_o": 80.0, "k_s": 80.0}),
    ("case 4 (no adaptation)", "backstepping_force", {"gamma": 0.0, "Gamma": [0.0] * 9}, {}),
    ("case 5 (MRAC)", "mrac_force", {}, {}),
]
CHAIN_SIZES = (1, 2, 3)


def offline_force(scheme: str, duration: float, controller: dict[str, Any] | None = None,
                  plant: dict[str, Any] | None = None, label: str | None = None) -> ForceRun:
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_control.offline import run_scheme

    result = run_scheme(scheme, duration, controller_overrides=controller, plant_overrides=plant)
    return force_from_offline(result, label or scheme, plant, controller)


def offline_chain(n: int, duration: float, plant: dict[str, Any] | None = None) -> ChainRun:
    # lazy: a session is read without loading the laws and plants (cr_control.analysis)
    from cr_control.offline import run_scheme

    plant = {**(plant or {}), "masses": n}
    result = run_scheme("cmmsd_backstepping", duration,
                        controller_overrides={"joint_names": [f"q{i + 1}" for i in range(n)]},
                        plant_overrides=plant)
    return chain_from_offline(result, f"n = {n}", plant)


def reproduce(out_dir: str | Path, duration: float = 100.0, chain_duration: float = 60.0,
              progress: Any = print) -> list[Path]:
    """Every chapter 4 case and the appendix C chains offline; figures and tables in
    ``out_dir`` (ch4_cases_1_3, ch4_case1_vs_case4, ch4_case1_vs_case5, per-case folders with
    the estimates, appC_chain, and ch4_comparison.md gathering every table)."""
    import time

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs: list[ForceRun] = []
    written: list[Path] = []
    for label, scheme, controller, plant in CASES:
        start = time.perf_counter()
        progress(f"chapter 4: {label}, {scheme}, {duration:g} s simulated ...")
        run = offline_force(scheme, duration, controller, plant, label)
        runs.append(run)
        written += plot_force_run(run, out / label.split(" (")[0].replace(" ", ""))
        progress(f"  done in {time.perf_counter() - start:.1f} s wall")
    c1 = runs[0]
    written += compare_force(runs[:3], out, "ch4_cases_1_3",
                             "Cases 1-3: backstepping on surfaces of growing stiffness "
                             "(figs. 4.2, 4.3)")
    written += compare_force([c1, runs[3]], out, "ch4_case1_vs_case4",
                             "Case 1 vs case 4: with and without adaptation (figs. 4.7, 4.8)")
    written += compare_force([c1, runs[4]], out, "ch4_case1_vs_case5",
                             "Case 1 vs case 5: backstepping vs MRAC (figs. 4.9, 4.10)")
    chains = []
    for n in CHAIN_SIZES:
        start = time.perf_counter()
        progress(f"appendix C: n = {n} masses, {chain_duration:g} s simulated ...")
        chains.append(offline_chain(n, chain_duration))
        progress(f"  done in {time.perf_counter() - start:.1f} s wall")
    written += plot_chains(chains, out)
    summary = out / "ch4_comparison.md"
    summary.write_text(
        "### Chapter 4: all five cases\n\n"
        + table([(r.label, force_metrics(r)) for r in runs], FORCE_COLUMNS) + "\n"
        + FORCE_NOTE + "\n\n" + (out / "appC_chain.md").read_text())
    written.append(summary)
    return written


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m cr_control.analysis.chapter4 OUT_DIR [DURATION [CHAIN_DURATION]]``: the
    five cases of section 4.3 (default 100 s each: the plant is lightly damped and the
    K-filters' slowest mode is ~59 s) and the appendix C chain for n = 1, 2, 3 (default 60 s)
    offline; writes the figures and ch4_comparison.md into OUT_DIR and prints the table."""
    import sys

    args = sys.argv[1:] if argv is None else list(argv)
    if not args or args[0] in ("-h", "--help"):
        print(main.__doc__)
        return 0 if args else 2
    duration = float(args[1]) if len(args) > 1 else 100.0
    chain = float(args[2]) if len(args) > 2 else 60.0
    written = reproduce(args[0], duration, chain, progress=lambda s: print(s, flush=True))
    print(written[-1].read_text())
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
