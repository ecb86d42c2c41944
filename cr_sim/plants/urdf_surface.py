"""Any URDF arm pressing a compliant surface with its tip: the generic contact plant.

What it simulates
-----------------
The serial chain ``base_link`` -> ``tip_link`` of a URDF (:func:`cr_control.models.urdf.load_chain`:
every other joint locked where the URDF's neutral position, clipped into its limits, puts
it; what it carries rides on the chain as rigid mass), torque-commanded, whose tip point
touches a compliant environment (:mod:`cr_sim.models.contact3d`). Frames: everything is
in the base frame (``base_link``): gravity, the surface, the contact force; the measured
wrench is in ``wrench_frame``: the base frame (the ideal sensor) or the wrist sensor's frame.

Equations (state x = [q, q'], n chain joints)
----------------------------------------------
    M(q) q'' + C(q, q') q' + G(q) = tau + J_v(q)^T f - D q' - F tanh(q'/eps_q)

- tau the held command, J_v the linear rows of the tip Jacobian in the base frame
  (Pinocchio ``LOCAL_WORLD_ALIGNED``), f the contact force on the tip (base frame);
- D = diag(URDF ``<dynamics damping>``) viscous joint damping, F = diag(``<dynamics
  friction>``) Coulomb joint friction regularised over eps_q = :data:`JOINT_FRICTION_EPSILON`;
- q'' from Pinocchio's articulated-body algorithm (``pin.aba``) with that total torque.

Contact law (unilateral, at the tip point r, outward unit normal n, depth delta):

    f_n = max(K_e delta - D_e n.r', 0)  if delta > 0         (never pulls)
    f_t = -mu f_n v_t / sqrt(|v_t|^2 + eps^2) - c_v v_t      (only while f_n > 0)
    f   = f_n n + f_t

- plane: delta = -n.(r - p); the environment is the side n.(r - p) < 0; default p = the
  tip's initial position (the robot starts touching at zero force), n = +z (a table);
- sphere: delta = R - |r - c|, n = (r - c)/|r - c|, the environment inside the ball;
  default c = r_0 - R n_param (touching the tip at its initial position from below);
- none: free motion.

``start_clearance`` d >= 0 moves the surface (given or default) away from the tip's initial
position r_0 by d along its outward normal there (plane: p - d n; sphere: c - d (r_0 -
c)/|r_0 - c|): the robot starts d above the table, at rest, and has to come down to it.

Defaults: K_e = 5000 N/m (a compliant pad on a table: 2 mm at 10 N), D_e = 20 N s/m (a
lightly damped pad: 0.07 of critical for the Panda at home, whose tip weighs m_n = 4 kg
along z, so the controller has to damp the contact; the pad alone rings at
sqrt(K_e/m_n) = 35 rad/s, 5.6 Hz), no friction (the pure normal-force problem of the
thesis; set ``friction_coulomb``/``friction_viscous`` for sliding).

Integration
-----------
Classical RK4 with the command held over the period and the contact force evaluated at
every stage, ``substeps`` steps per period. ``substeps = 0`` chooses them once, from the
initial pose q_0, so that h omega_c <= 0.5 (RK4's stability limit on the real axis is 2.79,
on the imaginary axis 2.83):

    omega_c = max( sqrt((K_e + D_e^2/m_n)/m_n),      contact spring-damper along n
                   c_v / m_min,                       tangential viscous friction
                   lambda_max(M^-1 diag(D + F/eps_q)) )   joint damping and friction
    substeps = max(1, ceil(dt omega_c / 0.5))

with m_n = 1/(n^T J_v M^-1 J_v^T n) the apparent mass of the tip along the surface normal
and m_min the smallest apparent mass over all directions, at q_0. sqrt((K + D^2/m)/m)
bounds the magnitude of both roots of m s^2 + D s + K. Not counted: the regularised
Coulomb friction's slope mu f_n/eps (it depends on the force: set ``substeps`` by hand
for stiff sliding) and changes of the apparent mass away from q_0.

Robot side
----------
A real torque-controlled arm's driver adds its own compensation to every command:
libfranka adds g(q) (franka_ros2 takes "desired joint torques without gravity"),
ur_robot_driver's effort interface adds gravity and joint friction, KUKA FRI's torque mode
is an overlay on a gravity-compensating joint impedance. ``robot_compensates_gravity`` and
``robot_compensates_friction`` imitate that: the held torque is

    tau = tau_cmd + G(q_k) [+ D q'_k + F tanh(q'_k/eps_q)]

with (q_k, q'_k) the state the period starts from, as the robot computes it once per cycle
(franka_ros2's Gazebo gravity compensation system and MuJoCo's ``gravcomp`` do the same in
simulation). The brakes and the initial hold then leave G(q) out of their commands
(:meth:`URDFSurface.gravity_torque`). ``/joint_states`` reports the held torque.

Wrist sensor
------------
``sensor_frame`` empty (the default): the ideal sensor of the thesis plants, force = f (base
frame), torque = 0, noise ``force_noise_std``. ``sensor_frame`` = S, a link rigidly fixed to
the tip's body (the flange: ``panda_link8``, ``tool0``): a force/torque sensor there, as
force_torque_sensor_broadcaster publishes it (frame_id = S). The chain is built with a rigid
tool on S (:class:`cr_control.models.urdf.Tool`: mass m = ``tool_mass``, centre of mass c =
``tool_com`` and inertia I_c = ``tool_inertia`` in S; everything the URDF mounts beyond S,
the Panda's hand, loses its mass), so the arm really carries it; ``tool_tcp`` adds a link
``tool_tcp`` at that point of S (then ``tip_link: tool_tcp``). The sensor reads the wrench
the tool side exerts on the arm at the origin of S, in S's axes (Newton-Euler for the tool:
what the arm must supply to move it, with the sign turned):

    F = R^T f + m (R^T g - a_c)                                         + b_F + n_F
    T = p x R^T f + c x m (R^T g - a_c) - (I_c alpha + omega x I_c omega) + b_T + n_T
    a_c = a_o + omega x v_o + alpha x c + omega x (omega x c)

- R: rotation base <- S; f: the contact force on the tip (base frame); g: gravity (base
  frame); p: the tip in S (constant: the sensor rides on the tip's body);
- (v_o, omega), (a_o, alpha): S's spatial velocity and acceleration in S (Pinocchio
  ``LOCAL``), so a_c is the classical acceleration of the tool's centre of mass in S;
- b = ``ft_bias`` (6, S), n white noise of std ``ft_noise_std`` (force, torque; every
  component, fresh each measurement).

At rest out of contact: F = m R^T g, the tool's weight as seen in S (+m g along the flange
axis when it points down), T = c x F. The accelerations are those of the state measured:
q'' from Pinocchio's ABA with the held command and the contact (the integrator's own
derivative there), then S's velocity and acceleration from ``forwardKinematics``.
:meth:`URDFSurface.contact_wrench` gives the true contact wrench in the base frame (force
f, zero torque about the tip, the tip's position) for ``/plant/contact_wrench``: analysis
and tests, no controller reads it.

Joints
------
``joint_names`` = the chain's joints, then every other joint of the URDF with one
coordinate (the Panda's fingers), reported at their locked position with zero velocity
and effort; ``command_joint_names`` = the chain's joints: controllers pick their joints by
name. Measurement noise (if asked) is added to the chain's joints and to the wrench only.

Cost
----
One period is, per RK4 stage, two Pinocchio calls (``computeFrameJacobian``, ``aba``) and
two compiled glue kernels working in preallocated buffers; the tip position is read
through a live view of ``data.oMf[tip]`` (no copy). The contact force and depth for the
sensors are evaluated lazily, when asked, at the state the step ended in. Measured for the
Panda (1 ms step, pressing 10 N; an empty Python ``for`` iteration took 14-15 ns in the
same run): 17 us with 1 substep, 34 us with 2, 65 us with 4; ``measurement()`` adds 6 us.
Of each ~4 us stage, Pinocchio takes ~3.2 us (aba 2.4, the Jacobian 0.8), the glue ~0.8.
The wrist sensor leaves the step as it is (the tool is one more rigid body on the last
link: 17.5 us either way) and adds ~6 us to ``measurement()`` (a step and a measurement:
23.0 us without, 28.9 with, 31.1 with its noise drawn): one more ABA (2.5 us), second-order
forward kinematics (0.8), the sensor frame's placement, velocity and acceleration (0.4
each) and a compiled kernel (0.4).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pinocchio as pin
from numba import njit

from cr_control.core.parameters import Bound, Param, ParameterError
from cr_control.models.brake import brake_torque
from cr_control.models.urdf import (
    CONTINUOUS,
    JOINT_FRICTION_EPSILON,
    ChainModel,
    RobotModelError,
    Tool,
    _locked_configuration,
    load_chain,
    parse_urdf,
    urdf_text,
)
from cr_sim.models import contact3d
from cr_sim.models.contact3d import contact_into
from cr_sim.plants.arm_on_surface import NOISE_PARAMETERS
from cr_sim.plants.base import (
    JointLimits,
    Measurement,
    Plant,
    max_contact_force_parameter,
    take_command,
)

NAME = "urdf_surface"

#: Automatic substeps keep h omega_c at or below this.
STEP_RATE_LIMIT = 0.5
#: Surfaces by name.
SURFACES = {"none": contact3d.NONE, "plane": contact3d.PLANE, "sphere": contact3d.SPHERE}

PARAMETERS = [
    Param("robot_description", "", "The robot's URDF (XML); empty: read urdf_file.", "string",
          read_only=True),
    Param("urdf_file", "", "URDF file if robot_description is empty: a path, a file of this "
          "package's config directory or package://PKG/path.", "string", read_only=True),
    Param("base_link", "base_link", "First link of the simulated chain; its frame is the base "
          "frame of gravity, the surface and the contact force.", "string", read_only=True),
    Param("tip_link", "tool0", "Last link of the chain: its origin is the contact point.",
          "string", read_only=True),
    Param("gravity", [0.0, 0.0, -9.81], "Gravitational acceleration in the base frame (m/s^2).",
          "vector", 3, read_only=True, bound=Bound.GRAVITY),
    Param("initial_joint_positions", [], "Chain joint positions at t = 0, at rest (rad or m); "
          "empty: Pinocchio's neutral clipped into the joint limits.", "vector", read_only=True,
          bound=Bound.JOINT),
    Param("surface", "plane", "Environment: a plane, a sphere (pressed from outside) or none.",
          "choice", read_only=True, choices=tuple(SURFACES)),
    Param("surface_point", [], "A point of the plane, base frame (m); empty: the tip's initial "
          "position (touching at zero force).", "vector", read_only=True, bound=Bound.LENGTH),
    Param("surface_normal", [0.0, 0.0, 1.0], "Outward normal of the plane (normalised; the "
          "environment is on the side n.(r - point) < 0); sphere with surface_centre empty: "
          "direction from the centre to the tip's initial position.", "vector", 3,
          read_only=True, bound=Bound.SCALE),
    Param("surface_centre", [], "Centre of the sphere, base frame (m); empty: the tip's initial "
          "position - surface_radius * surface_normal (touching at zero force).", "vector",
          read_only=True, bound=Bound.LENGTH),
    Param("surface_radius", 0.1, "Radius of the sphere (m).", "positive", read_only=True, bound=Bound.LENGTH),
    Param("stiffness", 5000.0, "Contact stiffness K_e along the normal (N/m): a compliant pad, "
          "2 mm at 10 N.", "positive", read_only=True, bound=Bound.CONTACT_STIFFNESS),
    Param("damping", 20.0, "Contact damping D_e along the normal (N s/m); the normal force "
          "max(K_e depth - D_e n.r', 0) never pulls.", "nonnegative", read_only=True, bound=Bound.DAMPING),
    Param("friction_coulomb", 0.0, "Tangential Coulomb friction coefficient mu (regularised).",
          "nonnegative", read_only=True, bound=Bound.SCALE),
    Param("friction_viscous", 0.0, "Tangential viscous friction c_v while in contact (N s/m).",
          "nonnegative", read_only=True, bound=Bound.DAMPING),
    Param("friction_velocity_epsilon", 1e-3, "Regularisation eps of the Coulomb friction: "
          "mu f_n v_t/sqrt(|v_t|^2 + eps^2) (m/s).", "positive", read_only=True, bound=Bound.SPEED),
    *NOISE_PARAMETERS,
    max_contact_force_parameter(50.0, "5 x the wiping task's 10 N (cr_session --robot)."),
    Param("substeps", 0, "RK4 substeps per period; 0 = automatic: h omega_c <= 0.5 at the "
          "initial pose (see the module docstring).", "integer", read_only=True, bound=Bound.SUBSTEPS),
    Param("sensor_frame", "", "Wrist force/torque sensor: the link whose frame the wrench is "
          "measured in and published in (the flange: panda_link8, tool0); it carries the tool "
          "(tool_*) and has a bias and noise (ft_*). Empty: the ideal sensor (the contact force "
          "at the tip, base frame, torque 0).", "string", read_only=True),
    Param("tool_mass", 0.0, "Mass of the tool on the wrist sensor (kg); it replaces what the URDF "
          "mounts beyond sensor_frame (the Panda's hand).", "nonnegative", read_only=True,
          bound=Bound.MASS),
    Param("tool_com", [0.0, 0.0, 0.0], "The tool's centre of mass in the sensor frame (m).",
          "vector", 3, read_only=True, bound=Bound.LENGTH),
    Param("tool_inertia", [0.0] * 6, "The tool's inertia about its centre of mass, sensor frame "
          "axes (kg m^2): xx, xy, xz, yy, yz, zz.", "vector", 6, read_only=True, bound=Bound.INERTIA),
    Param("tool_tcp", [], "A contact point on the tool in the sensor frame (m): adds the link "
          "tool_tcp (then tip_link: tool_tcp); empty: none.", "vector", read_only=True,
          bound=Bound.LENGTH),
    Param("ft_bias", [0.0] * 6, "Constant bias of the wrist sensor, sensor frame: fx, fy, fz (N), "
          "tx, ty, tz (N m).", "vector", 6, read_only=True, bound=Bound.FORCE),
    Param("ft_noise_std", [0.0, 0.0], "White noise of the wrist sensor, std: force (N), torque "
          "(N m), on every component.", "nonnegative_vector", 2, read_only=True, bound=Bound.FORCE),
    Param("robot_compensates_gravity", False, "The robot adds g(q) to every command itself, as "
          "its driver does (franka_ros2: libfranka; ur_robot_driver's effort interface; KUKA FRI "
          "torque mode): the command is the torque beyond gravity. G(q) is the chain's, with "
          "the tool, at the state each period starts from, held over the period (libfranka "
          "computes it once per 1 kHz cycle).", "bool", read_only=True),
    Param("robot_compensates_friction", False, "The robot also adds the URDF's joint damping "
          "and friction D q' + F tanh(q'/eps_q) to every command (ur_robot_driver's effort "
          "interface compensates joint friction on the robot), at the state each period "
          "starts from.", "bool", read_only=True),
    Param("wrench_sign", 1, "Sign of the published wrench: 1 = the wrench on the tool (a wrist "
          "sensor, UR's TCP sensor); -1 = its reaction, as franka users report Franka's "
          "estimated external wrench O_F_ext_hat_K.", "integer", read_only=True, bound=1.0),
    Param("sensor_removes_payload", False, "The wrist sensor's reading leaves the tool's weight "
          "and inertia out (the robot removes its configured payload, as UR's built-in TCP "
          "sensor does); the arm still carries the tool.", "bool", read_only=True),
    Param("start_clearance", 0.0, "The surface starts this far (m) from the tip, moved away along "
          "its outward normal: the robot starts above the table (sphere: the centre moves away).",
          "nonnegative", read_only=True, bound=Bound.LENGTH),
]

#: The wrist sensor's parameters that must keep their defaults (zeros, empty) without sensor_frame.
SENSOR_PARAMETERS = ("tool_mass", "tool_com", "tool_inertia", "tool_tcp", "ft_bias", "ft_noise_std")


# -- compiled glue: one call before and one after each Pinocchio forward dynamics ------------
# Everything the glue reads or writes lives in one float64 work array, so each call unboxes
# two or three arguments (numba's dispatch costs ~60 ns per array argument and more per
# Python scalar); Pinocchio gets views of it. Layout, n chain joints, nq Pinocchio coordinates:
#   [n, nq, h, stage | x (2n) | xs (2n) | k (4 x 2n) | tau (n) | total (n) | contact (7) |
#    joint (2n + 1) | qmap (2n) | surface (13) | qp (nq)]
# x the state, xs the stage state, k the RK4 derivatives, tau the held command, total the
# stage's joint torque, contact = [f (3), depth, r' (3)], joint = [D (n), F (n), eps_q],
# qmap = [idx_q (n), continuous flag (n)], qp Pinocchio's q of the stage.
HEADER = 4
CONTACT_SIZE = 7


@njit(cache=True)
def layout(n, nq):
    """Offsets (x, xs, k, tau, total, contact, joint, qmap, surface, qp, end) in the work array."""
    x = HEADER
    xs = x + 2 * n
    k = xs + 2 * n
    tau = k + 8 * n
    total = tau + n
    contact = total + n
    joint = contact + CONTACT_SIZE
    qmap = joint + 2 * n + 1
    surface = qmap + 2 * n
    qp = surface + contact3d.SURFACE_SIZE
    return x, xs, k, tau, total, contact, joint, qmap, surface, qp, qp + nq


@njit(cache=True, error_model="numpy")
def _configuration(work):
    """Pinocchio's q from the stage positions xs[:n]: a continuous joint takes (cos, sin)."""
    n, nq = int(work[0]), int(work[1])
    _, xs, _, _, _, _, _, qmap, _, qp, _ = layout(n, nq)
    for j in range(n):
        i = qp + int(work[qmap + j])
        if work[qmap + n + j] != 0.0:
            work[i] = math.cos(work[xs + j])
            work[i + 1] = math.sin(work[xs + j])
        else:
            work[i] = work[xs + j]


