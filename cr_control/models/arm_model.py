"""Planar 2-link arm of the thesis (ch. 2, 3, 5, 6) built from URDF through Pinocchio.

The arm moves in the vertical x-y plane with gravity along -y. Notation of eq. (2.103)
with the d/l swap of chapter 6 resolved (docs/thesis.md): link length ``length`` (0.3 m), centre of
mass ``com`` from the joint (0.15 m), mass ``mass`` (0.1 kg) and inertia ``inertia``
(0.3 kg m^2) about the centre of mass. The closed forms printed in the thesis are in
:func:`closed_form_dynamics` so tests can compare them with Pinocchio.

Any URDF whose chain ``base_link`` -> ``tip_link`` is a planar 2-link arm gives this arm
(:func:`two_link_chain`): the chain comes from :func:`cr_control.models.urdf.load_chain`
(joint names, limits, ``<dynamics>``), the :class:`LinkParameters` override its geometry
and inertia, and a chain that is not a planar 2-link arm is refused with
:class:`NotTwoLinkArmError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from cr_control.core.paths import config_file
from cr_control.models.urdf import CONTINUOUS, JOINT_KINDS, ChainModel, RobotModelError, load_chain

URDF_NAME = "two_link_arm.urdf"
TOOL_FRAME = "tool0"
BASE_FRAME = "base_link"
GRAVITY = 9.8
#: Rounding a re-rooted joint placement may carry (m, and entries of a rotation matrix).
PLACEMENT_TOLERANCE = 1e-9


class NotTwoLinkArmError(RobotModelError):
    """The URDF loads, but its chain is not a planar 2-link arm; the message says why."""


@dataclass
class LinkParameters:
    """Geometric and inertial parameters of the two links (thesis 3.5 defaults)."""

    length: list[float] = field(default_factory=lambda: [0.3, 0.3])
    com: list[float] = field(default_factory=lambda: [0.15, 0.15])
    mass: list[float] = field(default_factory=lambda: [0.1, 0.1])
    inertia: list[float] = field(default_factory=lambda: [0.3, 0.3])
    gravity: float = GRAVITY

    def validate(self) -> None:
        """Raise ValueError unless every value is finite and physically meaningful."""
        for name in ("length", "com", "mass", "inertia"):
            values = getattr(self, name)
            if len(values) != 2 or not all(math.isfinite(v) and v > 0 for v in values):
                raise ValueError(f"{name} must be two positive finite numbers, got {values}")
        if not math.isfinite(self.gravity) or self.gravity < 0:
            raise ValueError(f"gravity must be finite and >= 0, got {self.gravity}")

    def base_parameters(self) -> np.ndarray:
        """p1..p5 of eq. (6.119) (= P(1:5) of ch. 2): the arm's base inertial parameters."""
        m1, m2 = self.mass
        I1, I2 = self.inertia
        d1 = self.length[0]
        l1, l2 = self.com
        g = self.gravity
        return np.array([
            I1 + m1 * l1**2 + I2 + m2 * (d1**2 + l2**2),
            m2 * d1 * l2,
            I2 + m2 * l2**2,
            (m1 * l1 + m2 * d1) * g,
            m2 * l2 * g,
        ])


def _joint_kind(model: pin.Model, j: int) -> str:
    """How joint ``j`` moves, in words: "a revolute joint about z", "a continuous joint"..."""
    short = model.joints[j].shortname()
    kind = JOINT_KINDS.get(short)
    if kind is None:
        return f"a {short[len('JointModel'):]} joint"
    if kind == CONTINUOUS:
        return "a continuous joint"
    axis = short[-1].lower() if short[-1] in "XYZ" else \
        "(" + ", ".join(f"{a:g}" for a in model.joints[j].extract().axis) + ")"
    return f"a {kind} joint {'along' if kind == 'prismatic' else 'about'} {axis}"


