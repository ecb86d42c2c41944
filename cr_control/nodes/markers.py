"""Scene markers for RViz and Foxglove (visualization_msgs/MarkerArray, issue 22).

Who publishes what: the plant knows the surface, the links and the contact
(``/plant/markers``: :mod:`cr_sim.plant_markers`); a controller knows its desired path
(``/<controller>/markers``: :class:`ControllerMarkers`). Both build markers only every
:data:`PERIOD_S` of their stamps' time (~30 Hz: wall time in real time, simulated time in
lockstep), so the per-cycle cost is one float comparison; a trail keeps its
``geometry_msgs/Point`` objects, one new per publish, so a publish costs ~0.1-0.3 ms.

The helpers here build single markers (line strip, sphere, box, arrow) in one frame with
fixed namespaces and ids, so each publish replaces the previous markers in the viewer.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from cr_control.core import topics

#: Seconds (of the stamps' clock) between two marker publishes: ~30 Hz.
PERIOD_S = 1.0 / 30.0
#: Points kept in a trail (the actual tip's, the desired path's): 4 s at 30 Hz.
TRAIL_POINTS = 120
#: RELIABLE, depth 5: a viewer keeps up at 30 Hz; the recorder misses none.
MARKERS_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
#: Colours (r, g, b, a).
GREY, BLUE, GREEN, ORANGE, RED = ((0.6, 0.6, 0.6, 0.6), (0.2, 0.4, 0.9, 1.0),
                                  (0.1, 0.7, 0.2, 1.0), (1.0, 0.55, 0.0, 1.0),
                                  (0.9, 0.1, 0.1, 1.0))


def point(xyz: Sequence[float]) -> Point:
    return Point(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]) if len(xyz) > 2 else 0.0)


def marker(ns: str, kind: int, frame: str, rgba: Sequence[float], mid: int = 0) -> Marker:
    """A marker of ``kind`` (Marker.LINE_STRIP, ...) in ``frame``, identity pose."""
    m = Marker(ns=ns, id=mid, type=kind, action=Marker.ADD)
    m.header.frame_id = frame
    m.pose.orientation.w = 1.0
    m.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
    return m


def line_strip(ns: str, frame: str, points: Sequence[Sequence[float]], width: float,
               rgba: Sequence[float], mid: int = 0) -> Marker:
    m = marker(ns, Marker.LINE_STRIP, frame, rgba, mid)
    m.scale.x = width
    m.points = [point(p) for p in points]
    return m


def solid(ns: str, kind: int, frame: str, centre: Sequence[float], size: Sequence[float],
          rgba: Sequence[float], quaternion: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
          mid: int = 0) -> Marker:
    """A SPHERE or CUBE at ``centre`` with ``size`` (x, y, z) and orientation (x, y, z, w)."""
    m = marker(ns, kind, frame, rgba, mid)
    m.pose.position = point(centre)
    o = m.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in quaternion)
    m.scale.x, m.scale.y, m.scale.z = (float(v) for v in size)
    return m


def arrow(ns: str, frame: str, start: Sequence[float], end: Sequence[float],
          rgba: Sequence[float], shaft: float = 0.006) -> Marker:
    """An ARROW from ``start`` to ``end`` (two points; scale: shaft and head diameters)."""
    m = marker(ns, Marker.ARROW, frame, rgba)
    m.points = [point(start), point(end)]
    m.scale.x, m.scale.y, m.scale.z = shaft, 2.0 * shaft, 3.0 * shaft
    return m


class Trail:
    """The last ``size`` points of a path as a LINE_STRIP marker (its Points kept)."""

    def __init__(self, ns: str, frame: str, width: float, rgba: Sequence[float],
                 size: int = TRAIL_POINTS) -> None:
        self.points: deque[Point] = deque(maxlen=size)
        self.marker = line_strip(ns, frame, [], width, rgba)

    def add(self, xyz: Sequence[float]) -> Marker:
        """Append a point; the marker with the whole trail."""
        self.points.append(point(xyz))
        self.marker.points = list(self.points)
        return self.marker


class MarkerPublisher:
    """Publishes a MarkerArray on ``topic`` when its stamps' time has moved PERIOD_S on."""

    def __init__(self, node: Node, topic: str) -> None:
        self.pub = node.create_publisher(MarkerArray, topic, MARKERS_QOS)
        self.next_t = float("-inf")
        self.published = 0
        # The first conversion of a MarkerArray loads its type support (~90 ms here): done
        # now, not in the first cycle that publishes markers (it stalled the 1 kHz loop).
        serialize_message(MarkerArray(markers=[Marker()]))

    def due(self, t: float) -> bool:
        """True once every PERIOD_S of ``t`` (s): the caller then builds and :meth:`send`s."""
        if t < self.next_t:
            return False
        # the next one a period on; after a gap (or the first) a period from now
        self.next_t = self.next_t + PERIOD_S if t < self.next_t + PERIOD_S else t + PERIOD_S
        return True

    def send(self, markers: list[Marker], sec: int, nanosec: int) -> None:
        stamp = Time(sec=sec, nanosec=nanosec)
        for m in markers:
            m.header.stamp = stamp
        self.pub.publish(MarkerArray(markers=markers))
        self.published += 1


class ControllerMarkers:
    """A task-space controller's desired path: the trail of r_d and a sphere at r_d now,
    from its reference fields ``r_d_x``, ``r_d_y`` (``r_d_z``); nothing for a scheme
    without them (chapters 2, 4, 6 and C: their plant draws the scene alone)."""

    def __init__(self, node: Node, reference_fields: Sequence[str], frame: str) -> None:
        values = list(reference_fields)[1:]          # the reference array has no stamp
        self.index = [values.index(f) for f in ("r_d_x", "r_d_y", "r_d_z") if f in values]
        self.pub = MarkerPublisher(node, f"~/{topics.MARKERS_SUFFIX}") if len(self.index) >= 2 else None
        #: The stamp from which the next publish is due (inf: never, no desired position).
        self.next_t = self.pub.next_t if self.pub is not None else float("inf")
        self.trail = Trail("desired_path", frame, 0.004, ORANGE)
        self.now = solid("desired", Marker.SPHERE, frame, (0.0, 0.0, 0.0), (0.02,) * 3, ORANGE)

    def cycle(self, t: float, reference: Sequence[float]) -> None:
        """Per control cycle (``t``: the state's stamp, s): one comparison unless due. Hot path."""
        if t < self.next_t or not self.pub.due(t):
            return
        self.next_t = self.pub.next_t
        r = [float(reference[i]) for i in self.index]
        self.now.pose.position = point(r)
        sec = int(t // 1)
        self.pub.send([self.trail.add(r), self.now], sec, int(round((t - sec) * 1e9)) % 1_000_000_000)
