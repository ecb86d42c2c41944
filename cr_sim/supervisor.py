"""The plant's supervision as a plain object (no ROS): the plant node hands it every command
and steps the plant through it; the offline loop steps through it too, so a sweep point, a
tuning trial and a lockstep session of the same settings stop on the same reflex at the same
time. Modelled on libfranka's rules for a robot's control connection.

- **Command checks** (:meth:`PlantSupervisor.admit`, :meth:`PlantSupervisor.accept`): a
  command longer than :data:`MAX_COMMAND_BYTES` is refused unread (``commands_oversized``);
  one that does not name exactly the plant's commanded joints, one value each in the field
  of the plant's interface (``position`` for position plants, ``effort`` otherwise), or that
  holds a non-finite value is refused (``commands_refused``) and the last good one stays.
  A good command is clipped into the joint and rate limits (:class:`CommandLimiter`,
  ``commands_clipped``).
- **One commander** (ros2_control lets one controller claim an interface; libfranka takes
  one control connection; :class:`cr_control.supervision.single_source.SingleSource`, the
  rule the controller follows for its states too): the publisher of the first valid command
  commands; another one's commands are refused unread (``commands_foreign``) until the
  commander has been silent for ``handover_cycles`` cycles (ticks in real time, periods of
  wall time in lockstep); then the next valid command's publisher takes over
  (``commander_handovers``).
- **Watchdog** (real time only, :class:`cr_sim.watchdog.Watchdog`): ticks without a new
  command reuse the last one; after too many the reaction is a safe stop, ``hold`` or
  ``disabled``.
- **Reflexes** (libfranka's Cartesian and joint reflexes), after every step on the true
  state (:func:`reflex`): a contact force above the plant's ``max_contact_force`` or a joint
  faster than its URDF ``<limit velocity>`` engages the safe stop.
- **Transport delay** (:class:`cr_sim.transport_delay.TransportDelay`): the command the
  plant applies at a step is the one held ``cycles`` steps before, and in a late burst the
  last one applied, as a driver applies an answer a cycle or more after the state it answers
  (libfranka: the next 1 kHz cycle); the offline loop and both modes of the node step through
  it alike. The brakes of a safe stop are the plant's own: not delayed.
- **Safe stop** (:meth:`PlantSupervisor.engage`): the plant's brakes
  (:meth:`~cr_sim.plants.base.Plant.safe_stop_command`) act on every step, logged once with
  its reason, until :meth:`PlantSupervisor.resume`. In lockstep each command still advances
  the plant one period (with the brakes' command), so a recording goes on deterministically.
- **No NaN leaves the plant**: a non-finite true state ends the run (exit code 1).
- **Ends** (:attr:`PlantSupervisor.ended`, exit code :data:`EXIT_ENDED`): no valid command
  within :data:`FIRST_COMMAND_TIMEOUT_S` of the start; in lockstep, a safe stop with no
  command for ``idle_s`` (the controller stopped commanding: nothing would ever step the
  plant again).

It lives in ``cr_sim``, beside the plants it watches and brakes (it reads their reflex
quantities and brake commands, and no control law); what both nodes share, the one-source
rule and the rate-limited log, is in :mod:`cr_control.supervision` and
:mod:`cr_control.core.rate_limited_log`, below it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol

import numpy as np

from cr_control.core import cdr, topics
from cr_control.core.rate_limited_log import RateLimitedLog, logger_emit
from cr_control.supervision.single_source import SingleSource
from cr_sim.loop_stats import (
    SAFE_STOP_CONTACT_FORCE,
    SAFE_STOP_JOINT_VELOCITY,
    SAFE_STOP_NONE,
    SAFE_STOP_REASONS,
    SAFE_STOP_WATCHDOG,
    LoopStats,
)
from cr_sim.plants.base import CommandLimiter, Plant
from cr_sim.transport_delay import TransportDelay
from cr_sim.watchdog import Watchdog

#: The most joints a command may name ...
MAX_COMMAND_JOINTS = 64
#: ... and its size: a command longer than such a JointState (names of 63 characters, all
#: three arrays filled, a 255-character frame_id) is refused unread, whatever the plant's
#: joints (the Panda has 9, the largest URDF here).
MAX_COMMAND_BYTES = len(cdr.Writer(cdr.joint_state, frame_id="f" * 255,
                                   name=["n" * 63] * MAX_COMMAND_JOINTS,
                                   **dict.fromkeys(("position", "velocity", "effort"),
                                                   MAX_COMMAND_JOINTS)).message())
#: Wall seconds after the start (a controller connected) within which a valid command must
#: come; else the plant ends with one line (a controller that never commands, or whose every
#: command is refused). Long enough for a managed controller to be activated by hand.
FIRST_COMMAND_TIMEOUT_S = 30.0
#: Exit code of a plant that ended before its duration (:attr:`PlantSupervisor.ended`).
EXIT_ENDED = 3
#: Exit code of a plant whose state or output became non-finite.
EXIT_NON_FINITE = 1
#: The JointState fields a command may carry, one per command interface.
INTERFACE_FIELDS = ("position", "velocity", "effort")


class Command(Protocol):
    """What :meth:`PlantSupervisor.accept` reads of a command (a JointState's fields)."""

    name: tuple[str, ...]
    position: Sequence[float]
    velocity: Sequence[float]
    effort: Sequence[float]
    frame_id: str


def reflex(plant: Plant, max_force: float,
           velocity_limits: list[tuple[int, float, str]]) -> tuple[int, str] | None:
    """The reflex the plant's true state trips now, as (``safe_stop_reason``, the log line's
    start), or None: a contact force (:meth:`~cr_sim.plants.base.Plant.contact_force_magnitude`)
    above ``max_force``, else the first joint (index into ``true_velocity()``, limit, name
    of ``velocity_limits``) faster than its limit. Each comparison passes only a value
    inside its limit (``not abs(f) <= limit``): NaN and infinities trip it, as any value
    that is not a number must (with ``f > limit``, NaN passed)."""
    force = plant.contact_force_magnitude()
    if not abs(force) <= max_force:
        return (SAFE_STOP_CONTACT_FORCE,
                f"REFLEX: contact force {force:.4g} N > max_contact_force {max_force:g} N")
    if velocity_limits:
        velocity = plant.true_velocity()
        for i, limit, name in velocity_limits:
            if not abs(velocity[i]) <= limit:
                return (SAFE_STOP_JOINT_VELOCITY,
                        f"REFLEX: joint {name} velocity {velocity[i]:.4g} beyond its URDF "
                        f"<limit velocity> {limit:g}")
    return None


class _Silent:
    """A logger that says nothing (the offline loop's)."""

    def info(self, *_: Any, **__: Any) -> None:
        """Nothing."""

    warn = error = info


class PlantSupervisor:
    """The supervision of one plant (module docstring). ``limiter`` None: commands are held
    as given (the offline loop: its runs stay bit for bit those of a loop without limits);
    ``logger()`` gives the logger of the moment (``info``/``warn``/``error``);
    ``name_of(gid)`` the full node name of a publisher on /joint_commands (None if unknown);
    ``on_safe_stop(reason)`` is told when a safe stop begins (the node's /diagnostics);
    ``delay``: the driver's transport delay and late bursts (None: none)."""

    def __init__(self, plant: Plant, period: float, limiter: CommandLimiter | None = None, *,
                 lockstep: bool = True, watchdog_missed_cycles: int = 100,
                 watchdog_reaction: str = "safe_stop", handover_cycles: int = 50,
                 commanders: Iterable[str] = (),
                 idle_s: float = math.inf, scenario: str = "", command: np.ndarray | None = None,
                 stats: LoopStats | None = None,
                 logger: Callable[[], Any] = _Silent,
                 name_of: Callable[[bytes], str | None] = lambda gid: None,
                 on_safe_stop: Callable[[int], None] = lambda reason: None,
                 delay: TransportDelay | None = None) -> None:
        self.plant = plant
        #: What the driver applies of the held command (module docstring).
        self.delay = delay if delay is not None else TransportDelay()
        self.period = period
        self.limiter = limiter
        self.lockstep = lockstep
        self.scenario = scenario
        self.stats = stats if stats is not None else LoopStats()
        self._logger, self._on_safe_stop = logger, on_safe_stop
        #: Refusals and the watchdog's hold: one line per kind every 5 s; once-only warnings.
        self.log = RateLimitedLog(self._emit)
        self.once = RateLimitedLog(self._emit, math.inf)
        self.command_names = tuple(plant.command_joints)
        #: The command's field the plant reads: position, velocity (a position or velocity
        #: interface: cr_sim.plants.joint_servo) or effort.
        self._field = (plant.command_interface if plant.command_interface in INTERFACE_FIELDS
                       else "effort")
        #: The command held (applied at every step outside a safe stop).
        self.command = np.zeros(len(self.command_names)) if command is None else command
        self._command_list: list[float] | None = None     # last applied, for the rate limit
        self._order: tuple[tuple[str, ...], list[int] | None] = ((), None)
        # Watchdog (real time): armed by the first command.
        self.reaction = "disabled" if lockstep else watchdog_reaction
        self.watchdog = Watchdog(watchdog_missed_cycles, period)
        self.new_command = False
        # Reflexes: one comparison per step for the force, a short loop for the joints
        # with a URDF velocity limit.
        self.max_force = float(plant.max_contact_force)
        names = list(plant.joint_names)
        self.velocity_limits = [(i, limit, names[i]) for i, limit in plant.velocity_limits()]
        self.safe_stop = False
        #: The safe stop's reason and line, and the plant's time when it began (None: none yet).
        self.stop_reason = SAFE_STOP_NONE
        self.stop_text = ""
        self.stop_time: float | None = None
        # One commander, of the expected node(s) (``commanders``: full node names; empty:
        # any node's, the first to send a valid command), counted in cycles
        # (cr_control.supervision.plant_commander).
        self.guard = SingleSource(topics.JOINT_COMMANDS, commanders, handover_cycles, name_of,
                                  self.once, what="commands", parameter="commander",
                                  counter="commands_foreign", unit="cycles")
        self.ticks = 0
        #: Wall time (s) of the last valid command (or of the start).
        self.commander_wall = 0.0
        # Ends: the start (wall s; None: the rule is off) and the first valid command.
        self.idle_s = idle_s
        self._started_at: float | None = None
        self._commanded = False
        self._last_refusal = ""
        #: Why the plant must end now (one log line, said once), and its exit code.
        self.ended: str | None = None
        self.exit_code = 0

    def describe(self) -> str:
        """The limits, the watchdog and the reflexes in words (the node's first log line)."""
        limits = (f"command limits {self.limiter.lower}..{self.limiter.upper}, "
                  if self.limiter is not None else "")
        if not self.delay.passes_through:
            limits += self.delay.describe() + ", "
        return (limits + f"watchdog {self.reaction}"
                + ("" if self.reaction == "disabled"
                   else f" after {self.watchdog.missed_limit} missed cycles")
                + f", reflexes at contact force > {self.max_force:g} N"
                + "".join(f", |{name}'| > {limit:g}" for _, limit, name in self.velocity_limits))

    # -- logging -----------------------------------------------------------------------
    def _emit(self, severity: str, text: str) -> None:
        """Onto the logger of the moment (:func:`logger_emit`: one call site per severity)."""
        logger_emit(self._logger())(severity, text)

    def warn_once(self, key: str, text: Callable[[], str]) -> None:
        """Log ``text()`` as a warning the first time ``key`` comes (built only then)."""
        self.once(key, "warn", text)

    @property
    def commander(self) -> bytes | None:
        """The GID of the publisher whose commands are followed (None before the first)."""
        return self.guard.source

    # -- commands ----------------------------------------------------------------------
    def admit(self, gid: bytes, size: int, now: float) -> bool:
        """Whether a command of ``size`` bytes from publisher ``gid`` at ``now`` (wall s) is
        read at all: not beyond :data:`MAX_COMMAND_BYTES`, and from the commander or after
        its silence (refusals counted; each kind logged once)."""
        if size > MAX_COMMAND_BYTES:
            self.stats.commands_oversized += 1
            self.warn_once("oversized", lambda: (
                f"refused a {size}-byte command unread: more than {MAX_COMMAND_BYTES} bytes "
                f"({MAX_COMMAND_JOINTS} joints' worth); counted in commands_oversized, "
                "logged once"))
            return False
        guard = self.guard
        if gid == guard.source or not gid:
            return True
        guard.name(gid)               # its node's name for the log lines (cached)
        if guard.admit(gid, self._cycles(now)):
            return True
        self.stats.commands_foreign = guard.refused
        return False

    def _cycles(self, now: float) -> float:
        """The one-commander rule's clock: ticks in real time, periods of wall time in
        lockstep (which has no ticks)."""
        return now / self.period if self.lockstep else self.ticks

    def accept(self, msg: Command | None, gid: bytes, now: float) -> bool:
        """Check an admitted command (None: unreadable); hold it unless in a safe stop. True
        if it was valid (its publisher is then the commander)."""
        if msg is None:
            return self._refuse("not a readable JointState")
        values = getattr(msg, self._field)
        if msg.name != self.command_names or len(values) != len(self.command_names):
            values = self._reorder(msg.name, values)
            if values is None:
                return self._refuse(self._wrong_field(msg) or (
                    f"it names {list(msg.name)} with {len(msg.effort)} efforts and "
                    f"{len(msg.position)} positions; the plant's commanded joints are "
                    f"{list(self.command_names)}"))
        if self.limiter is not None:
            limited = self._clipped(values)
        else:
            limited = [float(x) for x in values]
            limited = limited if all(map(math.isfinite, limited)) else None
        if limited is None:
            return self._refuse("non-finite value")
        guard = self.guard
        cycles = now / self.period if self.lockstep else self.ticks
        if gid == guard.source:
            guard.last_heard = cycles                 # SingleSource.heard, without a call
        else:
            guard.heard(gid, cycles)
            self.stats.commander_handovers = guard.handovers
        guard.yielded = msg.frame_id == topics.BRAKE_FRAME_ID   # a brake gives way
        self.commander_wall = now
        self.new_command = self._commanded = True
        if not self.safe_stop:
            self._command_list = limited
            self.command = np.array(limited)
        return True

    def hold(self, command: np.ndarray) -> None:
        """Hold ``command`` (the offline loop: its controller's own output, in the plant's
        joint order), clipped into the command limits where there are any (as
        :meth:`accept` does; a non-finite one leaves the last), unless in a safe stop."""
        self._commanded = True
        if self.safe_stop:
            return
        if self.limiter is not None:
            limited = self._clipped(command)
            if limited is None:
                return
            self._command_list, command = limited, np.array(limited)
        self.command = command

    def _clipped(self, values: Sequence[float]) -> list[float] | None:
        """``values`` clipped into the limiter's bounds and rate from the last applied command
        (clips counted in ``commands_clipped``); None if one is not finite."""
        limited = self.limiter.limit(values, self._command_list)
        self.stats.commands_clipped = self.limiter.clipped
        return limited

    def _reorder(self, names: tuple[str, ...], values: Sequence[float]) -> list[float] | None:
        """``values`` in the plant's joint order if ``names`` are exactly its joints."""
        key = names
        if key != self._order[0]:
            ours = self.command_names
            ok = len(key) == len(ours) and set(key) == set(ours)
            self._order = (key, [key.index(n) for n in ours] if ok else None)
        order = self._order[1]
        if order is None or len(values) != len(key):
            return None
        return [values[i] for i in order]

    def _wrong_field(self, msg: Command) -> str:
        """Why ``msg`` is not a command of the plant's interface ("" if it is one)."""
        if len(getattr(msg, self._field)) > 0:
            return ""
        theirs = [field for field in INTERFACE_FIELDS if field != self._field
                  and len(getattr(msg, field, ())) > 0]
        if not theirs:
            return ""
        return (f"it carries {theirs[0]}s but this plant takes {self._field}s "
                f"(scenario {self.scenario})")

    def _refuse(self, why: str) -> bool:
        self.stats.commands_refused += 1
        self._last_refusal = why
        self.log("refused", "warn", lambda: (
            f"refused a command ({why}); {self.stats.commands_refused} so far; holding the "
            "last good one"))
        return False

    # -- stepping ----------------------------------------------------------------------
    def step(self) -> None:
        """One period of the plant: with the held command as the driver applies it (its
        transport delay), or the brakes' in a safe stop (the plant's own: not delayed; they
        go through the delay's stream, so a resumed plant applies no stale command); then,
        on the new state, the finiteness check and the reflexes (:func:`reflex`)."""
        plant = self.plant
        if self.safe_stop:                               # brakes act on every step
            brake = plant.safe_stop_command()
            if self.limiter is not None:
                self._command_list = self.limiter.bound(brake)
                brake = self._command_list
            self.command = np.array(brake, dtype=float)
            self.delay(self.command)
            plant.step(self.command, self.period)
            if not plant.state_is_finite():
                self.non_finite("the plant's state")
            return
        plant.step(self.delay(self.command), self.period)
        if not plant.state_is_finite():
            self.non_finite("the plant's state")
            return
        tripped = reflex(plant, self.max_force, self.velocity_limits)
        if tripped is not None:
            self.engage(*tripped)

    def non_finite(self, what: str) -> None:
        """``what`` became non-finite: no brake can act on a non-finite state and nothing
        non-finite may leave the plant, so the run ends (exit code 1; the last state out
        was finite)."""
        self._end(EXIT_NON_FINITE, f"NON-FINITE: {what} is not finite at t = "
                  f"{self.plant.time:.3f} s: nothing more is published (the last state was "
                  "finite) and the plant stops, exit code 1; a controller sees its states stop")

    def _end(self, code: int, line: str) -> None:
        if self.ended is None:
            self.ended, self.exit_code = line, code
            self._logger().error(line)

    def engage(self, reason: int, what: str) -> None:
        """Brake from the next step on until resumed; logged once with why (a safe stop
        already engaged keeps its reason)."""
        if self.safe_stop:
            return
        self.safe_stop = True
        self.stop_reason, self.stop_text, self.stop_time = reason, what, self.plant.time
        self.stats.safe_stop, self.stats.safe_stop_reason = 1.0, reason
        self._on_safe_stop(reason)
        self.plant.begin_safe_stop()
        self._logger().error(
            f"{what} at t = {self.plant.time:.3f} s: "
            f"{'braking' if reason == SAFE_STOP_WATCHDOG else 'safe stop, braking'} "
            f"({self.plant.describe_safe_stop()}). Commands are ignored until the parameter "
            "resume is set to true.")

    def resume(self) -> None:
        """Leave a safe stop: commands apply again (the watchdog re-armed by the next one;
        the brakes' command is held till then)."""
        if not self.safe_stop:
            self._logger().info("resume requested, but no safe stop is engaged")
            return
        self.safe_stop = False
        self.stats.safe_stop, self.stats.safe_stop_reason = 0.0, SAFE_STOP_NONE
        self.watchdog.disarm()
        self._logger().warn("resumed from safe stop on request: applying commands again")

    # -- time --------------------------------------------------------------------------
    def start(self, now: float) -> None:
        """The loop starts at ``now`` (wall s): the first valid command is due within
        :data:`FIRST_COMMAND_TIMEOUT_S`."""
        self._started_at = now
        self.commander_wall = now

    def tick(self, now: float) -> None:
        """Real time: a tick at ``now`` (wall s); tells the watchdog whether it saw a new
        command and reacts when it says so."""
        self.ticks += 1
        new, self.new_command = self.new_command, False
        if not self._commanded:
            self._check_start(now)
        reason = self.watchdog.tick(now, new)
        if self.watchdog.run > self.stats.window_max_missed_run:
            self.stats.window_max_missed_run = self.watchdog.run
        if reason is None or self.reaction == "disabled":
            return
        if self.reaction == "hold":
            self.log("hold", "warn", f"watchdog: {reason}: holding the last command "
                     "(watchdog_reaction hold)")
            return
        self.engage(SAFE_STOP_WATCHDOG, f"SAFE STOP: watchdog: {reason}")

    def idle(self, now: float) -> None:
        """Lockstep, no command for a while at ``now`` (wall s): the start-up rule, and a
        safe stop without a command for ``idle_s`` ends the run."""
        self._check_start(now)
        silent = now - self.commander_wall
        if self.safe_stop and self._commanded and silent >= self.idle_s:
            self._end(EXIT_ENDED, (
                f"ENDED: in a safe stop ({SAFE_STOP_REASONS[self.stop_reason]} at t = "
                f"{self.stop_time:.3f} s) and no command for {silent:.1f} s: the controller "
                f"stopped commanding; the plant stops at t = {self.plant.time:.3f} s, exit "
                f"code {EXIT_ENDED}"))

    def _check_start(self, now: float) -> None:
        if self._commanded or self._started_at is None or \
                now - self._started_at < FIRST_COMMAND_TIMEOUT_S:
            return
        refused = self.stats.commands_refused
        self._end(EXIT_ENDED, (
            f"ENDED: no valid command within {FIRST_COMMAND_TIMEOUT_S:g} s of the start ("
            + (f"{refused} refused, the last: {self._last_refusal}" if refused else
               "none came") + f"): the plant stops, exit code {EXIT_ENDED}"))