@njit(cache=True, error_model="numpy")
def _begin(work, h):
    """Start a period: step size h, first stage, xs = x and Pinocchio's q from it."""
    n, nq = int(work[0]), int(work[1])
    x, xs, _, _, _, _, _, _, _, _, _ = layout(n, nq)
    work[2], work[3] = h, 0.0
    for j in range(2 * n):
        work[xs + j] = work[x + j]
    _configuration(work)


@njit(cache=True, error_model="numpy")
def _joint_torque(J, r, work):
    """total = tau - D q' - F tanh(q'/eps_q) + J_v^T f at the stage state xs = [q, q'].

    J: the tip Jacobian (6 x n, linear rows first, base-frame axes), r: the tip position;
    writes contact = [f (3), depth, r' = J_v q' (3)]."""
    n, nq = int(work[0]), int(work[1])
    _, xs, _, tau, total, c, joint, _, surface, _, _ = layout(n, nq)
    for i in range(3):
        s = 0.0
        for j in range(n):
            s += J[i, j] * work[xs + n + j]
        work[c + 4 + i] = s
    work[c + 3] = contact_into(work[surface:surface + contact3d.SURFACE_SIZE], r,
                               work[c + 4:c + 7], work[c:c + 3])
    fx, fy, fz = work[c], work[c + 1], work[c + 2]
    eps = work[joint + 2 * n]
    for j in range(n):
        w = work[xs + n + j]
        t = work[tau + j] - work[joint + j] * w + J[0, j] * fx + J[1, j] * fy + J[2, j] * fz
        friction = work[joint + n + j]
        if friction != 0.0:
            t -= friction * math.tanh(w / eps)
        work[total + j] = t


