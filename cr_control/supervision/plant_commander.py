"""The plant's one commander, by rule: the controller it expects, not whichever node sends
first (the plant-side use of :mod:`cr_control.supervision.single_source`).

A plant takes commands on /joint_commands from one publisher at a time (ros2_control lets
one controller claim a command interface; libfranka takes one control connection). Which
one is a rule, the parameter ``commander``: the full node name(s) of the controller(s) it
obeys. By default these are the names this package's controller executables and
``cr_session`` give their node, the scheme's name (``/adaptive_impedance``, ...:
:data:`CONTROLLER_NODES`). Commands of any other node, or of a publisher the ROS graph
does not know yet, are refused unread and counted (``commands_foreign``); so are a second
expected publisher's while the followed one is alive. The plant also starts only once an
expected commander listens (publishes commands and subscribes to the states): a node that
merely publishes commands does not start it.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from cr_control.core import topics
from cr_control.core.parameters import Param
from cr_control.core.rate_limited_log import Emit, RateLimitedLog
from cr_control.supervision.single_source import SingleSource, expected_names

#: The node names of this package's controllers (one per scheme: the executable's name).
CONTROLLER_NODES = (
    "adaptive_impedance", "robust_adaptive_impedance", "nn_adaptive_impedance", "impedance",
    "fuzzy_unidirectional", "moving_object_adaptive", "moving_object_nn",
    "backstepping_force", "mrac_force", "cmmsd_backstepping", "fjr_robust_adaptive",
    "fjr_singular_perturbation",
)

COMMANDER_PARAMETER = Param(
    "commander", ",".join(f"/{name}" for name in CONTROLLER_NODES),
    "The node(s) whose /joint_commands the plant obeys (full names, comma-separated; by "
    "default this package's controllers, named after their scheme). Commands of any other "
    "node are refused unread (commands_foreign). Empty: the first publisher of a valid "
    "command, whatever its node.", "string", read_only=True)


def commander_guard(commander: str, handover_cycles: int, name_of: Callable[[bytes], str | None],
                    emit: Emit) -> SingleSource:
    """The single-source guard of a plant's /joint_commands: ``commander`` the parameter's
    value; ``handover_cycles`` the silence (cycles) after which another expected publisher
    may take over; ``name_of(gid)`` the publisher's full node name by the graph (None if
    unknown); refusals logged once each kind (``emit``), counted always. Its ``now`` is in
    cycles: ticks in real time, periods of wall time in lockstep."""
    return SingleSource(topics.JOINT_COMMANDS, expected_names(commander), handover_cycles,
                        name_of, RateLimitedLog(emit, math.inf), what="commands",
                        parameter="commander", counter="commands_foreign", unit="cycles")
