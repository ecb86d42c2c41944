"""What a plant looks like, for the scene markers: no ROS here.

:func:`scene_of` gives a :class:`Scene` for a plant: its fixed shapes (the surface or
constraint the tool presses on: plane, line, circle or sphere), and, read at the plant's
true state when asked, the links as a polyline from the base to the tip (Pinocchio's joint
placements, then the tip frame), the tip and the contact force on it. All in the plant's
base frame (:attr:`Scene.frame`). A plant without a kinematic model (chapter 4's mass
chains) has no scene (None).

Kinds of plant and what is drawn:

- the arm on a compliant plane or circle (ch. 3, 5; packed 2-D surfaces of
  :mod:`cr_sim.models.surfaces`): the line n.r + c = 0 or the circle |r - c| = R, z = 0;
- the flexible-joint arm on its rigid line (ch. 6): n.p + c = 0, and the force n lambda;
- the moving-object closed chain (ch. 2): the object (a box at its frame) and the
  constraint line through it with normal n_c, both moving with the object, and n_c lambda;
- a URDF robot on a compliant plane or sphere (:mod:`cr_sim.models.contact3d`):
  a square patch of the plane, or the sphere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from cr_sim.models import contact3d, surfaces
from cr_sim.plants.arm_on_surface import ArmOnSurface
from cr_sim.plants.flexible_joint_surface import FlexibleJointSurface
from cr_sim.plants.moving_object import OBJECT_FRAME, MovingObjectPlant
from cr_sim.plants.urdf_surface import URDFSurface

#: Half length (m) of the drawn lines and half side of the drawn plane patches.
HALF_EXTENT = 0.6
#: Segments of a drawn circle.
CIRCLE_SEGMENTS = 72


@dataclass
class Shape:
    """One drawn primitive: ``kind`` "line" (a polyline through ``points``), "sphere",
    "box" (``centre``, ``size`` (3,), ``quaternion`` (x, y, z, w)); moving shapes are
    re-made by :meth:`Scene.moving_shapes`."""

    kind: str
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    size: np.ndarray = field(default_factory=lambda: np.zeros(3))
    quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)


def line(point: np.ndarray, direction: np.ndarray, half: float = HALF_EXTENT) -> Shape:
    """The segment point ± half·direction (direction unit)."""
    p, d = np.asarray(point, float), np.asarray(direction, float)
    return Shape("line", points=np.array([p - half * d, p + half * d]))


def planar_line(normal, offset: float) -> Shape:
    """The line n.r + offset = 0 of the x-y plane (|n| = 1), about its point nearest the base."""
    n = np.array([normal[0], normal[1], 0.0])
    return line(-offset * n, np.array([-n[1], n[0], 0.0]))


def circle(centre, radius: float) -> Shape:
    """The circle |r - centre| = radius of the x-y plane."""
    a = np.linspace(0.0, 2.0 * np.pi, CIRCLE_SEGMENTS + 1)
    points = np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a),
                       np.zeros_like(a)], axis=1)
    return Shape("line", points=points)


def quaternion_z_to(normal) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the rotation taking +z onto ``normal``."""
    q = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), np.asarray(normal, float))
    return (q.x, q.y, q.z, q.w)


def plane_patch(point, normal, half: float = HALF_EXTENT, thickness: float = 0.002) -> Shape:
    """A thin square box of the plane through ``point`` with ``normal``, its top face on it."""
    n = np.asarray(normal, float)
    return Shape("box", centre=np.asarray(point, float) - 0.5 * thickness * n,
                 size=np.array([2 * half, 2 * half, thickness]), quaternion=quaternion_z_to(n))


def sphere(centre, radius: float) -> Shape:
    return Shape("sphere", centre=np.asarray(centre, float), size=np.full(3, 2.0 * radius))


def chain_joints(model: pin.Model, tip_frame: int) -> list[int]:
    """The joints from the root to the tip frame's parent joint (a serial path in a tree)."""
    joints, j = [], model.frames[tip_frame].parentJoint
    while j > 0:
        joints.append(j)
        j = model.parents[j]
    return joints[::-1]