@njit(cache=True, error_model="numpy")
def _rk4_stage(a, work):
    """Store this stage's derivative k = [q', a] and prepare the next stage's state in xs
    (and Pinocchio's q); after the fourth, x += h/6 (k1 + 2 k2 + 2 k3 + k4), xs = x and
    the next period's first stage."""
    n, nq = int(work[0]), int(work[1])
    x, xs, k, _, _, _, _, _, _, _, _ = layout(n, nq)
    m = 2 * n
    h, stage = work[2], int(work[3])
    ks = k + stage * m
    for j in range(n):
        work[ks + j] = work[xs + n + j]
        work[ks + n + j] = a[j]
    if stage < 3:
        c = h if stage == 2 else 0.5 * h
        for j in range(m):
            work[xs + j] = work[x + j] + c * work[ks + j]
        work[3] = stage + 1
    else:
        w = h / 6.0
        for j in range(m):
            work[x + j] += w * (work[k + j] + work[k + 3 * m + j]
                                + 2.0 * (work[k + m + j] + work[k + 2 * m + j]))
            work[xs + j] = work[x + j]
        work[3] = 0.0
    _configuration(work)


_frame_jacobian = pin.computeFrameJacobian


def _frame_jacobian_of_one_joint(model, data, q, frame, reference):
    """pin.computeFrameJacobian as a 6 x 1 matrix (eigenpy hands a one-column matrix back as
    a vector)."""
    return pin.computeFrameJacobian(model, data, q, frame, reference).reshape(6, 1)


