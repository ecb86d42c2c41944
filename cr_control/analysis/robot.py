"""Robot sessions: a task-space scheme on a URDF arm (Panda, UR5) wiping a table.

A robot session (``cr_session --robot NAME``, :mod:`cr_control.robots`) keeps a normal
force on a plane through the tool's start position (normal +z) while tracking a circle in
it. Its status has a z axis and the orientation error ``e_rot_*`` (see
:func:`cr_control.schemes.blocks.task_space.status_fields`); :func:`is_robot` tells such a
session. What :func:`robot_metrics` adds to :func:`cr_control.analysis.analyze.metrics`
(SI units unless the key says otherwise; "last half" = the second half of the status's
time span; time zero = the first status stamp):

- ``normal_force_mean_last_half_N``: mean of the normal force f_n = n . f (N) over the
  last half, n the table's unit normal (the status ``n_x/y/z`` of the chapter 5 schemes,
  else +z: then f_n is f_z) and f the plant's true contact force
  (``/plant/contact_wrench``) where it was recorded: force control is judged by the true
  force, never by the sensor alone (a wrist sensor reads in its own frame, with the tool's
  weight and a bias). Else the measured force of the wrench topic, at its full rate (the
  status may be decimated, to 100 Hz in real time), else of the status;
  ``force_source`` says which (``contact_wrench``, ``wrench``, ``status``);
- ``normal_force_err_rms_last_half_N``: RMS of f_n - f_d,n (N) over the last half, f_d,n
  = n . f_d from the reference topic (f_d_z for the table) at the force's stamps;
- ``path_err_rms_last_half_m`` / ``path_err_max_last_half_m``: RMS / max of the in-plane
  position error |e - (e . n) n| (m) over the last half: sqrt(e_x^2 + e_y^2) for the table.
  (``pos_err_*`` of the metrics include e along the normal, which holds the penetration
  and, for the chapter 3 schemes, the force admittance's offset of the reference);
- ``contact_lost_s``: total time (s) with f_n <= 0 after the first CONTACT_GRACE_S (50 ms;
  the tool starts touching at zero force), each force sample counting until the next one;
- ``orientation_err_max_deg``: largest rotation angle |e_rot| of the orientation error
  log(R_d R^T) (degrees);
- ``posture_err_max_rad``: largest null-space posture error (rad; redundant arms only);
- ``singularity_damping_max``: largest lambda^2 (1/kg) the task's generalised inverse was
  damped with near a singularity (0: never).

:func:`session_figures` draws a robot session: ``path_3d.png`` (desired and actual tip path
with the table plane), ``path_top.png`` (top view on the plane and the in-plane error),
``normal_force.png`` (with the contact-lost intervals shaded) and ``orientation.png``
(orientation, posture error, singularity damping). :func:`compare_panels` gives the
panels of ``compare_robot.png`` for :func:`cr_control.analysis.analyze.compare`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from cr_control.analysis.figures import column_figure
from cr_control.analysis.figures import save_figure as _save

AXES = ("x", "y", "z")
#: Status fields of a robot session (beyond at least one ``e_rot_*``).
REQUIRED = tuple(f"{q}_{a}" for q in ("r", "e", "f") for a in AXES)
#: Contact is judged from this long after the first sample on (s).
CONTACT_GRACE_S = 0.05
_UP = np.array([0.0, 0.0, 1.0])
#: (time, values, style) per line of a comparison panel (see plots._overlay).
Lines = list[tuple[np.ndarray, np.ndarray, str]]


def position_axes(fields: Any) -> tuple[str, ...]:
    """x, y, and z when ``fields`` (a status or its names) carry a z axis."""
    return AXES if "r_z" in fields or "e_z" in fields else AXES[:2]


def error_norm(status: dict[str, np.ndarray]) -> np.ndarray:
    """|e| over the position axes per sample (m): sqrt(e_x^2 + e_y^2 [+ e_z^2])."""
    axes = position_axes(status)
    if len(axes) == 2:
        return np.hypot(status["e_x"], status["e_y"])
    return np.sqrt(sum(np.square(status[f"e_{a}"]) for a in axes))


def is_robot(status: dict[str, np.ndarray]) -> bool:
    """True for a status with a z axis and orientation fields (a task-space scheme on a
    spatial arm), with samples."""
    return (all(name in status for name in REQUIRED) and len(status.get("stamp", ())) > 0
            and any(f"e_rot_{a}" in status for a in AXES))


# -- the quantities ----------------------------------------------------------------------

def _stack(series: dict[str, np.ndarray], prefix: str) -> np.ndarray:
    return np.column_stack([series[f"{prefix}{a}"] for a in AXES])


def _at(series: dict[str, np.ndarray], name: str, t: np.ndarray) -> np.ndarray:
    """``series[name]`` at stamps ``t``: as is where the stamps are the same, else linearly
    interpolated (held beyond the ends)."""
    if len(series["stamp"]) == len(t) and np.array_equal(series["stamp"], t):
        return series[name]
    return np.interp(t, series["stamp"], series[name])


def normals(status: dict[str, np.ndarray], t: np.ndarray | None = None) -> np.ndarray:
    """(k, 3) unit table normal at stamps ``t`` (default: the status's): ``n_*`` normalised
    if the status has it (and it is not zero), else +z."""
    t = status["stamp"] if t is None else t
    up = np.broadcast_to(_UP, (len(t), 3))
    if not all(f"n_{a}" in status for a in AXES):
        return up.copy()
    n = np.column_stack([_at(status, f"n_{a}", t) for a in AXES])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 0.0, n / np.where(norm > 0.0, norm, 1.0), up)


def normal_force(session: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(stamps, f_n, f_d,n): the contact force and the desired one along the table normal (N).

    The contact force is the plant's true one (``/plant/contact_wrench``) if recorded, else
    the wrench topic's (the sensor's full rate: the status may be decimated, e.g. to 100 Hz
    in real time), else the status's (:func:`force_source`); f_d,n = n . f_d from the
    reference at those stamps, None without a desired force.
    """
    status, ref = session.status, session.reference
    source = force_source(session)
    if source == "status":
        t, f = status["stamp"], _stack(status, "f_")
    else:
        series = getattr(session, source)
        t, f = series.time, series.force
    n = normals(status, t)
    f_n = np.sum(f * n, axis=1)
    if not (len(ref.get("stamp", ())) and all(f"f_d_{a}" in ref for a in AXES)):
        return t, f_n, None
    f_d = np.column_stack([_at(ref, f"f_d_{a}", t) for a in AXES])
    return t, f_n, np.sum(f_d * n, axis=1)


def force_source(session: Any) -> str:
    """Where the contact force is judged from: ``contact_wrench`` (the plant's true one),
    else ``wrench`` (the sensor topic), else ``status`` (what the law was given)."""
    for name in ("contact_wrench", "wrench"):
        series = getattr(session, name, None)
        if series is not None and len(series.time):
            return name
    return "status"


def in_plane_error(status: dict[str, np.ndarray]) -> np.ndarray:
    """|e - (e . n) n| per sample (m): the path error in the table's plane."""
    e, n = _stack(status, "e_"), normals(status)
    return np.linalg.norm(e - np.sum(e * n, axis=1, keepdims=True) * n, axis=1)


def orientation_error_deg(status: dict[str, np.ndarray]) -> np.ndarray:
    """Rotation angle of the orientation error per sample (degrees)."""
    rot = np.column_stack([status[f"e_rot_{a}"] for a in AXES if f"e_rot_{a}" in status])
    return np.degrees(np.linalg.norm(rot, axis=1))


def contact_lost_intervals(t: np.ndarray, f_n: np.ndarray, since: float | None = None,
                           ) -> list[tuple[float, float]]:
    """[start, end) intervals (on ``t``'s clock) with f_n <= 0 from ``since`` on (default
    t[0] + CONTACT_GRACE_S). A sample holds until the next one (the last for the median
    sample period)."""
    if not len(t):
        return []
    since = t[0] + CONTACT_GRACE_S if since is None else since
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    ends = np.append(t[1:], t[-1] + period)
    lost = (f_n <= 0.0) & (t >= since)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], lost.astype(np.int8), [0]])))
    return [(float(t[a]), float(ends[b - 1])) for a, b in zip(edges[::2], edges[1::2],
                                                                strict=True)]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def robot_metrics(session: Any) -> dict[str, float]:
    """The wiping task's figures of merit of a robot session (module docstring); empty if
    the session is not one (:func:`is_robot`)."""
    status = session.status
    if not is_robot(status):
        return {}
    t = status["stamp"]
    middle = t[0] + 0.5 * (t[-1] - t[0])
    t_f, f_n, f_d = normal_force(session)
    late = t_f >= middle
    out: dict[str, Any] = {"normal_force_mean_last_half_N": float(np.mean(f_n[late])),
                           "force_source": force_source(session)}
    if f_d is not None:
        out["normal_force_err_rms_last_half_N"] = _rms(f_n[late] - f_d[late])
    path = in_plane_error(status)[t >= middle]
    out["path_err_rms_last_half_m"] = _rms(path)
    out["path_err_max_last_half_m"] = float(np.max(path))
    lost = contact_lost_intervals(t_f, f_n, since=t[0] + CONTACT_GRACE_S)
    out["contact_lost_s"] = float(sum(b - a for a, b in lost))
    out["orientation_err_max_deg"] = float(np.max(orientation_error_deg(status)))
    if "posture_error" in status:
        out["posture_err_max_rad"] = float(np.max(status["posture_error"]))
    if "singularity_damping" in status:
        out["singularity_damping_max"] = float(np.max(status["singularity_damping"]))
    return out


