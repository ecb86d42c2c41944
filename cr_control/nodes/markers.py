"""Scene markers for RViz and Foxglove (visualization_msgs/MarkerArray).

Who publishes what: the plant knows the surface, the links and the contact
(``/plant/markers``: :mod:`cr_sim.plant_markers`); a controller knows its desired path
(``/<controller>/markers``: :class:`ControllerMarkers`). Both build markers only every
:data:`PERIOD_S` of their stamps' time (~30 Hz: wall time in real time, simulated time in
lockstep), so the per-cycle cost is one float comparison.

A publish does not go through rclpy's message conversion, which costs ~45 µs a Marker and
~1.5 µs a point here (0.3-1 ms for a plant's markers with a 120-point trail, stalling the
1 kHz loop 30 times a second). :class:`MarkerBytes` serializes each layout of markers (which
markers, how many points each) once, with sentinel numbers where the stamps, positions and
points go, finds them in the bytes, and from then on writes the numbers into those bytes
and publishes them (``publish(bytes)``): ~10 µs.

The helpers here build single markers (line strip, sphere, box, arrow) in one frame with
fixed namespaces and ids, so each publish replaces the previous markers in the viewer.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from cr_control.core import topics

#: Seconds (of the stamps' clock) between two marker publishes: ~30 Hz.
PERIOD_S = 1.0 / 30.0
#: Points in a trail (the actual tip's, the desired path's): 4 s at 30 Hz (until it has
#: as many, its first point repeated).
TRAIL_POINTS = 120
#: Layouts of markers serialized and kept per publisher (a new layout beyond: all dropped).
MAX_LAYOUTS = 16
#: RELIABLE, depth 16: the recorder misses none. A lockstep loop waits for its readers
#: only every lockstep.ACK_EVERY (250) states, 7.5 marker periods of simulated time: with
#: depth 5 a recorder stopped meanwhile lost markers the writer had already overwritten.
MARKERS_QOS = QoSProfile(depth=16, reliability=ReliabilityPolicy.RELIABLE)
#: The position of a marker drawn by its points.
ORIGIN = (0.0, 0.0, 0.0)
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


def xyz(points) -> np.ndarray:
    """Points (k, 2) or (k, 3) as (k, 3) floats (a planar scene's z = 0)."""
    p = np.asarray(points, dtype=float).reshape(len(points), -1)
    return p if p.shape[1] == 3 else np.hstack([p, np.zeros((len(p), 3 - p.shape[1]))])


class Trail:
    """The last ``size`` points of a path as a LINE_STRIP marker: :meth:`add` gives its
    points, oldest first (the first point repeated until there are ``size``)."""

    def __init__(self, ns: str, frame: str, width: float, rgba: Sequence[float],
                 size: int = TRAIL_POINTS) -> None:
        self.marker = line_strip(ns, frame, [], width, rgba)
        self.size = size
        self._ring = np.empty((2 * size, 3))     # each point twice: a contiguous window
        self._i = -1

    def add(self, p: Sequence[float]) -> np.ndarray:
        """Append point ``p`` (x, y[, z]); the trail's (size, 3) points."""
        p3 = (float(p[0]), float(p[1]), float(p[2]) if len(p) > 2 else 0.0)
        size = self.size
        if self._i < 0:
            self._ring[:] = p3
        self._i = i = (self._i + 1) % size
        self._ring[i] = self._ring[i + size] = p3
        return self._ring[i + 1:i + 1 + size]


def _sentinel(k: int) -> float:
    """The k-th sentinel: a finite double with a bit pattern no marker field holds."""
    return struct.unpack("<d", struct.pack("<Q", 0x412F_C3A5_0000_0000 + 7 * k + 1))[0]


#: Sentinel stamp (sec, nanosec) of every marker in a layout being serialized.
_STAMP = (0x2A5C_3E71, 0x1B4D_6F02)


class MarkerBytes:
    """One layout of markers serialized once (module docstring); :meth:`fill` writes the
    stamp and each marker's position and points into the bytes.

    ``markers[i]`` contributes its ``pose.position`` (3) then ``counts[i]`` points (3 each)
    in that order to the values :meth:`fill` takes; every other field is as the marker
    had it when the layout was made.
    """

    def __init__(self, markers: Sequence[Marker], counts: Sequence[int]) -> None:
        k = 0
        for m, n in zip(markers, counts, strict=True):
            m.header.stamp.sec, m.header.stamp.nanosec = _STAMP
            m.pose.position = Point(x=_sentinel(k), y=_sentinel(k + 1), z=_sentinel(k + 2))
            m.points = [Point(x=_sentinel(j), y=_sentinel(j + 1), z=_sentinel(j + 2))
                        for j in range(k + 3, k + 3 + 3 * n, 3)]
            k += 3 + 3 * n
        data = bytearray(serialize_message(MarkerArray(markers=list(markers))))
        if data[:2] != b"\x00\x01":
            raise ValueError("MarkerBytes needs little-endian CDR")
        body = bytes(data[4:])
        # doubles: aligned to 8 from the end of the 4-byte header, each sentinel once
        self._doubles = np.frombuffer(data, dtype="<f8", offset=4, count=len(body) // 8)
        self._index = np.array([_find_once(body, struct.pack("<d", _sentinel(j)), 8)
                                for j in range(k)], dtype=np.intp) // 8
        stamp = struct.pack("<iI", *_STAMP)
        at = [i for i in range(0, len(body) - 7, 4) if body[i:i + 8] == stamp]
        if len(at) != len(markers):
            raise ValueError(f"{len(at)} stamps found in {len(markers)} markers")
        self._words = np.frombuffer(data, dtype="<u4", offset=4, count=len(body) // 4)
        self._sec = np.array(at, dtype=np.intp) // 4
        self._data = data
        self.size = k

    def fill(self, values: np.ndarray, sec: int, nanosec: int) -> bytes:
        """The serialized MarkerArray with these ``values`` (positions and points) and stamp."""
        self._doubles[self._index] = values
        self._words[self._sec] = sec & 0xFFFF_FFFF      # int32 sec, two's complement
        self._words[self._sec + 1] = nanosec
        return bytes(self._data)


def _find_once(body: bytes, pattern: bytes, align: int) -> int:
    """Offset of the one aligned occurrence of ``pattern`` in ``body``."""
    at = body.find(pattern)
    if at < 0 or at % align or body.find(pattern, at + 1) >= 0:
        raise ValueError("a sentinel not found once, aligned")
    return at


class MarkerPublisher:
    """Publishes a MarkerArray on ``topic`` when its stamps' time has moved PERIOD_S on."""

    def __init__(self, node: Node, topic: str) -> None:
        self.pub = node.create_publisher(MarkerArray, topic, MARKERS_QOS)
        self.next_t = float("-inf")
        self.published = 0
        self._layouts: dict[tuple, MarkerBytes] = {}
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

    def send(self, markers: Sequence[Marker], positions: Sequence[Sequence[float]],
             points: Sequence[np.ndarray | None], sec: int, nanosec: int) -> None:
        """Publish ``markers`` stamped ``sec.nanosec``, marker i at ``positions[i]`` with
        ``points[i]`` ((k, 3), or None for none)."""
        layout = self.prepare(markers, points)
        values = np.concatenate([part for pos, pts in zip(positions, points, strict=True)
                                 for part in ((pos,) if pts is None else (pos, pts.ravel()))])
        self.pub.publish(layout.fill(values, sec, nanosec))
        self.published += 1

    def prepare(self, markers: Sequence[Marker], points: Sequence[np.ndarray | None]) -> MarkerBytes:
        """The layout of ``markers`` with as many ``points`` each, serialized now if it is
        new (~3 ms for a 120-point trail here): call it at start-up for every layout the
        loop will send, so that no 1 kHz cycle pays for a first one."""
        counts = tuple(0 if p is None else len(p) for p in points)
        key = (*map(id, markers), *counts)
        layout = self._layouts.get(key)
        if layout is None:
            if len(self._layouts) >= MAX_LAYOUTS:
                self._layouts.clear()
            layout = self._layouts[key] = MarkerBytes(markers, counts)
        return layout


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
        if self.pub is not None:                      # its one layout, before the loop
            self.pub.prepare([self.trail.marker, self.now], [np.zeros((self.trail.size, 3)), None])

    def cycle(self, t: float, reference: Sequence[float]) -> None:
        """Per control cycle (``t``: the state's stamp, s): one comparison unless due. Hot path."""
        if t < self.next_t or not self.pub.due(t):
            return
        self.next_t = self.pub.next_t
        r = [float(reference[i]) for i in self.index] + [0.0] * (3 - len(self.index))
        sec = int(t // 1)
        self.pub.send([self.trail.marker, self.now], [ORIGIN, r], [self.trail.add(r), None],
                      sec, int(round((t - sec) * 1e9)) % 1_000_000_000)
