"""Lockstep pacing: a loop that may wait loses nothing to a slow reader.

In lockstep the loop runs as fast as plant and controller allow, several times real
time. A reliable KEEP_LAST writer keeps only its last ``topics.PUBLISH_DEPTH`` samples:
a reader that fell further behind (a recorder starved of CPU) lost the rest. A node
whose loop may wait (the lockstep plant; a controller with ``lockstep`` set) therefore
waits, after every :data:`ACK_EVERY` messages per topic, until every reader has
acknowledged what it sent, so unacknowledged samples never exceed half the history.

Readers acknowledge in answer to the writer's heartbeats (every 10 ms in the nodes'
Fast DDS profile, ``cr_control/core/fastdds_profile.xml``; 3 s by default) and not
while their history is full (the recorder's KEEP_ALL readers), so the loop also waits
for a recorder that fell behind taking what arrived.
"""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.node import Node
from rclpy.publisher import Publisher

from cr_control.core import topics
from cr_control.nodes.spin import wait_for_readers

#: Wait for the readers after this many messages per topic: half the writer history.
ACK_EVERY = topics.PUBLISH_DEPTH // 2
#: Give up on a reader after this long (warned; it may then lose messages), so a reader
#: that hangs cannot stop the session.
ACK_TIMEOUT_S = 10.0


class ReaderPacer:
    """Call :meth:`published` once per loop cycle (one message per publisher); every
    :data:`ACK_EVERY` cycles it waits for the readers of ``publishers``.

    A topic whose readers acknowledged nothing for :data:`ACK_TIMEOUT_S` is waited for no
    more (warned once): such a reader is gone for good — a Fast DDS shared-memory port
    declared dead after its process froze for over a second (healthy_check_timeout_ms)
    never delivers again — and waiting for it every :data:`ACK_EVERY` cycles would slow
    the loop to a crawl."""

    def __init__(self, node: Node, publishers: Sequence[Publisher | None]):
        self._node = node
        self._publishers = [p for p in publishers if p is not None]
        self._since_acked = 0

    def published(self) -> None:
        self._since_acked += 1
        if self._since_acked < ACK_EVERY:
            return
        self._since_acked = 0
        for publisher in list(self._publishers):
            if not wait_for_readers([publisher], ACK_TIMEOUT_S):
                self._publishers.remove(publisher)
                self._node.get_logger().warn(
                    f"a reader of {publisher.topic_name} acknowledged nothing for "
                    f"{ACK_TIMEOUT_S:.0f} s: going on without waiting for that topic's "
                    "readers (they may lose messages)")
