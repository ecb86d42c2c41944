"""The wiping task judged as a robot user judges it: by the true contact force and the path.

One case runs a task-space scheme on a robot profile (:mod:`cr_control.robots`) in the
offline loop at the profile's rate with its driver's transport delay (``plant`` may set
the plant node's ``command_delay_cycles`` and ``late_burst_*``), with ``node_limits`` the plant
node's command limits too, optionally on a 10x stiffer table, started ``clearance`` above it,
with the controller's model scaled, or with the controller's
gravity setting the opposite of the robot's (a mismatch). Its figures (:func:`wiping_metrics`):

- force error mean and RMS (N): the true normal force f_n (the plant's contact force along
  the table's normal) against the desired normal force, over the second half of the run;
- radial path RMS (m): | |r - c_d| - a_d | over the second half (r the measured tip: on a
  position or velocity interface the robot's, not the law's virtual arm's), with c_d, a_d the circle
  the reference r_d draws (a least-squares circle through r_d in the table's plane), the
  centre error |c - c_d| (m), c the circle fitted to the measured path r, and the path
  error RMS |r - r_d| in the plane (m: a tool stuck on the circle has a small radial error
  but not this);
- impact speed (m/s): the tip's speed into the table when f_n first exceeds 0, the force
  peak (N) over the run, the time without contact after the first touch (s), and the
  sideways drift before contact (m: the tip's largest distance in the table's plane from
  where it started);
- the start check: whether and when the controller gave up, and the largest joint speed
  (fraction of its URDF velocity limit) with the joint that reached it (1-based);
- the longest run of cycles in which a joint's command sat at its URDF effort limit, and the
  plant's safe stop (its reason, 0: none; the time it began);
- the driver's late bursts (:mod:`cr_sim.transport_delay`): how many began, how many of them
  in the judged second half, and the fraction of the cycles they held the last command.
  :func:`late_bursts` gives the plant overrides of bursts lasting 20-70 ms on a fraction of
  the cycles (``--late-fraction``).

``python -m cr_control.experiments.wiping`` prints the table of every scheme on every profile
(default and stiff table) and the mismatch cases.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from cr_control import offline, robots

#: The stiff table: this many times the default contact stiffness.
STIFF_FACTOR = 10.0
#: Late bursts last this long (s), drawn uniformly (a Python controller on a loaded machine).
LATE_BURST_S = (0.020, 0.070)


def late_bursts(robot: str, fraction: float, seed: int) -> tuple[tuple[str, Any], ...]:
    """The plant node's overrides for late bursts of LATE_BURST_S on about ``fraction`` of
    ``robot``'s cycles: in its cycles (20-70 at 1 kHz, 10-35 at 500 Hz), each cycle outside
    a burst starting one with probability p = fraction / (L (1 - fraction)), L the mean
    length (the expected share of cycles in a burst is p L / (1 + p L) = ``fraction``)."""
    rate = robots.robot(robot).rate_hz
    low, high = (max(1, round(s * rate)) for s in LATE_BURST_S)
    p = fraction / (0.5 * (low + high) * (1.0 - fraction))
    return (("late_burst_probability", p), ("late_burst_min_cycles", low),
            ("late_burst_max_cycles", high), ("late_burst_seed", int(seed)))


@dataclass(frozen=True)
class Case:
    """One wiping run (module docstring)."""

    scheme: str
    robot: str
    table: str = "default"          # or "stiff"
    clearance: float = 0.0          # m above the table at the start
    model_scale: float = 1.0        # the controller's masses and inertias times this
    mismatch: bool = False          # the controller's gravity setting opposite the robot's
    duration: float = 8.0
    controller: tuple = ()          # extra controller overrides ((name, value), ...)
    plant: tuple = ()               # extra plant (and plant node) overrides
    node_limits: bool = False       # the plant node's effort and torque-rate limits too

    def overrides(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """(controller, plant) overrides of the case."""
        c: dict[str, Any] = dict(self.controller)
        p: dict[str, Any] = dict(self.plant)
        if self.table == "stiff":
            p["stiffness"] = robots.TABLE_STIFFNESS * STIFF_FACTOR
        if self.clearance:
            p["start_clearance"] = self.clearance
        if self.model_scale != 1.0:
            c.update(model_mass_scale=self.model_scale, model_inertia_scale=self.model_scale)
        if self.mismatch:
            c["robot_compensates_gravity"] = not robots.robot(self.robot).robot_compensates_gravity
        return c, p


def circle_fit(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares circle (Kasa fit) through the points ``xy`` (k x 2): centre, radius."""
    A = np.column_stack([2.0 * xy, np.ones(len(xy))])
    b = np.sum(xy * xy, axis=1)
    (cx, cy, c), *_ = np.linalg.lstsq(A, b, rcond=None)
    return np.array([cx, cy]), math.sqrt(max(c + cx * cx + cy * cy, 0.0))


