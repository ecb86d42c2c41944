"""The Panda wiping task's robustness map: force and path
error against the table's stiffness K_e and the tool's mass.

``adaptive_impedance`` (3.32) on the Panda's wiping task (:mod:`cr_control.robots`: a
10 N circle on a table of K_e = 5000 N/m, a 0.7 kg tool on the wrist sensor, which the
controller compensates with its own ``tool_mass`` = 0.7 kg). The map varies the plant only:
``plant.stiffness`` (x0.1 ... x10 of 5000 N/m) and ``plant.tool_mass`` (the payload the arm
really carries; the controller still assumes 0.7 kg, so 1.4 kg is a +100 % payload error).
Metrics: ``normal_force_err_rms_last_half_N`` (the true contact force along the normal
against 10 N) and ``path_err_rms_last_half_m`` (in the table's plane), as ``cr_analyze``
reports a robot session, plus ``contact_lost_s`` and ``command_at_limit_s``.

Quick: a 2 x 2 corner (K_e 5000, 50 000; 0.7, 1.4 kg), 4 s. Full: 5 x 4, 6 s. A map, not a
thesis claim: it adds no entry to claims.json. Registered in :mod:`.reproduce`.
"""

from __future__ import annotations

from typing import Any

from cr_control.experiments.study import Study
from cr_control.experiments.sweep import SweepResult

NAME = "panda_wiping_map"
STIFFNESS = {"quick": [5000.0, 50000.0], "full": [500.0, 1580.0, 5000.0, 15800.0, 50000.0]}
TOOL_MASS = {"quick": [0.7, 1.4], "full": [0.35, 0.7, 1.05, 1.4]}
SECONDS = {"quick": 4.0, "full": 6.0}
METRICS = ["normal_force_err_rms_last_half_N", "path_err_rms_last_half_m", "contact_lost_s",
           "command_at_limit_s"]


def studies(mode: str) -> list[Study]:
    """The map of ``mode`` (quick / full)."""
    return [Study(NAME, "3", "Panda wiping task, adaptive_impedance (3.32): force "
                  "and path error against the table's K_e (5000 N/m) and the tool's mass "
                  "(0.7 kg, which the controller assumes)",
                  {"scheme": "adaptive_impedance", "robot": "panda", "duration": SECONDS[mode],
                   "vary": {"plant.stiffness": STIFFNESS[mode],
                            "plant.tool_mass": TOOL_MASS[mode]},
                   "metrics": METRICS})]


def claims(results: dict[str, SweepResult]) -> list[dict[str, Any]]:
    """None: the map is not a thesis claim."""
    return []