class ContactWrench(NamedTuple):
    """The true contact wrench on the tool, world (base) frame: ``force`` (N), ``torque``
    (N m) about ``point``, the tip (m; zero torque: a point contact)."""

    force: np.ndarray
    torque: np.ndarray
    point: np.ndarray


# -- building ----------------------------------------------------------------------------------
def _tool(values: dict) -> Tool | None:
    """The tool on the wrist sensor (sensor_frame set), or None (the ideal sensor; then the
    tool_* and ft_* parameters must keep their defaults)."""
    tcp = np.asarray(values["tool_tcp"], dtype=float)
    if tcp.size not in (0, 3):
        raise ParameterError(f"tool_tcp needs 3 values (or none), got {tcp.size}")
    if not values["sensor_frame"]:
        given = [name for name in SENSOR_PARAMETERS if np.any(np.asarray(values[name]) != 0.0)]
        if given:
            raise ParameterError(f"{', '.join(given)} need sensor_frame (the wrist sensor's link): "
                                 "without it the sensor is ideal")
        return None
    if values["force_noise_std"] > 0.0:
        raise ParameterError("force_noise_std is the ideal sensor's noise: with sensor_frame set, "
                             "use ft_noise_std")
    return Tool(values["sensor_frame"], values["tool_mass"], values["tool_com"],
                values["tool_inertia"], tcp if tcp.size else None)