def wiping_metrics(run: offline.OfflineRun, controller: Any) -> dict[str, float]:
    """The case's figures (module docstring) from an offline run on a table of normal +z."""
    t = run.time
    f_n = run.true_force[:, 2]
    f_d = run.column("f_d_z")
    r = np.column_stack([run.column("r_x"), run.column("r_y")])
    tip = getattr(controller, "tip_positions", None)      # the outer loop's: the real tip
    if callable(tip):
        r = tip(run.position[:, :len(controller.state_joint_names)])[:, :2]
    r_d = np.column_stack([run.column("r_d_x"), run.column("r_d_y")])
    late = t >= t[0] + 0.5 * (t[-1] - t[0])
    out: dict[str, float] = {}
    error = f_n[late] - f_d[late]
    out["force_err_mean_N"] = float(np.mean(error))
    out["force_err_rms_N"] = float(np.sqrt(np.mean(error * error)))
    c_d, a_d = circle_fit(r_d[late])
    c, _ = circle_fit(r[late])
    radial = np.linalg.norm(r[late] - c_d, axis=1) - a_d
    out["radial_rms_m"] = float(np.sqrt(np.mean(radial * radial)))
    out["centre_err_m"] = float(np.linalg.norm(c - c_d))
    path = np.linalg.norm(r[late] - r_d[late], axis=1)
    out["path_err_rms_m"] = float(np.sqrt(np.mean(path * path)))
    touched = np.flatnonzero(f_n > 0.0)
    first = int(touched[0]) if touched.size else len(t)
    out["impact_speed_m_s"] = float(max(-run.column("v_z")[first], 0.0)) if touched.size else math.nan
    out["force_peak_N"] = float(np.max(f_n))
    period = float(np.median(np.diff(t)))
    out["contact_lost_s"] = float(np.sum(f_n[first:] <= 0.0) * period)
    drift = np.linalg.norm(r[:max(first, 1)] - r[0], axis=1)
    out["drift_before_contact_m"] = float(np.max(drift))
    n = len(controller.state_joint_names)
    limits = controller.model.limits[2 * n:3 * n]
    speed = np.abs(run.velocity[:, :n]) / np.where(np.isfinite(limits), limits, np.inf)
    out["joint_speed_max_fraction"] = float(np.max(speed))
    out["joint_speed_worst"] = float(np.argmax(np.max(speed, axis=0)) + 1)
    out["torque_limit_run_cycles"] = float(longest_run(
        np.any(np.abs(run.command) >= controller.command_limits * (1.0 - 1e-12), axis=1)))
    out["safe_stop_reason"] = float(run.safe_stop_reason)
    out["safe_stop_at_s"] = float(run.safe_stop_at)
    out["gave_up"] = float(controller.gave_up)
    return out


def longest_run(flags: np.ndarray) -> int:
    """The longest run of consecutive True values in ``flags``."""
    best = current = 0
    for flag in flags:
        current = current + 1 if flag else 0
        best = max(best, current)
    return best


def run_case(case: Case) -> tuple[dict[str, float], list[str]]:
    """Run ``case``: its figures and the controller's error lines (the start check's)."""
    c, p = case.overrides()
    controller, plant = offline.build_scheme(case.scheme, c, p, case.robot)
    errors: list[str] = []
    controller.log_error = errors.append
    controller.log_warning = controller.log_info = lambda message: None
    gave_up_at: list[float] = []

    def watch(k: int, t: float, ctl: Any, _plant: Any) -> None:
        if ctl.gave_up and not gave_up_at:
            gave_up_at.append(t)

    period = offline.robot_period(case.robot)
    limiter = (offline.build.node_limiter(plant, case.scheme, case.robot, p, period)
               if case.node_limits else None)
    delay = offline.build.node_delay(case.scheme, case.robot, p)
    bursts_at: list[float] = []

    def count(k: int, t: float, ctl: Any, plant_: Any) -> None:
        watch(k, t, ctl, plant_)
        if delay.bursts > len(bursts_at):        # the burst drawn at the step before
            bursts_at.append(t)

    run = offline.run(controller, plant, case.duration, period, count, limiter=limiter,
                      delay=delay)
    values = wiping_metrics(run, controller)
    values["gave_up_at_s"] = gave_up_at[0] if gave_up_at else math.nan
    half = run.time[0] + 0.5 * (run.time[-1] - run.time[0])
    values["late_bursts"] = float(delay.bursts)
    values["late_bursts_judged"] = float(sum(t >= half for t in bursts_at))
    values["late_fraction"] = delay.late_cycles / len(run.time)
    return values, errors


