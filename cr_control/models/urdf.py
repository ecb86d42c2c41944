"""A robot from its URDF: the chain from ``base_link`` to ``tip_link`` as a Pinocchio model.

What a controller or plant is given is what robot_state_publisher takes: the URDF XML
(``robot_description``) or a file (``urdf_file``: a path, a file of this package's config
directory, or ``package://PKG/...`` as URDF meshes are named), and the two links that bound
the controlled chain. :func:`load_chain` builds the model once, at start-up:

- Pinocchio parses the URDF (revolute, continuous and prismatic joints move the chain);
- every joint that does not lie on the path from ``base_link`` to ``tip_link`` (fingers,
  a second arm, a camera pan) is locked at its neutral position clipped into its limits,
  and what it carries stays on the chain as rigid mass (``pinocchio.buildReducedModel``);
- the model is re-rooted at ``base_link``: every position, Jacobian and the gravity vector
  are expressed in the base frame, as KDL chains in ros2_control are;
- a URDF that does not parse, a link that is not in it, a base that is not an ancestor of
  the tip, a chain with a joint that has no mass beyond it, or a joint type a serial
  chain controller cannot drive is refused with a one-line :class:`RobotModelError`.

The chain's joint limits (position, velocity, effort) and its ``<dynamics>`` (viscous
damping, Coulomb friction) come with it (:class:`ChainModel`).

A tool on a wrist sensor (:class:`Tool`) replaces what the URDF mounts beyond the sensor's
link, in the URDF's XML before Pinocchio parses it (so every frame of the URDF survives):

- every link beyond ``sensor_link`` (its descendants in the URDF tree: the Panda's hand and
  fingers beyond ``panda_link8``) loses its ``<inertial>``;
- a link ``tool`` carrying the tool's mass, centre of mass and inertia is attached to
  ``sensor_link`` by a fixed joint ``tool_joint`` at its origin (the ``tool`` frame is the
  sensor frame);
- with ``tcp`` given, a massless link ``tool_tcp`` is attached to ``sensor_link`` at that
  offset by a fixed joint ``tool_tcp_joint`` (a contact point where the URDF has none, e.g.
  the UR5's flange ``tool0``; ``tip_link`` may name it).

The sensor must ride on the tip's body: ``sensor_link`` must lie on the path from
``base_link`` to ``tip_link`` with only fixed joints between it and the tip; else, and for a
negative mass, a non-physical inertia or a URDF that already has a link or joint of those
names, :class:`RobotModelError`.

What is checked before Pinocchio parses a URDF
----------------------------------------------
A robot description comes from a parameter or a file, so it is checked with Python's
``xml.etree`` (non-recursive) before Pinocchio's parser (urdfdom), which recurses along the
kinematic tree (a chain 4000 links deep crashed every node that loaded it with SIGSEGV)
and trusts the numbers (a joint origin of 1e300 m, a zero or negative mass, a velocity
limit of 0 were accepted and failed later, as NaN states, a wrist joint at 13 times its
velocity limit, or a joint without a reflex). :func:`check_urdf` refuses, each with a
one-line :class:`RobotModelError` naming the link or joint:

- more than :data:`MAX_URDF_CHARS` characters (4 MiB; the Panda's URDF has 15 kB) - a file
  is read no further than that;
- an entity declaration (``<!ENTITY``): a URDF has no use for one, and an expansion that
  stays under expat's own limit took 4 GB and 42 s to start;
- XML that does not parse, a root element other than ``<robot>``;
- more than :data:`MAX_LINKS` links or joints (so the tree is at most that deep);
- an ``<origin>`` (of a joint, an inertial, a visual or a collision) whose ``xyz`` is not
  finite or more than :data:`MAX_OFFSET` (100 m) from its frame, or whose ``rpy`` is not
  finite; a joint ``<axis>`` that is not finite or is zero;
- an ``<inertial>`` whose mass is not finite, negative or above :data:`MAX_LINK_MASS`, or
  whose inertia is not finite, not positive semi-definite, has a principal moment above
  :data:`MAX_LINK_INERTIA`, or is not zero on a massless link;
- ``<limit>`` values that are not finite, ``<dynamics>`` damping or friction that is not a
  finite number >= 0.

:func:`load_chain` then checks the chain's joints (those a controller drives and a plant
simulates): the link each one moves (its child) has an ``<inertial>`` with a mass of at
least :data:`MIN_MASS` and a positive definite inertia (every principal moment at least
:data:`MIN_INERTIA`; links fixed to it may be massless frames); a revolute or prismatic
joint's ``lower`` is not above its ``upper``; a ``<limit>``'s ``effort`` and ``velocity``
are > 0. A 0 there means "not given" to some tools, but here it would silently remove the
joint's command clip and rate limit (effort) or its velocity reflex (velocity): it is
refused; a joint without ``<limit>`` (a continuous joint) has none, as before.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from cr_control.core.paths import config_dir

#: eps_q (rad/s, m/s): URDF joint Coulomb friction is modelled as F tanh(q'/eps_q), 76 % of F at
#: q' = eps_q (the plants simulate it, a controller compensates it).
JOINT_FRICTION_EPSILON = 0.01
#: Pinocchio joint models a serial chain controller drives: kind per short name.
REVOLUTE, CONTINUOUS, PRISMATIC = "revolute", "continuous", "prismatic"
JOINT_KINDS = {
    **dict.fromkeys(("JointModelRX", "JointModelRY", "JointModelRZ",
                     "JointModelRevoluteUnaligned"), REVOLUTE),
    **dict.fromkeys(("JointModelRUBX", "JointModelRUBY", "JointModelRUBZ",
                     "JointModelRevoluteUnboundedUnaligned"), CONTINUOUS),
    **dict.fromkeys(("JointModelPX", "JointModelPY", "JointModelPZ",
                     "JointModelPrismaticUnaligned"), PRISMATIC),
}
#: Smallest mass (kg) of the link each joint of a chain moves (and of all it carries).
MIN_MASS = 1e-9
#: Smallest principal moment of inertia (kg m^2) of the link each joint of a chain moves
#: (the lightest link of the arms here: the so100's gripper, 3e-6 kg m^2).
MIN_INERTIA = 1e-12
#: The most characters a robot description may have (4 MiB; the Panda's URDF: 15 kB).
MAX_URDF_CHARS = 4 * 1024 * 1024
#: The most links, and the most joints, a robot description may have (the largest URDF of
#: example-robot-data, the Tiago with its arm, has 130 links; Pinocchio's parser recurses
#: along the tree and crashed at 4000 links deep).
MAX_LINKS = 500
#: The farthest an ``<origin>`` may place a frame from its parent (m).
MAX_OFFSET = 100.0
#: The heaviest link (kg) and the largest principal moment of inertia (kg m^2) a robot
#: description may give: 10x the heaviest industrial arms' links.
MAX_LINK_MASS = 1e4
MAX_LINK_INERTIA = 1e4


class RobotModelError(ValueError):
    """The robot cannot be built from what was given; the message (one line) says why."""


#: Links (and their fixed joints, ``<link>_joint``) :func:`load_chain` adds for a tool.
TOOL_LINK, TCP_LINK = "tool", "tool_tcp"


def _floats(values, size: int, what: str) -> tuple[float, ...]:
    try:
        floats = tuple(float(v) for v in np.asarray(values, dtype=float).reshape(-1))
    except (TypeError, ValueError):
        floats = ()
    if len(floats) != size or not all(math.isfinite(v) for v in floats):
        given = " ".join(str(values).split())          # one line
        raise RobotModelError(f"{what} must be a finite number, got {given}" if size == 1
                              else f"{what} needs {size} finite values, got {given}")
    return floats


@dataclass(frozen=True)
class Tool:
    """A rigid tool mounted on a wrist force/torque sensor, for :func:`load_chain`.

    ``sensor_link``: the link whose frame is the sensor frame (the flange: ``panda_link8``,
    ``tool0``); ``mass`` (kg, >= 0); ``com`` (m): the centre of mass in the sensor frame;
    ``inertia`` (kg m^2): xx, xy, xz, yy, yz, zz about the centre of mass in the sensor
    frame's axes; ``tcp`` (m): a contact point in the sensor frame (adds the link
    ``tool_tcp``), or None. Values are stored as tuples of floats; RobotModelError (one
    line) for a negative mass or a non-physical inertia (not positive semi-definite, or a
    principal moment above the sum of the other two, or rotational inertia without mass).
    """

    sensor_link: str
    mass: float = 0.0
    com: tuple[float, ...] = (0.0, 0.0, 0.0)
    inertia: tuple[float, ...] = (0.0,) * 6
    tcp: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        mass = _floats(self.mass, 1, "tool mass")[0]
        if mass < 0.0:
            raise RobotModelError(f"tool mass must be >= 0 kg, got {mass:g}")
        object.__setattr__(self, "mass", mass)
        object.__setattr__(self, "com", _floats(self.com, 3, "tool com"))
        object.__setattr__(self, "inertia", _floats(self.inertia, 6, "tool inertia"))
        if self.tcp is not None:
            object.__setattr__(self, "tcp", _floats(self.tcp, 3, "tool tcp"))
        moments = np.linalg.eigvalsh(self.inertia_matrix)
        tol = 1e-12 + 1e-9 * float(np.max(np.abs(moments)))
        if moments[0] < -tol or moments[2] > moments[0] + moments[1] + tol:
            raise RobotModelError(f"tool inertia {list(self.inertia)} is not physical: its principal "
                                  f"moments {np.round(moments, 12).tolist()} must be >= 0 and each at "
                                  "most the sum of the other two")
        if mass == 0.0 and moments[2] > tol:
            raise RobotModelError("tool inertia without tool mass is not physical")

    @property
    def inertia_matrix(self) -> np.ndarray:
        """The 3 x 3 inertia about the centre of mass, sensor frame axes (kg m^2)."""
        xx, xy, xz, yy, yz, zz = self.inertia
        return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])

    @property
    def spatial_inertia(self) -> pin.Inertia:
        """The tool's spatial inertia about the sensor origin, sensor frame axes."""
        return pin.Inertia(self.mass, np.array(self.com), self.inertia_matrix)


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits of the chain in its joint order (inf where the URDF gives none)."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