def _chain(values: dict) -> ChainModel:
    try:
        return load_chain(values["robot_description"], values["urdf_file"], values["base_link"],
                          values["tip_link"], values["gravity"], _tool(values))
    except RobotModelError as exc:
        raise ParameterError(str(exc)) from None


def _locked_joints(values: dict, chain: ChainModel) -> tuple[tuple[str, ...], np.ndarray]:
    """Names and locked positions of the URDF's one-coordinate joints off the chain, in the
    URDF model's order (the position load_chain locked them at)."""
    full = parse_urdf(urdf_text(values["robot_description"], values["urdf_file"]))
    q = _locked_configuration(full)
    names, positions = [], []
    for j in range(1, full.njoints):
        joint, name = full.joints[j], full.names[j]
        if name in chain.joint_names or joint.nv != 1:
            continue
        i = joint.idx_q
        positions.append(math.atan2(q[i + 1], q[i]) if joint.nq == 2 else float(q[i]))
        names.append(name)
    return tuple(names), np.array(positions, dtype=float)


def _initial_positions(values: dict, chain: ChainModel) -> np.ndarray:
    given = np.asarray(values["initial_joint_positions"], dtype=float)
    if given.size == 0:
        neutral = pin.neutral(chain.model)
        angles = np.array([
            math.atan2(neutral[chain.model.joints[j + 1].idx_q + 1],
                       neutral[chain.model.joints[j + 1].idx_q]) if kind == CONTINUOUS
            else neutral[chain.model.joints[j + 1].idx_q]
            for j, kind in enumerate(chain.kinds)])
        return np.clip(angles, chain.limits.lower, chain.limits.upper)
    if given.shape != (chain.n,):
        raise ParameterError(f"initial_joint_positions needs {chain.n} values (joints "
                             f"{', '.join(chain.joint_names)}), got {given.size}")
    return given


def _three(values: dict, name: str, default: np.ndarray) -> np.ndarray:
    """A 3-vector parameter that may be left empty (then ``default``)."""
    given = np.asarray(values[name], dtype=float)
    if given.size == 0:
        return default
    if given.shape != (3,):
        raise ParameterError(f"{name} needs 3 values (or none), got {given.size}")
    return given


def _surface(values: dict, r0: np.ndarray) -> np.ndarray:
    """The packed surface (:mod:`cr_sim.models.contact3d`) from the parameters, with the tip
    at r0 (base frame) for the defaults that touch it."""
    normal = np.asarray(values["surface_normal"], dtype=float)
    norm = float(np.linalg.norm(normal))
    if not norm > 0.0:
        raise ParameterError("surface_normal must not be zero")
    normal = normal / norm
    kind, radius = values["surface"], values["surface_radius"]
    if kind == "sphere":
        anchor = _three(values, "surface_centre", r0 - radius * normal)
    else:
        anchor = _three(values, "surface_point", r0)
    surface = contact3d.packed(SURFACES[kind], anchor, normal, radius, values["stiffness"],
                               values["damping"], values["friction_coulomb"],
                               values["friction_viscous"], values["friction_velocity_epsilon"])
    clearance = values["start_clearance"]
    return contact3d.moved_away(surface, r0, clearance) if clearance else surface