#: (figure, column head, scale, decimals) of the printed table.
COLUMNS = [("force_err_mean_N", "F err mean N", 1.0, 3), ("force_err_rms_N", "F err RMS N", 1.0, 3),
           ("radial_rms_m", "radial RMS mm", 1e3, 2), ("centre_err_m", "centre mm", 1e3, 2),
           ("path_err_rms_m", "path RMS mm", 1e3, 2),
           ("impact_speed_m_s", "impact m/s", 1.0, 3), ("force_peak_N", "F peak N", 1.0, 2),
           ("contact_lost_s", "lost s", 1.0, 3), ("drift_before_contact_m", "drift mm", 1e3, 2),
           ("joint_speed_max_fraction", "max q'/limit", 1.0, 2),
           ("joint_speed_worst", "joint", 1.0, 0),
           ("torque_limit_run_cycles", "at limit cycles", 1.0, 0),
           ("safe_stop_at_s", "reflex s", 1.0, 2), ("late_bursts", "late bursts", 1.0, 0),
           ("late_fraction", "late %", 100.0, 1)]


def _cell(value: float, scale: float, decimals: int) -> str:
    return f"{value * scale:.{decimals}f}" if math.isfinite(value) else "-"


def table(cases: list[Case], progress: bool = True) -> str:
    """A markdown table of ``cases``."""
    head = ["scheme", "robot", "table", "clear. m", "model"] + [c[1] for c in COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for i, case in enumerate(cases):
        if progress:
            print(f"[{i + 1}/{len(cases)}] {case.scheme} on {case.robot} ({case.table})",
                  file=sys.stderr, flush=True)
        values, _ = run_case(case)
        row = [case.scheme, case.robot, case.table, f"{case.clearance:g}", f"{case.model_scale:g}"]
        row += [_cell(values[k], s, d) for k, _, s, d in COLUMNS]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m cr_control.experiments.wiping",
                                description="The wiping task on every profile (module docstring).")
    p.add_argument("--schemes", default=",".join(robots.TASK_SPACE_SCHEMES))
    p.add_argument("--robots", default=",".join(robots.ROBOTS))
    p.add_argument("--tables", default="default,stiff")
    p.add_argument("--clearance", type=float, default=0.0)
    p.add_argument("--model-scale", type=float, default=1.0)
    p.add_argument("--duration", type=float, default=8.0)
    p.add_argument("--delay", type=int, default=None,
                   help="the driver's transport delay (cycles; the plant's command_delay_cycles; "
                        "default: the profile's)")
    p.add_argument("--late-fraction", type=float, default=0.0,
                   help="late bursts of 20-70 ms on about this fraction of the cycles "
                        "(late_bursts; default 0: none)")
    p.add_argument("--seed", type=int, default=0, help="the late bursts' seed")
    p.add_argument("--node-limits", action="store_true",
                   help="with the plant node's effort and torque-rate limits")
    args = p.parse_args(argv)
    try:
        if not 0.0 <= args.late_fraction < 1.0:
            raise ValueError(f"--late-fraction {args.late_fraction}: 0 <= fraction < 1")
        cases = [Case(s, r, tb, args.clearance, args.model_scale, duration=args.duration,
                      plant=(() if args.delay is None else
                             (("command_delay_cycles", args.delay),))
                      + (late_bursts(r, args.late_fraction, args.seed)
                         if args.late_fraction > 0.0 else ()),
                      node_limits=args.node_limits)
                 for s in args.schemes.split(",") for r in args.robots.split(",")
                 for tb in args.tables.split(",")]
        for case in cases:
            robots.robot(case.robot)
            if case.scheme not in robots.TASK_SPACE_SCHEMES:
                raise ValueError(f"{case.scheme} is not a task-space scheme")
    except ValueError as exc:
        print(f"wiping: {exc}", file=sys.stderr)
        return 2
    print(table(cases))
    return 0


if __name__ == "__main__":
    sys.exit(main())
