"""The publishers of a controller's /joint_states as the ROS graph shows them.

The controller follows one publisher of its states, chosen by rule
(:mod:`cr_control.supervision.single_source`): the first that delivers a valid state and
belongs to the node named by ``state_source``. Its reader matches every writer on the
topic, so that the rule, not the order in which DDS discovered them, decides: a writer
matched first that never publishes (a silent intruder) keeps nobody out. A state of any
other publisher is refused unread on its GID (one bytes comparison; a message longer than
a ``max_joints`` state is not even copied to Python: :mod:`cr_control.nodes.sender_aware`).

Off the hot path (a timer, every ``period_s``), :class:`StateSourceWatch` asks the graph
for the topic's publishers (``get_publishers_info_by_topic``: endpoint GID -> node name and
namespace) and

- tells the single-source guard each publisher's node, so that the hot path seldom needs
  a graph query of its own (:meth:`SingleSource.known`);
- counts the publishers not followed (:attr:`StateSourceWatch.unfollowed`, on
  /diagnostics) and warns, naming their nodes, each time their number grows.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.node import Node

from cr_control.supervision.single_source import SingleSource, full_node_name

#: The name rmw gives an endpoint whose node it does not know (yet).
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"


def publishers(node: Node, topic: str) -> list[tuple[bytes, str]]:
    """(endpoint GID, full node name) of every publisher on ``topic`` the graph knows; the
    name "" for one whose node is not known yet."""
    out = []
    for info in node.get_publishers_info_by_topic(topic):
        name = "" if info.node_name == UNKNOWN_NODE else \
            full_node_name(info.node_namespace, info.node_name)
        out.append((bytes(info.endpoint_gid), name))
    return out


def publisher_node(node: Node, topic: str, gid: bytes) -> str | None:
    """The full node name of publisher ``gid`` on ``topic`` (None if the graph does not know
    it or its node yet)."""
    for endpoint, name in publishers(node, topic):
        if endpoint == gid:
            return name or None
    return None


class StateSourceWatch:
    """Names the publishers on ``topic`` for ``guard`` (then calls ``named()``) and counts
    those not followed (module docstring); ``guard`` None (publishers cannot be told
    apart): counts only."""

    def __init__(self, node: Node, topic: str, guard: SingleSource | None,
                 named: Callable[[], None] = lambda: None, period_s: float = 0.5) -> None:
        self.node, self.topic, self.guard, self.named = node, topic, guard, named
        #: Publishers on the topic other than the one followed (the last check).
        self.unfollowed = 0
        self._reported = 0                    # the largest ``unfollowed`` warned about
        self.timer = node.create_timer(period_s, self.tick)

    def tick(self) -> None:
        """One check (see the module docstring)."""
        found = publishers(self.node, self.topic)
        guard = self.guard
        followed = guard.source if guard is not None else None
        others = [(gid, name) for gid, name in found if gid != followed]
        if guard is not None:
            for gid, name in found:
                if name:
                    guard.known(gid, name)
            self.named()
        self.unfollowed = len(others) if guard is not None else max(0, len(found) - 1)
        if self.unfollowed > self._reported:
            names = sorted({name or "a node unknown yet" for _, name in others})
            rule = (f"only {' or '.join(sorted(guard.expected))} is followed"
                    if guard is not None and guard.expected else
                    "the first that delivers a valid state is followed")
            self.node.get_logger().warn(
                f"{self.unfollowed} publisher(s) on {self.topic} not followed ({', '.join(names)}): "
                f"{rule}, one at a time; their states are refused and counted in states_foreign")
        self._reported = max(self._reported, self.unfollowed) if self.unfollowed else 0
