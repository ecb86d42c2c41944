"""The plant's scene markers on ``/plant/markers`` (:mod:`cr_control.nodes.markers`).

Every ~33 ms of simulated time (real time: wall time; lockstep: the simulation's), from the
plant's true state (:mod:`cr_sim.scene`): the surface or constraint (``surface``), the
links as a line strip (``links``), a trail of the actual tip (``tip_path``), the moving
object and its constraint line where there is one (``object``), and the contact force on
the tip as an arrow of :data:`FORCE_SCALE` m per N (``contact_force``).
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node
from visualization_msgs.msg import Marker

from cr_control.core import topics
from cr_control.nodes.markers import (
    BLUE,
    GREEN,
    GREY,
    ORIGIN,
    RED,
    MarkerPublisher,
    Trail,
    arrow,
    line_strip,
    solid,
    xyz,
)
from cr_sim.scene import Shape, scene_of

#: Length of the contact-force arrow per newton (m/N): 10 N draws 0.1 m.
FORCE_SCALE = 0.01
#: Forces below this (N) draw no arrow (a zero-length arrow is deleted instead).
FORCE_MIN_N = 1e-3
#: The fixed shapes (surface) go out with every this many publishes (2 Hz): a viewer keeps
#: them meanwhile, and a circle's 73 points are not re-sent 30 times a second.
SURFACE_EVERY = 15


def shape_marker(ns: str, frame: str, shape: Shape, rgba, mid: int = 0) -> Marker:
    """A :class:`~cr_sim.scene.Shape` as a marker."""
    if shape.kind == "line":
        return line_strip(ns, frame, shape.points, 0.004, rgba, mid)
    kind = Marker.SPHERE if shape.kind == "sphere" else Marker.CUBE
    return solid(ns, kind, frame, shape.centre, shape.size, rgba, shape.quaternion, mid)


class PlantMarkers:
    """Builds and publishes the plant's markers when due (:meth:`tick`, per published state)."""

    def __init__(self, node: Node, plant) -> None:
        self.scene = scene_of(plant)
        # The arm's base link (what a task-space controller's markers use too), else the
        # plant's frame.
        frame = getattr(plant, "base_frame", None) or (
            node.get_parameter("base_link").value if node.has_parameter("base_link")
            else plant.wrench_frame)
        self.frame = frame
        self.pub = MarkerPublisher(node, topics.PLANT_MARKERS)
        #: The simulated time from which the next publish is due (inf: never, no scene).
        self.next_t = self.pub.next_t if self.scene is not None else float("inf")
        scene = self.scene
        self.fixed = ([shape_marker("surface", frame, s, GREY, i) for i, s in enumerate(scene.shapes)]
                      if scene is not None else [])
        # the fixed shapes' numbers, kept: their markers hold sentinels once serialized
        self.fixed_values = ([_values(s) for s in scene.shapes] if scene is not None else [])
        self.trail = Trail("tip_path", frame, 0.004, GREEN)
        # Made once; their numbers go in at each publish (cr_control.nodes.markers.MarkerBytes).
        self.links = line_strip("links", frame, [], 0.012, BLUE)
        self.force = arrow("contact_force", frame, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), RED)
        self.no_force = Marker(ns="contact_force", id=0, action=Marker.DELETE)
        self.no_force.header.frame_id = frame
        self._moving: list[Marker] = []
        self._moving_kinds: list[str] = []

    def _moving_markers(self, shapes: list[Shape]) -> list[Marker]:
        """The moving shapes' markers, made at the first publish (or when they change kind)."""
        kinds = [s.kind for s in shapes]
        if kinds != self._moving_kinds:
            self._moving = [shape_marker("object", self.frame, s, GREY, i) for i, s in enumerate(shapes)]
            self._moving_kinds = kinds
        return self._moving

    def tick(self, t: float, sec: int, nanosec: int) -> None:
        """Per published state (``t``: simulated time, s): publish if due. Hot path."""
        if t < self.next_t or not self.pub.due(t):
            return
        self.next_t = self.pub.next_t
        scene = self.scene
        scene.update()
        tip = scene.tip()
        trail = None if tip is None else self.trail.add(tip)
        force = None if tip is None else scene.force()
        surface = self.pub.published % SURFACE_EVERY == 0
        self.pub.send(*self._compose(surface, tip, trail, force), sec, nanosec)

    def warm_up(self) -> None:
        """Serialize every layout :meth:`tick` can send (with and without the surface, with
        the force arrow or its deletion) now: each first one took ~3 ms of a 1 kHz tick
        (three late ticks in the first half second of every Panda session)."""
        if self.scene is None:
            return
        self.scene.update()
        tip = self.scene.tip()
        trail = None if tip is None else np.zeros((self.trail.size, 3))
        force = None if tip is None else np.asarray(self.scene.force(), dtype=float)
        forces = (None,) if tip is None else (np.ones_like(force), np.zeros_like(force))
        for surface in (True, False):
            for f in forces:
                markers, _, points = self._compose(surface, tip, trail, f)
                self.pub.prepare(markers, points)

    def _compose(self, surface: bool, tip, trail: np.ndarray | None,
                 force: np.ndarray | None) -> tuple[list[Marker], list, list]:
        """(markers, positions, points) of one publish: the fixed shapes if ``surface``, the
        links, the moving shapes, and with a ``tip`` its ``trail`` and the ``force`` arrow."""
        scene = self.scene
        markers, positions, points = [], [], []
        if surface:
            markers += self.fixed
            for position, pts in self.fixed_values:
                positions.append(position)
                points.append(pts)
        markers.append(self.links)
        positions.append(ORIGIN)
        points.append(xyz(scene.links()))
        shapes = scene.moving_shapes()
        markers += self._moving_markers(shapes)
        for s in shapes:
            position, pts = _values(s)
            positions.append(position)
            points.append(pts)
        if tip is not None:
            markers.append(self.trail.marker)
            positions.append(ORIGIN)
            points.append(trail)
            positions.append(ORIGIN)
            if float(force @ force) > FORCE_MIN_N ** 2:
                markers.append(self.force)
                points.append(xyz([tip, tip + FORCE_SCALE * force]))
            else:
                markers.append(self.no_force)
                points.append(None)
        return markers, positions, points


def _values(shape: Shape) -> tuple[tuple[float, ...], np.ndarray | None]:
    """A shape marker's position and points (a line: its points; a solid: its centre)."""
    if shape.kind == "line":
        return ORIGIN, xyz(shape.points)
    c = xyz([shape.centre])[0]
    return (float(c[0]), float(c[1]), float(c[2])), None