# -- figures -----------------------------------------------------------------------------

def plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane of normal ``n``: x and y for n = +z."""
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = ref - np.dot(ref, n) * n
    a /= np.linalg.norm(a)
    return a, np.cross(n, a)


def _paths(session: Any) -> dict[str, Any]:
    """Actual and desired tip path (mm from the start), the normal and the plane's axes."""
    status, ref = session.status, session.reference
    start = _stack(status, "r_")[0]
    n = normals(status)[0]
    a, b = plane_basis(n)
    vertical = n[2] > 0.999       # then the plane axes are x and y
    paths = {"actual": 1e3 * (_stack(status, "r_") - start), "start": start, "n": n,
             "a": a, "b": b, "labels": ("x − x₀", "y − y₀") if vertical else ("u", "v")}
    if all(f"r_d_{ax}" in ref for ax in AXES) and len(ref.get("stamp", ())):
        paths["desired"] = 1e3 * (_stack(ref, "r_d_") - start)
    return paths


def _figure_3d(session: Any, out: Path, written: list[Path]) -> None:
    # lazy: no plotting cost where no figure is drawn
    from matplotlib.figure import Figure

    p = _paths(session)
    fig = Figure(figsize=(7.5, 6.5), layout="constrained")
    ax = fig.add_subplot(projection="3d")
    curves = [p["actual"]] + ([p["desired"]] if "desired" in p else [])
    points = np.concatenate(curves)
    u, v = points @ p["a"], points @ p["b"]
    pad = 0.15 * max(np.ptp(u), np.ptp(v), 1.0)
    U, V = np.meshgrid(np.linspace(u.min() - pad, u.max() + pad, 2),
                       np.linspace(v.min() - pad, v.max() + pad, 2))
    plane = U[..., None] * p["a"] + V[..., None] * p["b"]
    ax.plot_surface(plane[..., 0], plane[..., 1], plane[..., 2], color="tab:gray", alpha=0.2,
                    label="table plane")
    if "desired" in p:
        ax.plot(*p["desired"].T, "k--", lw=0.9, label="desired")
    ax.plot(*p["actual"].T, color="C0", lw=1.2, label="actual")
    ax.scatter([0.0], [0.0], [0.0], color="k", s=15, label="start")
    ax.set_xlabel("x − x₀ [mm]")
    ax.set_ylabel("y − y₀ [mm]")
    ax.set_zlabel("z − z₀ [mm]")
    ax.set_box_aspect((1.0, 1.0, 0.6))
    x0, n = np.round(p["start"], 3) + 0.0, np.round(p["n"], 2) + 0.0
    fig.suptitle(f"{session.name}: tip path [mm] from the start ({x0[0]:.3f}, {x0[1]:.3f}, "
                 f"{x0[2]:.3f}) m\ntable plane through the start, normal ({n[0]:.2f}, "
                 f"{n[1]:.2f}, {n[2]:.2f}); z not to scale")
    _save(fig, out / "path_3d.png", written)


