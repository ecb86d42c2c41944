"""What a cr_fuzz session case and suite are (:mod:`cr_control.tools.fuzz`): the records the
case modules (:mod:`~cr_control.tools.fuzz_delay`, :mod:`~cr_control.tools.fuzz_position`,
:mod:`~cr_control.tools.fuzz_gains`) fill in, without the fuzz's ROS node or judge."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

#: What a case's ``send`` and ``prepare`` are given: :class:`cr_control.tools.fuzz.Intruder`
#: (not imported here: that module imports this one).
Intruder = Any


@dataclass(frozen=True)
class Case:
    """One kind of bad input: ``send(intruder)`` sends it; ``miss_margin`` (ms): the case's
    longest miss may exceed the baseline's by this much (None: not judged); ``extra_s``:
    the session runs this much longer (an input that takes seconds to send, so that the
    controller's resumption is judged after it); ``suite``: the group it runs in (its
    baseline, robot and scheme: SUITES); ``prepare(intruder)``: what the intruder does before
    the session starts; ``speed_judged``: max |q'| judged against the baseline's (a target
    that moves the arm on purpose is not); ``force_judged``: the true contact force too,
    against the baseline's.

    Judged against the robot, not the baseline: ``speed_limit_share``, every joint's largest
    speed at most this share of its URDF velocity limit; ``force_limit``, the true contact
    force at most this (N); ``commands_judged``, the commanded joint positions (a position
    interface's /joint_commands) finite and never more than one control period of the
    joint's velocity limit apart, message to message.

    ``session_args``: the session's own parameters, as cr_session's ``-p NODE.PARAM=VALUE``
    (e.g. ``plant.command_delay_cycles=3``): what the case changes is the session, not a
    message."""

    name: str
    what: str
    send: Callable[[Intruder], None]
    miss_margin: float | None = None
    extra_s: float = 0.0
    suite: str = "session"
    prepare: Callable[[Intruder], None] | None = None
    speed_judged: bool = True
    force_judged: bool = False
    speed_limit_share: float | None = None
    force_limit: float | None = None
    commands_judged: bool = False
    session_args: tuple[str, ...] = ()


class Suite(NamedTuple):
    """A session suite: the case it is judged against (run first), the robot profile its
    sessions run on (None: --robot, by default the scheme's thesis plant; --robot overrides
    it) and its scheme (None: --scheme)."""

    baseline: str
    robot: str | None
    scheme: str | None = None


def plant_args(**values: object) -> tuple[str, ...]:
    """cr_session overrides of the plant node's parameters: ``plant.<name>=<value>``."""
    return tuple(f"plant.{name}={value}" for name, value in values.items())


def nothing(intruder: Intruder) -> None:
    """Send nothing (a baseline, or a case whose change is the session's own)."""
