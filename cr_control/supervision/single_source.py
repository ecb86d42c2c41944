"""Follow one publisher of a topic, chosen by rule, not by race.

Both nodes of the loop take one input from one publisher only: the controller its
``/joint_states`` (the plant's, or a robot's ``joint_state_broadcaster``), the plant its
``/joint_commands`` (its controller's). ros2_control lets one controller claim a command
interface and libfranka takes one control connection; here the topic is open to any node
on the domain, so the node must choose. :class:`SingleSource` is that choice, for both.

The rule (one per topic, stated in docs/safety.md):

1. **Only a publisher that delivers is followed.** Following starts with the first
   message the node found valid (read, sized and checked by its caller), never on
   matching: a publisher that stays silent is never followed and cannot keep a real one
   out.
2. **Only the expected node is followed.** ``expected`` names the node(s) whose messages
   count (full names, e.g. ``/plant``; ``/joint_state_broadcaster`` on a ros2_control
   robot). The publisher of each message is known by its endpoint GID (taken with the
   message); its node by the ROS graph (``get_publishers_info_by_topic``: endpoint GID ->
   node name and namespace), looked up once per GID and cached. A message of another node,
   or of a GID the graph does not know (yet), is refused unread. ``expected`` empty: any
   publisher may be followed (rule 1 and 3 still hold).
3. **One at a time.** Once one publisher is followed, every other one's messages are
   refused unread until the followed one has delivered nothing for ``silence`` (a
   restarted plant, a switched controller): the next valid message of an expected
   publisher is then followed (a handover). A followed publisher may give way
   (:attr:`SingleSource.yielded`, set by the caller from its messages: a deactivated
   controller's brake): the next valid message of an expected publisher is then followed
   at once, without the silence.

Each refusal is counted (:attr:`SingleSource.refused`, of which :attr:`unexpected` by
rule 2) and logged, rate-limited (:class:`~cr_control.core.rate_limited_log.RateLimitedLog`).
Node names are not authenticated by DDS: a process that takes the expected node's name
is not told apart by this rule (SROS2's access control is what keeps other processes off
the topic, https://docs.ros.org/en/jazzy/Tutorials/Advanced/Security/Introducing-ros2-security.html).

Time is whatever the caller counts in (``now`` and ``silence`` in the same unit): seconds
for the controller, cycles for a plant in real time.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable

from cr_control.core.rate_limited_log import RateLimitedLog

#: A GID the graph did not know is looked up again at most this often (s of ``clock``):
#: a flood of messages of an unknown publisher costs one graph query per period.
LOOKUP_RETRY_S = 0.05
#: Names cached at most (GIDs): beyond it the cache starts afresh (publishers come and go).
MAX_CACHED = 256


def full_node_name(namespace: str, name: str) -> str:
    """``/ns/name`` from a node's namespace and name (``/name`` in the root namespace)."""
    return f"{namespace.rstrip('/')}/{name}"


def expected_names(text: str | Iterable[str]) -> frozenset[str]:
    """The node names of a parameter: a comma-separated string or a list; each made a full
    name (a leading ``/`` added); blank entries dropped. Empty: any publisher."""
    items = text.split(",") if isinstance(text, str) else list(text)
    names = (item.strip() for item in items)
    return frozenset(name if name.startswith("/") else f"/{name}" for name in names if name)