def _figure_top(session: Any, out: Path, written: list[Path]) -> None:
    # lazy: no plotting cost where no figure is drawn
    from matplotlib.figure import Figure

    p = _paths(session)
    fig = Figure(figsize=(11.0, 5.0), layout="constrained")
    top, err = fig.subplots(1, 2, width_ratios=(1.0, 1.3))
    if "desired" in p:
        top.plot(p["desired"] @ p["a"], p["desired"] @ p["b"], "k--", lw=0.9, label="desired")
    top.plot(p["actual"] @ p["a"], p["actual"] @ p["b"], color="C0", lw=1.2, label="actual")
    top.plot([0.0], [0.0], "ko", ms=4, label="start")
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel(f"{p['labels'][0]} [mm]")
    top.set_ylabel(f"{p['labels'][1]} [mm]")
    top.set_title("top view on the table plane")
    status = session.status
    t = session.relative_time(status["stamp"])
    err.plot(t, 1e3 * in_plane_error(status), label="in-plane |e_∥|")
    e_n = np.sum(_stack(status, "e_") * normals(status), axis=1)
    err.plot(t, 1e3 * e_n, lw=0.8, label="along the normal e·n")
    err.set_xlabel("t [s]")
    err.set_ylabel("position error [mm]")
    err.set_title("path error (e = r_d − r)")
    fig.suptitle(f"{session.name}: tip path on the table [mm from the start]")
    _save(fig, out / "path_top.png", written)


