"""A scheme's offline run: its controller and plant built from the registries (thesis
defaults, a robot profile's wiping task, overrides) and stepped by :func:`.loop.run`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from cr_control import robots
from cr_control.offline.loop import OfflineRun, run
from cr_control.schemes.controller import Controller
from cr_control.schemes.registry import default_plant_overrides, default_scenario, make_controller
from cr_sim.plant_setup import NODE_PARAMETERS, command_limiter, transport_delay
from cr_sim.plants.base import CommandLimiter, Plant
from cr_sim.plants.registry import SCENARIOS, make_plant
from cr_sim.transport_delay import TransportDelay

#: The plant node's own settings (command limits, delay, ...): not the scenario's.
NODE_SETTINGS = frozenset(p.name for p in NODE_PARAMETERS)


def scheme_plant_overrides(scheme: str, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """The plant parameters ``scheme``'s offline runs use: the thesis settings of the
    registry that belong to the scenario (not the plant node's, such as command limits:
    there is no node here), then ``overrides``."""
    own = {p.name for p in SCENARIOS[default_scenario(scheme)][0]}
    thesis = {k: v for k, v in default_plant_overrides(scheme).items() if k in own}
    return {**thesis, **(overrides or {})}


def build_scheme(scheme: str, controller_overrides: dict[str, Any] | None = None,
                 plant_overrides: dict[str, Any] | None = None,
                 robot: str | None = None) -> tuple[Controller, Plant]:
    """The controller and plant :func:`run_scheme` steps: ``scheme`` on its thesis plant
    with thesis defaults and overrides, or on ``robot``'s wiping task (the parameters of
    config/robots/<robot>/, see :mod:`cr_control.robots`). ``plant_overrides`` may name the
    plant node's settings too (``command_delay_cycles``, ``effort_rate_limit``, ...): they
    are the loop's (:func:`node_settings`), not the plant's."""
    plant_overrides = {k: v for k, v in (plant_overrides or {}).items()
                       if k not in NODE_SETTINGS}
    if robot is None:
        plant = make_plant(default_scenario(scheme), scheme_plant_overrides(scheme, plant_overrides))
        controller = make_controller(scheme, controller_overrides)
    else:
        r = robots.robot(robot)
        plant_values = {k: v for k, v in robots.plant_values(r).items() if k != "scenario"}
        plant = make_plant(robots.plant_values(r)["scenario"], {**plant_values,
                                                                **(plant_overrides or {})})
        controller = make_controller(scheme, {**robots.controller_values(r, scheme),
                                              **(controller_overrides or {})})
    return controller, plant


def run_scheme(scheme: str, duration: float, controller_overrides: dict[str, Any] | None = None,
               plant_overrides: dict[str, Any] | None = None, period: float | None = None,
               robot: str | None = None,
               hook: Callable[[int, float, Controller, Plant], None] | None = None,
               supervise: bool = True, wrench_ages: np.ndarray | None = None) -> OfflineRun:
    """Offline run of ``scheme`` on its thesis plant with thesis defaults and overrides, or
    on ``robot``'s wiping task (see :func:`build_scheme`); ``period`` (s) defaults to 1 ms,
    on a robot to its driver's rate (the plant's ``rate_hz``: 2 ms for a UR). The plant's
    supervision, on a robot with the plant node's command limits (:func:`node_limiter`: its
    effort bounds and libfranka's 1 kN m/s torque-rate limit, which a lockstep session
    applies too); a thesis plant without them, as the thesis's simulations (its starts ask
    ~20 N m within a cycle: a session of those opens the node's limits to match). The
    driver's transport delay (:func:`node_delay`): on a robot its profile's
    (``command_delay_cycles``: 1 cycle on the Panda and the UR5), none on a thesis plant;
    ``plant_overrides`` may set it and the late bursts (``late_burst_*``) as the plant
    node's parameters. ``supervise`` False: without the plant's reflexes and limits;
    ``wrench_ages``: the wrench a controller node read, replayed (:func:`run`)."""
    controller, plant = build_scheme(scheme, controller_overrides, plant_overrides, robot)
    period = robot_period(robot) if period is None else period
    limiter = None if robot is None else node_limiter(plant, scheme, robot, plant_overrides, period)
    delay = node_delay(scheme, robot, plant_overrides)
    return run(controller, plant, duration, period, hook, supervise, limiter, delay, wrench_ages)


def node_settings(scheme: str, robot: str | None,
                  plant_overrides: dict[str, Any] | None) -> dict[str, Any]:
    """The plant node's settings for this run: its defaults, the robot profile's driver
    (:func:`cr_control.robots.plant_node_values`) or the thesis scheme's session settings,
    then ``plant_overrides``."""
    settings = {p.name: p.default for p in NODE_PARAMETERS}
    given = {**(default_plant_overrides(scheme) if robot is None
                else robots.plant_node_values(robots.robot(robot))), **(plant_overrides or {})}
    settings.update({k: v for k, v in given.items() if k in settings})
    return settings


def node_delay(scheme: str, robot: str | None,
               plant_overrides: dict[str, Any] | None = None) -> TransportDelay:
    """The driver's transport delay the plant node would apply for this run (its
    ``command_delay_cycles`` and ``late_burst_*``: :func:`node_settings`)."""
    return transport_delay(node_settings(scheme, robot, plant_overrides))


def node_limiter(plant: Plant, scheme: str, robot: str | None,
                 plant_overrides: dict[str, Any] | None, period: float) -> CommandLimiter:
    """The command limits the plant node would set for this run (its ``effort_limit`` and
    ``effort_rate_limit``: defaults, the scheme's session settings, ``plant_overrides``)."""
    return command_limiter(plant, node_settings(scheme, robot, plant_overrides), period)


def robot_period(robot: str | None) -> float:
    """The control period (s) of ``robot``'s profile, 1 ms on a thesis plant."""
    return 1e-3 if robot is None else 1.0 / robots.robot(robot).rate_hz