class SingleSource:
    """The publisher followed on ``topic`` (module docstring), for a node that takes each
    message with its publisher's GID.

    ``admit(gid, now)`` before a message is read (False: refused unread, counted, logged);
    ``heard(gid, now)`` once the caller found it valid (follows ``gid`` if it is not
    followed yet). ``name_of(gid)``: the node of a publisher by the ROS graph (None if the
    graph does not know it); ``log``: where refusals and handovers are told."""

    def __init__(self, topic: str, expected: Iterable[str], silence: float,
                 name_of: Callable[[bytes], str | None], log: RateLimitedLog, *,
                 what: str = "messages", parameter: str = "", counter: str = "",
                 unit: str = "s", clock: Callable[[], float] = time.monotonic) -> None:
        self.topic, self.expected, self.silence = topic, frozenset(expected), silence
        self.name_of, self.log, self.clock = name_of, log, clock
        self.what, self.parameter, self.counter, self.unit = what, parameter, counter, unit
        #: GID of the publisher followed (None until the first valid message).
        self.source: bytes | None = None
        #: ``now`` of the followed publisher's last valid message.
        self.last_heard = -math.inf
        #: Messages refused unread (every reason), of which ``unexpected`` by the rule.
        self.refused = 0
        self.unexpected = 0
        #: Times another publisher was followed after the followed one's silence.
        self.handovers = 0
        #: The followed publisher gives way (module docstring, rule 3): set by the caller.
        self.yielded = False
        self._names: dict[bytes, str] = {}
        self._looked_up: dict[bytes, float] = {}

    # -- the rule ----------------------------------------------------------------------
    def allows(self, node_name: str) -> bool:
        """Whether node ``node_name`` (full name) may be followed by the rule."""
        return not self.expected or node_name in self.expected

    def admit(self, gid: bytes | None, now: float) -> bool:
        """True if a message of ``gid`` may be read: it is the followed publisher's, or none
        is followed (or it fell silent) and the rule allows its node. A falsy ``gid`` (the
        publisher cannot be known here) is admitted: the caller said so once at start."""
        if gid == self.source or not gid:
            return True
        if self.source is not None and now - self.last_heard < self.silence and not self.yielded:
            self._refuse("foreign", gid, lambda: (
                f"following {self.describe(self.source)}; another is followed only after "
                f"{self.silence:g} {self.unit} without a valid message from it"))
            return False
        if self.expected:
            name = self.name(gid)
            if name is None or name not in self.expected:
                self.unexpected += 1
                self._refuse("unexpected", gid, lambda: (
                    f"only {self._expected_text()} is followed"
                    + (f" (parameter {self.parameter})" if self.parameter else "")))
                return False
        return True

    def heard(self, gid: bytes | None, now: float) -> None:
        """A valid message of ``gid`` (admitted): follow it if not followed yet."""
        if gid != self.source and gid:
            previous, self.source, self.yielded = self.source, gid, False
            if previous is None:
                self.log(f"{self.topic} follow", "info",
                         lambda: f"{self.topic}: following {self.describe(gid)}")
            else:
                self.handovers += 1
                silent = now - self.last_heard
                self.log(f"{self.topic} handover", "warn", lambda: (
                    f"{self.topic}: handover: {self.what} now from {self.describe(gid)}; "
                    f"{self.describe(previous)} " + (
                        "gave way" if silent < self.silence else
                        f"delivered nothing for {silent:.3g} {self.unit}")
                    + f" (handover {self.handovers})"))
        self.last_heard = now

    def silent_for(self, now: float) -> float:
        """How long the followed publisher has delivered nothing (inf if none followed)."""
        return now - self.last_heard

    # -- names from the graph ------------------------------------------------------------
    def known(self, gid: bytes, node_name: str) -> None:
        """Tell the name of ``gid``'s node (from a graph query made elsewhere, off the hot
        path): later messages of it need no lookup."""
        if len(self._names) >= MAX_CACHED:
            self._names.clear()
        self._names[gid] = node_name

    def name(self, gid: bytes) -> str | None:
        """The node of publisher ``gid`` (cached; looked up at most every LOOKUP_RETRY_S
        while the graph does not know it)."""
        name = self._names.get(gid)
        if name is not None:
            return name
        now = self.clock()
        if now - self._looked_up.get(gid, -math.inf) < LOOKUP_RETRY_S:
            return None
        if len(self._looked_up) >= MAX_CACHED:
            self._looked_up.clear()
        self._looked_up[gid] = now
        name = self.name_of(gid)
        if name is not None:
            self._looked_up.pop(gid, None)
            self.known(gid, name)
        return name

    def describe(self, gid: bytes | None) -> str:
        """``node '/plant' (gid ...)`` for the log (the node as far as the cache knows)."""
        if not gid:
            return "a publisher of unknown gid"
        name = self._names.get(gid)
        return (f"node '{name}'" if name else "a publisher unknown to the graph") + \
            f" (gid {gid.hex()})"

    def _expected_text(self) -> str:
        return " or ".join(repr(name) for name in sorted(self.expected))

    def _refuse(self, reason: str, gid: bytes, why: Callable[[], str]) -> None:
        self.refused += 1
        counted = f"; counted in {self.counter}" if self.counter else ""
        self.log(f"{self.topic} {reason}", "warn", lambda: (
            f"{self.what} from {self.describe(gid)} on {self.topic} refused unread: "
            f"{why()}{counted} ({self.refused} so far)"))