def _figure_force(session: Any, out: Path, written: list[Path]) -> None:
    t0 = session.status["stamp"][0]
    t_abs, f_n, f_d = normal_force(session)
    t, shift = session.relative_time(t_abs), session.relative_time(np.array([t0]))[0] - t0
    intervals = [(a + shift, b + shift)
                 for a, b in contact_lost_intervals(t_abs, f_n, since=t0 + CONTACT_GRACE_S)]
    lost = sum(b - a for a, b in intervals)
    fig, axes = column_figure(2 if f_d is not None else 1, 2.6)
    source = force_source(session)
    axes[0].plot(t, f_n, label="f_n (true contact)" if source == "contact_wrench"
                 else "f_n (measured)")
    if f_d is not None:
        axes[0].plot(t, f_d, "k--", lw=0.9, label="f_d,n (desired)")
        axes[1].plot(t, f_n - f_d, label="f_n − f_d,n")
        axes[1].set_ylabel("force error [N]")
    for ax in axes:
        ax.axhline(0.0, color="k", lw=0.5)
        for i, (a, b) in enumerate(intervals):
            ax.axvspan(a, b, color="red", alpha=0.2,
                       label="contact lost (f_n ≤ 0)" if i == 0 and ax is axes[0] else None)
    axes[0].set_ylabel("normal force f_n [N]")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{session.name}: normal force [N]; shaded: contact lost, "
                 f"{1e3 * lost:.0f} ms (after {1e3 * CONTACT_GRACE_S:.0f} ms)")
    _save(fig, out / "normal_force.png", written)


def _figure_orientation(session: Any, out: Path, written: list[Path]) -> None:
    status = session.status
    t = session.relative_time(status["stamp"])
    panels = ["orientation"] + ["posture"] * ("posture_error" in status)
    if "singularity_damping" in status and np.any(status["singularity_damping"] > 0.0):
        panels.append("singularity")
    fig, axes = column_figure(len(panels), 2.3)
    for ax, panel in zip(axes, panels, strict=True):
        if panel == "orientation":
            ax.plot(t, orientation_error_deg(status), "k", lw=1.0, label="|e_rot|")
            for a in AXES:
                if f"e_rot_{a}" in status:
                    ax.plot(t, np.degrees(status[f"e_rot_{a}"]), lw=0.8, label=f"e_rot_{a}")
            ax.set_ylabel("orientation error [deg]")
        elif panel == "posture":
            ax.plot(t, status["posture_error"], label="posture error |N_s^T (q_p − q)|")
            ax.set_ylabel("posture error [rad]")
        else:
            ax.plot(t, status["singularity_damping"], label="λ²")
            ax.set_ylabel("singularity damping [1/kg]")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{session.name}: orientation error [deg]"
                 + (" and null-space posture error [rad]" if "posture" in panels else ""))
    _save(fig, out / "orientation.png", written)


def session_figures(session: Any, out_dir: str | Path) -> list[Path]:
    """A robot session's figures (module docstring) as PNG in ``out_dir`` (else nothing)."""
    if not is_robot(session.status):
        return []
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    _figure_3d(session, out, written)
    _figure_top(session, out, written)
    _figure_force(session, out, written)
    _figure_orientation(session, out, written)
    return written



def compare_panels() -> list[tuple[str, Callable[[Any], Lines]]]:
    """(y label, lines of a session) per panel of ``compare_robot.png``: normal force (with
    the desired one dashed), in-plane path error, orientation error; no lines for a
    session that is not a robot one."""
    def force(s: Any) -> Lines:
        if not is_robot(s.status):
            return []
        t, f_n, f_d = normal_force(s)
        return [(t, f_n, "first")] + ([(t, f_d, "desired")] if f_d is not None else [])

    def path(s: Any) -> Lines:
        return [(s.status["stamp"], 1e3 * in_plane_error(s.status), "first")] if is_robot(
            s.status) else []

    def orientation(s: Any) -> Lines:
        return [(s.status["stamp"], orientation_error_deg(s.status), "first")] if is_robot(
            s.status) else []

    return [("normal force f_n [N]", force), ("in-plane path error [mm]", path),
            ("orientation error [deg]", orientation)]

