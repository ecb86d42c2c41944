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
"""

from __future__ import annotations

import contextlib
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
#: Smallest mass (kg) and rotational inertia (kg m^2) the bodies moved by a joint may have.
MIN_MASS = 1e-9


class RobotModelError(ValueError):
    """The robot cannot be built from what was given; the message (one line) says why."""


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
    if not path.is_file():
        raise RobotModelError(f"urdf_file {name}: no such file")
    return path


def urdf_text(robot_description: str, urdf_file: str) -> str:
    """The URDF XML: ``robot_description`` if given, else the contents of ``urdf_file``."""
    if robot_description.strip():
        return robot_description
    if not urdf_file.strip():
        raise RobotModelError("no robot given: set robot_description (the URDF XML) or urdf_file")
    try:
        return resolve_urdf_file(urdf_file).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise RobotModelError(f"urdf_file {urdf_file}: cannot read it ({exc})") from None


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
    """Pinocchio's model of the whole URDF; RobotModelError with urdfdom's first reason."""
    try:
        ET.fromstring(xml)
    except ET.ParseError as exc:
        raise RobotModelError(f"the URDF is not valid XML: {exc}") from None
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


def load_chain(robot_description: str, urdf_file: str, base_link: str, tip_link: str,
               gravity: np.ndarray | None = None) -> ChainModel:
    """The chain ``base_link`` -> ``tip_link`` of the URDF (see the module docstring).

    ``gravity`` (m/s^2, base frame) replaces Pinocchio's default (0, 0, -9.81) if given.
    """
    full = parse_urdf(urdf_text(robot_description, urdf_file))
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
    _check_inertia(model, names)
    kinds = tuple(JOINT_KINDS[model.joints[j].shortname()] for j in range(1, model.njoints))
    return ChainModel(model, tip, base_link, tip_link, names, kinds, _limits(model, kinds),
                      np.array(model.damping, dtype=float), np.array(model.friction, dtype=float))


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