def check_two_link(chain: ChainModel) -> None:
    """NotTwoLinkArmError unless ``chain`` is a planar 2-link arm as the thesis's scenarios
    need it: two revolute joints about z (URDF ``axis 0 0 1``), their origins not rotated
    (the links stay in the x-y plane of the base) and the first joint on the base's z axis."""
    model, names = chain.model, chain.joint_names
    if chain.n != 2:
        raise NotTwoLinkArmError(f"the chain {chain.base_link} -> {chain.tip_link} has "
                                 f"{chain.n} joint{'' if chain.n == 1 else 's'} "
                                 f"({', '.join(names)}), not 2")
    for j, name in enumerate(names, start=1):
        if model.joints[j].shortname() != "JointModelRZ":
            raise NotTwoLinkArmError(f"joint {name!r} is {_joint_kind(model, j)}, not a "
                                     "revolute joint about z")
        if not np.allclose(model.jointPlacements[j].rotation, np.eye(3), rtol=0.0,
                           atol=PLACEMENT_TOLERANCE):
            raise NotTwoLinkArmError(f"joint {name!r} has a rotated origin: its link leaves the "
                                     f"x-y plane of {chain.base_link!r} or turns in it")
    offset = model.jointPlacements[1].translation[:2]
    if np.abs(offset).max() > PLACEMENT_TOLERANCE:
        raise NotTwoLinkArmError(f"joint {names[0]!r} is at x-y "
                                 f"{[round(float(v), 6) for v in offset]} m from "
                                 f"{chain.base_link!r}, not at its origin")


def two_link_chain(robot_description: str, urdf_file: str, base_link: str, tip_link: str,
                   params: LinkParameters | None = None) -> ChainModel:
    """The chain ``base_link`` -> ``tip_link`` of the URDF (:func:`load_chain`) as the thesis's
    arm: a planar 2-link arm (:func:`check_two_link`) with ``params`` applied over the URDF's
    values - joint 2 at ``length[0]`` and the tip at ``length[1]`` along their link's x axis,
    each link's mass, centre of mass on its x axis and inertia about it (isotropic, as the
    thesis's I_i) - gravity ``params.gravity`` along -y of the base frame and joint 1 at the
    base's origin (a height above it dropped). The joint names, limits and ``<dynamics>``
    are the URDF's.

    RobotModelError (one line) if the URDF cannot be loaded; NotTwoLinkArmError if its chain
    is not a planar 2-link arm; ValueError if ``params`` are not physical.
    """
    params = params or LinkParameters()
    params.validate()
    chain = load_chain(robot_description, urdf_file, base_link, tip_link,
                       np.array([0.0, -params.gravity, 0.0]))
    check_two_link(chain)
    model = chain.model
    # exactly the planar arm: rounding of the re-rooting and a height of joint 1 above the
    # base (which a planar model does not see) dropped
    model.jointPlacements[1] = pin.SE3(np.eye(3), np.zeros(3))
    model.jointPlacements[2] = pin.SE3(np.eye(3), np.array([params.length[0], 0.0, 0.0]))
    for j in (1, 2):
        izz = params.inertia[j - 1]
        model.inertias[j] = pin.Inertia(
            params.mass[j - 1], np.array([params.com[j - 1], 0.0, 0.0]), np.diag([izz, izz, izz])
        )
    # the tip (and a joint frame of the tip's name, which frame lookups by name may find first)
    for frame in model.frames:
        if frame.name == tip_link and frame.parentJoint == 2:
            frame.placement.translation = np.array([params.length[1], 0.0, 0.0])
    return chain


def build_model(params: LinkParameters, urdf: Path | None = None) -> pin.Model:
    """Pinocchio model of the arm: URDF structure (default: the shipped one) with ``params`` applied."""
    return two_link_chain("", str(urdf or config_file(URDF_NAME)), BASE_FRAME, TOOL_FRAME,
                          params).model


