"""A controller's one source of /joint_states at the DDS level (issue 25, item 3).

The nodes' Fast DDS profile (:data:`cr_control.core.ros_env.NODE_DDS_PROFILE`) lets a
reader of /joint_states match one writer at most (``matchedPublishersAllocation``, maximum
1): the samples of a second publisher never enter the controller's reader, so neither a
10 MB state nor a flood from it costs the control thread anything. Before, rmw copied a
10 MB state twice on that thread before any code of ours could see its length (12-27 ms
of missed cycles); a flood cost one take per message.

Fast DDS matches a writer only when it discovers it, and never later when the reader's
one slot frees. So :class:`StateSourceWatch`, off the hot path (a timer, every
``period_s``), compares the publishers the ROS graph knows on the topic with the writers
the reader matched, and:

- reports the publishers not followed: one warning each time their number grows, and
  :attr:`StateSourceWatch.unfollowed` for the node's diagnostics;
- when the followed writer has left (none matched, a publisher present, no state for
  ``silence_s``: a restarted plant, a switched driver), makes the subscription again, so
  that DDS matches a writer present now (``resubscriptions``, one info line each). A
  publisher left unmatched for ORPHANED_S is taken to be refused; one just discovered is
  matched long before.

A writer that left cleanly is unmatched at once; one whose process died is unmatched when
its participant's lease ends (Fast DDS: 20 s by default). Where the profile is not in
force (a user's own Fast DDS profile, a remapped topic), every writer is matched and the
node's own guard (``states_foreign``: states of any other publisher are ignored unread)
still follows one source; this watch then reports nothing.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.node import Node

#: A writer the graph shows is matched within milliseconds when the reader's slot is free:
#: one present but unmatched for this long (s) was refused (the slot was taken).
ORPHANED_S = 1.0


class StateSourceWatch:
    """Watches the matched writers of ``subscription()`` against the graph's publishers.

    ``subscription``: returns the node's current state subscription (anything with
    ``get_publisher_count()`` and ``topic_name``); ``resubscribe``: makes it again;
    ``last_state``: ``time.perf_counter()`` of the last state followed (-inf if none)."""

    def __init__(self, node: Node, subscription: Callable[[], object],
                 resubscribe: Callable[[], None], last_state: Callable[[], float],
                 silence_s: float, period_s: float = 0.5) -> None:
        self.node = node
        self.subscription, self.resubscribe = subscription, resubscribe
        self.last_state, self.silence_s = last_state, silence_s
        #: Publishers on the topic that the reader did not match (the last check).
        self.unfollowed = 0
        #: Times the subscription was made again after its writer left.
        self.resubscriptions = 0
        self._reported = 0                    # the largest ``unfollowed`` warned about
        self._orphaned_since = None           # perf_counter: none matched, one present
        self.timer = node.create_timer(period_s, self.tick)

    def tick(self) -> None:
        """One check (see the module docstring)."""
        sub = self.subscription()
        if sub is None:                       # not subscribed yet (discovery_settle)
            return
        matched = sub.get_publisher_count()
        present = self.node.count_publishers(sub.topic_name)
        self.unfollowed = max(0, present - matched)
        if self.unfollowed > self._reported:
            self.node.get_logger().warn(
                f"{self.unfollowed} publisher(s) on {sub.topic_name} not followed: this "
                "controller takes the states of one publisher, the first it matched; another "
                f"is followed only after that one has left and {self.silence_s:g} s passed "
                "without a state")
        self._reported = max(self._reported, self.unfollowed) if self.unfollowed else 0
        now = time.perf_counter()
        if matched or not present:
            self._orphaned_since = None
            return
        if self._orphaned_since is None:
            self._orphaned_since = now
        silent = now - self.last_state()
        if silent >= self.silence_s and now - self._orphaned_since >= ORPHANED_S:
            self.resubscriptions += 1
            self._orphaned_since = None
            self.node.get_logger().info(
                f"{sub.topic_name}: the publisher followed has left and {present} other(s) "
                f"are present, none of them matched: subscribing again "
                f"(no state for {min(silent, 1e6):.1f} s)")
            self.resubscribe()