@dataclass(frozen=True)
class ChainModel:
    """The chain from ``base_link`` to ``tip_link``, rooted at the base.

    ``model`` is the reduced Pinocchio model (only the chain's joints move; base frame =
    world frame of the model, gravity ``model.gravity`` expressed in it); ``tip`` is the
    frame id of ``tip_link``. ``kinds`` is revolute / continuous / prismatic per joint;
    continuous joints have two configuration entries in Pinocchio (cos, sin): use
    :meth:`configuration` to turn joint angles into Pinocchio's ``q``.
    """

    model: pin.Model
    tip: int
    base_link: str
    tip_link: str
    joint_names: tuple[str, ...]
    kinds: tuple[str, ...]
    limits: JointLimits
    damping: np.ndarray
    friction: np.ndarray
    #: The tool on a wrist sensor the model carries (:class:`Tool`), or None.
    tool: Tool | None = None

    @property
    def n(self) -> int:
        """Number of joints of the chain."""
        return len(self.joint_names)

    def configuration(self, angles: np.ndarray) -> np.ndarray:
        """Pinocchio's configuration vector for joint positions ``angles`` (rad or m)."""
        if self.model.nq == self.n:
            return np.asarray(angles, dtype=float)
        q = np.empty(self.model.nq)
        for j, (kind, x) in enumerate(zip(self.kinds, angles, strict=True)):
            i = self.model.joints[j + 1].idx_q
            if kind == CONTINUOUS:
                q[i], q[i + 1] = np.cos(x), np.sin(x)
            else:
                q[i] = x
        return q

    def tip_pose(self, angles: np.ndarray) -> pin.SE3:
        """Placement of the tip in the base frame at joint positions ``angles``."""
        data = self.model.createData()
        pin.framesForwardKinematics(self.model, data, self.configuration(angles))
        return data.oMf[self.tip].copy()


