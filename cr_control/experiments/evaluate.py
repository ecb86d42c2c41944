"""One point of a sweep: the offline loop, then the metrics ``cr_analyze`` prints.

The run is :func:`cr_control.offline.run` (bit-for-bit deterministic) of the scheme and
plant :func:`cr_control.offline.build_scheme` makes; its columns are handed to
:func:`cr_control.analysis.analyze.metrics` as a session would be, so every metric has the
name and the definition of ``cr_analyze``'s (e.g. ``pos_err_rms_last_half_m``); a robot's
run is judged, as ``cr_analyze`` judges a robot session, by the plant's true contact force
(the wrist sensor reads in its own frame, with the tool's weight and a bias); a thesis plant's
run also gets its chapter's own figures (:mod:`.chapter_metrics`: chapters 2, 4, 6 and
appendix C) and the robot sessions' ``contact_lost_s`` (time with no contact force, |f| as the
normal force, after the first CONTACT_GRACE_S) and ``command_at_limit_s`` (time some command
sat at its clip: max_effort or the URDF effort). Left out:
figures of the wall clock (``compute_time_*``: they differ from run to run) and of a
recording's bookkeeping (publishers, stamps, sample counts).

Status of a point (a stated rule):
- ``failed``: the scheme or plant could not be built or stepped (the reason: the error);
- ``stopped``: the plant's supervision safe-stopped it (a reflex: the contact force above
  the plant's ``max_contact_force``, a joint faster than its URDF limit), as a lockstep
  session of the same settings stops (the reason: the reflex's line and its time; the
  metrics are those of the run braked from then on);
- ``diverged``: a state, force, command or status value became non-finite, or a joint
  position or velocity norm went beyond the controller's own ``max_joint_position`` /
  ``max_joint_velocity`` (states it would hold as absurd);
- ``ok`` otherwise.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cr_control import offline
from cr_control.analysis import analyze, chapter5, robot
from cr_control.experiments import chapter_metrics
from cr_control.schemes.registry import default_scenario
from cr_sim.plants.registry import SCENARIOS

#: Metrics of a recording's bookkeeping or of the wall clock: not figures of a point.
LEFT_OUT = ("controller", "samples", "duration_s", "data_warnings")
LEFT_OUT_PREFIXES = ("compute_time_", "publishers_", "stamps_", "loop_")


def as_session(run: offline.OfflineRun, scheme: str, command_names: list[str],
               true_force: bool = False) -> analyze.Session:
    """The offline run as a loaded session: the controller's status and reference, the
    joint states, the commands (efforts) and the measured wrench, stamped with run time;
    with ``true_force`` also the plant's true contact force (``/plant/contact_wrench`` of a
    robot session, which ``cr_analyze`` judges the normal force by: a wrist sensor reads in
    its own frame, with the tool's weight and a bias)."""
    status = {"stamp": run.time, **{n: run.column(n) for n in run.status_fields[1:]}}
    reference = {"stamp": run.time, **{n: run.column(n) for n in run.reference_fields[1:]}}
    commands = analyze.JointSeries(run.time, list(command_names), np.full_like(run.command, np.nan),
                                   np.full_like(run.command, np.nan), run.command)
    wrench = analyze.WrenchSeries(run.time, run.force, np.zeros_like(run.force))
    contact = None
    if true_force and run.true_force is not None and np.isfinite(run.true_force).all():
        contact = analyze.WrenchSeries(run.time, run.true_force, np.zeros_like(run.true_force))
    return analyze.Session(Path(f"{scheme}.mcap"), controller=scheme, status=status,
                           reference=reference, joint_commands=commands, wrench=wrench,
                           contact_wrench=contact)


def point_metrics(run: offline.OfflineRun, scheme: str, command_names: list[str],
                  true_force: bool = False) -> dict[str, float]:
    """``cr_analyze``'s metrics of ``run`` (see the module docstring for what is left out;
    ``true_force``: see :func:`as_session`)."""
    values = analyze.metrics(as_session(run, scheme, command_names, true_force))
    if "contact_lost_s" not in values and len(run.time):
        # the robot sessions' metric (cr_control.analysis.robot) on a thesis plant, with |f|
        # as the normal force: a unilateral contact presses or is lost
        lost = robot.contact_lost_intervals(run.time, np.linalg.norm(run.force, axis=1))
        values["contact_lost_s"] = float(sum(b - a for a, b in lost))
    return {k: float(v) for k, v in values.items()
            if k not in LEFT_OUT and not k.startswith(LEFT_OUT_PREFIXES)
            and isinstance(v, (int, float))}