class Scene:
    """A plant's drawable geometry (module docstring), read at its true state."""

    def __init__(self, frame: str, shapes: list[Shape], model: pin.Model | None = None,
                 tip_frame: int = -1, q_of: Callable[[], np.ndarray] | None = None,
                 force_of: Callable[[], np.ndarray] | None = None,
                 moving: Callable[[pin.Data], list[Shape]] | None = None) -> None:
        self.frame = frame
        self.shapes = shapes                  #: fixed shapes (the surface or constraint)
        self.model, self.tip_frame = model, tip_frame
        self._q_of, self._force_of, self._moving = q_of, force_of, moving
        self._data = model.createData() if model is not None else None
        self._joints = chain_joints(model, tip_frame) if model is not None else []
        self._updated = False

    def update(self) -> None:
        """Read the plant's state: joint and frame placements (a few us)."""
        if self._data is not None:
            pin.framesForwardKinematics(self.model, self._data, self._q_of())
            self._updated = True

    def links(self) -> np.ndarray:
        """(k, 3): the base frame's origin (where it is not the first joint's), each joint of
        the chain to the tip, the tip (after update())."""
        if not self._updated:
            return np.zeros((0, 3))
        d = self._data
        points = [d.oMi[j].translation for j in self._joints]
        if not points or np.any(points[0] != 0.0):
            points.insert(0, np.zeros(3))
        points.append(d.oMf[self.tip_frame].translation)
        return np.array(points)

    def tip(self) -> np.ndarray | None:
        """The tip's position (after update()), None without a model."""
        return self._data.oMf[self.tip_frame].translation.copy() if self._updated else None

    def force(self) -> np.ndarray:
        """The true contact force on the tip (3,), base frame (N)."""
        if self._force_of is None:
            return np.zeros(3)
        f = np.asarray(self._force_of(), float)
        return np.concatenate([f, np.zeros(3 - len(f))]) if len(f) < 3 else f[:3]

    def moving_shapes(self) -> list[Shape]:
        """Shapes that move with the state (the moving object and its line; after update())."""
        return self._moving(self._data) if self._moving is not None and self._updated else []


def scene_of(plant) -> Scene | None:
    """The scene of a cr_sim plant (module docstring), None for one with nothing to draw."""
    frame = getattr(plant, "base_frame", None) or plant.wrench_frame
    if isinstance(plant, ArmOnSurface):
        s = plant.surface
        shape = (planar_line(s[1:3], s[3]) if s[0] == surfaces.PLANE else circle(s[1:3], s[3]))
        model = plant.arm.model
        return Scene(frame, [shape], model, plant.arm.tool, lambda: plant._x[:model.nq],
                     plant.contact_force)
    if isinstance(plant, FlexibleJointSurface):
        n = plant.normal
        return Scene(frame, [planar_line(n, plant.offset)], plant.model, plant._tool,
                     lambda: plant._x[:2], lambda: n * plant._sensors[0])
    if isinstance(plant, MovingObjectPlant):
        model, n = plant.model, plant.normal
        obj = model.getFrameId(OBJECT_FRAME)
        direction = np.array([-n[1], n[0], 0.0])

        def moving(data: pin.Data) -> list[Shape]:
            p = data.oMf[obj].translation
            box = Shape("box", centre=p.copy(), size=np.array([0.08, 0.04, 0.04]))
            return [box, line(p, direction, 0.25)]
        return Scene(frame, [], model, plant._tool, lambda: plant._x[:model.nq],
                     lambda: n * plant._lam[0], moving)
    if isinstance(plant, URDFSurface):
        s = plant.surface
        if s[0] == contact3d.PLANE:
            shape = [plane_patch(s[1:4], s[4:7])]
        elif s[0] == contact3d.SPHERE:
            shape = [sphere(s[1:4], s[7])]
        else:
            shape = []
        return Scene(frame, shape, plant.model, plant._tip, lambda: plant._q(plant._x),
                     plant.contact_force)
    return None