# -- finding the URDF ----------------------------------------------------------------------------
def package_share(package: str) -> Path:
    """The share directory of ``package``: a ROS install (AMENT_PREFIX_PATH), a pip-installed
    cmeel package (example-robot-data installs ``cmeel.prefix/share/<package>``), or
    ROS_PACKAGE_PATH. RobotModelError if none has it."""
    candidates = [Path(p) / "share" / package
                  for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    candidates += [Path(p) / "cmeel.prefix" / "share" / package for p in sys.path if p]
    candidates += [Path(p) / package
                   for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
    for path in candidates:
        if path.is_dir():
            return path
    hint = " (pip install example-robot-data; `make demo ROBOT=panda` installs it)" \
        if package == "example-robot-data" else ""
    raise RobotModelError(f"package {package!r} not found{hint}")


def resolve_urdf_file(name: str) -> Path:
    """The file ``name`` names: ``package://PKG/path``, a path, or a file of the config
    directory (``two_link_arm.urdf``). RobotModelError if there is none."""
    if name.startswith("package://"):
        package, _, rest = name[len("package://"):].partition("/")
        path = package_share(package) / rest
    else:
        path = Path(name).expanduser()
        if not path.is_absolute() and not path.exists() and (config_dir() / name).exists():
            path = config_dir() / name
    if path.exists() and not path.is_file():    # a pipe would block its reader for ever
        raise RobotModelError(f"urdf_file {name}: not a regular file (a directory, pipe, device "
                              "or socket)")
    if not path.is_file():
        raise RobotModelError(f"urdf_file {name}: no such file")
    return path


def urdf_text(robot_description: str, urdf_file: str) -> str:
    """The URDF XML: ``robot_description`` if given, else the contents of ``urdf_file`` (read
    no further than :data:`MAX_URDF_CHARS` and one more character: :func:`check_urdf`
    refuses a longer one)."""
    if robot_description.strip():
        return robot_description
    if not urdf_file.strip():
        raise RobotModelError("no robot given: set robot_description (the URDF XML) or urdf_file")
    try:
        with resolve_urdf_file(urdf_file).open(encoding="utf-8") as f:
            return f.read(MAX_URDF_CHARS + 1)
    except (OSError, UnicodeDecodeError) as exc:
        raise RobotModelError(f"urdf_file {urdf_file}: cannot read it ({exc})") from None


# -- checking a robot description (module docstring) -------------------------------------------
def _numbers(element: ET.Element, attribute: str, size: int, where: str) -> tuple[float, ...] | None:
    """The ``size`` numbers of ``element``'s ``attribute`` (None if it has none: the URDF's
    default applies); RobotModelError unless they are that many finite numbers."""
    text = element.get(attribute)
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        values = ()
    if len(values) != size or not all(math.isfinite(v) for v in values):
        shown = " ".join(text.split())[:80]
        raise RobotModelError(f"{where}: <{element.tag} {attribute}=\"{shown}\"> needs "
                              + ("a finite number" if size == 1 else f"{size} finite numbers"))
    return values


def _check_origin(origin: ET.Element, where: str) -> None:
    xyz = _numbers(origin, "xyz", 3, where)
    _numbers(origin, "rpy", 3, where)
    if xyz is not None and math.hypot(*xyz) > MAX_OFFSET:
        raise RobotModelError(f"{where}: <origin xyz=\"{_xyz(xyz)}\"> places a frame "
                              f"{math.hypot(*xyz):.3g} m from its parent: more than {MAX_OFFSET:g} m")


def _inertia_moments(inertia: ET.Element, where: str) -> np.ndarray | None:
    """The principal moments (ascending) of an ``<inertia>`` (None if it misses a value:
    urdfdom then refuses the URDF)."""
    values = [_numbers(inertia, a, 1, where) for a in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")]
    if any(v is None for v in values):
        return None
    xx, xy, xz, yy, yz, zz = (v[0] for v in values)
    return np.linalg.eigvalsh(np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]))


def _check_link(link: ET.Element) -> None:
    where = f"link {link.get('name')!r}"
    for origin in link.iter("origin"):
        _check_origin(origin, where)
    for inertial in link.findall("inertial"):
        mass_element = inertial.find("mass")
        mass = _numbers(mass_element, "value", 1, where) if mass_element is not None else None
        if mass is not None and not 0.0 <= mass[0] <= MAX_LINK_MASS:
            raise RobotModelError(f"{where}: <mass value=\"{mass[0]:g}\">: a link's mass must be "
                                  f">= 0 and at most {MAX_LINK_MASS:g} kg")
        inertia = inertial.find("inertia")
        moments = _inertia_moments(inertia, where) if inertia is not None else None
        if moments is None:
            continue
        tol = 1e-12 + 1e-9 * float(np.max(np.abs(moments)))
        if moments[0] < -tol:
            raise RobotModelError(f"{where}: its <inertia> is not positive semi-definite (principal "
                                  f"moments {_moments(moments)} kg m^2)")
        if moments[2] > MAX_LINK_INERTIA:
            raise RobotModelError(f"{where}: its <inertia> has a principal moment of "
                                  f"{moments[2]:.3g} kg m^2: more than {MAX_LINK_INERTIA:g}")
        if mass is not None and mass[0] == 0.0 and moments[2] > tol:
            raise RobotModelError(f"{where}: rotational inertia (principal moments "
                                  f"{_moments(moments)} kg m^2) without mass is not physical")


def _moments(moments: np.ndarray) -> str:
    return "[" + ", ".join(f"{m:.3g}" for m in moments) + "]"


def _check_joint(joint: ET.Element) -> None:
    where = f"joint {joint.get('name')!r}"
    for origin in joint.findall("origin"):
        _check_origin(origin, where)
    for axis in joint.findall("axis"):
        xyz = _numbers(axis, "xyz", 3, where)
        if xyz is not None and math.hypot(*xyz) == 0.0:
            raise RobotModelError(f"{where}: <axis xyz=\"{_xyz(xyz)}\"> is zero: a joint needs a "
                                  "direction")
    for limit in joint.findall("limit"):
        for attribute in ("lower", "upper"):
            _numbers(limit, attribute, 1, where)
        for attribute in ("effort", "velocity"):
            value = _numbers(limit, attribute, 1, where)
            if value is not None and value[0] < 0.0:
                _refuse_limit(where, attribute, value[0])
    for dynamics in joint.findall("dynamics"):
        for attribute in ("damping", "friction"):
            value = _numbers(dynamics, attribute, 1, where)
            if value is not None and value[0] < 0.0:
                raise RobotModelError(f"{where}: <dynamics {attribute}=\"{value[0]:g}\"> must be >= 0 "
                                      "(a negative one would drive the joint)")


def check_urdf(xml: str) -> ET.Element:
    """The root element of the robot description ``xml`` once it has passed the checks of the
    module docstring ("What is checked before Pinocchio parses a URDF"); RobotModelError
    (one line) with the first that fails. Linear in the size of ``xml``; nothing recurses."""
    if len(xml) > MAX_URDF_CHARS:
        size = f"{len(xml) / 2**20:.1f} MiB" if len(xml) <= 10 * MAX_URDF_CHARS else "more than 40 MiB"
        raise RobotModelError(f"the URDF is {size} of text: more than the "
                              f"{MAX_URDF_CHARS // 2**20} MiB a robot description may have")
    if "<!ENTITY" in xml:
        raise RobotModelError("the URDF declares an entity (<!ENTITY ...>): refused, a URDF has no "
                              "use for one and its expansion can take gigabytes")
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as exc:
        raise RobotModelError(f"the URDF is not valid XML: {exc}") from None
    if root.tag != "robot":
        raise RobotModelError(f"the URDF's root element is <{root.tag}>, not <robot>")
    links, joints = root.findall("link"), root.findall("joint")
    for what, elements in (("links", links), ("joints", joints)):
        if len(elements) > MAX_LINKS:
            raise RobotModelError(f"the URDF has {len(elements)} {what}: more than the {MAX_LINKS} a "
                                  "robot description may have")
    for link in links:
        _check_link(link)
    for joint in joints:
        _check_joint(joint)
    return root


def _check_chain_joints(root: ET.Element, names: tuple[str, ...]) -> None:
    """The checks of the joints ``names`` of the chain (module docstring): the link each
    moves has mass and a positive definite inertia; position limits in order; effort and
    velocity limits > 0 where a ``<limit>`` gives them."""
    joints = {joint.get("name"): joint for joint in root.findall("joint")}
    links = {link.get("name"): link for link in root.findall("link")}
    for name in names:
        joint = joints.get(name)
        if joint is None:                    # not a URDF joint (cannot happen with urdfdom)
            continue
        where = f"joint {name!r}"
        child = joint.find("child")
        link_name = child.get("link") if child is not None else None
        link = links.get(link_name)
        inertial = link.find("inertial") if link is not None else None
        mass_element = inertial.find("mass") if inertial is not None else None
        inertia = inertial.find("inertia") if inertial is not None else None
        mass = _numbers(mass_element, "value", 1, where) if mass_element is not None else None
        moments = _inertia_moments(inertia, where) if inertia is not None else None
        if mass is None or mass[0] < MIN_MASS or moments is None or moments[0] < MIN_INERTIA:
            given = ("no <inertial>" if inertial is None else
                     f"mass {mass[0]:g} kg" if mass is not None and mass[0] < MIN_MASS else
                     f"principal moments {_moments(moments)} kg m^2" if moments is not None
                     else "an incomplete <inertial>")
            raise RobotModelError(f"{where} moves link {link_name!r}, which has {given}: the link a "
                                  f"joint of the chain moves needs a mass >= {MIN_MASS:g} kg and a "
                                  f"positive definite inertia (principal moments >= {MIN_INERTIA:g} "
                                  "kg m^2)")
        limit = joint.find("limit")
        if limit is None:
            continue
        lower, upper = (_numbers(limit, a, 1, where) or (0.0,) for a in ("lower", "upper"))
        if joint.get("type") in ("revolute", "prismatic") and lower[0] > upper[0]:
            raise RobotModelError(f"{where}: <limit lower=\"{lower[0]:g}\" upper=\"{upper[0]:g}\">: "
                                  "the lower position limit is above the upper one")
        for attribute in ("effort", "velocity"):
            value = _numbers(limit, attribute, 1, where)
            if value is not None and not value[0] > 0.0:
                _refuse_limit(where, attribute, value[0])


def _refuse_limit(where: str, attribute: str, value: float) -> None:
    """RobotModelError for an effort or velocity ``<limit>`` that is not > 0."""
    what, removed = {"effort": ("an effort limit", "its command clip and rate limit"),
                     "velocity": ("a velocity limit", "its velocity reflex")}[attribute]
    raise RobotModelError(f"{where}: <limit {attribute}=\"{value:g}\">: {what} must be > 0 "
                          f"({value:g} would remove {removed}); give the joint's real limit")


# -- building the chain --------------------------------------------------------------------------
@contextlib.contextmanager
def _captured_stderr() -> Iterator[list[str]]:
    """Capture what C code writes to file descriptor 2 (urdfdom prints its parse errors
    there) into the yielded list of lines, instead of the terminal."""
    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            lines += sink.read().decode(errors="replace").splitlines()


def parse_urdf(xml: str) -> pin.Model:
    """Pinocchio's model of the whole URDF once :func:`check_urdf` has passed it;
    RobotModelError with the check's or urdfdom's first reason."""
    check_urdf(xml)
    return _pinocchio_model(xml)


def _pinocchio_model(xml: str) -> pin.Model:
    """Pinocchio's model of a URDF :func:`check_urdf` has passed (urdfdom's first reason if
    it refuses it)."""
    with _captured_stderr() as errors:
        try:
            model = pin.buildModelFromXML(xml)
        except (ValueError, RuntimeError) as exc:
            model, failure = None, str(exc)
    if model is None:
        reasons = [e.split("Error:", 1)[1].strip() for e in errors if "Error:" in e]
        raise RobotModelError(f"the URDF does not parse: {reasons[0] if reasons else failure}")
    return model


def _body_frame(model: pin.Model, link: str, role: str) -> int:
    if not model.existFrame(link, pin.BODY):
        links = sorted(f.name for f in model.frames if f.type == pin.BODY)
        raise RobotModelError(f"{role} {link!r} is not a link of the URDF (links: {', '.join(links)})")
    return model.getFrameId(link, pin.BODY)


def _supporting_joints(model: pin.Model, frame: int) -> list[int]:
    """Joint ids from the root to the joint that carries ``frame`` (universe excluded)."""
    return [j for j in model.supports[model.frames[frame].parentJoint] if j > 0]


def _rooted_at(model: pin.Model, base: int) -> None:
    """Re-express ``model`` (whose moving joints all lie beyond ``base``, a frame on the
    universe) in the base frame: the first joints' placements, the universe's frames and
    gravity are moved by the inverse of the base's placement."""
    to_base = model.frames[base].placement.inverse()
    for j in range(1, model.njoints):
        if model.parents[j] == 0:
            model.jointPlacements[j] = to_base * model.jointPlacements[j]
    for frame in model.frames:
        if frame.parentJoint == 0:
            frame.placement = to_base * frame.placement
    model.gravity = pin.Motion(to_base.rotation @ model.gravity.linear, np.zeros(3))


def _locked_configuration(model: pin.Model) -> np.ndarray:
    """Neutral configuration with every bounded joint clipped into its limits."""
    q = pin.neutral(model)
    lower, upper = model.lowerPositionLimit, model.upperPositionLimit
    bounded = np.isfinite(lower) & np.isfinite(upper) & (lower <= upper)
    q[bounded] = np.clip(q[bounded], lower[bounded], upper[bounded])
    return q


def _xyz(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _with_tool(xml: str, base_link: str, tip_link: str, tool: Tool) -> str | None:
    """The URDF ``xml`` with ``tool`` mounted on its sensor link (module docstring), or None
    where the chain itself is wrong (not XML, no such base or tip, the base not above the
    tip): the checks on the parsed model then say why. RobotModelError for a sensor link
    the tool cannot ride on."""
    try:
        root = ET.fromstring(xml)
    except ET.ParseError:
        return None
    links = {link.get("name"): link for link in root.findall("link")}
    joint_names = {joint.get("name") for joint in root.findall("joint")}
    sensor = tool.sensor_link
    if sensor not in links:
        raise RobotModelError(f"sensor_link {sensor!r} is not a link of the URDF")
    added = [TOOL_LINK] + ([TCP_LINK] if tool.tcp is not None else [])
    for name in added:
        if name in links or f"{name}_joint" in joint_names:
            raise RobotModelError(f"the URDF already has a link or joint named {name!r}: cannot "
                                  "mount the tool")
    parent_joint = {}                               # child link -> the joint carrying it
    children: dict[str, list[str]] = {}
    for joint in root.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is not None and child is not None:
            parent_joint[child.get("link")] = joint
            children.setdefault(parent.get("link"), []).append(child.get("link"))
    # what the URDF mounts beyond the sensor loses its mass: the tool replaces it
    beyond, stack = set(), list(children.get(sensor, []))
    while stack:
        link = stack.pop()
        if link not in beyond:
            beyond.add(link)
            stack += children.get(link, [])
    for link in beyond:
        for inertial in links[link].findall("inertial") if link in links else ():
            links[link].remove(inertial)
    # the tool's body (its frame: the sensor frame) and its contact point
    body = ET.Element("link", name=TOOL_LINK)
    inertial = ET.SubElement(body, "inertial")
    ET.SubElement(inertial, "origin", xyz=_xyz(tool.com), rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=repr(tool.mass))
    ET.SubElement(inertial, "inertia", **dict(zip(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"),
                                                  (repr(v) for v in tool.inertia), strict=True)))
    mounted = [(body, (0.0, 0.0, 0.0))]
    if tool.tcp is not None:
        mounted.append((ET.Element("link", name=TCP_LINK), tool.tcp))
    for link, offset in mounted:
        name = link.get("name")
        joint = ET.Element("joint", name=f"{name}_joint", type="fixed")
        ET.SubElement(joint, "parent", link=sensor)
        ET.SubElement(joint, "child", link=name)
        ET.SubElement(joint, "origin", xyz=_xyz(offset), rpy="0 0 0")
        root.extend([link, joint])
        links[name], parent_joint[name] = link, joint
    # the sensor rides on the tip's body: on the path base -> tip, only fixed joints to the tip
    if tip_link not in links or base_link not in links:
        return None
    path = [tip_link]
    while path[-1] != base_link and path[-1] in parent_joint and len(path) <= len(links):
        path.append(parent_joint[path[-1]].find("parent").get("link"))
    if path[-1] != base_link:
        return None
    if sensor not in path:
        raise RobotModelError(f"sensor_link {sensor!r} is not on the chain from base_link "
                              f"{base_link!r} to tip_link {tip_link!r}")
    for link in path[:path.index(sensor)]:
        joint = parent_joint[link]
        if joint.get("type") != "fixed":
            raise RobotModelError(f"sensor_link {sensor!r} is not fixed to tip_link {tip_link!r}: "
                                  f"joint {joint.get('name')!r} moves between them (the sensor must "
                                  "ride on the tip's link)")
    return ET.tostring(root, encoding="unicode")


def load_chain(robot_description: str, urdf_file: str, base_link: str, tip_link: str,
               gravity: np.ndarray | None = None, tool: Tool | None = None) -> ChainModel:
    """The chain ``base_link`` -> ``tip_link`` of the URDF (see the module docstring).

    ``gravity`` (m/s^2, base frame) replaces Pinocchio's default (0, 0, -9.81) if given.
    ``tool``: a tool on a wrist sensor replacing what the URDF mounts beyond the sensor's
    link (module docstring); the model then carries it, and ``tip_link`` may be ``tool_tcp``
    if the tool has a ``tcp``.
    """
    xml = urdf_text(robot_description, urdf_file)
    root = check_urdf(xml)
    if tool is not None:
        xml = _with_tool(xml, base_link, tip_link, tool) or xml
    full = _pinocchio_model(xml)
    base = _body_frame(full, base_link, "base_link")
    tip = _body_frame(full, tip_link, "tip_link")
    to_base, to_tip = _supporting_joints(full, base), _supporting_joints(full, tip)
    if to_tip[:len(to_base)] != to_base:
        raise RobotModelError(f"base_link {base_link!r} is not on the way from the root to "
                              f"tip_link {tip_link!r}")
    chain = to_tip[len(to_base):]
    if not chain:
        raise RobotModelError(f"no joint moves {tip_link!r} relative to {base_link!r}")
    for j in chain:
        kind = full.joints[j].shortname()
        if kind not in JOINT_KINDS:
            raise RobotModelError(f"joint {full.names[j]!r} is a {kind[len('JointModel'):]} "
                                  "joint: a chain may have revolute, continuous and prismatic "
                                  "joints only")
    locked = [j for j in range(1, full.njoints) if j not in chain]
    model = pin.buildReducedModel(full, locked, _locked_configuration(full)) if locked else full
    base = model.getFrameId(base_link, pin.BODY)
    tip = model.getFrameId(tip_link, pin.BODY)
    _rooted_at(model, base)
    if gravity is not None:
        model.gravity = pin.Motion(np.asarray(gravity, dtype=float), np.zeros(3))
    names = tuple(model.names[1:])
    _check_chain_joints(root, names)
    _check_inertia(model, names)
    kinds = tuple(JOINT_KINDS[model.joints[j].shortname()] for j in range(1, model.njoints))
    if tool is not None and not model.existFrame(TOOL_LINK, pin.BODY):
        raise RobotModelError(f"cannot mount the tool on sensor_link {tool.sensor_link!r}")
    return ChainModel(model, tip, base_link, tip_link, names, kinds, _limits(model, kinds),
                      np.array(model.damping, dtype=float), np.array(model.friction, dtype=float),
                      tool)


def _check_inertia(model: pin.Model, names: tuple[str, ...]) -> None:
    """RobotModelError unless every joint moves some mass: the mass matrix must be positive
    definite (a URDF without <inertial> elements is a kinematic model only)."""
    for j in range(model.njoints - 1, 0, -1):
        beyond = sum(model.inertias[k].mass for k in range(j, model.njoints)
                     if j in model.supports[k])
        if beyond < MIN_MASS:
            raise RobotModelError(f"no mass beyond joint {names[j - 1]!r}: the URDF has no "
                                  "<inertial> for the links it moves, so the chain has no dynamics")


def _limits(model: pin.Model, kinds: tuple[str, ...]) -> JointLimits:
    lower, upper, velocity, effort = [], [], [], []
    for j, kind in enumerate(kinds, start=1):
        iq, iv = model.joints[j].idx_q, model.joints[j].idx_v
        bounded = kind != CONTINUOUS
        lower.append(float(model.lowerPositionLimit[iq]) if bounded else -np.inf)
        upper.append(float(model.upperPositionLimit[iq]) if bounded else np.inf)
        velocity.append(float(model.velocityLimit[iv]))
        effort.append(float(model.effortLimit[iv]))
    as_limit = lambda v: np.where(np.isfinite(v) & (np.abs(v) < 1e300), v, np.sign(v) * np.inf)  # noqa: E731
    return JointLimits(as_limit(np.array(lower)), as_limit(np.array(upper)),
                       as_limit(np.array(velocity)), as_limit(np.array(effort)))