def chapter5_metrics(run: offline.OfflineRun, scheme: str, controller_values: dict[str, Any],
                     plant_overrides: dict[str, Any]) -> dict[str, float]:
    """``cr_analyze``'s chapter 5 figures (:func:`cr_control.analysis.chapter5.contact_metrics`:
    separation time, force after the disturbance...), those whose names the generic metrics
    do not already use."""
    values = chapter5.contact_metrics(chapter5.from_offline(run, scheme, controller_values,
                                                            plant_values(scheme, plant_overrides)))
    return {k: float(v) for k, v in values.items() if k not in ("pos_err_rms_m",)}


def plant_values(scheme: str, plant_overrides: dict[str, Any]) -> dict[str, Any]:
    """The thesis plant's parameter values of an offline run of ``scheme``: the scenario's
    defaults, the registry's thesis settings, then ``plant_overrides``."""
    values = {p.name: p.default for p in SCENARIOS[default_scenario(scheme)][0]}
    values.update(offline.scheme_plant_overrides(scheme, plant_overrides))
    return values


def at_limit_seconds(run: offline.OfflineRun, controller: Any, plant_joints: list[str]) -> float:
    """Time (s) some command sat at its clip: +-max_effort, or the joint's URDF effort where
    the scheme clips to it (``Controller.command_limits``)."""
    limits = np.minimum(float(controller.values["max_effort"]), controller.command_limits)
    order = list(controller.values["joint_names"]) or plant_joints
    per_plant = np.array([limits[order.index(j)] if j in order else np.inf for j in plant_joints])
    hit = (np.abs(run.command) >= per_plant * (1 - 1e-9)).any(axis=1)
    period = float(np.median(np.diff(run.time))) if len(run.time) > 1 else 0.0
    return float(hit.sum() * period)


def divergence(run: offline.OfflineRun, controller_values: dict[str, Any]) -> str:
    """Why ``run`` diverged ('' if it did not; the rule of the module docstring)."""
    for name in ("position", "velocity", "force", "command", "status"):
        values = getattr(run, name)
        bad = ~np.isfinite(values)
        if bad.any():
            k = int(np.argmax(bad.any(axis=1)))
            return f"non-finite {name} at t = {run.time[k]:.3f} s"
    for name, limit in (("position", "max_joint_position"), ("velocity", "max_joint_velocity")):
        bound = controller_values.get(limit)
        if bound is None:
            continue
        norm = np.linalg.norm(getattr(run, name), axis=1)
        over = norm > float(bound)
        if over.any():
            k = int(np.argmax(over))
            return f"joint {name} norm {norm[k]:.3g} beyond {limit} {float(bound):g} at " \
                   f"t = {run.time[k]:.3f} s"
    return ""


def run_point(scheme: str, robot: str | None, duration: float, controller_overrides: dict[str, Any],
              plant_overrides: dict[str, Any]) -> dict[str, Any]:
    """``{"status", "reason", metrics...}`` of one offline run (never raises)."""
    try:
        controller, plant = offline.build_scheme(scheme, controller_overrides, plant_overrides,
                                                 robot)
        names = list(plant.command_joints)
        with np.errstate(all="ignore"):
            run = offline.run(controller, plant, duration)
            why = divergence(run, controller.values)
            values = point_metrics(run, scheme, names, true_force=robot is not None)
            values["command_at_limit_s"] = at_limit_seconds(run, controller, names)
            if robot is None and chapter5.is_chapter5(run.status_fields):
                values.update(chapter5_metrics(run, scheme, controller.values, plant_overrides))
            if robot is None:
                values.update(chapter_metrics.chapter_metrics(
                    run, scheme, plant_values(scheme, plant_overrides), controller.values))
    except Exception as exc:                    # noqa: BLE001 - a point's failure is a result
        text = str(exc).splitlines()[0] if str(exc) else ""
        return {"status": "failed", "reason": f"{type(exc).__name__}: {text}"[:300]}
    if run.safe_stop_reason:
        return {"status": "stopped", "reason": f"{run.safe_stop_text} at t = "
                f"{run.safe_stop_at:.3f} s", **values}
    return {"status": "diverged" if why else "ok", "reason": why, **values}