class TwoLinkArm:
    """Joint-space dynamics M q'' + C q' + G = tau + J^T f (3.1) and tool kinematics."""

    joint_names = ("joint1", "joint2")

    def __init__(self, params: LinkParameters | None = None, urdf: Path | None = None,
                 chain: ChainModel | None = None):
        """The arm of ``params`` from the URDF ``urdf`` (default: the shipped one), or from
        ``chain``, a :func:`two_link_chain` already made with ``params``."""
        self.params = params or LinkParameters()
        if chain is None:
            chain = two_link_chain("", str(urdf or config_file(URDF_NAME)), BASE_FRAME,
                                   TOOL_FRAME, self.params)
        #: The URDF chain the arm was made from (names, limits, ``<dynamics>``).
        self.chain = chain
        self.model = chain.model
        self.data = self.model.createData()
        self.tool = chain.tip
        self.joint_names = chain.joint_names
        self._zero = np.zeros(2)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q), symmetric."""
        M = pin.crba(self.model, self.data, q)
        return np.triu(M) + np.triu(M, 1).T

    def nonlinear_effects(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """C(q, q') q' + G(q)."""
        return pin.rnea(self.model, self.data, q, v, self._zero)

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """G(q)."""
        return pin.computeGeneralizedGravity(self.model, self.data, q)

    def coriolis_matrix(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """C(q, q') in Christoffel form (M' - 2C skew-symmetric)."""
        return pin.computeCoriolisMatrix(self.model, self.data, q, v).copy()

    def tool_position(self, q: np.ndarray) -> np.ndarray:
        """End-effector position r = phi(q) in the x-y plane (5.2)."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.tool].translation[:2].copy()

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """J(q), 2x2: r' = J q' (5.3)."""
        J = pin.computeFrameJacobian(self.model, self.data, q, self.tool, pin.LOCAL_WORLD_ALIGNED)
        return J[:2, :].copy()

    def kinematics(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """r, J and J' q' at (q, q') in one pass."""
        model, data = self.model, self.data
        pin.forwardKinematics(model, data, q, v, self._zero)
        pin.updateFramePlacement(model, data, self.tool)
        r = data.oMf[self.tool].translation[:2].copy()
        jdot_v = pin.getFrameClassicalAcceleration(
            model, data, self.tool, pin.LOCAL_WORLD_ALIGNED
        ).linear[:2].copy()
        J = pin.computeFrameJacobian(model, data, q, self.tool, pin.LOCAL_WORLD_ALIGNED)[:2, :]
        return r, J.copy(), jdot_v

    def forward_dynamics(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """q'' from M q'' + C q' + G = tau (articulated-body algorithm)."""
        return pin.aba(self.model, self.data, q, v, tau).copy()

    def inverse_kinematics(self, r: np.ndarray, elbow_sign: float = -1.0) -> np.ndarray:
        """Joint angles reaching ``r`` with sign(sin theta2) = elbow_sign (ch. 6.3 inverse kinematics).

        The default branch (sin(theta2) < 0) is the one printed for ch. 6.
        """
        return two_link_inverse_kinematics(self.params.length, (0.0, 0.0), r, elbow_sign)


def two_link_inverse_kinematics(length, base, point, elbow_sign: float) -> np.ndarray:
    """[theta1, theta2] putting the tool of a 2-link arm based at ``base`` at ``point`` with
    sign(sin theta2) = elbow_sign: c1 = ((d1 + d2 c2) x + d2 s2 y)/r^2 with x, y relative to
    the base and atan2 (2.95-2.100 as corrected in docs/thesis.md; ch. 6.3). ValueError if out
    of reach."""
    d1, d2 = length
    x, y = float(point[0]) - base[0], float(point[1]) - base[1]
    rr = x * x + y * y
    c2 = (rr - d1 * d1 - d2 * d2) / (2.0 * d1 * d2)
    if not -1.0 <= c2 <= 1.0:
        raise ValueError(f"point {list(point)} is out of reach")
    s2 = math.copysign(math.sqrt(1.0 - c2 * c2), elbow_sign)
    c1 = ((d1 + d2 * c2) * x + d2 * s2 * y) / rr
    s1 = ((d1 + d2 * c2) * y - d2 * s2 * x) / rr
    return np.array([math.atan2(s1, c1), math.atan2(s2, c2)])


def closed_form_dynamics(
    params: LinkParameters, q: np.ndarray, v: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """M, C, G of eq. (2.103) and J of eq. (6.117) as printed (for checking the model).

    Thesis letters: d_i link length, l_i centre-of-mass distance (ch. 2 notation).
    """
    m1, m2 = params.mass
    I1, I2 = params.inertia
    d1, d2 = params.length
    l1, l2 = params.com
    g = params.gravity
    c1, c2, c12 = math.cos(q[0]), math.cos(q[1]), math.cos(q[0] + q[1])
    s1, s2, s12 = math.sin(q[0]), math.sin(q[1]), math.sin(q[0] + q[1])
    h = m2 * d1 * l2 * s2
    M = np.array([
        [I1 + m1 * l1**2 + I2 + m2 * (d1**2 + l2**2 + 2 * d1 * l2 * c2),
         I2 + m2 * (l2**2 + d1 * l2 * c2)],
        [I2 + m2 * (l2**2 + d1 * l2 * c2), I2 + m2 * l2**2],
    ])
    C = np.array([[-h * v[1], -h * (v[0] + v[1])], [h * v[0], 0.0]])
    G = np.array([(m1 * l1 + m2 * d1) * g * c1 + m2 * l2 * g * c12, m2 * l2 * g * c12])
    J = np.array([[-d1 * s1 - d2 * s12, -d2 * s12], [d1 * c1 + d2 * c12, d2 * c12]])
    return M, C, G, J