class URDFSurface(Plant):
    """A URDF chain pressing a compliant plane or sphere with its tip (see the module
    docstring). State x = [q (n), q' (n)] of the chain."""

    command_interface = "effort"
    # No /plant/sensors: the contact depth is a method (tests, analysis offline), not a
    # 1 kHz topic no controller reads (it cost the recorder a message per cycle).

    def __init__(self, values: dict):
        if values["substeps"] < 0:
            raise ParameterError(f"substeps must be >= 0, got {values['substeps']}")
        self.chain = _chain(values)
        chain, n = self.chain, self.chain.n
        self._n = n
        self._locked_names, self._locked_q = _locked_joints(values, chain)
        self.joint_names = (*chain.joint_names, *self._locked_names)
        self.command_joint_names = tuple(chain.joint_names)
        #: The frame of the measured wrench (the frame_id to publish): the sensor's, else the base.
        self.wrench_frame = values["sensor_frame"] or values["base_link"]
        #: The base frame: gravity, the surface and :meth:`contact_wrench` are expressed in it.
        self.base_frame = values["base_link"]
        self.model, self._data = chain.model, chain.model.createData()
        self._query = chain.model.createData()      # for model queries, off the hot path
        self._tip = chain.tip
        q0 = _initial_positions(values, chain)
        self.surface = _surface(values, chain.tip_pose(q0).translation)
        self._noise = (values["position_noise_std"], values["velocity_noise_std"],
                       values["force_noise_std"])
        self._noisy = any(self._noise)
        self._rng = np.random.default_rng(values["noise_seed"])
        self._allocate()
        self._wrist_sensor(values)
        self._t = 0.0
        self.reset_state(q0)
        self.step_rate = self.stiffest_rate(q0)
        self.substeps = int(values["substeps"])
        self.max_contact_force = float(values["max_contact_force"])
        self._auto: tuple[float, int] = (math.nan, 1)
        #: The robot's own compensation added to every command (module docstring, "Robot side").
        if values["wrench_sign"] not in (1, -1):
            raise ParameterError(f"wrench_sign must be 1 or -1, got {values['wrench_sign']}")
        self._wrench_sign = float(values["wrench_sign"])
        self.robot_compensates_gravity = bool(values["robot_compensates_gravity"])
        self.robot_compensates_friction = bool(values["robot_compensates_friction"])
        robot_side = self.robot_compensates_gravity or self.robot_compensates_friction
        #: The last accepted command; the same array as the held torque unless the robot adds
        #: its own compensation to it.
        self._held = np.zeros(n) if robot_side else self._tau
        self._hold_with_robot_side()

    def _allocate(self) -> None:
        """The work array of the compiled glue (layout above) and the views of it the plant
        and Pinocchio use, made once: the hot path allocates nothing of its own."""
        chain, n, model = self.chain, self._n, self.model
        x, xs, _, tau, total, contact, joint, qmap, surface, qp, end = layout(n, model.nq)
        work = np.zeros(end)
        work[0], work[1] = n, model.nq
        work[joint:qmap] = np.concatenate([chain.damping, chain.friction, [JOINT_FRICTION_EPSILON]])
        work[qmap:surface] = ([model.joints[j + 1].idx_q for j in range(n)]
                              + [float(kind == CONTINUOUS) for kind in chain.kinds])
        work[surface:qp] = self.surface
        work[qp:end] = pin.neutral(model)
        self._work = work
        self.surface = work[surface:qp]                # packed surface (contact3d): edit in place
        self._x = work[x:xs]                           # the state [q, q']
        self._vs = work[xs + n:xs + 2 * n]             # the stage velocities, for aba
        self._tau = work[tau:total]                    # the torque held: command + robot's own
        self._total = work[total:contact]              # the stage's total joint torque
        self._contact = work[contact:joint]            # [f (3), depth, r' (3)]
        self._qp = work[qp:end]                        # Pinocchio's q of the stage
        self._none = np.empty(0)
        self._jacobian = _frame_jacobian if n > 1 else _frame_jacobian_of_one_joint
        self._tip_r = self._live_tip_position()
        self._fresh = False

    def _wrist_sensor(self, values: dict) -> None:
        """The wrist sensor's frame, packed tool (:func:`contact3d.packed_tool`), Pinocchio
        data of its own, noise and the buffer of its noise-free reading; ``_sensor`` is None
        for the ideal sensor."""
        force_std, torque_std = values["ft_noise_std"]
        self._ft_std = np.array([force_std] * 3 + [torque_std] * 3, dtype=float)
        self._ft_noisy = bool(np.any(self._ft_std))
        self._wrench = np.zeros(6)
        self._sensed = False
        tool = self.chain.tool
        if tool is None:
            self._sensor = None
            return
        model = self.model
        sensor = model.getFrameId(tool.sensor_link, pin.BODY)
        frame, tip = model.frames[sensor], model.frames[self._tip]
        assert frame.parentJoint == tip.parentJoint       # load_chain: the sensor rides on the tip
        point = frame.placement.actInv(tip.placement.translation)    # the tip in the sensor frame
        self._sensor = sensor
        self._sensor_data = model.createData()
        seen = 0.0 if values["sensor_removes_payload"] else 1.0    # the reading's tool
        self._packed_tool = contact3d.packed_tool(seen * tool.mass, tool.com,
                                                  seen * tool.inertia_matrix, point,
                                                  model.gravity.linear, values["ft_bias"])

    def _live_tip_position(self) -> np.ndarray | None:
        """A numpy view of ``data.oMf[tip].translation`` that follows every Jacobian
        computation (eigenpy maps it onto Pinocchio's memory), or None if this Pinocchio
        hands out copies (then every stage reads it anew)."""
        model, data, tip = self.model, self._data, self._tip
        pin.computeFrameJacobian(model, data, pin.neutral(model), tip, pin.LOCAL_WORLD_ALIGNED)
        view = data.oMf[tip].translation
        probe = self.chain.configuration(np.full(self._n, 0.3))
        pin.computeFrameJacobian(model, data, probe, tip, pin.LOCAL_WORLD_ALIGNED)
        live = np.array_equal(view, data.oMf[tip].translation) and not view.flags.owndata
        return view if live else None

    # -- model queries (Pinocchio; not on the hot path) ----------------------------------------
    def _q(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio's q for chain positions (the first n values of ``q``)."""
        return self.chain.configuration(np.asarray(q, dtype=float)[:self._n])

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """G(q) of the chain (N m); ``q`` may be the chain's positions or all of joint_names'."""
        return pin.computeGeneralizedGravity(self.model, self._query, self._q(q)).copy()

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q) of the chain, symmetric."""
        M = np.reshape(pin.crba(self.model, self._query, self._q(q)), (self._n, self._n))
        return np.triu(M) + np.triu(M, 1).T

    def tip_jacobian(self, q: np.ndarray) -> np.ndarray:
        """J_v(q) (3 x n): r' = J_v q' in the base frame."""
        J = pin.computeFrameJacobian(self.model, self._query, self._q(q), self._tip,
                                     pin.LOCAL_WORLD_ALIGNED)
        return J.reshape(6, -1)[:3].copy()

    def tip_position(self, q: np.ndarray) -> np.ndarray:
        """r(q): the tip's position in the base frame (m)."""
        return self.chain.tip_pose(np.asarray(q, dtype=float)[:self._n]).translation.copy()

    def kinetic_energy(self) -> float:
        """T = 1/2 q'^T M(q) q' now (J)."""
        q, v = self._x[:self._n], self._x[self._n:]
        return 0.5 * float(v @ self.mass_matrix(q) @ v)

    def surface_normal_at(self, r: np.ndarray) -> np.ndarray:
        """The outward unit normal of the surface nearest r (plane: n; sphere: (r - c)/|r - c|)."""
        s = self.surface
        if s[0] == contact3d.SPHERE:
            d = np.asarray(r, dtype=float) - s[1:4]
            dist = float(np.linalg.norm(d))
            return d / dist if dist > 0.0 else np.array([0.0, 0.0, 1.0])
        return s[4:7].copy()

    def stiffest_rate(self, q: np.ndarray) -> float:
        """omega_c (1/s) of the automatic substep rule at q (module docstring)."""
        Minv = np.linalg.inv(self.mass_matrix(q))
        joint = np.diag(self.chain.damping + self.chain.friction / JOINT_FRICTION_EPSILON)
        rates = [float(np.max(np.linalg.eigvals(Minv @ joint).real, initial=0.0))]
        s = self.surface
        if s[0] != contact3d.NONE:
            Jv = self.tip_jacobian(q)
            mobility = Jv @ Minv @ Jv.T                 # inverse apparent mass (3 x 3), 1/kg
            normal = self.surface_normal_at(self.tip_position(q))
            inv_mn = float(normal @ mobility @ normal)
            K, D, cv = s[8], s[9], s[11]
            rates.append(math.sqrt(K * inv_mn + (D * inv_mn) ** 2))
            rates.append(cv * float(np.linalg.eigvalsh(mobility)[-1]))
        return max(rates)

    def substeps_for(self, dt: float) -> int:
        """RK4 steps per period dt: ``substeps``, or if 0 the automatic rule
        max(1, ceil(dt omega_c / 0.5))."""
        if self.substeps > 0:
            return self.substeps
        if self._auto[0] != dt:
            self._auto = (dt, max(1, math.ceil(dt * self.step_rate / STEP_RATE_LIMIT - 1e-12)))
        return self._auto[1]

    # -- state and stepping --------------------------------------------------------------------
    def reset_state(self, q0, v0=None) -> None:
        """Put the chain at positions q0 (at rest unless velocities v0 are given), time and
        held command unchanged."""
        n = self._n
        q0 = np.asarray(q0, dtype=float)
        v0 = np.zeros(n) if v0 is None else np.asarray(v0, dtype=float)
        if q0.shape != (n,) or v0.shape != (n,):
            raise ValueError(f"reset_state needs {n} positions and {n} velocities")
        self._x[:n], self._x[n:] = q0, v0
        self._fresh = self._sensed = False
        if getattr(self, "_held", None) is not None:
            self._hold_with_robot_side()

    def _hold_with_robot_side(self) -> None:
        """The held torque: the held command plus what the robot adds at the current state
        (at start and after a reset too, so the sensors see the robot as it holds itself)."""
        if self._held is not self._tau:
            self._tau[:] = self._held + self.robot_torque()
            self._fresh = self._sensed = False

    def step(self, command: np.ndarray, dt: float) -> None:
        """Advance by dt with the joint torques ``command`` held (a refused command keeps the
        last): substeps_for(dt) classical RK4 steps, the contact force at every stage."""
        command = np.asarray(command, dtype=np.float64)
        take_command(self._held, command if command.ndim == 1 else self._none)
        self._hold_with_robot_side()
        substeps = self.substeps_for(dt)
        model, data, tip, frame = self.model, self._data, self._tip, pin.LOCAL_WORLD_ALIGNED
        work, qp, vs, total, r = self._work, self._qp, self._vs, self._total, self._tip_r
        aba, jacobian, convention = pin.aba, self._jacobian, pin.Convention.WORLD
        _begin(work, dt / substeps)
        for _ in range(4 * substeps):
            J = jacobian(model, data, qp, tip, frame)
            _joint_torque(J, data.oMf[tip].translation if r is None else r, work)
            _rk4_stage(aba(model, data, qp, vs, total, convention), work)
        self._t += dt
        self._fresh = self._sensed = False

    def _evaluate(self) -> None:
        """Contact force and depth at the current state (lazily, for the sensors)."""
        if self._fresh:
            return
        _begin(self._work, 0.0)
        J = self._jacobian(self.model, self._data, self._qp, self._tip, pin.LOCAL_WORLD_ALIGNED)
        r = self._tip_r if self._tip_r is not None else self._data.oMf[self._tip].translation
        _joint_torque(J, r, self._work)
        self._fresh = True

    # -- sensors -------------------------------------------------------------------------------
    def contact_force(self) -> np.ndarray:
        """The true (noise-free) contact force on the tip now, base frame (N)."""
        self._evaluate()
        return self._contact[:3].copy()

    def contact_depth(self) -> float:
        """Penetration depth of the tip now (m; negative: distance when separated)."""
        self._evaluate()
        return float(self._contact[3])

    def contact_force_magnitude(self) -> float:
        """|f| (N) of the true contact force (no noise drawn: for a force reflex)."""
        self._evaluate()
        fx, fy, fz = self._contact[0], self._contact[1], self._contact[2]
        return math.sqrt(fx * fx + fy * fy + fz * fz)

    def true_position(self) -> list[float]:
        """Joint positions in ``joint_names`` order without noise (no noise is drawn)."""
        return [*self._x[:self._n].tolist(), *self._locked_q.tolist()]

    def true_velocity(self) -> list[float]:
        """Joint velocities in ``joint_names`` order without noise (the locked ones: 0)."""
        return [*self._x[self._n:].tolist(), *[0.0] * self._locked_q.size]

    def contact_wrench(self) -> ContactWrench:
        """The true (noise-free) contact wrench on the tool now, base frame: the contact force,
        zero torque about the tip (a point contact) and the tip's position
        (``/plant/contact_wrench``: for analysis and tests, no controller reads it)."""
        self._evaluate()
        r = self._tip_r if self._tip_r is not None else self._data.oMf[self._tip].translation
        return ContactWrench(self._contact[:3].copy(), np.zeros(3), np.array(r, dtype=float))

    def sensor_wrench(self) -> np.ndarray:
        """The wrist sensor's reading now without noise (6: force N, torque N m, in
        ``wrench_frame``; bias included; module docstring); the ideal sensor: the contact
        force and zero torque."""
        if self._sensed:
            return self._wrench.copy()
        self._evaluate()
        if self._sensor is None:
            self._wrench[:3], self._wrench[3:] = self._contact[:3], 0.0
        else:
            # q'' at this state (held command, contact), then the sensor frame's motion
            model, data, frame, local = self.model, self._sensor_data, self._sensor, pin.LOCAL
            a = pin.aba(model, data, self._qp, self._vs, self._total, pin.Convention.WORLD)
            pin.forwardKinematics(model, data, self._qp, self._vs, a)
            R = pin.updateFramePlacement(model, data, frame).rotation
            contact3d.wrist_wrench_into(R, pin.getFrameVelocity(model, data, frame, local).vector,
                                        pin.getFrameAcceleration(model, data, frame, local).vector,
                                        self._contact, self._packed_tool, self._wrench)
        self._sensed = True
        return self._wrench.copy()

    @property
    def applied_effort(self) -> np.ndarray:
        """The joint torques held now: the last accepted command plus, on a robot that adds
        them, its own gravity and friction compensation (what the joints' torque sensors read
        and ``/joint_states`` reports as effort)."""
        return self._tau.copy()

    def robot_torque(self) -> np.ndarray:
        """What the robot adds to a command at the current state (zeros when it adds nothing):
        G(q) with ``robot_compensates_gravity``, D q' + F tanh(q'/eps_q) with
        ``robot_compensates_friction``."""
        n = self._n
        q, v = self._x[:n], self._x[n:]
        out = np.zeros(n)
        if self.robot_compensates_gravity:
            out += self.gravity(q)
        if self.robot_compensates_friction:
            out += self.chain.damping * v + self.chain.friction * np.tanh(v / JOINT_FRICTION_EPSILON)
        return out

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """The command that holds the chain against gravity: G(q), or zeros on a robot that
        adds G(q) itself (``robot_compensates_gravity``)."""
        return np.zeros(self._n) if self.robot_compensates_gravity else self.gravity(q)

    def measurement(self) -> Measurement:
        """Joint state (noise on the chain's joints) and the wrench in ``wrench_frame``: the
        ideal sensor's contact force (``force_noise_std``), or the wrist sensor's reading
        (:meth:`sensor_wrench`, ``ft_noise_std``)."""
        n, x, locked = self._n, self._x, self._locked_q.size
        q, v = x[:n].copy(), x[n:].copy()
        ideal = self._sensor is None
        if ideal:
            force, torque = self.contact_force(), np.zeros(3)
        else:
            wrench = self.sensor_wrench()
            if self._ft_noisy:
                wrench += self._ft_std * self._rng.standard_normal(6)
            force, torque = wrench[:3], wrench[3:]
        if self._noisy:
            q_std, v_std, f_std = self._noise
            q += q_std * self._rng.standard_normal(n)
            v += v_std * self._rng.standard_normal(n)
            if ideal:
                force += f_std * self._rng.standard_normal(3)
        if self._wrench_sign < 0.0:
            force, torque = -force, -torque
        zeros = np.zeros(locked)
        return Measurement(self._t, np.concatenate([q, self._locked_q]),
                           np.concatenate([v, zeros]), np.concatenate([self._tau, zeros]), force,
                           torque)

    # -- limits and brakes ---------------------------------------------------------------------
    def joint_limits(self) -> JointLimits:
        """The chain's URDF limits (inf where none is given)."""
        limits = self.chain.limits
        return JointLimits(limits.effort.copy(), limits.velocity.copy(), limits.lower.copy(),
                           limits.upper.copy())

    def begin_safe_stop(self) -> None:
        """Engage the brakes: remember where the chain's joints come to rest
        (:meth:`~cr_sim.plants.base.Plant.brake_stop_position`, from the measured state)."""
        m, n = self.measurement(), self._n
        self._brake_hold = self.brake_stop_position(m.position[:n], m.velocity[:n])

    def safe_stop_command(self) -> np.ndarray:
        """The base class's brakes on the chain's joints (the locked ones take no command):
        tau = G(q) - M(q) (2 w_b q' + w_b^2 (q - q_stop)) with the chain's mass matrix
        (tool included), without G(q) on a robot that adds it itself (:meth:`gravity_torque`)."""
        m, n = self.measurement(), self._n
        q, v = m.position[:n], m.velocity[:n]
        hold = self._brake_hold if self._brake_hold is not None else self.brake_stop_position(q, v)
        return brake_torque(self.mass_matrix(q), self.gravity_torque(q), q, v, hold,
                            self.brake_frequency)
